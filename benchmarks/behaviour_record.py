"""Record what the solver computes, and compare two records: the proof that a
refactor left behaviour unchanged.

``record`` runs, with fixed seeds and no compilation cache, every bundled task
under both solvers at the defaults, the untuned suite's task files and the ant
of the robot suite (a free joint: the tangent space) under both (as
``podilqr solve FILE --compare`` runs them), a tiny reproduction
(``podilqr reproduce --tiny``) and a tiny evaluation of a noisy solve
(``podilqr evaluate --tiny``), and keeps every cost history, control and gain
array and the studies' JSON. ``compare`` lists what differs between two
records: arrays bit for bit, JSON numbers with their largest relative
difference (timings and machine facts left out).

    python benchmarks/behaviour_record.py record runs/behaviour/new      # ~8 min on 2 cores
    git worktree add /tmp/before <commit>
    PYTHONPATH=/tmp/before python benchmarks/behaviour_record.py record runs/behaviour/before
    python benchmarks/behaviour_record.py compare runs/behaviour/before runs/behaviour/new

The record of a commit is made with that commit's package (``PYTHONPATH``) and
this script; it uses only ``make_task``, ``load_task``, ``default_config``,
``solve``, ``solve_model_based`` and the command line, which every version
since the native engine has.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
from untuned_suite import SUITE  # noqa: E402 - the benchmarks folder is not a package

# JSON keys that are timings or facts of the machine, not results: names ending in _s (seconds), and these parts.
LEFT_OUT = ("wall", "seconds", "compile", "time", "machine", "date", "version", "host", "path", "plan")


def _left_out(key: str) -> bool:
    return key.endswith("_s") or any(part in key for part in LEFT_OUT)


# A floating base, which no bundled or untuned task has. Its model-based reference stalls
# and amplifies round-off into another stopping point (benchmarks/journal.md, the last
# section): a difference here is explained by the cost histories' first iterations.
FLOATING = ("robots/gym_ant_rise.toml",)
STUDIES = ("reproduce/summary.json", "evaluate/evaluate.json", "noisy/result.json")


def record(out: str) -> None:
    os.environ["PODILQR_CACHE"] = "0"  # every program compiled afresh, as on a new machine (read on import)
    import podilqr_jax as pj
    from podilqr_jax.task.taskfile import load_task

    os.makedirs(out, exist_ok=True)
    arrays: dict[str, np.ndarray] = {}
    envs = [(name, pj.make_task(name)) for name in pj.TASKS]
    files = [path for path, _ in SUITE] + list(FLOATING)
    envs += [(path, load_task(os.path.join(ROOT, "examples", "tasks", path))) for path in files]
    for name, env in envs:
        t0 = time.perf_counter()
        cfg = pj.default_config(env)
        for method, result in (("pod", pj.solve(env, cfg)), ("mb", pj.solve_model_based(env, cfg))):
            arrays[f"{name}/{method}/costs"] = np.asarray(result.cost_history)
            arrays[f"{name}/{method}/u"] = np.asarray(result.controls)
            arrays[f"{name}/{method}/K"] = np.asarray(result.K)
            print(f"{name} {method}: {result.status}, {result.iterations} iterations, cost {result.final_cost!r}")
        print(f"  {time.perf_counter() - t0:.0f} s", flush=True)
    np.savez(os.path.join(out, "solves.npz"), **arrays)
    cli = [sys.executable, "-m", "podilqr_jax.cli"]
    noisy = os.path.join(out, "noisy", "result.json")
    for argv in (
        ["reproduce", "--tiny", "--out", os.path.join(out, "reproduce")],
        ["solve", "pendulum-partial", "--noise", "paper", "--set", "max_iterations=20", "--no-plots", "--out", noisy],
        ["evaluate", noisy, "--tiny", "--out", os.path.join(out, "evaluate")],
    ):
        subprocess.run(cli + argv, check=True, stdout=subprocess.DEVNULL, env=os.environ)
        print("ran podilqr", " ".join(argv[:2]), flush=True)


def _walk(x, y, path: str, found: list) -> None:
    if isinstance(x, dict) and isinstance(y, dict):
        for key in sorted(set(x) | set(y)):
            if _left_out(key):
                continue
            if key not in x or key not in y:
                found.append((f"{path}/{key}", "only in " + ("the second" if key in y else "the first")))
            else:
                _walk(x[key], y[key], f"{path}/{key}", found)
    elif isinstance(x, list) and isinstance(y, list):
        if len(x) != len(y):
            found.append((path, f"lengths {len(x)} and {len(y)}"))
            return
        for i, (p, q) in enumerate(zip(x, y, strict=True)):
            _walk(p, q, f"{path}[{i}]", found)
    elif isinstance(x, (int, float)) and isinstance(y, (int, float)) and not isinstance(x, bool):
        if x != y and not (isinstance(x, float) and math.isnan(x) and math.isnan(y)):
            found.append((path, abs(x - y) / max(abs(x), 1e-300)))
    elif x != y:
        found.append((path, f"{x!r} and {y!r}"))


def compare(first: str, second: str) -> int:
    """Print what differs; returns the number of things that are not bit for bit."""
    a, b = np.load(os.path.join(first, "solves.npz")), np.load(os.path.join(second, "solves.npz"))
    differ = 0
    equal = [k for k in a.files if k in b.files and a[k].shape == b[k].shape and np.array_equal(a[k], b[k])]
    print(f"solves: {len(equal)} of {len(a.files)} arrays bit for bit")
    for key in a.files:
        if key in equal:
            continue
        differ += 1
        x, y = a[key], b.get(key)
        if y is None:
            print(f"  {key}: only in the first record")
        elif x.shape != y.shape:
            print(f"  {key}: shape {x.shape} and {y.shape}")
        else:
            print(f"  {key}: largest relative difference {np.max(np.abs(x - y)) / max(np.max(np.abs(x)), 1e-300):.2e}")
    for name in STUDIES:
        with open(os.path.join(first, name)) as f, open(os.path.join(second, name)) as g:
            found: list = []
            _walk(json.load(f), json.load(g), "", found)
        numbers = [d for d in found if isinstance(d[1], float)]
        largest = f", the largest relative difference {max(d[1] for d in numbers):.2e}" if numbers else ""
        print(f"{name}: {len(numbers)} numbers differ{largest}; {len(found) - len(numbers)} other differences")
        for path, what in [d for d in found if not isinstance(d[1], float)][:10]:
            print(f"  {path}: {what}")
        differ += len(found)
    return differ


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("record", help="record this package's results into a folder").add_argument("out")
    c = sub.add_parser("compare", help="what differs between two records")
    c.add_argument("first")
    c.add_argument("second")
    args = parser.parse_args()
    if args.command == "record":
        record(args.out)
        return 0
    return 1 if compare(args.first, args.second) else 0


if __name__ == "__main__":
    sys.exit(main())
