"""The acceptance suite of the robust defaults: tasks nobody tuned, solved at the library's defaults.

Every task file names a model as it ships in dm_control's suite or Gymnasium's
MuJoCo assets and sets only the cost, horizon, start and observation; no
solver setting. Each runs ``podilqr solve FILE --compare`` in a fresh
process (two at a time) and the table (POD-iLQR over the model-based
reference from the same start, which passes at <= 1.01) goes into
docs/robustness.md between its markers.

    python benchmarks/untuned_suite.py               # about 15 min on 2 cores
    python benchmarks/untuned_suite.py --only acrobot_partial,dmc_cartpole_swingup
    python benchmarks/untuned_suite.py --table-only  # rebuild the table from runs/untuned/

Results go to runs/untuned/STEM/result.json (and log.txt).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SUITE = [  # (task file, what it stands for)
    ("held_out/acrobot_partial.toml", "acrobot swing-up, joint angles observed"),
    ("held_out/pendulum_partial_limited.toml", "torque-limited pendulum, angle observed"),
    ("third_party/dmc_pendulum_swingup.toml", "torque-limited pendulum, full state"),
    ("third_party/gym_inverted_pendulum_balance.toml", "torque-limited cart-pole balance, joint limits"),
    ("third_party/dmc_acrobot_swingup.toml", "acrobot swing-up, full state"),
    ("third_party/dmc_cartpole_swingup.toml", "cart-pole swing-up, cart and pole observed"),
    ("third_party/dmc_point_mass_reach.toml", "point mass through two tendons"),
    ("third_party/dmc_reacher_reach.toml", "two-link reacher"),
    ("third_party/gym_reacher_reach.toml", "two-link reacher"),
    ("third_party/gym_swimmer_swim.toml", "three-link swimmer in a viscous medium"),
    ("third_party/gym_inverted_double_pendulum_balance.toml", "double pendulum on a cart, balance"),
]
BEGIN, END = "<!-- untuned suite: begin -->", "<!-- untuned suite: end -->"
PASS = 1.01


def stem(path: str) -> str:
    return os.path.splitext(os.path.basename(path))[0]


def run_one(path: str, out_dir: str, timeout: float) -> str:
    folder = os.path.join(out_dir, stem(path))
    os.makedirs(folder, exist_ok=True)
    out = os.path.join(folder, "result.json")
    cmd = [sys.executable, "-m", "podilqr_jax.cli", "solve", os.path.join(ROOT, "examples", "tasks", path)]
    cmd += ["--compare", "--quiet", "--no-plots", "--out", out]
    t0 = time.perf_counter()
    with open(os.path.join(folder, "log.txt"), "w") as log:
        try:
            rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, timeout=timeout).returncode
        except subprocess.TimeoutExpired:
            rc = "timeout"
    return f"{stem(path)}: exit {rc} in {time.perf_counter() - t0:.0f} s"


def row(path: str, what: str, out_dir: str) -> tuple[str, bool]:
    name = stem(path)
    try:
        with open(os.path.join(out_dir, name, "result.json")) as f:
            pod = json.load(f)
    except (OSError, ValueError):
        return f"| {name} | {what} | (no result, see runs/untuned/{name}/log.txt) ||||||||||", False
    ref = pod["model_based"]
    ratio = pod["final_cost"] / ref["final_cost"]
    sig = pod.get("sigma_history") or [float("nan")]
    gap = max(
        abs(a - b) for xs, ys in zip(pod["states"], ref["states"], strict=True) for a, b in zip(xs, ys, strict=True)
    )
    passed = ratio <= PASS
    link = f"[{name}](../examples/tasks/{path})"
    return (
        f"| {link} | {what} | {ratio:.6f} | {'yes' if passed else '**no**'} | {pod['status']} | "
        f"{pod['final_cost']:.6g} | {ref['final_cost']:.6g} ({ref['status']}) | "
        f"{pod['iterations']} / {ref['iterations']} | {pod['rollouts']} | "
        f"{sig[0]:.2g} .. {min(sig):.2g} .. {max(sig):.2g} | {experiment(pod)} | {gap:.2g} |",
        passed,
    )


def experiment(pod: dict) -> str:
    """The identification the solve ended with (the recovery may have changed it)."""
    if pod.get("open_loop"):
        return "open loop" if pod.get("variant") == "plain" else "open loop (switched)"
    return "mirrored pairs (switched)" if pod.get("mirrored") else "closed loop"


def table(out_dir: str) -> str:
    head = (
        "| task | what | POD-iLQR / model-based | within 1% or below | POD status | POD cost | model-based cost "
        "(status) | iterations (POD / MB) | POD rollouts | sigma: first .. min .. max | identification at the end | "
        "largest state gap to the reference's trajectory |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|"
    )
    rows = [row(p, w, out_dir) for p, w in SUITE]
    n = sum(ok for _, ok in rows)
    return (
        head + "\n" + "\n".join(r for r, _ in rows) + f"\n\n{n} of {len(rows)} within 1% of the reference or below it."
    )


def write(doc: str, text: str) -> None:
    page = ""
    if os.path.exists(doc):
        with open(doc) as f:
            page = f.read()
    if BEGIN not in page:
        page += f"\n{BEGIN}\n{END}\n"
    head, rest = page.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    with open(doc, "w") as f:
        f.write(f"{head}{BEGIN}\n{text}\n{END}{tail}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", default="", help="comma-separated task file stems (default: all)")
    p.add_argument("--table-only", action="store_true", help="rebuild the table from runs/untuned/ only")
    p.add_argument("--out", default=os.path.join(ROOT, "runs", "untuned"))
    p.add_argument("--doc", default=os.path.join(ROOT, "docs", "robustness.md"))
    p.add_argument("--jobs", type=int, default=2, help="solves at once")
    p.add_argument("--timeout", type=float, default=3600.0, help="seconds per task (both solves)")
    args = p.parse_args(argv)
    only = {s for s in args.only.split(",") if s}
    known = {stem(path) for path, _ in SUITE}
    if only - known:
        p.error(f"unknown task(s) {sorted(only - known)}; the suite has {sorted(known)}")
    if not args.table_only:
        todo = [path for path, _ in SUITE if not only or stem(path) in only]
        with concurrent.futures.ThreadPoolExecutor(args.jobs) as pool:
            for line in pool.map(lambda path: run_one(path, args.out, args.timeout), todo):
                print(line, flush=True)
    text = table(args.out)
    write(args.doc, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
