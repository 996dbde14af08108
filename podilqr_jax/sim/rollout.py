"""The rollout engine: every closed-loop rollout of the package, batched through MJX.

One scan skeleton, :func:`run`, runs every rollout: the sysid batches, the
line search, the training-time true cost, the Monte Carlo episodes and the
receding-horizon segments. It takes a *controller* (``start``, ``command``,
``advance`` and a per-step ``schedule``) and one noise realisation,
:class:`~podilqr_jax.task.noise.Disturbance` ``(dx0, w, v, a)``:

- :class:`InfoStateFeedback`, the training rollouts' controller,

    u_t = clip(u_bar_t + offset_t + K_t (Z_t - Z_bar_t) + du_t)

  clamped to the model's ctrlrange as MuJoCo clamps ``ctrl``; the recorded u
  is the applied, clamped control, so the fit sees what acted. Z_t is the
  information state built online from the rollout's own measurements and
  applied controls (see ``info_state``). Sysid rollouts use ``offset = 0`` and
  ``du ~ N(0, sigma^2 I)``; line-search rollouts use ``offset = alpha k`` and
  ``du = 0``; with ``K = 0`` the rollout is open loop (:func:`simulate`).
- the estimator recursion of a :class:`~podilqr_jax.control.policy.Controller` (a
  learnt policy, raw or Kalman-filtered), run by ``episodes``.

A batch is one ``vmap`` (:func:`run_batch`) over the leading axis of whichever
inputs carry one; nothing loops over rollouts in Python.

Scale (benchmarks/journal.md): with several devices (``jax.devices()``: GPUs,
or CPU devices from ``XLA_FLAGS=--xla_force_host_platform_device_count=N``,
or every host's devices after ``jax.distributed.initialize()``) the sysid and
line-search batches are sharded over a one-axis device mesh (``batch_sharding``)
when the batch divides evenly; every rollout runs the same operations as on
one device, so the results are the same. A sysid batch larger than ``chunk``
rollouts runs as a ``lax.map`` over chunks of whole repeat groups, so memory
grows with the chunk, not with n_s x n_avg.

Noise (see ``noise``): with a :class:`~podilqr_jax.task.noise.Disturbance` per
rollout the start state is x0 (+) dx_0, the process noise w_t is written into
``qpos``/``qvel`` after each control step (x (+) w_t: on a free or ball
joint's quaternion a rotation, ``tangent.integrate``) and the measurement noise v_t is
added to every measurement; the controller sees the measured (noisy) values.
:func:`simulate` returns the measured observations (what the fit sees) and
the true states ``x``; the episodes return the true observations (what the
cost is of). Without noise (``None``) a rollout is deterministic and draws nothing.

Shapes: u_bar [T, nu], Z_bar [T, nZ], K [T, nu, nZ]; per rollout z [T+1, nz],
u [T, nu] and, when recorded, x = [qpos, qvel] [T+1, nx].
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from mujoco import mjx

from ..compilation import xla_options
from ..compilation.stages import stage
from ..errors import ModelLoadError
from ..identify.info_state import initial_info_state, shift
from ..task import tangent
from ..task.env import EnvData, EnvDims, MJXUnavailable
from ..task.noise import Disturbance, sample
from . import native, rk4


class Policy(NamedTuple):
    """Nominal controls with affine feedback on the information state."""

    u_bar: jnp.ndarray  # [T, nu]
    Z_bar: jnp.ndarray  # [T, nZ]
    K: jnp.ndarray  # [T, nu, nZ]


class Trajectory(NamedTuple):
    """A (batch of) rollout(s)."""

    z: jnp.ndarray  # [..., T+1, nz] observations (as measured)
    u: jnp.ndarray  # [..., T, nu] applied controls
    x: Optional[jnp.ndarray]  # [..., T+1, nx] states, when recorded


def open_loop_policy(u_bar: jnp.ndarray, nZ: int) -> Policy:
    """A policy with no feedback: u_t = u_bar_t."""
    T, nu = u_bar.shape
    return Policy(u_bar, jnp.zeros((T, nZ), u_bar.dtype), jnp.zeros((T, nu, nZ), u_bar.dtype))


@functools.partial(jax.jit, static_argnames=("dims", "mj_step"))
def physics_step(dims: EnvDims, model, d, u: jnp.ndarray, mj_step=None):
    """One control step: hold ``u`` for ``dims.substeps`` MuJoCo steps.

    Returns data of the same dtypes as ``d``, so that the loops carrying it
    (this one and the rollouts' scans) keep one carry type: with x64 on, MJX's
    tendon stage writes its wrap indices (``ten_wrapadr``, ``ten_wrapnum``,
    ``wrap_obj``) as int64 where ``mjx.make_data`` made them int32.

    An RK4 model steps through ``rk4.step`` (MuJoCo's RK4 with one compiled
    copy of the forward dynamics instead of ``mjx.step``'s four), anything
    else through ``mjx.step``; ``mj_step`` overrides the choice (the compile
    comparison of benchmarks/third_party_compile.py passes ``mjx.step``).
    """
    if dims.native is not None:
        return native.step(dims.native, dims.substeps, d, u)
    _runs_on_mjx(model)
    if mj_step is None:
        mj_step = rk4.step if rk4.applies(model) else mjx.step

    def one_step(_, dd):
        return jax.tree_util.tree_map(lambda new, old: new.astype(old.dtype), mj_step(model, dd), dd)

    return jax.lax.fori_loop(0, dims.substeps, one_step, d.replace(ctrl=u))


def make_data(model):
    """``mjx.make_data`` for ``model`` in the model's own MJX implementation
    (``jax`` or ``warp``, see ``SolverConfig.impl``)."""
    _runs_on_mjx(model)
    return mjx.make_data(model, impl=getattr(model, "impl", None))


def _runs_on_mjx(model) -> None:
    """Refuse, with MJX's reason, a model MJX cannot convert (``task.env.MJXUnavailable``)."""
    if isinstance(model, MJXUnavailable):
        raise ModelLoadError(model.message)


def start_data(dims: EnvDims, data: EnvData):
    """A rollout's first carry on the engine of ``dims``: MJX data, or the
    native engine's :class:`~podilqr_jax.sim.native.NativeData` (its state
    is overwritten with the start state by :func:`with_state`)."""
    if dims.native is not None:
        return native.start_data(dims.native, data.x0.dtype)
    return make_data(data.model)


def observe(dims: EnvDims, data: EnvData, d, x: jnp.ndarray) -> jnp.ndarray:
    """z = C x (+ D sensordata, with the sensors recomputed at the state of ``d``)."""
    z = data.C @ x
    if dims.sensors:
        if dims.native is not None:
            return z + data.D @ native.sensordata(dims.native, d)
        z = z + data.D @ mjx.forward(data.model, d).sensordata
    return z


@xla_options.jit(static_argnames=("dims",))
def observations_of(dims: EnvDims, data: EnvData, x: jnp.ndarray) -> jnp.ndarray:
    """The noise-free observations of states x [N, nx] (sensors recomputed)."""
    d0 = start_data(dims, data)
    return jax.vmap(lambda x_i: observe(dims, data, with_state(dims, d0, x_i), x_i))(x)


def state_of(d) -> jnp.ndarray:
    """x = [qpos, qvel, act] of ``d`` (``act`` is empty on a model without activations)."""
    return jnp.concatenate([d.qpos, d.qvel, d.act])


def with_state(dims: EnvDims, d, x: jnp.ndarray):
    """``d`` at the state x = [qpos, qvel, act]."""
    nq, nv = dims.nq, dims.nv
    if not dims.na:
        return d.replace(qpos=x[:nq], qvel=x[nq:])
    return d.replace(qpos=x[:nq], qvel=x[nq : nq + nv], act=x[nq + nv :])


@dataclasses.dataclass(frozen=True)
class InfoStateFeedback:
    """The training rollouts' controller: u_t = u_bar_t + offset_t +
    K_t (Z_t - Z_bar_t) + du_t, with Z_t the information state of the
    rollout's own measurements and applied controls (``info_state``, ``q``
    past measurements; the carry of :func:`run` is Z_t)."""

    policy: Policy
    offset: jnp.ndarray  # [T, nu]
    du: jnp.ndarray  # [T, nu]
    q: int  # static

    def schedule(self, steps: int):
        return (self.policy.u_bar, self.policy.Z_bar, self.policy.K, self.offset, self.du)

    def start(self, m0: jnp.ndarray) -> jnp.ndarray:
        return initial_info_state(m0, self.policy.u_bar.shape[-1], self.q)

    def command(self, Z: jnp.ndarray, s) -> jnp.ndarray:
        u_bar_t, Z_bar_t, K_t, offset_t, du_t = s
        return u_bar_t + offset_t + K_t @ (Z - Z_bar_t) + du_t

    def advance(self, Z: jnp.ndarray, s, u: jnp.ndarray, m: jnp.ndarray) -> jnp.ndarray:
        return shift(Z, m, u, m.shape[0], u.shape[0], self.q)


jax.tree_util.register_dataclass(InfoStateFeedback, data_fields=["policy", "offset", "du"], meta_fields=["q"])


def run(
    dims: EnvDims,
    data: EnvData,
    controller,
    disturbance: Optional[Disturbance],
    x_start: jnp.ndarray,
    d,
    limits,
    *,
    steps: Optional[int] = None,
    measures_state: bool = False,
    record_measured: bool = False,
    record_state: bool = False,
) -> Trajectory:
    """One closed-loop rollout of ``steps`` control steps (default: the
    horizon): the one scan skeleton every rollout of the package runs.

    From the true start state x_0 = x_start (+) dx_0 (``tangent.integrate``), at every step t

      m_t     = z_t (or x_t, ``measures_state``) + v_t   what the controller measures
      u_t     = clip(controller.command(c_t, s_t), limits)
      x_{t+1} = f(x_t, u_t + a_t) (+) w_t                  ``substeps`` MuJoCo steps
      c_{t+1} = controller.advance(c_t, s_t, u_t, m_{t+1})

    with c_0 = controller.start(m_0) and s_t the controller's schedule at t
    (its per-step arrays, or t itself). The controller is the information-state
    feedback of the training rollouts (:class:`InfoStateFeedback`) or the
    estimator recursion of a :class:`~podilqr_jax.control.policy.Controller`; the noise
    is one :class:`~podilqr_jax.task.noise.Disturbance` (None: deterministic).
    ``d`` is MJX data to start from (its state is overwritten).

    Returns the true observations z [S+1, nz] (with ``record_measured``: the
    measurements m, what the controller saw), the commanded (clipped)
    controls u [S, nu] and, with ``record_state``, the true states x [S+1, nx].
    """
    model = data.model
    steps = dims.horizon if steps is None else steps
    dist = Disturbance() if disturbance is None else disturbance
    x0 = x_start if dist.dx0 is None else tangent.integrate(dims, x_start, dist.dx0)
    d = with_state(dims, d, x0)
    v_now, v_next = (None, None) if dist.v is None else (dist.v[0], dist.v[1:])

    def measured(z, x, v_t):
        m = x if measures_state else z
        return m if v_t is None else m + v_t

    z0 = observe(dims, data, d, x0)
    m0 = measured(z0, x0, v_now)
    c0 = controller.start(m0)

    def step(carry, inp):
        d, c = carry
        s, w_t, v_t, a_t = inp
        u = jnp.clip(controller.command(c, s), *limits)
        d = physics_step(dims, model, d, u if a_t is None else u + a_t)
        if w_t is not None:
            d = with_state(dims, d, tangent.integrate(dims, state_of(d), w_t))
        x = state_of(d)
        z = observe(dims, data, d, x)
        m = measured(z, x, v_t)
        c = controller.advance(c, s, u, m)
        return (d, c), (m if record_measured else z, u, x if record_state else None)

    _, (z, u, x) = jax.lax.scan(step, (d, c0), (controller.schedule(steps), dist.w, v_next, dist.a), length=steps)
    z = jnp.concatenate([(m0 if record_measured else z0)[None], z])
    if record_state:
        x = jnp.concatenate([x0[None], x])
    return Trajectory(z, u, x)


def run_batch(
    dims: EnvDims,
    data: EnvData,
    controller,
    disturbance: Optional[Disturbance],
    x_start: jnp.ndarray,
    limits,
    *,
    batch: int,
    in_axes,
    **options,
) -> Trajectory:
    """``batch`` rollouts of :func:`run` as one ``vmap``: ``in_axes`` (for
    controller, disturbance and x_start, as ``jax.vmap`` takes them) says
    which carry a leading batch axis; ``options`` go to :func:`run`.

    Every rollout starts from its own copy of MJX's data and of the start
    state: with the scan's whole carry (MJX data, the controller's state)
    batched from the first step, vmap batches the step's jaxpr once. A carry
    that starts shared and becomes batched after one step makes the scan's
    batching rule run twice, and so the one of the substeps' loop inside it:
    a shared start state alone (every noiseless batch) made the model-based
    line search of doublependulum-partial trace in 2.8-3.1 s (three cold runs)
    instead of 1.9-2.6 s (four; ``jax_log_compiles``).
    """
    d0 = start_data(dims, data)
    d_init = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (batch,) + a.shape), d0)
    *axes, x_axis = in_axes
    if x_axis is None:
        x_start = jnp.broadcast_to(x_start, (batch,) + x_start.shape)

    def one(c, dist, x_i, d_i):
        return run(dims, data, c, dist, x_i, d_i, limits, **options)

    return jax.vmap(one, in_axes=(*axes, 0, 0))(controller, disturbance, x_start, d_init)


