"""The two engines side by side: physics steps/s per model, and time to the optimum.

``podilqr bench --sections engines`` runs, on this machine:

1. **Steps/s** per model and engine: one sysid batch of ``batch`` closed-loop
   perturbation rollouts (``rollout.perturbation_rollouts``, the solver's
   own stage), compiled first (``compile_s``), then timed ``repeats`` times
   (the median); steps/s counts physics steps (rollouts x horizon x
   substeps). Models: the bundled tasks, the third-party gallery and the robot
   suite (task files), each on MJX and on the native engine, and which one
   ``auto`` picks;
2. **Time to cost** on the bundled tasks: the model-based optimum J* (MJX's
   exact Jacobians), then one cold POD-iLQR solve per engine in this process
   (compile included, no persistent cache) and the wall seconds at which its
   cost first reached 1.001 J*.

An MJX batch on a large contact model can take many minutes to compile on a
CPU: each MJX measurement runs in a child process under a limit of
``mjx_budget_s`` seconds (compile and timed calls); past it the row records
that MJX had no result in that time.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import time
from typing import Any, Optional

import jax
import jax.numpy as jnp
import numpy as np

import podilqr_jax as pj
from podilqr_jax.sim import engines
from podilqr_jax.sim.native import default_threads, native_model
from podilqr_jax.sim.rollout import open_loop_policy, perturbation_rollouts
from podilqr_jax.task.loading import load_env

TASK_GLOBS = ("examples/tasks/third_party/*.toml", "examples/tasks/robots/*.toml")


def task_list(names: tuple[str, ...], globs: tuple[str, ...] = TASK_GLOBS) -> list[str]:
    """The bundled ``names`` and every task file the globs find (from the working folder)."""
    files = sorted(f for g in globs for f in glob.glob(g))
    return list(names) + files


def sysid_batch_speed(env, engine: str, batch: int, repeats: int) -> dict[str, Any]:
    """Compile and time one sysid batch of ``batch`` rollouts of ``env`` on ``engine``."""
    on = env.on_engine(native_model(env.mj_model) if engine == "native" else None)
    dims, data = on.dims, on.data
    policy = open_loop_policy(jnp.zeros((dims.horizon, dims.nu)), dims.nz)
    sigma = jnp.full((dims.nu,), 0.1)

    def once(seed: int) -> float:
        t = time.perf_counter()
        perturbation_rollouts(dims, 1, batch, data, policy, jax.random.PRNGKey(seed), sigma).z.block_until_ready()
        return time.perf_counter() - t

    compile_s = once(0)
    times = [once(r + 1) for r in range(repeats)]
    seconds = float(np.median(times))
    steps = batch * dims.horizon * dims.substeps
    return {"compile_s": compile_s, "batch_s": seconds, "steps_per_s": steps / seconds}


def mjx_in_child(source: str, batch: int, repeats: int, budget_s: float) -> dict[str, Any]:
    """:func:`sysid_batch_speed` on MJX in a fresh process, or why it gave none within ``budget_s``."""
    cmd = [sys.executable, "-m", __name__, source, str(batch), str(repeats)]
    try:
        out = subprocess.run(
            cmd, capture_output=True, text=True, timeout=budget_s, env=os.environ | {"PODILQR_CACHE": "0"}
        )
    except subprocess.TimeoutExpired:
        return {"skipped": f"no result within {budget_s:.0f} s (compile and {repeats + 1} batches)"}
    if out.returncode != 0:
        return {"skipped": (out.stderr.strip().splitlines() or [f"exit {out.returncode}"])[-1]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def run_speeds(tasks: list[str], batch: int, repeats: int, mjx_budget_s: float, progress) -> list[dict[str, Any]]:
    rows = []
    for name in tasks:
        env = load_env(name)
        row: dict[str, Any] = {
            "task": env.name,
            "source": name,
            "nx": env.dims.nx,
            "nu": env.dims.nu,
            "auto": engines.auto_engine(env),
        }
        row["native"] = sysid_batch_speed(env, "native", batch, repeats)
        row["mjx"] = mjx_in_child(name, batch, repeats, mjx_budget_s)
        if "skipped" not in row["mjx"]:
            row["mjx_over_native"] = row["mjx"]["steps_per_s"] / row["native"]["steps_per_s"]
        progress(f"engines {env.name}: {_speed_cell(row)}")
        rows.append(row)
    return rows


def time_to_cost(task: str, engine: str, target: float, max_iterations: int) -> Optional[float]:
    """Seconds (from the call, compile included) until a POD-iLQR solve on ``engine`` reaches ``target``."""
    env = pj.make_task(task)
    reached: list[float] = []
    t = time.perf_counter()

    def cb(info):
        if not reached and info.cost <= target:
            reached.append(time.perf_counter() - t)

    pj.solve(env, pj.default_config(env, engine=engine, max_iterations=max_iterations), callback=cb)
    return reached[0] if reached else None


def run_time_to_cost(tasks: tuple[str, ...], max_iterations: int, progress) -> list[dict[str, Any]]:
    rows = []
    for task in tasks:
        env = pj.make_task(task)
        reference = pj.solve_model_based(env, pj.default_config(env, engine="mjx"))
        target = reference.final_cost * 1.001
        row = {"task": task, "target_cost": target, "auto": engines.auto_engine(env)}
        for engine in ("mjx", "native"):
            row[f"{engine}_s"] = time_to_cost(task, engine, target, max_iterations)
        progress(f"time to 1.001 J*, {task}: mjx {row['mjx_s']}, native {row['native_s']}")
        rows.append(row)
    return rows


def run(settings, progress) -> dict[str, Any]:
    """The section's report (``settings``: ``BenchSettings``)."""
    old = os.environ.get("PODILQR_CACHE")
    os.environ["PODILQR_CACHE"] = "0"  # cold compiles, as a first run on a new machine
    try:
        tasks = task_list(settings.tasks, settings.engine_globs)
        budget = settings.engine_mjx_budget_s
        speeds = run_speeds(tasks, settings.engine_batch, settings.engine_repeats, budget, progress)
        to_cost = run_time_to_cost(settings.tasks, settings.engine_max_iterations, progress)
    finally:
        if old is None:
            os.environ.pop("PODILQR_CACHE", None)
        else:
            os.environ["PODILQR_CACHE"] = old
    return {"batch": settings.engine_batch, "threads": default_threads(), "speeds": speeds, "time_to_cost": to_cost}


