"""What the package's XLA options (``podilqr_jax.compilation.xla_options``) change: cold compile and run time.

For each task, in fresh processes with the persistent compilation cache off
(``PODILQR_CACHE=0``), once with the package's options and once with XLA's
defaults (``PODILQR_XLA_DEFAULTS=1``), interleaved so each pair sees the same
load: a solve of ``--iterations`` iterations at ``--n-s`` (its ``compile_s``),
then the same solve again in the same process (compiled: milliseconds per
iteration), and the final cost of both, which must agree. Prints a Markdown
table (benchmarks/journal.md):

    python benchmarks/xla_options_speed.py pendulum-full:4096 cartpole-full:1024 cartpole-partial:40
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = """
import json, sys, time
import podilqr_jax as pj
from podilqr_jax.compilation import xla_options
task, n_s, iterations, which = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
env = pj.make_task(task)
solve = pj.solve if which == "pod" else pj.solve_model_based
cfg = pj.default_config(env, max_iterations=iterations, n_s=n_s, rtol=0.0, gtol=0.0)
cold = solve(env, cfg)
t0 = time.perf_counter()
warm = solve(env, cfg)
ms = 1000 * (time.perf_counter() - t0) / warm.iterations
print(json.dumps({"options": xla_options.options(), "compile_s": cold.compile_s, "ms_per_iteration": ms,
                  "cost": warm.final_cost, "iterations": warm.iterations}))
"""


def run(task: str, n_s: int, iterations: int, which: str, defaults: bool) -> dict:
    env = dict(os.environ, PODILQR_CACHE="0", PODILQR_XLA_DEFAULTS="1" if defaults else "0")
    out = subprocess.run(
        [sys.executable, "-c", CHILD, task, str(n_s), str(iterations), which],
        env=env,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    if out.returncode:
        sys.stderr.write(out.stderr[-2000:])
        raise SystemExit(f"{task} failed")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("tasks", nargs="+", help="TASK:N_S, e.g. cartpole-full:1024")
    p.add_argument("--iterations", type=int, default=10)
    p.add_argument("--solver", choices=("pod", "mb"), default="pod")
    p.add_argument("--out", help="also write the rows as JSON here")
    a = p.parse_args(argv)
    print(
        "| task | n_s | compile s (XLA defaults) | compile s (package) | ratio "
        "| ms/iteration (XLA defaults) | ms/iteration (package) | ratio | same cost |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    rows = []
    for spec in a.tasks:
        task, _, n_s = spec.partition(":")
        n_s = int(n_s or 40)
        xla = run(task, n_s, a.iterations, a.solver, defaults=True)
        ours = run(task, n_s, a.iterations, a.solver, defaults=False)
        same = abs(xla["cost"] - ours["cost"]) <= 1e-9 * abs(xla["cost"])
        rows.append({"task": task, "n_s": n_s, "xla_defaults": xla, "package": ours, "same_cost": same})
        print(
            f"| {task} | {n_s} | {xla['compile_s']:.1f} | {ours['compile_s']:.1f} "
            f"| {ours['compile_s'] / xla['compile_s']:.2f} | {xla['ms_per_iteration']:.1f} "
            f"| {ours['ms_per_iteration']:.1f} | {ours['ms_per_iteration'] / xla['ms_per_iteration']:.2f} "
            f"| {'yes' if same else 'no'} ({ours['cost']:.10g}) |",
            flush=True,
        )
    if a.out:
        with open(a.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
