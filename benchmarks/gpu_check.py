"""The GPU check: MJX and MJX-Warp against MuJoCo's C engine, and solves with 1, 4 and 16 starts.

One script, prepared for the first session that is lent a GPU (at most 10 minutes):

1. **Steps/s** of one batch of open-loop rollouts (random controls, ``T`` control
   steps of the task's substeps) on the bundled cart-pole, dm_control's walker and
   dm_control's humanoid, at batch 10^3, 10^4 and 10^5: MuJoCo's C engine
   (``mujoco.rollout`` on all the host's cores), MJX (``impl="jax"``) and MJX-Warp
   (``impl="warp"``, where ``mujoco_warp`` is installed; else the row says why not).
   The MJX figures are of a call after the compiling one, ended by ``block_until_ready``.
2. **Solves**: ``pj.solve`` on the bundled cart-pole (the defaults) and on dm_control's
   walker lifting a knee (``examples/tasks/robots/dmc_walker_knee.toml``, at most
   ``--robot-iterations`` iterations), each with 1, 4 and 16 starts: wall, compile,
   iterations, cost, and the engine ``auto`` picked.

Cells run until ``--budget-s`` is spent (batch 10^5 last); the ones left are rows that say so.
The table is printed and written with every figure to ``OUT/gpu_check.json``.

    python benchmarks/gpu_check.py                      # on the GPU machine (about 8 minutes)
    python benchmarks/gpu_check.py --quick              # a CPU smoke run: tiny batches, 2 iterations
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
import types

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import jax  # noqa: E402

import podilqr_jax as pj  # noqa: E402
from podilqr_jax.errors import ConfigError, ModelLoadError  # noqa: E402
from podilqr_jax.ilqr.config import check_impl  # noqa: E402
from podilqr_jax.studies.bench.native_rollout import mjx_rollouts, native_rollouts  # noqa: E402

ROBOT = os.path.join(ROOT, "examples", "tasks", "robots", "dmc_walker_knee.toml")
MODELS = {
    "cartpole": lambda T: pj.make_task("cartpole-full", horizon=T),
    "dmc-walker": lambda T: pj.make_task(ROBOT).replace(horizon=T),
    "dmc-humanoid": lambda T: pj.Env.from_xml("pkg://dm_control/suite/humanoid.xml", horizon=T, substeps=5),
}
IMPLS = ("jax", "warp")


def steps_row(name: str, env, batch: int, engine: str, repeats: int) -> dict:
    """One batch of ``batch`` rollouts of ``env`` on ``engine`` (native, jax or warp): steps/s."""
    dims = env.dims
    row = {"model": name, "engine": engine, "batch": batch, "horizon": dims.horizon, "substeps": dims.substeps}
    controls = np.random.default_rng(0).normal(size=(batch, dims.horizon, dims.nu))
    steps = batch * dims.horizon * dims.substeps
    try:
        if engine == "native":
            _, seconds = native_rollouts(env, controls, nthread=os.cpu_count(), repeats=repeats)
        else:
            check_impl(engine)
            data = env.data._replace(model=env.mjx_model(engine))
            info: dict = {}
            _, seconds = mjx_rollouts(types.SimpleNamespace(dims=dims, data=data), controls, repeats, info)
            row["compile_s"] = info["compile_s"]
    except (ConfigError, ModelLoadError, RuntimeError, ValueError, MemoryError) as exc:
        return row | {"error": f"{type(exc).__name__}: {str(exc).splitlines()[0][:200]}"}
    return row | {"seconds": seconds, "steps_per_s": steps / seconds}


def solve_row(name: str, env, k: int, max_iterations: int | None) -> dict:
    cfg = pj.default_config(env, restarts=k)
    if max_iterations is not None:
        cfg = cfg.replace(max_iterations=max_iterations)
    t0 = time.perf_counter()
    r = pj.solve(env, cfg)
    return {
        "task": name,
        "starts": k,
        "engine": r.engine,
        "status": str(r.status),
        "iterations": r.iterations,
        "cost": r.final_cost,
        "rollouts": sum(s["rollouts"] for s in r.starts) if r.starts else r.rollouts,
        "wall_s": time.perf_counter() - t0,
        "compile_s": r.compile_s,
    }


def table(out: dict) -> str:
    lines = ["| model | batch | engine | steps/s | s per batch | compile s |", "|---|---|---|---|---|---|"]
    for r in out["steps"]:
        if "steps_per_s" in r:
            c = f"{r['compile_s']:.1f}" if "compile_s" in r else ""
            lines.append(
                f"| {r['model']} | {r['batch']} | {r['engine']} | {r['steps_per_s']:.3g} | {r['seconds']:.3g} | {c} |"
            )
        else:
            lines.append(f"| {r['model']} | {r['batch']} | {r['engine']} | {r.get('error', r.get('skipped'))} | | |")
    lines += ["", "| task | starts | engine | status | iterations | cost | rollouts | wall s | compile s |"]
    lines.append("|---|---|---|---|---|---|---|---|---|")
    for r in out["solves"]:
        if "wall_s" in r:
            lines.append(
                f"| {r['task']} | {r['starts']} | {r['engine']} | {r['status']} | {r['iterations']} | "
                f"{r['cost']:.6g} | {r['rollouts']} | {r['wall_s']:.1f} | {r['compile_s']:.1f} |"
            )
        else:
            lines.append(f"| {r['task']} | {r['starts']} | | {r.get('error', r.get('skipped'))} | | | | | |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=os.path.join(ROOT, "runs", "gpu_check"))
    ap.add_argument("--budget-s", type=float, default=540.0, help="stop starting cells after this many seconds")
    ap.add_argument("--horizon", type=int, default=20, help="control steps per rollout of the steps/s cells")
    ap.add_argument("--robot-iterations", type=int, default=60, help="max_iterations of the robot's solves")
    ap.add_argument("--quick", action="store_true", help="a CPU smoke run: batch 8, the cart-pole, 2 iterations")
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    batches = (8,) if args.quick else (1_000, 10_000, 100_000)
    models = ("cartpole",) if args.quick else tuple(MODELS)
    ks = (1,) if args.quick else (1, 4, 16)
    t_start = time.perf_counter()
    out = {
        "devices": [str(d) for d in jax.devices()],
        "backend": jax.default_backend(),
        "host": {"cpus": os.cpu_count(), "machine": platform.processor() or platform.machine()},
        "steps": [],
        "solves": [],
    }

    def spent() -> bool:
        return time.perf_counter() - t_start > args.budget_s

    envs = {name: MODELS[name](args.horizon) for name in models}

    def steps_cells(batch_sizes) -> None:
        for batch in batch_sizes:
            for name, env in envs.items():
                for engine in ("native", *IMPLS):
                    if spent():
                        row = {"model": name, "engine": engine, "batch": batch, "skipped": "budget spent"}
                        out["steps"].append(row)
                        continue
                    out["steps"].append(steps_row(name, env, batch, engine, repeats=1 if args.quick else 2))
                    print(out["steps"][-1], flush=True)

    steps_cells(batches[:2])  # the largest batch last, after the solves: it is the one the budget may cut
    solves = [("cartpole-full", pj.make_task("cartpole-full"), 2 if args.quick else None)]
    if not args.quick:
        solves.append(("dmc-walker-knee", pj.make_task(ROBOT), args.robot_iterations))
    for name, env, iterations in solves:
        for k in ks:
            if spent():
                out["solves"].append({"task": name, "starts": k, "skipped": "budget spent"})
                continue
            out["solves"].append(solve_row(name, env, k, iterations))
            print(out["solves"][-1], flush=True)
    steps_cells(batches[2:])
    out["wall_s"] = time.perf_counter() - t_start
    text = table(out)
    print(f"\non {out['backend']} ({', '.join(out['devices'])}), host {out['host']}:\n\n{text}")
    with open(os.path.join(args.out, "gpu_check.json"), "w") as f:
        json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