def simulate(
    dims: EnvDims,
    q: int,
    data: EnvData,
    policy: Policy,
    offset: jnp.ndarray,
    du: jnp.ndarray,
    record_state: bool = False,
    noise: Optional[Disturbance] = None,
) -> Trajectory:
    """The training rollouts (traceable; call it inside a jitted function):
    :func:`run` with :class:`InfoStateFeedback`, clamped to the model's
    ctrlrange, from the task's x0, returning the *measured* observations
    z + v (what the fit sees).

    ``offset`` and ``du`` are each either shared, [T, nu], or per rollout,
    [B, T, nu]; ``noise``, when given, is per rollout (leading axis B). The
    batch size B is taken from whichever is batched.
    """
    in_offset = 0 if offset.ndim == 3 else None
    in_du = 0 if du.ndim == 3 else None
    in_noise = None if noise is None else 0
    limits = (data.u_low, data.u_high)
    controller = InfoStateFeedback(policy, offset, du, q)
    options = dict(record_measured=True, record_state=record_state)
    if in_offset is None and in_du is None and in_noise is None:
        return run(dims, data, controller, None, data.x0, start_data(dims, data), limits, **options)
    batched = (offset if in_offset == 0 else None, du if in_du == 0 else None, noise)
    batch = jax.tree_util.tree_leaves(batched)[0].shape[0]
    axes = (InfoStateFeedback(None, in_offset, in_du, q), in_noise, None)
    return run_batch(dims, data, controller, noise, data.x0, limits, batch=batch, in_axes=axes, **options)


