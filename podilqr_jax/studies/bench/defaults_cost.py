"""What the robust defaults cost: rollouts per iteration and time to 1.001 x the optimum.

For each task, the model-based reference gives the optimum J*; then
POD-iLQR runs twice in this process, with the settings before the robust
defaults (``BEFORE``, ``config.PAPER_SETTINGS``: the paper's open-loop
identification, every direction above rcond, one fixed sigma in absolute
units, no change of experiment on failure) and with today's defaults. Each row
reports the rollouts per iteration, the iterations, rollouts and seconds until
the nominal cost first comes within 1.001 x J* (``null`` if it never does), the
final ratio and the compile time. The solves run one after the other in
one process, so their wall times compare on a shared machine only as well as
the load stayed level; rollouts and iterations do not depend on it.

    python -m podilqr_jax.studies.bench.defaults_cost [--tasks pendulum-full,...] [--out FILE]
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any, Optional, Sequence

import podilqr_jax as pj

from .report import emit

BEFORE = pj.PAPER_SETTINGS
TARGET = 1.001


def one(env: pj.Env, optimum: float, overrides: dict[str, Any], max_iterations: Optional[int]) -> dict[str, Any]:
    """One POD-iLQR solve with ``overrides`` on the task's defaults, timed to ``TARGET x optimum``."""
    if max_iterations is not None:
        overrides = {**overrides, "max_iterations": max_iterations}
    cfg = pj.default_config(env, **overrides)
    pj.solve(env, cfg.replace(max_iterations=2))  # warm-up: the stages compile here
    reached: dict[str, Any] = {}
    seen = {"rollouts": 0}
    t0 = time.perf_counter()

    def watch(info: pj.IterationInfo) -> None:
        seen["rollouts"] += info.rollouts
        if not reached and info.cost <= TARGET * optimum:
            reached.update(iterations=info.iteration, rollouts=seen["rollouts"], wall_s=time.perf_counter() - t0)

    result = pj.solve(env, cfg, callback=watch)
    return {
        "settings": overrides,
        "status": str(result.status),
        "ratio": result.final_cost / optimum,
        "iterations": result.iterations,
        "rollouts": result.rollouts,
        "rollouts_per_iteration": result.rollouts / max(result.iterations, 1),
        "to_target": reached or None,
        "wall_s": result.wall_s,
        "compile_s": result.compile_s,
    }


def run(tasks: Sequence[str], horizon: Optional[int] = None, max_iterations: Optional[int] = None) -> dict:
    rows = {}
    for name in tasks:
        env = pj.make_task(name, **({"horizon": horizon} if horizon else {}))
        ref_cfg = pj.default_config(env, **({"max_iterations": max_iterations} if max_iterations else {}))
        reference = pj.solve_model_based(env, ref_cfg)
        optimum = reference.final_cost
        rows[name] = {
            "model_based_cost": optimum,
            "before": one(env, optimum, dict(BEFORE), max_iterations),
            "after": one(env, optimum, {}, max_iterations),
        }
        print(_line(name, rows[name]), file=sys.stderr, flush=True)
    return {"target": TARGET, "before_settings": BEFORE, "tasks": rows}


def _line(name: str, row: dict) -> str:
    def cell(r):
        t = r["to_target"]
        reach = f"{t['iterations']} it, {t['rollouts']} rollouts, {t['wall_s']:.1f} s" if t else "never"
        return f"{r['rollouts_per_iteration']:.0f} rollouts/it, to {TARGET}: {reach}, final {r['ratio']:.7f}"

    return f"{name}: before {cell(row['before'])} | after {cell(row['after'])}"


def table(report: dict) -> str:
    lines = [
        f"| task | settings | rollouts / iteration | iterations to {TARGET} x J* | rollouts to it | "
        "seconds to it (compile s) | final / J* | status |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, row in report["tasks"].items():
        for which in ("before", "after"):
            r = row[which]
            t = r["to_target"]
            seconds = f"{t['wall_s']:.1f}" if t else "-"
            lines.append(
                f"| {name} | {which} | {r['rollouts_per_iteration']:.0f} | {t['iterations'] if t else 'never'} | "
                f"{t['rollouts'] if t else '-'} | {seconds} ({r['compile_s']:.1f}) | "
                f"{r['ratio']:.7f} | {r['status']} |"
            )
    return "\n".join(lines)


def main(argv: Optional[Sequence[str]] = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", default=",".join(pj.TASKS), help="comma-separated bundled tasks")
    p.add_argument("--horizon", type=int, default=None, help="shorter horizons for a smoke run")
    p.add_argument("--max-iterations", type=int, default=None)
    p.add_argument("--out", default=None, help="also write the JSON report here")
    args = p.parse_args(argv)
    tasks = [t for t in args.tasks.split(",") if t]
    unknown = [t for t in tasks if t not in pj.TASKS]
    if unknown:
        p.error(f"--tasks takes bundled tasks ({', '.join(pj.TASKS)}); got {', '.join(unknown)}")
    report = run(tasks, args.horizon, args.max_iterations)
    emit(report, args.out)
    print(table(report), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
