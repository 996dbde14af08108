"""Milliseconds per iteration with and without the shared rollout program (podilqr_jax/sim/shared.py).

In one process, for one task: a solve of ``ITERATIONS`` iterations
(``rtol = gtol = 0``) with ``PODILQR_SHARED_ROLLOUTS=1`` (the sysid batch in
calls of the line search's width) and with ``=0`` (each stage its own
rollouts), each compiled once first, then ``ROUNDS`` timed solves of each,
interleaved so both see the same load. Prints the milliseconds per
iteration of every timed solve and the ratio of the best of each
(benchmarks/journal.md):

    PODILQR_CACHE=0 python benchmarks/shared_rollouts_speed.py cartpole-partial 20 3
    PODILQR_CACHE=0 python benchmarks/shared_rollouts_speed.py examples/tasks/third_party/dmc_cartpole_swingup.toml 10 2
"""

from __future__ import annotations

import json
import os
import sys
import time

import podilqr_jax as pj
from podilqr_jax.task.taskfile import load_task


def main() -> None:
    task, iterations, rounds = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    env = load_task(task) if task.endswith(".toml") else pj.make_task(task)
    cfg = pj.default_config(env, max_iterations=iterations, rtol=0.0, gtol=0.0)

    def ms_per_iteration(setting: str) -> float:
        os.environ["PODILQR_SHARED_ROLLOUTS"] = setting  # read per solve
        t0 = time.perf_counter()
        result = pj.solve(env, cfg)
        return 1000 * (time.perf_counter() - t0) / result.iterations

    for setting in ("1", "0"):
        ms_per_iteration(setting)  # compiles
    times: dict[str, list[float]] = {"1": [], "0": []}
    for _ in range(rounds):
        for setting in ("1", "0"):
            times[setting].append(round(ms_per_iteration(setting), 1))
    print(json.dumps({
        "task": os.path.basename(task), "shared_ms": times["1"], "own_ms": times["0"],
        "best_shared_over_best_own": round(min(times["1"]) / min(times["0"]), 3),
    }))  # fmt: skip


if __name__ == "__main__":
    main()