def average_repeats(traj: Trajectory, n_avg: int) -> Trajectory:
    """Mean over consecutive groups of ``n_avg`` rollouts: [B n_avg, ...] -> [B, ...]."""
    if n_avg == 1:
        return traj

    def mean(a):
        return None if a is None else a.reshape((-1, n_avg) + a.shape[1:]).mean(axis=1)

    return Trajectory(mean(traj.z), mean(traj.u), mean(traj.x))


def _batch_mesh() -> Mesh:
    """Every device on one axis, ``batch``."""
    return Mesh(np.array(jax.devices()), ("batch",))


def batch_sharding(batch: int) -> Optional[NamedSharding]:
    """The batch axis split over every device (a one-axis mesh), or None when
    there is one device or ``batch`` does not divide evenly (then the batch
    stays on the default device)."""
    devices = jax.devices()
    if len(devices) == 1 or batch % len(devices):
        return None
    return NamedSharding(_batch_mesh(), PartitionSpec("batch"))


def replicated():
    """Where the driver puts its arrays: the default device, or replicated over
    every device of the batch mesh when there are several (arrays committed to
    one device cannot meet a batch sharded over all of them)."""
    devices = jax.devices()
    if len(devices) == 1:
        return jax.sharding.SingleDeviceSharding(devices[0])
    return NamedSharding(_batch_mesh(), PartitionSpec())


