"""Run time of ``rk4.step`` against ``mjx.step``: 32 rollouts of 50 steps of RK4 models.

    PODILQR_CACHE=0 python benchmarks/rk4_speed.py examples/tasks/third_party/dmc_cartpole_swingup.toml \\
        examples/tasks/third_party/gym_inverted_pendulum_balance.toml examples/tasks/third_party/gym_hopper_balance.toml

Prints, per task file, the best of five timed calls of each compiled batch (benchmarks/journal.md).
"""

import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

from podilqr_jax.sim import rk4
from podilqr_jax.task.taskfile import load_task


def best_seconds(env, stepper, repeats: int = 5) -> float:
    """The best of ``repeats`` timed calls of 32 rollouts x 50 steps, compiled as one batch."""
    m, dims = env.data.model, env.dims
    X = env.data.x0 + 0.02 * np.random.default_rng(0).standard_normal((32, dims.nx))
    d0 = mjx.make_data(m)

    def body(_, dd):
        return jax.tree_util.tree_map(lambda a, b: a.astype(b.dtype), stepper(m, dd), dd)

    def run(x):
        d = d0.replace(qpos=x[: dims.nq], qvel=x[dims.nq :], ctrl=0.1 * jnp.ones(dims.nu))
        return jax.lax.fori_loop(0, 50, body, d).qpos

    compiled = jax.jit(jax.vmap(run)).lower(X).compile()
    compiled(X).block_until_ready()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        compiled(X).block_until_ready()
        times.append(time.perf_counter() - t0)
    return min(times)


def main(paths: list[str]) -> None:
    for f in paths:
        env = load_task(f)
        ref, ours = best_seconds(env, mjx.step), best_seconds(env, rk4.step)
        print(
            f"{f.split('/')[-1]}: mjx.step {ref * 1e3:.1f} ms, rk4.step {ours * 1e3:.1f} ms, ratio {ours / ref:.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main(sys.argv[1:])
