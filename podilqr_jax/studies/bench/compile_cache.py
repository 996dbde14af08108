"""What the persistent compilation cache saves: ``podilqr solve TASK --compare``
in fresh processes, with the cache off, cold (an empty folder) and warm (the
folder the cold run filled).

    python -m podilqr_jax.studies.bench.compile_cache [--task cartpole-partial] [--set KEY=VALUE ...]

Each run is ``python -m podilqr_jax.cli solve TASK --compare --no-plots
--quiet`` in its own process with ``PODILQR_CACHE_DIR`` pointing at a fresh
temporary folder (or ``PODILQR_CACHE=0``), so the user's own cache is neither
read nor written. A row holds the process's wall time (imports included), and
per solver the solve's wall and compile time (trace + lower + compile or load,
``Result.compile_s``) from the result JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from typing import Any, Optional, Sequence

from .report import emit

MODES = ("off", "cold", "warm")


def _cache_contents(path: str) -> tuple[int, int]:
    files = [e for e in os.scandir(path) if e.is_file() and e.name.endswith("-cache")] if os.path.isdir(path) else []
    return len(files), sum(e.stat().st_size for e in files)


def solve_in_fresh_process(
    task: str,
    mode: str,
    cache_dir: str,
    out_dir: str,
    sets: Sequence[str] = (),
    timeout: float = 1800,
    compare: bool = True,
) -> dict[str, Any]:
    """One ``podilqr solve TASK --compare`` in a new process; ``mode`` is
    ``off`` (``PODILQR_CACHE=0``) or ``cold``/``warm`` (cache in ``cache_dir``).
    ``compare=False`` leaves out ``--compare`` (POD-iLQR alone)."""
    env = dict(os.environ)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)  # the package's own cache, not one configured for JAX
    if mode == "off":
        env["PODILQR_CACHE"] = "0"
    else:
        env["PODILQR_CACHE"] = "1"
        env["PODILQR_CACHE_DIR"] = cache_dir
    out = os.path.join(out_dir, f"{mode}.json")
    cmd = [sys.executable, "-m", "podilqr_jax.cli", "solve", task, *(["--compare"] if compare else [])]
    cmd += ["--no-plots", "--quiet", "--out", out]
    for s in sets:
        cmd += ["--set", s]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        tail = proc.stderr.strip().splitlines()[-1:] or [f"exit {proc.returncode}"]
        return {"mode": mode, "error": tail[0]}
    with open(out) as f:
        result = json.load(f)
    reference = result.get("model_based", {})
    entries, size = _cache_contents(cache_dir)
    row = {
        "mode": mode,
        "process_wall_s": wall,
        "pod_ilqr_wall_s": result["wall_s"],
        "pod_ilqr_compile_s": result["compile_s"],
        "model_based_wall_s": reference.get("wall_s"),
        "model_based_compile_s": reference.get("compile_s"),
        "final_cost": result["final_cost"],
        "model_based_cost": result.get("model_based_cost"),
        "cache_entries": entries if mode != "off" else 0,
        "cache_mb": size / 2**20 if mode != "off" else 0.0,
    }
    row["compile_s_total"] = row["pod_ilqr_compile_s"] + (row["model_based_compile_s"] or 0.0)
    return row


def cold_warm(
    task: str = "cartpole-partial", sets: Sequence[str] = (), workdir: Optional[str] = None, compare: bool = True
) -> dict[str, Any]:
    """Cache off, cold and warm runs of ``podilqr solve TASK --compare``, one
    fresh process each, in that order; with the ratios warm / cold and
    warm / off of the process wall time and of the total compile time.
    ``compare=False`` runs POD-iLQR alone (``podilqr bench --tiny``).

    ``workdir`` (default: a temporary folder, removed afterwards) holds the
    cache folder and the result JSONs. The target of issue 16 is a warm
    compile under 2 s in all (``warm_compile_under_2s``)."""
    own = workdir is None
    workdir = tempfile.mkdtemp(prefix="podilqr-cache-bench-") if own else workdir
    try:
        cache_dir = os.path.join(workdir, "jax-cache")
        if os.path.exists(cache_dir):
            shutil.rmtree(cache_dir)
        rows = [solve_in_fresh_process(task, mode, cache_dir, workdir, sets, compare=compare) for mode in MODES]
    finally:
        if own:
            shutil.rmtree(workdir, ignore_errors=True)
    report: dict[str, Any] = {"task": task, "sets": list(sets), "compare": compare, "runs": rows}
    by = {r["mode"]: r for r in rows if "error" not in r}
    if {"cold", "warm"} <= set(by):
        cold, warm = by["cold"], by["warm"]
        report["warm_over_cold_process_wall"] = warm["process_wall_s"] / cold["process_wall_s"]
        report["warm_over_cold_compile"] = warm["compile_s_total"] / cold["compile_s_total"]
        report["warm_compile_s_total"] = warm["compile_s_total"]
        report["warm_compile_under_2s"] = warm["compile_s_total"] < 2.0
        report["same_cost_warm_as_cold"] = warm["final_cost"] == cold["final_cost"]
    if {"off", "cold"} <= set(by):
        report["cold_over_off_process_wall"] = by["cold"]["process_wall_s"] / by["off"]["process_wall_s"]
    if {"off", "warm"} <= set(by):
        report["warm_over_off_process_wall"] = by["warm"]["process_wall_s"] / by["off"]["process_wall_s"]
    return report


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m podilqr_jax.studies.bench.compile_cache", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--task", default="cartpole-partial")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", default=None, help="write the report as JSON here")
    args = parser.parse_args(argv)
    report = cold_warm(args.task, args.set)
    emit(report, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