def on_device(x):
    """``x`` committed to the default device (replicated over all devices when
    there are several, see ``rollout.replicated``): a number or NumPy array becomes a
    float64 (or float32) array, a pytree of arrays (``EnvData``) keeps its types.

    Driver-made arrays must be committed like the jitted stages' outputs they
    alternate with: JAX keys its compilation cache on whether an argument is
    committed, and mixing the two compiles every stage twice.

    With several processes (``jax.distributed``) every process holds the same
    values (the same task, settings and seed, or a replicated stage output):
    each places its own host copy on its devices, and nothing crosses hosts.
    """
    if isinstance(x, (int, float, np.ndarray, np.generic)):
        x = jnp.asarray(x, dtype=jnp.result_type(float))
    if jax.process_count() > 1:
        x = jax.tree_util.tree_map(lambda a: np.asarray(a) if isinstance(a, jax.Array) else a, x)
    return jax.device_put(x, replicated())


def shard_batch(tree, batch: int, dims: Optional[EnvDims] = None):
    """Constrain every array of ``tree`` (leading axis ``batch``) to ``batch_sharding``;
    not on the native engine (``dims.native``), whose batches run on this host's cores."""
    sharding = batch_sharding(batch)
    if sharding is None or tree is None or (dims is not None and dims.native is not None):
        return tree
    return jax.tree_util.tree_map(lambda a: jax.lax.with_sharding_constraint(a, sharding), tree)


