"""Cold compile time per solver, per model: what a first run pays.

For each task (bundled names or task files) runs a one-iteration solve of
POD-iLQR and of the model-based reference, each in a fresh process with the
persistent compilation cache off (``PODILQR_CACHE=0``), and prints a Markdown
table of ``Result.compile_s`` (trace + lower + compile) and, in brackets, the solve's
wall time (``Result.wall_s``: the compile and one iteration; the same
measure for a checkout whose ``compile_s`` counts otherwise). ``--source DIR`` runs
the package from another checkout (``PYTHONPATH=DIR``), which is how
benchmarks/journal.md puts the compile of an older commit beside this one in one
run, model by model, interleaved, so both see the same machine load:

    git worktree add /tmp/before <commit>
    python benchmarks/compile_per_model.py --source /tmp/before --source . \\
        pendulum-full cartpole-partial examples/tasks/third_party/*.toml
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD = """
import json, sys
import podilqr_jax
print("source", podilqr_jax.__file__, file=sys.stderr)
import podilqr_jax as pj
try:
    from podilqr_jax.task.taskfile import load_task
except ImportError:  # a checkout from before the subpackages (--source of an older commit)
    from podilqr_jax.taskfile import load_task
task, which = sys.argv[1], sys.argv[2]
env = load_task(task) if task.endswith(".toml") else pj.make_task(task)
solve = pj.solve if which == "pod" else pj.solve_model_based
r = solve(env, pj.default_config(env, max_iterations=1))
print(json.dumps({"compile_s": r.compile_s, "wall_s": r.wall_s, "status": str(r.status)}))
"""


def compile_seconds(source: str, task: str, which: str, timeout: float) -> dict | None:
    """{"compile_s", "wall_s", "status"} of a cold one-iteration solve in a fresh process, or None."""
    env = dict(os.environ, PODILQR_CACHE="0", PYTHONPATH=os.path.abspath(source))
    if task.endswith(".toml"):
        task = os.path.abspath(task)
    try:  # from the checkout's parent, so that the working directory does not shadow PYTHONPATH
        out = subprocess.run(
            [sys.executable, "-c", CHILD, task, which],
            env=env,
            cwd=os.path.dirname(os.path.abspath(source)),
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired:
        return None
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("{")]
    if out.returncode or not lines:
        sys.stderr.write(out.stderr[-2000:])
        return None
    return json.loads(lines[-1])


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("tasks", nargs="+", help="bundled task names or task files")
    p.add_argument("--source", action="append", help="a checkout to import podilqr_jax from (repeatable)")
    p.add_argument("--timeout", type=float, default=900.0, help="seconds per process")
    p.add_argument("--out", help="also write the figures as JSON here")
    p.add_argument("--solver", choices=("pod", "mb", "both"), default="both", help="which solver(s) to time")
    a = p.parse_args(argv)
    sources = a.source or ["."]
    solvers = ("pod", "mb") if a.solver == "both" else (a.solver,)
    head = " | ".join(
        f"{w.upper()} compile s ({os.path.basename(os.path.abspath(s))})" for w in solvers for s in sources
    )
    print(f"| task | {head} |\n|---|" + "---|" * (len(solvers) * len(sources)), flush=True)
    rows = {}
    for task in a.tasks:
        figures = {}
        for which in solvers:
            for s in sources:  # interleaved: each pair sees the same load
                figures[f"{which}:{s}"] = compile_seconds(s, task, which, a.timeout)
        rows[task] = figures
        cells = " | ".join(
            "timeout" if v is None else f"{v['compile_s']:.1f} ({v['wall_s']:.1f})" for v in figures.values()
        )
        print(f"| {os.path.splitext(os.path.basename(task))[0]} | {cells} |", flush=True)
    if a.out:
        with open(a.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
