"""What several starts in one batch cost: ``restarts = k`` against k solves one after another.

For each task and each k, in a fresh process: the solve with ``restarts = k`` twice
(the first run compiles the batched programs, the second finds them compiled: the
time a user pays from then on), then each of its k starts solved alone, one after
another, from the same first guess and seed (``ilqr.restarts.first_guesses``), warm.
The table gives the wall seconds of both, the start-iterations they ran, the
batched calls by width, and the best cost against start 0's (the default solve's).

    python benchmarks/restarts.py                                   # k = 1, 4, 16 on two tasks (6.3 min on 2 cores)
    python benchmarks/restarts.py --ks 1,4 --tasks pendulum-partial  # a quick look

The numbers are this machine's (a CPU: each start's rollouts are real work; on a GPU a
batch of k starts costs about one). Results go to runs/restarts/TASK-kK.json and the
table is printed; docs/robustness.md ("Several starts in one batch") holds the one
measured for it.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TASKS = ["pendulum-partial", os.path.join("examples", "tasks", "basins", "gym_inverted_pendulum_tilted.toml")]

CHILD = """
import json, sys, time
import numpy as np
import podilqr_jax as pj
from podilqr_jax.ilqr.restarts import first_guesses
task, k, sequential = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1"
env = pj.make_task(task)
cfg = pj.default_config(env, restarts=k)
runs = []
for _ in range(2):
    t0 = time.perf_counter()
    r = pj.solve(env, cfg)
    runs.append(time.perf_counter() - t0)
starts = r.starts or [{"start": 0, "seed": cfg.seed, "cost": r.final_cost, "iterations": r.iterations,
                       "rollouts": r.rollouts, "status": str(r.status)}]
out = {"task": env.name, "engine": r.engine, "k": k, "cold_s": runs[0], "warm_s": runs[1],
       "best": r.final_cost, "start0": starts[0]["cost"], "starts": starts,
       "widths": r.message.split("batched calls: ")[1].split(")")[0] if k > 1 else "-"}
if sequential and k > 1:
    zero = np.zeros((env.dims.horizon, env.dims.nu))
    guesses = first_guesses(cfg, env.data.u_low, env.data.u_high, zero, k)
    one = cfg.replace(restarts=1)
    pj.solve(env, one, u_init=np.asarray(guesses[0]))  # compiled once, as the batch's second run found it
    t0 = time.perf_counter()
    alone = [pj.solve(env, one.replace(seed=cfg.seed + j), u_init=np.asarray(g)) for j, g in enumerate(guesses)]
    out["sequential_s"] = time.perf_counter() - t0
    out["sequential_best"] = min(a.final_cost for a in alone)
print(json.dumps(out))
"""


def run(task: str, k: int, sequential: bool, out_dir: str, timeout: float) -> dict:
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, task, str(k), "1" if sequential else "0"],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=ROOT,
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        raise SystemExit(f"{task} k={k}: exit {proc.returncode}\n{proc.stderr[-2000:]}")
    row = json.loads(lines[-1])
    row["process_s"] = time.perf_counter() - t0
    os.makedirs(out_dir, exist_ok=True)
    name = os.path.splitext(os.path.basename(task))[0]
    with open(os.path.join(out_dir, f"{name}-k{k}.json"), "w") as f:
        json.dump(row, f, indent=1)
    return row


def table(rows: list[dict]) -> str:
    lines = [
        "| task | engine | k | first run (s) | again (s) | the k starts alone, one after another (s) | "
        "start-iterations | batched calls (width) | start 0's cost | best cost |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        seq = f"{r['sequential_s']:.1f}" if "sequential_s" in r else "-"
        its = sum(s["iterations"] for s in r["starts"])
        lines.append(
            f"| {r['task']} | {r['engine']} | {r['k']} | {r['cold_s']:.1f} | {r['warm_s']:.1f} | {seq} | {its} | "
            f"{r['widths']} | {r['start0']:.6g} | {r['best']:.6g} |"
        )
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--tasks", default=",".join(TASKS), help="comma-separated bundled task names or task files")
    p.add_argument("--ks", default="1,4,16", help="comma-separated numbers of starts")
    p.add_argument("--no-sequential", action="store_true", help="skip the k starts solved one after another")
    p.add_argument("--out", default=os.path.join("runs", "restarts"), help="folder of the per-run JSON")
    p.add_argument("--timeout", type=float, default=1200.0, help="seconds per process")
    args = p.parse_args()
    rows = []
    for task in args.tasks.split(","):
        for k in (int(x) for x in args.ks.split(",")):
            rows.append(run(task, k, not args.no_sequential, args.out, args.timeout))
            print(table(rows[-1:]).splitlines()[-1], flush=True)
    print()
    print(table(rows))


if __name__ == "__main__":
    main()