def bytes_per_rollout(dims: EnvDims, data: EnvData, noisy: bool = True, record_state: bool = False) -> int:
    """A conservative estimate of the memory one sysid rollout holds while it
    runs: its MJX data (carry and a step's temporaries, counted 8 times), its
    inputs and outputs (with ``record_state``, as in the line search, also
    its states). Used to turn a memory budget into a chunk size; the
    benchmark (benchmarks/journal.md) measures the real peak."""
    if dims.native is not None:  # the carry is MuJoCo's state vector; MjData lives on the host, per thread
        mjx_bytes = 8 * dims.native.nstate
    else:
        shapes = jax.tree_util.tree_leaves(jax.eval_shape(make_data, data.model))  # no device memory touched
        mjx_bytes = sum(int(np.prod(a.shape)) * np.dtype(a.dtype).itemsize for a in shapes)
    T, nx = dims.horizon, dims.nx
    floats = (T + 1) * dims.nz + 2 * T * dims.nu  # z, u, du
    if noisy:
        floats += dims.ndx + T * dims.ndx + (T + 1) * dims.nz  # dx0, w, v
    if record_state:
        floats += (T + 1) * nx  # x
    return int(8 * mjx_bytes + 8 * floats)


rollout_batch = xla_options.jit(simulate, static_argnames=("dims", "q", "record_state"))
rollout_batch.__doc__ = """Jitted :func:`simulate`: a batch of rollouts for given perturbations ``du``
[B, T, nu] (and/or offsets), returning observations z [B, T+1, nz] and applied
controls u [B, T, nu] (and states x when ``record_state``)."""


@functools.partial(jax.jit, static_argnames=("n_s", "horizon", "nu", "dtype"))
def injected_perturbations(key: jax.Array, sigma, n_s: int, horizon: int, nu: int, dtype=None) -> jnp.ndarray:
    """The sysid perturbations du [n_s, T, nu] that ``perturbation_rollouts`` injects for ``key``."""
    dtype = dtype or jnp.result_type(float)
    return sigma * jax.random.normal(key, (n_s, horizon, nu), dtype=dtype)


