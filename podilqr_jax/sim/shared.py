"""One compiled rollout program for the sysid batch and the line search.

On a CPU most of a cold solve's wait is XLA compiling the rollouts: the
sysid batch (``rollout.perturbation_rollouts``) and the line search
(``ilqr.line_search``) each hold their own copy of the vmapped MJX step, and
for a contact-rich model each copy compiles for seconds to tens of seconds
(benchmarks/journal.md). Both run the same closed-loop rollout

  u_t = clip(u_bar_t + offset_t + K_t (Z_t - Z_bar_t) + du_t),

the sysid batch with ``offset = 0`` and a perturbation ``du`` per rollout,
the line search with ``offset = alpha k`` per candidate and ``du = 0``; only
the batch sizes differ. So where it pays, the solver compiles that rollout
once, as :func:`rollout_group` of ``width`` rollouts, the line search's batch
((n_alphas [+1 under noise]) x n_forward), and runs

- the line search as one call of it, between a small program that makes its
  inputs and one that averages the repeats and picks the candidate
  (``line_search.line_search_grouped``);
- the sysid batch (n_s x n_avg rollouts, twice that mirrored) as
  ceil(batch / width) calls of it, the last one padded with zero
  perturbations, between :func:`sysid_inputs` and :func:`sysid_outcome`
  (:func:`perturbation_rollouts`).

The perturbations, the noise and the rollouts are those of the fused stages,
drawn from the same keys, so a solve gives the same numbers either way (to
round-off: XLA may order a few operations differently in another program;
tests/test_shared_rollouts.py measures it). A switch to the mirrored
experiment only adds calls of the same program.

When: :func:`width` says, once per solve, from ``PODILQR_SHARED_ROLLOUTS``
(read per solve):

- unset or ``auto``: where the sysid batch runs as *one* call, padded by
  at most a quarter (the averaged variant's n_s x n_avg = 400 sysid rollouts
  in the line search's 440), and, for a model whose MJX step carries at
  least ``MANY_ROWS`` constraint rows (``contacts.constraint_rows``),
  also in up to ``MAX_GROUPS`` calls, again padded by at most a quarter in
  all (n_s = 40 in 4 calls of 10; not n_s = 12 in 2 calls). Splitting the
  sysid batch into calls costs run time where a rollout is cheap: a call of
  a small batch costs nearly what a larger one does (the per-operation
  overhead of a scan of small operations, the constraint solver's loops
  running to the slowest rollout), so the 4 calls of 10 that replace one of 40 made an iteration
  1.2-1.7x slower on the bundled tasks and dm_control's cart-pole (0-1
  rows; benchmarks/journal.md), every iteration of every run, while the
  compile they save is paid once per machine (the persistent cache keeps
  it). Where the constraint solver carries contact rows a rollout costs far
  more than a call's overhead: dmc_finger_turn (93 rows) and Gymnasium's
  hopper (38) iterate no slower in 4 calls (0.95 and 0.93 of the time) and
  compile in 0.65 and 0.75 of it. Every model the project has measured has
  either at most 3 rows (no contacts) or at least 38.
- ``1`` or ``on``: up to ``MAX_GROUPS`` calls whatever the model: the
  fastest first result for a cold run, at the run-time cost above on small
  models.
- ``0`` or ``off``: never. Anything else warns and means ``auto``.

In every case only on one CPU device (on a GPU a small batch is bound by
latency; over several devices the sysid batch is sharded whole), for
POD-iLQR, and where neither batch runs in chunks under the memory budget.
The model-based reference has no sysid batch and keeps its one line-search
program (on a contact-rich model it computes its Jacobians one JVP at a
time instead: ``contacts.one_at_a_time``).
"""

from __future__ import annotations

from typing import Optional

import jax
import jax.numpy as jnp

from .. import environment
from ..task.env import EnvData, EnvDims
from ..task.noise import Disturbance, sample
from .contacts import many_rows
from .rollout import Policy, Trajectory, average_repeats, injected_perturbations, shard_batch, simulate
from .stages import stage

ENV_SWITCH = environment.SHARED_ROLLOUTS
MAX_GROUPS = 8  # calls of the shared program per sysid batch (not mirrored), at most


