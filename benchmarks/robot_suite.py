"""The robot suite: every task file of a folder solved by `podilqr solve FILE --compare`, defaults only.

    python benchmarks/robot_suite.py [--tasks examples/tasks/robots] [--out runs/robots] \
        [--timeout 600] [--only NAME,NAME] [--table docs/robot_suite_table.md]

Each task runs in its own process (a cold start: compile included) under a
wall-clock limit; the table gives, per task, the engine ``auto`` picked, both
solvers' status, iterations and cost, the ratio POD-iLQR / model-based, the
compile and wall seconds of the whole command. A task past the limit is a row
that says so. Task files hold no solver settings: this measures the defaults.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import time


def run_one(path: str, out_dir: str, timeout: float) -> dict:
    name = os.path.splitext(os.path.basename(path))[0]
    out = os.path.join(out_dir, name + ".json")
    cmd = [sys.executable, "-m", "podilqr_jax.cli", "solve", path, "--compare", "--no-plots", "--quiet", "--out", out]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        wall = time.perf_counter() - t0
        rc, tail = proc.returncode, (proc.stderr or "")[-2000:]
    except subprocess.TimeoutExpired:
        return {"task": name, "timed_out": True, "wall_s": timeout, "command": " ".join(cmd[1:])}
    row = {"task": name, "timed_out": False, "wall_s": wall, "rc": rc, "command": " ".join(cmd[1:])}
    if not os.path.exists(out):
        row["error"] = tail
        return row
    with open(out) as f:
        r = json.load(f)
    mb = r.get("model_based", {})
    row.update(
        engine=r.get("engine", "mjx"),
        starts=len(r.get("starts") or []) or 1,
        pod_best_start=r.get("best_start", 0),
        mb_best_start=mb.get("best_start", 0),
        pod_status=r["status"],
        pod_iterations=r["iterations"],
        pod_cost=r["final_cost"],
        pod_compile_s=r["compile_s"],
        pod_wall_s=r["wall_s"],
        mb_status=mb.get("status"),
        mb_iterations=mb.get("iterations"),
        mb_cost=r.get("model_based_cost"),
        mb_compile_s=mb.get("compile_s"),
        mb_wall_s=mb.get("wall_s"),
        ratio=r.get("ratio_to_model_based"),
    )
    return row


def table(rows: list[dict]) -> str:
    lines = [
        "| task | engine | starts | POD-iLQR | iterations | cost | model-based | iterations | cost | ratio | compile s "
        "(POD / MB) | command wall s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r.get("timed_out"):
            lines.append(f"| {r['task']} | | | no result in {r['wall_s']:.0f} s | | | | | | | | |")
            continue
        if "pod_status" not in r:
            lines.append(f"| {r['task']} | | | failed (rc {r['rc']}) | | | | | | | | {r['wall_s']:.0f} |")
            continue
        ratio = "" if r["ratio"] is None else f"{r['ratio']:.4f}"
        starts = r.get("starts", 1)
        best = f" (best {r['pod_best_start']} / {r['mb_best_start']})" if starts > 1 else ""
        lines.append(
            f"| {r['task']} | {r['engine']} | {starts}{best} | {r['pod_status']} | {r['pod_iterations']} | "
            f"{r['pod_cost']:.6g} | "
            f"{r['mb_status']} | {r['mb_iterations']} | {r['mb_cost']:.6g} | {ratio} | "
            f"{r['pod_compile_s']:.1f} / {r['mb_compile_s']:.1f} | {r['wall_s']:.0f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", default="examples/tasks/robots", help="a folder of task files")
    parser.add_argument("--extra", default="", help="comma-separated task files added to the folder's")
    parser.add_argument("--out", default="runs/robots", help="folder for each task's result JSON")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per task (default 600)")
    parser.add_argument("--only", default="", help="comma-separated task file stems to run")
    parser.add_argument("--table", default="", help="also write the table (markdown) here")
    args = parser.parse_args(argv)
    paths = sorted(glob.glob(os.path.join(args.tasks, "*.toml"))) + [p for p in args.extra.split(",") if p]
    if args.only:
        keep = set(args.only.split(","))
        paths = [p for p in paths if os.path.splitext(os.path.basename(p))[0] in keep]
    os.makedirs(args.out, exist_ok=True)
    rows = []
    for path in paths:
        print(f"{path} ...", file=sys.stderr, flush=True)
        rows.append(run_one(path, args.out, args.timeout))
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    with open(os.path.join(args.out, "suite.json"), "w") as f:
        json.dump(rows, f, indent=1)
    text = table(rows)
    print(text)
    if args.table:
        with open(args.table, "w") as f:
            f.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
