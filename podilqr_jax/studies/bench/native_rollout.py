"""Native baseline: MuJoCo's multi-threaded C rollout against our MJX batch.

    python -m podilqr_jax.studies.bench.native_rollout --task pendulum-full --batch 256,1024,4096 \
        [--repeats 3] [--json PATH]

The same model, start state x0, controls [B, T, nu] (each held for ``substeps``
physics steps) and batch B run through

  (a) ``mujoco.rollout.Rollout`` (the C rollout shipped with mujoco >= 3.2): a
      persistent thread pool of ``nthread`` threads (default: all cores) with
      one ``MjData`` per thread; the pool and the MjData are built once per
      (model, nthread) and reused, so no thread-pool start-up is timed;
  (b) our jitted ``podilqr_jax.sim.rollout.rollout_batch`` (q = 1, an open-loop
      policy with u_bar = 0 and du = the controls, states recorded); the timed
      call is one after the compiling one, ended with ``block_until_ready``.

Both give the states at the control steps, [B, T+1, nq+nv]; the table reports
their largest difference (same physics: it should be round-off, ~1e-12) and
``MJX / native`` = MJX rollouts/s over native rollouts/s (above 1: MJX faster).
Times are medians over ``--repeats`` calls; MJX compile time is printed apart.
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

import podilqr_jax as pj
from podilqr_jax.identify.info_state import info_dim
from podilqr_jax.sim.rollout import open_loop_policy, rollout_batch

_STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS

# (id(model), nthread) -> (model, Rollout pool, [MjData] one per pool thread); the model is kept so its id stays valid.
_POOLS: dict[tuple[int, int], tuple[mujoco.MjModel, mj_rollout.Rollout, list[mujoco.MjData]]] = {}


def _close_pools() -> None:
    for _, pool, _ in _POOLS.values():
        pool.close()
    _POOLS.clear()


atexit.register(_close_pools)


def _pool(m: mujoco.MjModel, nthread: int) -> tuple[mj_rollout.Rollout, list[mujoco.MjData]]:
    """The persistent pool for ``m`` with ``nthread`` threads and its MjData (one per thread).

    ``nthread = 1`` uses ``Rollout(nthread=0)``: the rollout runs on the calling
    thread with one MjData, no pool thread at all."""
    key = (id(m), nthread)
    if key not in _POOLS:
        pool = mj_rollout.Rollout(nthread=nthread if nthread > 1 else 0)
        _POOLS[key] = (m, pool, [mujoco.MjData(m) for _ in range(nthread)])
    _, pool, datas = _POOLS[key]
    return pool, datas


def _state_slices(m: mujoco.MjModel) -> tuple[slice, slice]:
    """Where qpos and qvel sit in a full-physics state vector (mj_getState order)."""
    S = mujoco.mjtState
    q0 = mujoco.mj_stateSize(m, S.mjSTATE_TIME)
    v0 = mujoco.mj_stateSize(m, S.mjSTATE_TIME | S.mjSTATE_QPOS)
    return slice(q0, q0 + m.nq), slice(v0, v0 + m.nv)


def native_rollouts(
    env, controls: np.ndarray, nthread: int | None = None, chunk: int | None = None, repeats: int = 1
) -> tuple[np.ndarray, float]:
    """B rollouts of ``controls`` [B, T, nu] from x0 with ``mujoco.rollout``.

    Each control is held for ``env.dims.substeps`` physics steps. Returns the
    states at the control steps, [B, T+1, nq+nv] (x0 first), and the wall
    seconds of the rollout call alone (median of ``repeats`` calls): building
    the inputs, the output arrays, the pool and its MjData is not timed.
    ``chunk``: rollouts per thread-pool task (MuJoCo's default
    max(1, B / (10 nthread)) when None).
    """
    m, dims = env.mj_model, env.dims
    nthread = int(nthread or os.cpu_count() or 1)
    controls = np.asarray(controls, dtype=np.float64)
    B, T, nu = controls.shape
    if (T, nu) != (dims.horizon, dims.nu):
        raise ValueError(f"controls must be [B, {dims.horizon}, {dims.nu}]; got {controls.shape}")
    nstep = T * dims.substeps
    ctrl = np.ascontiguousarray(np.repeat(controls, dims.substeps, axis=1))  # [B, T*substeps, nu]

    x0 = np.asarray(env.data.x0, dtype=np.float64)
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = x0[: m.nq], x0[m.nq :]
    s0 = np.empty(mujoco.mj_stateSize(m, _STATE_SPEC))
    mujoco.mj_getState(m, d, s0, _STATE_SPEC)
    state0 = np.ascontiguousarray(np.broadcast_to(s0, (B, s0.size)))
    warmstart0 = np.zeros((B, m.nv))  # as mjx.make_data (no constraints here; only for equal footing)
    state = np.zeros((B, nstep, s0.size))  # touched now, so first-touch page faults are not timed
    sensordata = np.zeros((B, nstep, m.nsensordata))

    pool, datas = _pool(m, nthread)
    models = [m] * B
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        pool.rollout(
            models,
            datas,
            state0,
            ctrl,
            control_spec=mujoco.mjtState.mjSTATE_CTRL.value,
            skip_checks=True,  # shapes and dtypes are right by construction; skip the Python-side checks
            nstep=nstep,
            initial_warmstart=warmstart0,
            state=state,
            sensordata=sensordata,
            chunk_size=chunk,
        )
        times.append(time.perf_counter() - t0)

    qs, vs = _state_slices(m)
    at_control = state[:, dims.substeps - 1 :: dims.substeps]  # after each control step, [B, T, nstate]
    x = np.concatenate([at_control[..., qs], at_control[..., vs]], axis=-1)
    x = np.concatenate([np.broadcast_to(x0, (B, 1, x0.size)), x], axis=1)
    return x, float(np.median(times))


def mjx_rollouts(env, controls, repeats: int = 1, info: dict | None = None) -> tuple[np.ndarray, float]:
    """The same batch through our jitted ``rollout_batch`` (q = 1, open loop, u_bar = 0, du = controls).

    Returns the states [B, T+1, nq+nv] and the wall seconds of one call after
    the compiling one (median of ``repeats``), each ended by
    ``block_until_ready``. With ``info`` (a dict) also stores ``first_call_s``
    (compile + one run) and ``compile_s`` (first call minus a run).
    """
    dims, data = env.dims, env.data
    nZ = info_dim(dims.nz, dims.nu, 1)
    dtype = data.x0.dtype
    policy = open_loop_policy(jnp.zeros((dims.horizon, dims.nu), dtype), nZ)
    zero_offset = jnp.zeros((dims.horizon, dims.nu), dtype)
    du = jax.device_put(jnp.asarray(controls, dtype))
    du.block_until_ready()

    def call():
        t0 = time.perf_counter()
        traj = rollout_batch(dims, 1, data, policy, zero_offset, du, record_state=True)
        traj.x.block_until_ready()
        return traj, time.perf_counter() - t0

    _, first = call()
    times = []
    for _ in range(max(1, repeats)):
        traj, dt = call()
        times.append(dt)
    run = float(np.median(times))
    if info is not None:
        info.update(first_call_s=first, compile_s=max(first - run, 0.0), times_s=times)
    return np.asarray(traj.x), run


def compare(env, batch: int, repeats: int = 3, nthread: int | None = None, sigma: float = 1.0, seed: int = 0) -> dict:
    """One table row: both rollouts of one random control batch, N(0, sigma^2) per entry."""
    dims = env.dims
    nthread = int(nthread or os.cpu_count() or 1)
    controls = sigma * np.random.default_rng(seed).normal(size=(batch, dims.horizon, dims.nu))
    x_nat, t_nat = native_rollouts(env, controls, nthread=nthread, repeats=repeats)
    info: dict = {}
    x_mjx, t_mjx = mjx_rollouts(env, controls, repeats=repeats, info=info)
    steps = batch * dims.horizon * dims.substeps
    return dict(
        task=env.name,
        batch=batch,
        horizon=dims.horizon,
        substeps=dims.substeps,
        nthread=nthread,
        native_s=t_nat,
        native_rollouts_per_s=batch / t_nat,
        native_steps_per_s=steps / t_nat,
        mjx_s=t_mjx,
        mjx_rollouts_per_s=batch / t_mjx,
        mjx_steps_per_s=steps / t_mjx,
        mjx_over_native=t_nat / t_mjx,
        mjx_compile_s=info["compile_s"],
        max_abs_state_diff=float(np.max(np.abs(x_mjx - x_nat))),
    )


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="pendulum-full", help="a bundled task (podilqr_jax.task.tasks.TASKS)")
    parser.add_argument("--batch", default="256,1024", help="comma-separated batch sizes")
    parser.add_argument("--repeats", type=int, default=3, help="timed calls per measurement (median)")
    parser.add_argument("--nthread", type=int, default=None, help="native threads (default: os.cpu_count())")
    parser.add_argument("--sigma", type=float, default=1.0, help="control standard deviation")
    parser.add_argument("--json", default=None, help="write the rows to this JSON file")
    args = parser.parse_args(argv)

    env = pj.make_task(args.task)
    batches = [int(b) for b in args.batch.split(",") if b.strip()]
    nthread = int(args.nthread or os.cpu_count() or 1)
    print(
        f"{env.name}: {env.dims.horizon} control steps x {env.dims.substeps} substeps; JAX {jax.__version__} on "
        f"{jax.default_backend()}, float64={jax.config.jax_enable_x64}; MuJoCo {mujoco.__version__}, "
        f"native threads {nthread} of {os.cpu_count()} cores; median of {args.repeats}"
    )
    print(
        "| batch | native rollouts/s | native steps/s | MJX rollouts/s | MJX / native | MJX compile s "
        "| max abs state diff |"
    )
    print("|---|---|---|---|---|---|---|")
    rows = []
    for batch in batches:
        row = compare(env, batch, repeats=args.repeats, nthread=nthread, sigma=args.sigma)
        rows.append(row)
        print(
            f"| {batch} | {row['native_rollouts_per_s']:,.0f} | {row['native_steps_per_s']:,.0f} "
            f"| {row['mjx_rollouts_per_s']:,.0f} | {row['mjx_over_native']:.3f} | {row['mjx_compile_s']:.1f} "
            f"| {row['max_abs_state_diff']:.2e} |",
            flush=True,
        )
    if args.json:
        meta = dict(jax=jax.__version__, backend=jax.default_backend(), mujoco=mujoco.__version__)
        meta.update(cpu_count=os.cpu_count(), repeats=args.repeats, sigma=args.sigma)
        with open(args.json, "w") as f:
            json.dump(dict(meta=meta, rows=rows), f, indent=2)
    return rows


if __name__ == "__main__":
    main()
