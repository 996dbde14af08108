"""Which basin each solver lands in, on a multi-modal suite of our own (issue 36).

Eight swing-up and balance tasks under partial observation (``examples/tasks/basins/``),
on the bundled models and on dm_control's and Gymnasium's as they ship, none of them
in ``benchmarks/untuned_suite.py``, no solver setting in any. For each task:

- ``podilqr solve FILE --compare`` at the defaults (POD-iLQR and the model-based
  reference, both from zero controls);
- with ``--seeds N``, POD-iLQR again with seeds 1..N (other sysid draws, the same
  zero controls);
- with ``--starts N``, both solvers from N other first guesses: zero controls plus
  Gaussian noise of 0.3 times the control range's half-width (1 where an actuator is
  not limited), clipped to the range, drawn with ``numpy.random.default_rng(j)``;
- with ``--restarts K``, ``podilqr solve FILE --restarts K``: POD-iLQR from K first
  guesses in one batch (``restarts``: the zero controls and K - 1 perturbed ones,
  seeds 0..K-1), keeping the lowest;

and the table gives the default POD-iLQR cost over the reference's, the best cost
any run reached, and where the two solvers part: the first iteration at which their
costs differ by more than 10% (both start at the same nominal), and the largest gap
between their final state trajectories. Each run is a fresh process, one at a time.

``--first-step`` (in this process) compares the two solvers' first step, where they
still share the nominal (zero controls) and the cost and differ only in the model
(identified from rollouts, or the exact linearisation): the relative difference of
the feedforward ``k_t`` of their first backward pass, over the first ``q`` steps (where
the information state still holds the history before ``t = 0``) and over the rest,
the cost of each ``k`` as a full step without feedback (``u = k`` from the zero
controls), and the costs after each solver's first accepted step (with its own
feedback) and its step size.

    python benchmarks/basins.py                 # the --compare runs (about 3 min on 2 cores)
    python benchmarks/basins.py --seeds 3       # and three more POD-iLQR seeds per task (about 7 min)
    python benchmarks/basins.py --seeds 3 --starts 3   # and both solvers from 3 other first guesses
    python benchmarks/basins.py --restarts 8    # and POD-iLQR with 8 starts in one batch
    python benchmarks/basins.py --restarts 8 --restarts-only   # only those, the other runs as saved
    python benchmarks/basins.py --table-only    # print the table from runs/basins/
    python benchmarks/basins.py --first-step    # the first steps side by side (under a minute)

Results go to runs/basins/STEM/seedS.json (seed 0: the ``--compare`` run),
startJ.json (the costs from first guess J), restartsK.json and log.txt.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TASKS = os.path.join(ROOT, "examples", "tasks", "basins")
OUT = os.path.join(ROOT, "runs", "basins")
PART = 0.10  # the solvers part where their costs differ by more than this fraction


def stem(path: str) -> str:
    return os.path.splitext(os.path.basename(path))[0]


def _solve_cli(path: str, name: str, options: list[str], out_dir: str, timeout: float) -> str:
    """``podilqr solve FILE OPTIONS`` in a fresh process: runs/basins/STEM/NAME.json (log.txt beside it)."""
    folder = os.path.join(out_dir, stem(path))
    os.makedirs(folder, exist_ok=True)
    out = os.path.join(folder, f"{name}.json")
    cmd = [sys.executable, "-m", "podilqr_jax.cli", "solve", path, "--quiet", "--no-plots", "--out", out, *options]
    t0 = time.perf_counter()
    with open(os.path.join(folder, "log.txt"), "a") as log:
        try:
            rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, timeout=timeout).returncode
        except subprocess.TimeoutExpired:
            rc = "timeout"
    return f"{stem(path)} {name}: exit {rc} in {time.perf_counter() - t0:.0f} s"


def run_one(path: str, seed: int, out_dir: str, timeout: float) -> str:
    """The ``--compare`` run (seed 0) or POD-iLQR with another seed: seedS.json."""
    options = ["--compare"] if seed == 0 else ["--set", f"seed={seed}"]
    return _solve_cli(path, f"seed{seed}", options, out_dir, timeout)


def run_restarts(path: str, k: int, out_dir: str, timeout: float) -> str:
    """``podilqr solve FILE --restarts K``: restartsK.json."""
    return _solve_cli(path, f"restarts{k}", ["--restarts", str(k)], out_dir, timeout)


START = """
import json, sys
import numpy as np
import podilqr_jax as pj
from podilqr_jax.task.taskfile import load_task
path, j = sys.argv[1], int(sys.argv[2])
env = load_task(path)
lo, hi = np.asarray(env.data.u_low), np.asarray(env.data.u_high)
half = np.where(np.isfinite(hi - lo), (hi - lo) / 2, 1.0)
u0 = np.random.default_rng(j).standard_normal((env.dims.horizon, env.dims.nu)) * 0.3 * half
u0 = np.clip(u0, lo, hi)
out = {}
for name, solve in (("pod", pj.solve), ("ref", pj.solve_model_based)):
    r = solve(env, pj.default_config(env), u_init=u0)
    out[name] = {"cost": r.final_cost, "status": str(r.status), "iterations": r.iterations}
