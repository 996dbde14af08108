"""``podilqr bench``: where an iteration's time goes, how it grows with n_s x n_avg,
and how it compares with what a user would otherwise run.

    podilqr bench [--quick | --tiny] [--tasks pendulum-full,cartpole-full] [--out DIR]
    python -m podilqr_jax.studies.bench ...            (the same)

Per task:

1. **Grid** (noisy task, the paper's noise; variant ``averaged`` with n_avg in
   the grid, ``n_forward = 1``): for each (n_s, n_avg) a warm-up solve of one
   iteration compiles everything (``compile_s``), then a timed solve of
   ``iterations`` iterations gives the per-iteration wall time (median, min,
   max), the split by phase (rollouts, fit, backward, line search, evaluation,
   host), rollouts/s and physics steps/s, the compilations after the warm-up
   (``recompiles_after_first``) and the process's peak RSS. On a GPU also the
   device's peak memory.
2. **Baselines**:
   - ``mujoco.rollout`` (native C, all threads) on the same model, controls
     and batch (``bench/native_rollout.py``): ``rollout_throughput_vs_native`` =
     MJX rollouts/s / native rollouts/s at the largest batch of the run;
   - the serial NumPy reference (``bench/serial_reference.py``, one rollout at a
     time with ``mujoco.mj_step``): ``speedup_vs_serial`` = its seconds per
     iteration / ours, noiseless, same settings, at ``serial_n_s`` rollouts
     per iteration; the full run also times both (and the model-based iLQR)
     to the same cost;
3. **Memory** (subprocesses, one per batch): the sysid batch alone at
   growing n_s x n_avg under the default memory budget, its time and peak
   RSS, to show that memory follows the chunk, not the batch;
4. **Devices** (subprocesses with ``XLA_FLAGS=--xla_force_host_platform_device_count=N``):
   seconds per iteration against the device count.
5. **Cache** (``bench/compile_cache.py``): ``podilqr solve TASK --compare`` in
   fresh processes with the persistent compilation cache off, cold and warm:
   process wall time and compile time of each, and their ratios.
6. **Line-search memory** (``bench/line_search_memory.py``): one noisy line
   search of ``(n_alphas + 1) x n_forward`` rollouts per fresh process, one
   process per chunk size: peak memory, time, and the costs against the
   unchunked batch.
7. **Engines** (``bench/engines.py``): physics steps/s of a sysid batch on MJX
   and on the native engine (MuJoCo's C step) per model, the bundled tasks and
   the task files of ``examples/tasks/third_party`` and ``examples/tasks/robots``
   (from a checkout), and the cold wall time of a POD-iLQR solve on each
   engine to 1.001 x the model-based optimum on the bundled tasks.

Writes ``DIR/bench.json`` (the machine, every measurement, and per task the
summary fields ``rollout_throughput_vs_native``, ``non_rollout_fraction``,
``speedup_vs_serial``, ``compile_s``, ``recompiles_after_first``,
``peak_host_mb``) and the plots ``time_per_iteration.png``, ``phases.png``,
``throughput.png``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import subprocess
import sys
import time
from typing import Any, Optional

import numpy as np

import podilqr_jax as pj
from podilqr_jax.studies.report import header, write
from podilqr_jax.studies.settings import Sized, add_size_flags, check_writable, parse_names, size_of
from podilqr_jax.verbosity import VERBOSE_HELP

NON_ROLLOUT_PHASES = ("fit", "backward", "host")


@dataclasses.dataclass(frozen=True)
class BenchSettings(Sized):
    """What ``podilqr bench`` measures (sizes and changes as every study's: ``studies/settings.py``)."""

    tasks: tuple[str, ...] = ("pendulum-full", "cartpole-full")
    n_s: tuple[int, ...] = (16, 64, 256, 1024, 4096)
    n_avg: tuple[int, ...] = (1, 4, 16)
    iterations: int = 3
    native_batch: int = 4096
    serial_n_s: int = 1024
    serial_iterations: int = 3
    time_to_cost: bool = True
    memory_batches: tuple[int, ...] = (10_000, 100_000, 1_000_000)
    memory_task: str = "cartpole-full"
    devices: tuple[int, ...] = (1, 2, 4)
    device_cell: tuple[int, int] = (256, 4)
    cache_task: str = "cartpole-partial"
    cache_sets: tuple[str, ...] = ()
    cache_compare: bool = True
    ls_memory_task: str = "cartpole-partial"
    ls_memory_n_forward: int = 10_000
    ls_memory_chunks: tuple[Optional[int], ...] = (None, 22_000, 10_000, 5_000)
    engine_globs: tuple[str, ...] = ("examples/tasks/third_party/*.toml", "examples/tasks/robots/*.toml")
    engine_batch: int = 40
    engine_repeats: int = 3
    engine_mjx_budget_s: float = 90.0
    engine_max_iterations: int = 300

    @classmethod
    def quick(cls) -> "BenchSettings":
        """A small grid and small baselines: a few minutes on a CPU."""
        return cls(
            n_s=(16, 256),
            n_avg=(1, 4),
            iterations=2,
            native_batch=1024,
            serial_iterations=2,
            time_to_cost=False,
            memory_batches=(4_096, 16_384),
            devices=(1, 2),
            device_cell=(64, 4),
            cache_sets=("max_iterations=20",),
            ls_memory_n_forward=1_000,
            ls_memory_chunks=(None, 2_200, 1_000),
            engine_globs=("examples/tasks/third_party/*.toml",),
        )

    @classmethod
    def tiny(cls) -> "BenchSettings":
        """Every section at the smallest size that runs it: a smoke test (seconds
        to a minute), not a measurement."""
        return cls(
            tasks=("pendulum-full",),
            n_s=(8,),
            n_avg=(1, 2),
            iterations=1,
            native_batch=32,
            serial_n_s=8,
            serial_iterations=1,
            time_to_cost=False,
            memory_batches=(256,),
            memory_task="pendulum-full",
            devices=(2,),
            device_cell=(8, 2),
            cache_task="pendulum-full",
            cache_sets=("horizon=8", "max_iterations=2"),
            cache_compare=False,
            ls_memory_task="pendulum-full",
            ls_memory_n_forward=20,
            ls_memory_chunks=(None, 44),
            engine_globs=(),
            engine_batch=4,
            engine_repeats=1,
            engine_max_iterations=3,
        )


def peak_host_mb() -> float:
    """Peak resident memory of this process so far: VmHWM of /proc/self/status
    (Linux; reset by exec, unlike ru_maxrss, which a child started by
    subprocess inherits from its parent), else ru_maxrss."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def peak_device_mb() -> Optional[float]:
    import jax

    stats = jax.devices()[0].memory_stats() if jax.default_backend() != "cpu" else None
    return None if not stats else stats.get("peak_bytes_in_use", 0) / 2**20


def warm_and_timed(env, cfg, iterations: int):
    """A one-iteration solve that compiles every stage, then a timed solve of
    ``iterations`` iterations; returns both results and the per-iteration walls."""
    warm = pj.solve(env, cfg.replace(max_iterations=1))
    walls: list[float] = []
    timed = pj.solve(env, cfg.replace(max_iterations=iterations), callback=lambda info: walls.append(info.wall_s))
    return warm, timed, walls


def grid_cell(task: str, n_s: int, n_avg: int, iterations: int) -> dict[str, Any]:
    """One (n_s, n_avg) cell: warm-up solve, then a timed solve."""
    env = pj.make_task(task, noise="paper")
    cfg = pj.default_config(env, variant="averaged", n_s=n_s, n_avg=n_avg, n_forward=1)
    warm, timed, walls = warm_and_timed(env, cfg, iterations)
    dims = env.dims
    per_iter = timed.rollouts / timed.iterations
    median = float(np.median(walls))
    phases = {k: v / timed.iterations for k, v in timed.phase_s.items()}
    total = sum(phases.values())
    return {
        "task": task,
        "n_s": n_s,
        "n_avg": n_avg,
        "rollouts_per_iteration": per_iter,
        "sysid_rollouts": n_s * n_avg,
        "iteration_s_median": median,
        "iteration_s_min": float(np.min(walls)),
        "iteration_s_max": float(np.max(walls)),
        "phase_s_per_iteration": phases,
        "non_rollout_fraction": sum(phases[p] for p in NON_ROLLOUT_PHASES) / total,
        "rollouts_per_s": per_iter / median,
        "steps_per_s": per_iter * dims.horizon * dims.substeps / median,
        "compile_s": warm.compile_s,
        "recompiles_after_first": int(sum(timed.compiles_per_iteration)),
        "peak_host_mb": peak_host_mb(),
        "peak_device_mb": peak_device_mb(),
    }


def serial_comparison(task: str, n_s: int, iterations: int, time_to_cost: bool) -> dict[str, Any]:
    """Seconds per iteration of the serial NumPy reference and of ours, noiseless plain POD-iLQR."""
    from .serial_reference import PAPER_SETTINGS, serial_solve

    env = pj.make_task(task)
    cfg = pj.default_config(env, n_s=n_s, **PAPER_SETTINGS)
    serial = serial_solve(env, cfg.replace(max_iterations=iterations))
    warm, ours, walls = warm_and_timed(env, cfg, iterations)
    out = {
        "task": task,
        "n_s": n_s,
        "serial_iteration_s": float(np.median(serial["iteration_s"])),
        "ours_iteration_s": float(np.median(walls)),
        "ours_iterations": ours.iterations,
        "ours_compile_s": warm.compile_s,
    }
    out["speedup_per_iteration"] = out["serial_iteration_s"] / out["ours_iteration_s"]
    if time_to_cost:
        out.update(_time_to_cost(env, cfg, warm.compile_s))
    return out


def _time_to_cost(env, cfg, ours_compile_s: float) -> dict[str, Any]:
    """Wall time for each method to first reach the model-based optimum x (1 + 1e-3):
    ours (compiled; the compile time of its stages is added for the cold figure),
    the serial reference, and the model-based iLQR (compiled)."""
    from .serial_reference import serial_solve

    first = pj.solve_model_based(env)  # compiles the model-based stages
    target = first.final_cost * (1 + 1e-3)

    def reach(fn) -> Optional[float]:
        reached: list[float] = []
        t = time.perf_counter()

        def cb(info):
            if not reached and info.cost <= target:
                reached.append(time.perf_counter() - t)

        fn(cb)
        return reached[0] if reached else None

    mb_s = reach(lambda cb: pj.solve_model_based(env, callback=cb))
    ours_s = reach(lambda cb: pj.solve(env, cfg, callback=cb))
    serial = serial_solve(env, cfg, target_cost=target, stop_at_target=True, time_limit_s=600)
    serial_s = serial["reached_target_s"]
    return {
        "target_cost": target,
        "ours_to_cost_s": ours_s,
        "ours_to_cost_s_plus_compile": None if ours_s is None else ours_s + ours_compile_s,
        "serial_to_cost_s": serial_s,
        "model_based_to_cost_s": mb_s,
        "model_based_compile_s": first.compile_s,
        "speedup_to_cost_vs_serial": serial_s / ours_s if serial_s and ours_s else None,
        "speedup_to_cost_vs_serial_with_compile": serial_s / (ours_s + ours_compile_s) if serial_s and ours_s else None,
    }


def _child(args: list[str], env_extra: dict[str, str]) -> dict[str, Any]:
    """``python -m podilqr_jax.studies.bench ARGS`` in a fresh process; its last stdout line, parsed."""
    env = dict(os.environ)
    env.update(env_extra)
    cmd = [sys.executable, "-m", "podilqr_jax.studies.bench", *args]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=3600)
    if out.returncode != 0:
        return {"error": out.stderr.strip().splitlines()[-1] if out.stderr.strip() else f"exit {out.returncode}"}
    return json.loads(out.stdout.strip().splitlines()[-1])


def memory_child(task: str, batch: int) -> dict[str, Any]:
    """In a fresh process: one sysid batch of ``batch`` rollouts (n_avg = 10)
    under the default memory budget; time and peak RSS."""
    import jax

    from podilqr_jax.identify.info_state import info_dim
    from podilqr_jax.sim.rollout import bytes_per_rollout, open_loop_policy, perturbation_rollouts

    env = pj.make_task(task, noise="paper")
    dims = env.dims
    n_avg = 10
    n_s = max(1, batch // n_avg)
    cfg = pj.SolverConfig(variant="averaged", n_avg=n_avg)
    chunk = cfg.resolved_chunk(bytes_per_rollout(dims, env.data, True))
    policy = open_loop_policy(jax.numpy.zeros((dims.horizon, dims.nu)), info_dim(dims.nz, dims.nu, 1))
    base_mb = peak_host_mb()
    t0 = time.perf_counter()
    traj = perturbation_rollouts(
        dims, 1, n_s, env.data, policy, jax.random.PRNGKey(0), jax.numpy.asarray(0.1), n_avg, True, chunk
    )
    traj.z.block_until_ready()
    wall = time.perf_counter() - t0
    return {
        "task": task,
        "rollouts": n_s * n_avg,
        "chunk": chunk,
        "chunks": -(-(n_s * n_avg) // chunk),
        "wall_s_with_compile": wall,
        "rollouts_per_s_with_compile": n_s * n_avg / wall,
        "peak_host_mb": peak_host_mb(),
        "import_peak_host_mb": base_mb,
        "finite": bool(np.all(np.isfinite(np.asarray(traj.z)))),
    }


def devices_child(task: str, n_s: int, n_avg: int, iterations: int) -> dict[str, Any]:
    import jax

    row = grid_cell(task, n_s, n_avg, iterations)
    row["devices"] = jax.device_count()
    return row


SECTIONS = ("grid", "baselines", "memory", "devices", "cache", "ls_memory", "engines")


def run(settings: BenchSettings, out: str, progress=print, sections=SECTIONS) -> dict[str, Any]:
    """Run ``sections`` and write DIR/bench.json; sections not run keep what an
    earlier bench.json in DIR holds."""
    os.makedirs(out, exist_ok=True)
    path = os.path.join(out, "bench.json")
    report: dict[str, Any] = {}
    if set(sections) != set(SECTIONS) and os.path.exists(path):
        with open(path) as f:
            report = json.load(f)
    report.update(header(settings))
    progress(f"machine: {report['machine']['cpu']} x{report['machine']['cpu_count']}, {report['machine']['backend']}")
    if "grid" in sections:
        report["grids"] = run_grid(settings, progress)
    if "baselines" in sections:
        report["baselines"] = run_baselines(settings, progress)
    if "grids" in report:
        report["tasks"] = summarise(report["grids"], report.get("baselines", {}))
    if "memory" in sections:
        report["memory"] = run_memory(settings, progress)
    if "devices" in sections:
        report["devices"] = run_devices(settings, progress)
    if "cache" in sections:
        report["cache"] = run_cache(settings, progress)
    if "ls_memory" in sections:
        report["ls_memory"] = run_ls_memory(settings, progress)
    if "engines" in sections:
        from . import engines

        report["engines"] = engines.run(settings, progress)
    write(out, "bench", report)
    if "tasks" in report:
        plot(report, out)  # three figures from one report
    return report


def run_grid(settings: BenchSettings, progress) -> dict[str, list[dict[str, Any]]]:
    """The n_s x n_avg grid, per task."""
    grids: dict[str, list[dict[str, Any]]] = {}
    for task in settings.tasks:
        grids[task] = []
        for n_avg in settings.n_avg:
            for n_s in settings.n_s:
                cell = grid_cell(task, n_s, n_avg, settings.iterations)
                grids[task].append(cell)
                progress(
                    f"{task} n_s={n_s:5d} n_avg={n_avg:3d}: {cell['iteration_s_median'] * 1e3:8.1f} ms/iteration, "
                    f"{cell['rollouts_per_s']:9.0f} rollouts/s, non-rollout {100 * cell['non_rollout_fraction']:.1f}%, "
                    f"compile {cell['compile_s']:.1f} s, recompiles {cell['recompiles_after_first']}"
                )
    return grids


def run_baselines(settings: BenchSettings, progress) -> dict[str, dict[str, Any]]:
    """Native mujoco.rollout and the serial reference (and time to cost), per task."""
    from .native_rollout import compare

    out: dict[str, dict[str, Any]] = {}
    for task in settings.tasks:
        native = compare(pj.make_task(task), settings.native_batch, repeats=3)
        progress(
            f"{task} native mujoco.rollout at batch {settings.native_batch}: "
            f"{native['native_rollouts_per_s']:.0f} rollouts/s vs MJX {native['mjx_rollouts_per_s']:.0f} "
            f"(x{native['mjx_over_native']:.2f})"
        )
        serial = serial_comparison(task, settings.serial_n_s, settings.serial_iterations, settings.time_to_cost)
        progress(
            f"{task} serial reference at n_s={settings.serial_n_s}: {serial['serial_iteration_s']:.3f} s/iteration "
            f"vs ours {serial['ours_iteration_s']:.3f} (x{serial['speedup_per_iteration']:.1f})"
        )
        out[task] = {"native": native, "serial": serial}
    return out


def summarise(grids: dict[str, list], baselines: dict[str, dict]) -> dict[str, Any]:
    """The per-task summary fields of bench.json."""
    tasks: dict[str, Any] = {}
    for task, cells in grids.items():
        largest = max(cells, key=lambda c: (c["n_s"], c["n_avg"]))
        at_256 = [c for c in cells if c["n_s"] >= 256]
        base = baselines.get(task, {})
        tasks[task] = {
            "rollout_throughput_vs_native": base["native"]["mjx_over_native"] if base else None,
            "non_rollout_fraction": largest["non_rollout_fraction"],
            "non_rollout_fraction_at": [largest["n_s"], largest["n_avg"]],
            "non_rollout_fraction_max_at_n_s_256_up": max((c["non_rollout_fraction"] for c in at_256), default=None),
            "speedup_vs_serial": base["serial"]["speedup_per_iteration"] if base else None,
            "compile_s": max(c["compile_s"] for c in cells),
            "recompiles_after_first": sum(c["recompiles_after_first"] for c in cells),
            "peak_host_mb": max(c["peak_host_mb"] for c in cells),
            "grid": cells,
            **base,
        }
    return tasks


def run_memory(settings: BenchSettings, progress) -> list[dict[str, Any]]:
    """One fresh process per batch size: the sysid batch alone, under the default budget."""
    memory = []
    for batch in settings.memory_batches:
        row = _child(["--memory-child", settings.memory_task, str(batch)], {})
        memory.append(row)
        progress(f"memory: {json.dumps(row)}")
    return memory


def run_devices(settings: BenchSettings, progress) -> list[dict[str, Any]]:
    """One process per device count (virtual CPU devices): one grid cell."""
    devices = []
    n_s, n_avg = settings.device_cell
    for count in settings.devices:
        flags = f"--xla_force_host_platform_device_count={count}"
        row = _child(
            ["--devices-child", settings.tasks[0], str(n_s), str(n_avg), str(settings.iterations)],
            {"XLA_FLAGS": flags, "JAX_PLATFORMS": "cpu"},
        )
        devices.append(row)
        progress(f"devices={count}: {row.get('iteration_s_median', row.get('error'))}")
    return devices


def run_cache(settings: BenchSettings, progress) -> dict[str, Any]:
    """``podilqr solve TASK --compare`` in fresh processes with the persistent
    compilation cache off, cold and warm (``compile_cache.cold_warm``)."""
    from .compile_cache import cold_warm

    report = cold_warm(settings.cache_task, settings.cache_sets, compare=settings.cache_compare)
    solve = f"{settings.cache_task}{' --compare' if settings.cache_compare else ''}"
    for row in report["runs"]:
        if "error" in row:
            progress(f"cache {row['mode']}: {row['error']}")
        else:
            progress(
                f"cache {row['mode']:4s}: {solve} {row['process_wall_s']:.1f} s "
                f"in the process, compiling {row['compile_s_total']:.1f} s"
            )
    return report


def run_ls_memory(settings: BenchSettings, progress) -> dict[str, Any]:
    """Peak memory of one noisy line search of ``(n_alphas + 1) x n_forward``
    rollouts against its chunk (``line_search_memory.peak_memory_vs_chunk``)."""
    from .line_search_memory import peak_memory_vs_chunk

    report = peak_memory_vs_chunk(settings.ls_memory_task, settings.ls_memory_n_forward, settings.ls_memory_chunks)
    for row in report["rows"]:
        what = row.get("error") or f"peak {row['peak_host_mb']:.0f} MB, {row['wall_s_with_compile']:.1f} s"
        progress(f"line search n_forward={settings.ls_memory_n_forward} chunk={row['chunk']}: {what}")
    return report


def plot(report: dict[str, Any], out: str) -> list[str]:
    from podilqr_jax.viz.plots import agg_pyplot

    plt = agg_pyplot()
    paths = []
    tasks = report["tasks"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for task, data in tasks.items():
        for n_avg in sorted({c["n_avg"] for c in data["grid"]}):
            cells = sorted((c for c in data["grid"] if c["n_avg"] == n_avg), key=lambda c: c["n_s"])
            x = [c["sysid_rollouts"] for c in cells]
            axes[0].loglog(x, [c["iteration_s_median"] for c in cells], "o-", label=f"{task}, n_avg={n_avg}")
            axes[1].loglog(x, [c["rollouts_per_s"] for c in cells], "o-", label=f"{task}, n_avg={n_avg}")
    axes[0].set_ylabel("seconds per iteration (median)")
    axes[1].set_ylabel("rollouts / s")
    for ax in axes:
        ax.set_xlabel("sysid rollouts per iteration, n_s x n_avg")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"{report['machine']['cpu']} x{report['machine']['cpu_count']} ({report['machine']['backend']})")
    fig.tight_layout()
    paths.append(os.path.join(out, "time_per_iteration.png"))
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, len(tasks), figsize=(5.5 * len(tasks), 4.2), squeeze=False)
    for ax, (task, data) in zip(axes[0], tasks.items(), strict=True):
        cells = sorted(data["grid"], key=lambda c: (c["n_avg"], c["n_s"]))
        phases = list(cells[0]["phase_s_per_iteration"])  # the phases a cell holds
        labels = [f"{c['n_s']}x{c['n_avg']}" for c in cells]
        bottom = np.zeros(len(cells))
        for p in phases:
            frac = np.array([c["phase_s_per_iteration"][p] / sum(c["phase_s_per_iteration"].values()) for c in cells])
            ax.bar(labels, frac, bottom=bottom, label=p)
            bottom += frac
        ax.set_title(task)
        ax.set_ylabel("share of the solve's time, by phase")
        ax.tick_params(axis="x", rotation=60)
        ax.legend(fontsize=7)
    fig.tight_layout()
    paths.append(os.path.join(out, "phases.png"))
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    for task, data in tasks.items():
        cells = sorted(data["grid"], key=lambda c: c["rollouts_per_iteration"])
        ax.loglog(
            [c["rollouts_per_iteration"] for c in cells], [c["steps_per_s"] for c in cells], "o", label=f"{task} (MJX)"
        )
        ax.axhline(data["native"]["native_steps_per_s"], ls="--", lw=1, label=f"{task} native mujoco.rollout")
    ax.set_xlabel("rollouts per iteration")
    ax.set_ylabel("physics steps / s")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    paths.append(os.path.join(out, "throughput.png"))
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def format_summary(report: dict[str, Any]) -> str:
    lines = [
        "| task | MJX / native rollouts/s | non-rollout share (at n_s x n_avg) | speed-up vs serial "
        "| compile s (max) | recompiles after first | peak host MB |",
        "|---|---|---|---|---|---|---|",
    ]
    for task, d in report["tasks"].items():
        n_s, n_avg = d["non_rollout_fraction_at"]
        lines.append(
            f"| {task} | {d['rollout_throughput_vs_native']:.2f} | {100 * d['non_rollout_fraction']:.1f}% "
            f"({n_s}x{n_avg}) | {d['speedup_vs_serial']:.1f} | {d['compile_s']:.1f} | "
            f"{d['recompiles_after_first']} | {d['peak_host_mb']:.0f} |"
        )
    return "\n".join(lines)


def parser() -> argparse.ArgumentParser:
    """The options of ``podilqr bench``."""
    parser = argparse.ArgumentParser(prog="podilqr bench", description=" ".join(__doc__.split("\n\n")[0].split()))
    add_size_flags(
        parser, quick="a small grid: a few minutes on a CPU", tiny="every section at the smallest size: a smoke test"
    )
    parser.add_argument(
        "--tasks", default=None, help="comma-separated bundled tasks (default pendulum-full,cartpole-full)"
    )
    parser.add_argument("--out", default="benchmarks/results/latest", help="output folder (bench.json and plots)")
    parser.add_argument(
        "--sections",
        default=",".join(SECTIONS),
        help=f"comma-separated subset of {','.join(SECTIONS)} (others keep DIR/bench.json's values)",
    )
    parser.add_argument("--verbose", action="store_true", help=VERBOSE_HELP)
    parser.add_argument("--memory-child", nargs=2, metavar=("TASK", "BATCH"), help=argparse.SUPPRESS)
    parser.add_argument("--devices-child", nargs=4, metavar=("TASK", "N_S", "N_AVG", "IT"), help=argparse.SUPPRESS)
    return parser


def main(argv=None) -> int:
    args = parser().parse_args(argv)
    if args.memory_child:
        print(json.dumps(memory_child(args.memory_child[0], int(args.memory_child[1]))))
        return 0
    if args.devices_child:
        task, n_s, n_avg, it = args.devices_child
        print(json.dumps(devices_child(task, int(n_s), int(n_avg), int(it))))
        return 0
    try:
        settings = BenchSettings.sized(size_of(args)).changed(
            tasks=None if args.tasks is None else parse_names(args.tasks, tuple(pj.TASKS), "--tasks")
        )
        sections = parse_names(args.sections, SECTIONS, "--sections")
        check_writable(os.path.join(args.out, "bench.json"))
    except pj.ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    report = run(settings, args.out, progress=lambda m: print(m, file=sys.stderr, flush=True), sections=sections)
    if "tasks" in report:
        print(format_summary(report))
    if "engines" in sections:
        from . import engines

        print(engines.format_table(report["engines"]))
    print(f"wrote {args.out}/bench.json and plots in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