def _speed_cell(row: dict[str, Any]) -> str:
    mjx = row["mjx"]
    mjx_text = mjx.get("skipped") or f"MJX {mjx['steps_per_s']:,.0f} steps/s (compile {mjx['compile_s']:.1f} s)"
    nat = row["native"]
    native_text = f"native {nat['steps_per_s']:,.0f} steps/s (compile {nat['compile_s']:.2f} s)"
    return f"{native_text}; {mjx_text}; auto {row['auto']}"


def format_table(section: dict[str, Any]) -> str:
    lines = [
        f"Sysid batch of {section['batch']} rollouts, native on {section['threads']} threads:",
        "",
        "| task | nx | nu | native steps/s | native compile s | MJX steps/s | MJX compile s | MJX / native | auto |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in section["speeds"]:
        n, m = r["native"], r["mjx"]
        if "skipped" in m:
            mjx_cells = "skipped | | "
        else:
            mjx_cells = f"{m['steps_per_s']:,.0f} | {m['compile_s']:.1f} | {r['mjx_over_native']:.2f}"
        lines.append(
            f"| {r['task']} | {r['nx']} | {r['nu']} | {n['steps_per_s']:,.0f} | {n['compile_s']:.2f} | "
            f"{mjx_cells} | {r['auto']} |"
        )
    lines += ["", "| task | s to 1.001 J*, MJX (cold) | native (cold) | auto |", "|---|---|---|---|"]
    for r in section["time_to_cost"]:
        cells = ["not reached" if r[k] is None else f"{r[k]:.1f}" for k in ("mjx_s", "native_s")]
        lines.append(f"| {r['task']} | {cells[0]} | {cells[1]} | {r['auto']} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    """The child of :func:`mjx_in_child`: one model's MJX measurement, printed as one JSON line."""
    parser = argparse.ArgumentParser(description="one MJX sysid-batch measurement (podilqr bench's engines section)")
    parser.add_argument("task", help="a bundled task or a task file")
    parser.add_argument("batch", type=int)
    parser.add_argument("repeats", type=int)
    args = parser.parse_args(argv)
    print(json.dumps(sysid_batch_speed(load_env(args.task), "mjx", args.batch, args.repeats)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