def width(
    n_s: int, n_avg: int, ls_rollouts: int, sysid_chunk: Optional[int], ls_chunk: Optional[int], rows: int = 0
) -> Optional[int]:
    """The shared program's batch (the line search's ``ls_rollouts``), or None
    where the stages keep their own rollouts (module docstring); ``rows``:
    the model's ``contacts.constraint_rows``."""
    setting = environment.choice(ENV_SWITCH, "auto", {"auto": "auto"})
    if setting == "off" or jax.default_backend() != "cpu" or jax.device_count() > 1:
        return None
    batch = n_s * n_avg
    if (sysid_chunk is not None and batch > sysid_chunk) or (ls_chunk is not None and ls_rollouts > ls_chunk):
        return None
    calls = groups(batch, ls_rollouts)
    if setting == "on":
        return ls_rollouts if calls <= MAX_GROUPS else None
    # By itself: one call, or several on a contact model, padded by at most a
    # quarter in all (a padding rollout costs what a sysid rollout does).
    most = MAX_GROUPS if many_rows(rows) else 1
    return ls_rollouts if calls <= most and calls * ls_rollouts <= 1.25 * batch else None


def groups(batch: int, width: int) -> int:
    """Calls of a ``width``-rollout program that run ``batch`` rollouts."""
    return -(-batch // width)


@stage(static_argnames=("dims", "q"), outputs=(Trajectory,))
def rollout_group(
    dims: EnvDims,
    q: int,
    data: EnvData,
    policy: Policy,
    offset: jnp.ndarray,
    du: jnp.ndarray,
    noise: Optional[Disturbance] = None,
) -> Trajectory:
    """``width`` closed-loop rollouts (``rollout.simulate``), one per row of
    ``offset`` and ``du`` [width, T, nu] (and of ``noise``), with the
    states recorded: the program the sysid batch and the line search share."""
    batch = offset.shape[0]
    offset, du, noise = shard_batch((offset, du, noise), batch, dims)
    return simulate(dims, q, data, policy, offset, du, record_state=True, noise=noise)


@stage(static_argnames=("dims", "n_s", "n_avg", "noisy", "mirrored", "width"), outputs=(Disturbance,))
def sysid_inputs(
    dims: EnvDims,
    n_s: int,
    data: EnvData,
    key: jax.Array,
    sigma: jnp.ndarray,
    n_avg: int = 1,
    noisy: bool = False,
    mirrored: bool = False,
    width: int = 1,
) -> tuple[tuple, tuple]:
    """The sysid batch's perturbations and noise, drawn as the fused stage
    draws them, in ``groups`` of ``width`` rows (the last padded with zeros):
    (du [width, T, nu] per group, the noise per group or Nones)."""
    du = injected_perturbations(key, sigma, n_s, dims.horizon, dims.nu, sigma.dtype)
    if mirrored:
        du = jnp.concatenate([du, -du])
    if n_avg > 1:
        du = jnp.repeat(du, n_avg, axis=0)
    batch = du.shape[0]
    m = groups(batch, width)

    def split(a):
        a = jnp.pad(a, [(0, m * width - batch)] + [(0, 0)] * (a.ndim - 1))
        return [a[i * width : (i + 1) * width] for i in range(m)]

    if not noisy:
        return tuple(split(du)), (None,) * m
    noise = sample(jax.random.fold_in(key, 1), data.noise, batch, dims.horizon)
    fields = [[None] * m if a is None else split(a) for a in noise]
    return tuple(split(du)), tuple(Disturbance(*(f[i] for f in fields)) for i in range(m))


@stage(static_argnames=("n_s", "n_avg", "mirrored"), outputs=(Trajectory,))
def sysid_outcome(parts: tuple, n_s: int, n_avg: int = 1, mirrored: bool = False) -> Trajectory:
    """The sysid batch's result from its groups' rollouts, as the fused stage
    returns it: repeats averaged, mirrored pairs as half-differences."""
    batch = n_s * n_avg * (2 if mirrored else 1)
    z = jnp.concatenate([p.z for p in parts])[:batch]
    u = jnp.concatenate([p.u for p in parts])[:batch]
    traj = average_repeats(Trajectory(z, u, None), n_avg)
    if mirrored:
        return Trajectory((traj.z[:n_s] - traj.z[n_s:]) / 2, (traj.u[:n_s] - traj.u[n_s:]) / 2, None)
    return traj


def perturbation_rollouts(
    dims: EnvDims,
    q: int,
    n_s: int,
    data: EnvData,
    policy: Policy,
    key: jax.Array,
    sigma: jnp.ndarray,
    zero_offset: jnp.ndarray,
    *,
    width: int,
    n_avg: int = 1,
    noisy: bool = False,
    mirrored: bool = False,
) -> Trajectory:
    """``rollout.perturbation_rollouts`` (unchunked) through :func:`rollout_group`:
    the same rollouts, in calls of ``width``. ``zero_offset`` [width, T, nu] zeros."""
    du, noise = sysid_inputs(dims, n_s, data, key, sigma, n_avg, noisy, mirrored, width)
    parts = tuple(
        rollout_group(dims, q, data, policy, zero_offset, du_i, n_i) for du_i, n_i in zip(du, noise, strict=True)
    )
    return sysid_outcome(parts, n_s, n_avg, mirrored)