print(json.dumps(out))
"""


def run_start(path: str, j: int, out_dir: str, timeout: float) -> str:
    """Both solvers from first guess ``j`` (``START``, in a fresh process): runs/basins/STEM/startJ.json."""
    folder = os.path.join(out_dir, stem(path))
    os.makedirs(folder, exist_ok=True)
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(
            [sys.executable, "-c", START, path, str(j)], capture_output=True, text=True, timeout=timeout
        )
    except subprocess.TimeoutExpired:
        return f"{stem(path)} start {j}: timeout"
    with open(os.path.join(folder, "log.txt"), "a") as log:
        log.write(proc.stderr)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode == 0 and lines:
        with open(os.path.join(folder, f"start{j}.json"), "w") as f:
            f.write(lines[-1])
    return f"{stem(path)} start {j}: exit {proc.returncode} in {time.perf_counter() - t0:.0f} s"


def _load(path: str):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def parting(pod: list[float], ref: list[float]) -> int | None:
    """The first iteration at which the two cost histories differ by more than PART (None: never)."""
    for i, (a, b) in enumerate(zip(pod, ref, strict=False)):
        if abs(a - b) > PART * max(abs(b), 1e-300):
            return i
    return None


def row(path: str, out_dir: str) -> dict | None:
    name = stem(path)
    first = _load(os.path.join(out_dir, name, "seed0.json"))
    if first is None:
        return None
    ref = first["model_based"]
    seeds = {0: first["final_cost"]}
    for f in sorted(glob.glob(os.path.join(out_dir, name, "seed*.json"))):
        seed = int(os.path.basename(f)[4:-5])
        if seed and (other := _load(f)) is not None:
            seeds[seed] = other["final_cost"]
    starts = {}
    for f in sorted(glob.glob(os.path.join(out_dir, name, "start*.json"))):
        if (other := _load(f)) is not None:
            starts[int(os.path.basename(f)[5:-5])] = (other["pod"]["cost"], other["ref"]["cost"])
    known = [c for pair in starts.values() for c in pair]
    restarts = {}
    for f in sorted(glob.glob(os.path.join(out_dir, name, "restarts*.json"))):
        if (other := _load(f)) is not None:
            restarts[int(os.path.basename(f)[8:-5])] = (other["final_cost"], other["best_start"], other["wall_s"])
    pairs = zip(first["states"], ref["states"], strict=True)
    gap = max(abs(a - b) for xs, ys in pairs for a, b in zip(xs, ys, strict=True))
    return {
        "task": name,
        "pod": first["final_cost"],
        "pod_status": first["status"],
        "pod_iterations": first["iterations"],
        "ref": ref["final_cost"],
        "ref_status": ref["status"],
        "ref_iterations": ref["iterations"],
        "ratio": first["final_cost"] / ref["final_cost"],
        "seeds": seeds,
        "starts": starts,
        "restarts": restarts,
        "best": min([*seeds.values(), ref["final_cost"], *known, *(c for c, _, _ in restarts.values())]),
        "part": parting(first["cost_history"], ref["cost_history"]),
        "state_gap": gap,
    }


def table(rows: list[dict]) -> str:
    lines = [
        "| task | POD-iLQR (defaults) | model-based | ratio | POD-iLQR, seeds 0.. | other first guesses, "
        "POD-iLQR / model-based | POD-iLQR, restarts = K: cost (best start, s) | best known | part at | state gap |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        seeds = ", ".join(f"{c:.6g}" for _, c in sorted(r["seeds"].items()))
        starts = ", ".join(f"{a:.6g} / {b:.6g}" for _, (a, b) in sorted(r["starts"].items())) or "-"
        restarts = (
            "; ".join(
                f"K = {k}: {c:.6g} (start {j}, {w:.0f} s){' = best' if c <= r['best'] * (1 + 1e-4) else ''}"
                for k, (c, j, w) in sorted(r["restarts"].items())
            )
            or "-"
        )
        part = "never" if r["part"] is None else str(r["part"])
        lines.append(
            f"| {r['task']} | {r['pod']:.6g} ({r['pod_status']}, {r['pod_iterations']}) | "
            f"{r['ref']:.6g} ({r['ref_status']}, {r['ref_iterations']}) | {r['ratio']:.4f} | {seeds} | {starts} | "
            f"{restarts} | {r['best']:.6g} | {part} | {r['state_gap']:.3g} |"
        )
    return "\n".join(lines)


def first_step(path: str) -> str:
    """One Markdown row: the two solvers' first backward pass and step, side by side."""
    import numpy as np

    import podilqr_jax as pj
    from podilqr_jax.task.taskfile import load_task

    env = load_task(path)
    pod = pj.solve(env, pj.default_config(env, max_iterations=1))
    ref = pj.solve_model_based(env, pj.default_config(env, max_iterations=1))
    q = pod.q
    k_pod, k_ref = np.asarray(pod.k), np.asarray(ref.k)

    def rel(a, b):
        return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300))

    def open_loop(k):  # the cost of u = 0 + k, no feedback: the first nominal a solve from u_init = k measures
        return pj.solve_model_based(env, pj.default_config(env, max_iterations=1), u_init=k).cost_history[0]

    return (
        f"| {stem(path)} | {q} | {rel(k_pod[:q], k_ref[:q]):.3g} | {rel(k_pod[q:], k_ref[q:]):.3g} | "
        f"{open_loop(k_pod):.6g} / {open_loop(k_ref):.6g} | "
        f"{pod.cost_history[-1]:.6g} (alpha {pod.alpha_history[-1]:g}) | "
        f"{ref.cost_history[-1]:.6g} (alpha {ref.alpha_history[-1]:g}) |"
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=0, help="POD-iLQR runs with seeds 1..N besides the --compare run")
    p.add_argument("--starts", type=int, default=0, help="both solvers from N other first guesses")
    p.add_argument("--restarts", type=int, default=0, help="POD-iLQR with K starts in one batch (--restarts K)")
    p.add_argument("--restarts-only", action="store_true", help="run only the --restarts solves (the rest as saved)")
    p.add_argument("--only", default="", help="comma-separated task stems")
    p.add_argument("--out", default=OUT, help="results folder (default runs/basins)")
    p.add_argument("--timeout", type=float, default=900.0, help="seconds per run")
    p.add_argument("--table-only", action="store_true", help="print the table from the results folder")
    p.add_argument("--first-step", action="store_true", help="compare the two solvers' first step (in this process)")
    args = p.parse_args(argv)
    paths = sorted(glob.glob(os.path.join(TASKS, "*.toml")))
    if args.only:
        wanted = set(args.only.split(","))
        paths = [p for p in paths if stem(p) in wanted]
    if args.first_step:
        print(
            "| task | q | k, first q steps | k, the rest | full step open loop, POD-iLQR's / the reference's k "
            "| POD-iLQR after step 1 | model-based after step 1 |"
        )
        print("|---|---|---|---|---|---|---|")
        for path in paths:
            print(first_step(path), flush=True)
        return 0
    if not args.table_only:
        for path in paths:
            for seed in range(0 if args.restarts_only else args.seeds + 1):
                print(run_one(path, seed, args.out, args.timeout), flush=True)
            for j in range(1, 1 if args.restarts_only else args.starts + 1):
                print(run_start(path, j, args.out, args.timeout), flush=True)
            if args.restarts:
                print(run_restarts(path, args.restarts, args.out, args.timeout), flush=True)
    rows = [r for r in (row(path, args.out) for path in paths) if r is not None]
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