@stage(static_argnames=("dims", "q", "n_s", "n_avg", "noisy", "chunk", "mirrored"), outputs=(Trajectory,))
def perturbation_rollouts(
    dims: EnvDims,
    q: int,
    n_s: int,
    data: EnvData,
    policy: Policy,
    key: jax.Array,
    sigma: jnp.ndarray,
    n_avg: int = 1,
    noisy: bool = False,
    chunk: Optional[int] = None,
    mirrored: bool = False,
) -> Trajectory:
    """The sysid rollouts: u = u_bar + K dZ + du with du ~ N(0, sigma^2 I).

    ``n_s`` perturbation sequences; with ``n_avg`` > 1 each runs ``n_avg`` times
    (different noise, one batch of n_s x n_avg rollouts) and the mean of its
    repeats (observations and applied controls) is returned, [n_s, ...]. With
    ``noisy`` every rollout draws the noise of ``data.noise``.

    With ``mirrored`` each sequence also runs as ``-du`` (2 n_s x n_avg
    rollouts, each with its own noise) and the *half-differences*
    ``((z+ - z-) / 2, (u+ - u-) / 2)`` are returned: deviations from the
    nominal, not trajectories (fit them against a zero nominal, see
    ``sysid``). The response's even-order terms in du are the same for both
    signs and cancel, so the fit's curvature bias drops from O(sigma) to
    O(sigma^2); and the nominal's own measurement, with its noise, is never
    subtracted.

    With ``chunk`` < the batch, it runs as a ``lax.map`` over chunks of
    ``chunk // n_avg`` perturbation sequences (``_chunked``): the same du, and
    under noise per-sequence noise keys, so the result does not depend on the
    chunk size (it draws different noise than the single batch, from the same
    distribution).
    """
    du = injected_perturbations(key, sigma, n_s, dims.horizon, dims.nu, policy.u_bar.dtype)
    noise_key = jax.random.fold_in(key, 1)
    if mirrored:
        pair = _sequences(dims, q, data, policy, jnp.concatenate([du, -du]), noise_key, n_avg, noisy, chunk)
        return Trajectory((pair.z[:n_s] - pair.z[n_s:]) / 2, (pair.u[:n_s] - pair.u[n_s:]) / 2, None)
    return _sequences(dims, q, data, policy, du, noise_key, n_avg, noisy, chunk)


def _sequences(dims, q, data, policy, du, noise_key, n_avg, noisy, chunk) -> Trajectory:
    """Roll out each sequence of ``du`` [n, T, nu] ``n_avg`` times and average its repeats."""
    n = du.shape[0]
    if chunk is not None and n * n_avg > chunk:
        return _chunked(dims, q, data, policy, du, noise_key, n_avg, noisy, max(1, chunk // n_avg))
    if n_avg > 1:
        du = jnp.repeat(du, n_avg, axis=0)
    batch = n * n_avg
    noise = sample(noise_key, data.noise, batch, dims.horizon) if noisy else None
    du, noise = shard_batch((du, noise), batch, dims)
    zero = jnp.zeros((dims.horizon, dims.nu), policy.u_bar.dtype)
    return average_repeats(simulate(dims, q, data, policy, zero, du, noise=noise), n_avg)


def _chunked(dims, q, data, policy, du, noise_key, n_avg, noisy, per_chunk) -> Trajectory:
    """The sysid batch as a ``lax.map`` over chunks of ``per_chunk`` sequences,
    each sequence's ``n_avg`` repeats averaged inside its chunk."""
    T, nu = dims.horizon, dims.nu
    zero = jnp.zeros((T, nu), policy.u_bar.dtype)

    def one(args):
        du_j, key_j = args
        noise = sample(key_j, data.noise, n_avg, T) if noisy else None
        traj = simulate(dims, q, data, policy, zero, jnp.broadcast_to(du_j, (n_avg, T, nu)), noise=noise)
        return traj.z.mean(axis=0), traj.u.mean(axis=0)

    keys = jax.random.split(noise_key, du.shape[0])
    z, u = jax.lax.map(one, (du, keys), batch_size=per_chunk)
    return Trajectory(z, u, None)
