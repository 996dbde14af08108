"""Rollout throughput: our MJX batch against MuJoCo's native multi-threaded rollout.

    python -m podilqr_jax.studies.bench.rollout_throughput [--batch 1024] [--repeats 3]

For each bundled system, the same model, start state, controls and batch run
through (a) podilqr_jax's jitted MJX rollout (``perturbation_rollouts``) and
(b) ``mujoco.rollout.rollout`` with one thread per core. Also times the cart-pole
with dm_control's RK4 integrator to show why the bundled model uses Euler.
Prints physics steps per second; compile time is reported separately.
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

import podilqr_jax as pj
from podilqr_jax.identify.info_state import info_dim
from podilqr_jax.sim.rollout import open_loop_policy, perturbation_rollouts
from podilqr_jax.task.tasks import MODELS_DIR


def time_mjx(env, batch, repeats):
    dims, data = env.dims, env.data
    nZ = info_dim(dims.nz, dims.nu, 1)
    policy = open_loop_policy(jnp.zeros((dims.horizon, dims.nu)), nZ)
    key, sigma = jax.random.PRNGKey(0), jnp.asarray(0.1)
    t0 = time.perf_counter()
    perturbation_rollouts(dims, 1, batch, data, policy, key, sigma).z.block_until_ready()
    compile_s = time.perf_counter() - t0
    times = []
    for r in range(repeats):
        t0 = time.perf_counter()
        perturbation_rollouts(dims, 1, batch, data, policy, jax.random.PRNGKey(r + 1), sigma).z.block_until_ready()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), compile_s


def time_native(env, batch, repeats):
    m = env.mj_model
    steps = env.dims.horizon * env.dims.substeps
    datas = [mujoco.MjData(m) for _ in range(os.cpu_count() or 1)]
    x0 = np.asarray(env.data.x0)
    state = np.zeros((batch, mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS)))
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = x0[: m.nq], x0[m.nq :]
    mujoco.mj_getState(m, d, state[0], mujoco.mjtState.mjSTATE_FULLPHYSICS)
    state[:] = state[0]
    ctrl = np.repeat(
        0.1 * np.random.default_rng(0).normal(size=(batch, env.dims.horizon, m.nu)), env.dims.substeps, axis=1
    )
    with mj_rollout.Rollout(nthread=len(datas)) as runner:
        runner.rollout(m, datas, state, ctrl, nstep=steps)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            runner.rollout(m, datas, state, ctrl, nstep=steps)
            times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--batch", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(
        f"JAX {jax.__version__} on {jax.default_backend()}, MuJoCo {mujoco.__version__}, "
        f"{os.cpu_count()} cores, batch {args.batch}, float64={jax.config.jax_enable_x64}"
    )
    print(
        "| model | physics steps / rollout | MJX steps/s | native steps/s (all threads) "
        "| MJX / native | MJX compile s |"
    )
    print("|---|---|---|---|---|---|")
    envs = [pj.make_task("pendulum-full"), pj.make_task("cartpole-full")]
    rk4 = mujoco.MjModel.from_xml_path(os.path.join(MODELS_DIR, "cartpole.xml"))
    rk4.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    envs.append(pj.Env.from_model(rk4, substeps=10, horizon=30, x0=np.asarray(envs[1].data.x0), name="cartpole RK4"))
    for env in envs:
        steps = args.batch * env.dims.horizon * env.dims.substeps
        t_mjx, compile_s = time_mjx(env, args.batch, args.repeats)
        t_nat = time_native(env, args.batch, args.repeats)
        print(
            f"| {env.name} | {env.dims.horizon * env.dims.substeps} | {steps / t_mjx:,.0f} | {steps / t_nat:,.0f} "
            f"| {t_nat / t_mjx:.2f} | {compile_s:.1f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
