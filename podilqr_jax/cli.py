"""The ``podilqr`` command line.

  podilqr solve TASK [--method pod-ilqr|model-based] [--compare]
                     [--noise paper|none|initial=S0,process=SW,measurement=SV]
                     [--set key=value ...] [--out result.json] [--no-plots]
                     [--checkpoint DIR [--every N]] [--resume DIR]
  podilqr reproduce [--quick | --tiny] [--seeds N] [--systems pendulum,cartpole]
                    [--no-sweep] [--out DIR]
  podilqr evaluate RESULT [--noise 0,0.1,0.2,0.3,0.5] [--quick | --tiny] [--task TASK]
                    [--episodes N] [--system-noise SPEC] [--no-replan]
                    [--no-estimator] [--replan-every N] [--u-limit X]
                    [--model-error X] [--seed S] [--out DIR]
  podilqr animate RESULT --out motion.gif [--episodes N --noise EPS] [--open-loop]
                    [--compare OTHER | --vs-open-loop] [--task TASK] [--fps F]
                    [--width W] [--height H] [--hold S] [--renderer R] [--seed S]
  podilqr bench [--quick | --tiny] [--tasks pendulum-full,cartpole-full] [--sections ...] [--out DIR]
  podilqr tasks

TASK is a bundled task name (``podilqr tasks`` lists them) or a task file
(.toml / .json, see docs/task_files.md). Errors in the input print one
paragraph and exit with status 2, without a traceback (docs/bad_input.md
lists every case tried). Ctrl-C during ``podilqr solve`` writes the result
after the last completed iteration and exits with status 130; so do a
scheduler's SIGTERM, SIGHUP and SIGUSR1, exiting with 128 + the signal's
number (143 for SIGTERM). XLA's and JAX's own log lines are kept out of the
terminal unless ``--verbose`` (or ``PODILQR_VERBOSE=1``) asks for them. The
module imports neither JAX nor MuJoCo until a command needs them, so
``--help`` answers at once.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import textwrap
from typing import Any, Optional, Sequence

from .studies.settings import add_size_flags, check_writable, parse_names, size_of
from .verbosity import VERBOSE_HELP, quiet_backends

EXIT_INPUT_ERROR = 2


def main(argv: Optional[Sequence[str]] = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["bench"]:
        quiet_backends("--verbose" in argv)
        return _cmd_bench(argv[1:])
    parser = _parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return EXIT_INPUT_ERROR
    quiet_backends(getattr(args, "verbose", False))
    from .errors import PodIlqrError

    try:
        return args.func(args)
    except PodIlqrError as exc:
        _fail(str(exc))
        return EXIT_INPUT_ERROR
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
        return 130


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="podilqr", description="Data-based iterative LQR (POD-iLQR) on MJX.")
    sub = parser.add_subparsers(dest="command")
    p = sub.add_parser("solve", help="solve a task and write JSON and plots")
    p.add_argument("task", help="bundled task name (see `podilqr tasks`) or a .toml/.json task file")
    p.add_argument(
        "--method",
        choices=("pod-ilqr", "model-based"),
        default="pod-ilqr",
        help="pod-ilqr (the default: from rollouts alone) or model-based (iLQR on the model's derivatives)",
    )
    p.add_argument(
        "--compare",
        action="store_true",
        help="also run the model-based reference and report the cost ratio "
        "(and, 1%% or more apart, where the two trajectories part)",
    )
    p.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="a solver setting or `horizon` (repeatable)"
    )
    p.add_argument(
        "--noise",
        default=None,
        metavar="SPEC",
        help="system noise: `paper` (s0=0.01, 10%% process/measurement noise), `none`, or "
        "initial=S0,process=SW,measurement=SV (standard deviations); pick the algorithm with --set variant=...",
    )
    p.add_argument(
        "--restarts",
        type=int,
        default=None,
        metavar="K",
        help="solve from K first guesses at once (one batch per stage) and keep the lowest cost "
        "(the setting `restarts`; default 1, and 4 on a model with floor contacts; checkpoints go to DIR/startJ)",
    )
    p.add_argument("--out", default="result.json", help="JSON result path (plots are written beside it)")
    p.add_argument(
        "--checkpoint",
        default=None,
        metavar="DIR",
        help="save the solver state to DIR/checkpoint.npz (atomically) every --every iterations and at the end",
    )
    p.add_argument("--every", type=int, default=10, metavar="N", help="iterations between checkpoints (default 10)")
    p.add_argument(
        "--resume",
        default=None,
        metavar="DIR",
        help="continue from the checkpoint in DIR (same task and settings; --set max_iterations may be raised)",
    )
    p.add_argument("--no-plots", action="store_true", help="do not write PNG plots or the motion GIF")
    p.add_argument("--quiet", action="store_true", help="no live progress")
    p.add_argument("--verbose", action="store_true", help=VERBOSE_HELP)
    p.set_defaults(func=_cmd_solve)
    r = sub.add_parser("reproduce", help="reproduce the paper's noise study (Fig. 2) and a sigma sweep")
    add_size_flags(
        r,
        quick="2 seeds, shorter runs, 3-point sweep (minutes on a CPU)",
        tiny="1 seed, 2 iterations, horizon 8: a smoke run",
    )
    r.add_argument("--seeds", type=int, default=None, help="seeds per variant (default 5, quick 2)")
    r.add_argument("--systems", default="pendulum,cartpole", help="comma-separated: pendulum, cartpole")
    r.add_argument("--no-sweep", action="store_true", help="skip the sigma sweep")
    r.add_argument("--out", default="runs/reproduce", help="output folder (summary.json, figures, table.md)")
    r.add_argument("--verbose", action="store_true", help=VERBOSE_HELP)
    r.set_defaults(func=_cmd_reproduce)
    e = sub.add_parser("evaluate", help="Monte Carlo evaluation of a solve's controllers over noise levels")
    e.add_argument("result", help="a result JSON written by `podilqr solve --out`")
    e.add_argument(
        "--noise",
        default=None,
        metavar="LEVELS",
        help="comma-separated noise levels: actuator noise std as a fraction of the largest nominal control "
        "(measurement noise scales with it); default 0,0.1,0.2,0.3,0.5 (quick: 0,0.1,0.3)",
    )
    add_size_flags(
        e,
        quick="3 levels, 64 episodes, 4 replanning episodes (minutes on a CPU)",
        tiny="2 levels, 8 episodes, 1 replanning episode of 1 iteration: a smoke run",
    )
    e.add_argument("--task", default=None, help="the task the result was solved on (default: its recorded name)")
    e.add_argument("--episodes", type=int, default=None, help="episodes per controller and level (default 256)")
    e.add_argument("--replan-episodes", type=int, default=None, help="episodes of the replanning controller")
    e.add_argument("--replan-every", type=int, default=None, help="steps between replans (default horizon/3)")
    e.add_argument("--replan-iterations", type=int, default=None, help="POD-iLQR iterations per replan (default 5)")
    e.add_argument("--no-replan", action="store_true", help="skip the receding-horizon controller")
    e.add_argument("--no-estimator", action="store_true", help="skip the Kalman-estimator controller")
    e.add_argument(
        "--system-noise",
        default=None,
        metavar="SPEC",
        help="extra state noise at every level: `paper`, `none` or initial=S0,process=SW,measurement=SV",
    )
    e.add_argument(
        "--u-limit",
        type=float,
        default=None,
        help="clip commands to +- this multiple of the largest nominal control where the model has no "
        "ctrlrange (default 2; `inf` for none)",
    )
    e.add_argument(
        "--model-error",
        type=float,
        default=None,
        help="the Kalman estimator's allowance for model error, a share of the actuator noise (default 0.1)",
    )
    e.add_argument(
        "--measurement-ratio",
        type=float,
        default=None,
        help="measurement noise as a share of the actuator noise's level (default 0.1, the paper's; 0: exact "
        "measurements, which isolates what the gains cost)",
    )
    e.add_argument("--seed", type=int, default=None, help="PRNG seed of the episodes' noise (default 0)")
    e.add_argument("--out", default="runs/evaluate", help="output folder (evaluate.json, evaluate.png, table.md)")
    e.add_argument("--verbose", action="store_true", help=VERBOSE_HELP)
    e.set_defaults(func=_cmd_evaluate)
    a = sub.add_parser("animate", help="the motion of a solve as a GIF/MP4 (noisy episodes, side by side)")
    a.add_argument("result", help="a result JSON written by `podilqr solve --out`")
    a.add_argument("--out", default="motion.gif", help="the animation: .gif, or .mp4 where ffmpeg is installed")
    a.add_argument("--verbose", action="store_true", help=VERBOSE_HELP)
    a.add_argument("--episodes", type=int, default=0, help="overlay N noisy closed-loop episodes of the policy")
    a.add_argument(
        "--noise",
        type=float,
        default=0.1,
        metavar="EPS",
        help="the episodes' noise level, as `podilqr evaluate`'s: actuator noise std EPS x max|u| (default 0.1)",
    )
    a.add_argument("--open-loop", action="store_true", help="the episodes replay the nominal controls alone")
    a.add_argument("--seed", type=int, default=0, help="PRNG seed of the episodes' noise (default 0)")
    a.add_argument("--compare", default=None, metavar="OTHER", help="a second result of the task, drawn beside")
    a.add_argument(
        "--vs-open-loop",
        action="store_true",
        help="draw beside it the same noisy episodes run open loop (the nominal controls alone; needs --episodes)",
    )
    a.add_argument("--task", default=None, help="the task the result was solved on (default: its recorded name)")
    a.add_argument("--fps", type=float, default=None, help="highest frame rate (default 25); frames keep real time")
    a.add_argument("--width", type=int, default=320, help="pixels per panel (default 320)")
    a.add_argument("--height", type=int, default=240, help="pixels (default 240)")
    a.add_argument("--hold", type=float, default=1.0, help="seconds the last frame is held (default 1)")
    a.add_argument(
        "--renderer",
        choices=("auto", "mujoco", "matplotlib"),
        default="auto",
        help="auto: MuJoCo's renderer when an OpenGL backend (MUJOCO_GL) loads, else a matplotlib drawing",
    )
    a.set_defaults(func=_cmd_animate)
    sub.add_parser(
        "bench",
        help="benchmark: n_s x n_avg grid, phases, native/serial baselines, memory, devices (`podilqr bench --help`)",
        add_help=False,
    )
    t = sub.add_parser("tasks", help="the bundled tasks as a table: observation, nx / nz / nu, horizon, control step")
    t.set_defaults(func=_cmd_tasks)
    return parser


def _fail(message: str) -> None:
    print(
        textwrap.fill("error: " + message, width=100, break_long_words=False, break_on_hyphens=False), file=sys.stderr
    )


def _parse_sets(items: Sequence[str]) -> dict[str, Any]:
    from .errors import ConfigError

    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"--set expects KEY=VALUE (e.g. --set sigma=1e-4); got {item!r}.")
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        out[key.strip()] = value
    return out


def _cmd_bench(argv: list[str]) -> int:
    """``podilqr bench``: the benchmark suite installed with the package (podilqr_jax/studies/bench)."""
    from .studies.bench import main as bench_main

    return bench_main(argv)


def _cmd_tasks(args: argparse.Namespace) -> int:
    from .task.tasks import TASKS, make_task

    rows = [("task", "observation", "nx", "nz", "nu", "horizon", "control dt", "controls")]
    for name in TASKS:
        env = make_task(name)
        d = env.dims
        limits = "limited" if env.limited else "free"
        rows.append((name, ", ".join(env.observation_labels), str(d.nx), str(d.nz), str(d.nu), str(d.horizon),
                     f"{env.control_dt:g} s", limits))  # fmt: skip
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    for row in rows:
        print("  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip())
    return 0


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from .studies.reproduce import SYSTEMS, ReproduceSettings, format_table, run_study

    settings = ReproduceSettings.sized(size_of(args)).changed(
        systems=parse_names(args.systems, SYSTEMS, "--systems"),
        seeds=args.seeds,
        sweep_factors=() if args.no_sweep else None,
    )
    settings.validate()
    check_writable(os.path.join(args.out, "summary.json"))
    print(f"reproducing the paper's study into {args.out} ({settings})", file=sys.stderr)
    rows = run_study(args.out, settings, progress=lambda msg: print(msg, file=sys.stderr, flush=True))
    print(format_table(rows))
    print(f"wrote {args.out}/summary.json, fig2_true_cost.png, sigma_sweep.png, table.md", file=sys.stderr)
    return 0


def _parse_levels(text: str) -> tuple[float, ...]:
    from .errors import ConfigError

    try:
        levels = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        levels = ()
    if not levels:
        raise ConfigError(
            f"--noise expects comma-separated noise levels >= 0 (fractions of the largest control), "
            f"e.g. 0,0.1,0.3; got {text!r}."
        )
    return levels


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from .ilqr.result import load_result
    from .studies.evaluate import EvaluateSettings, format_table, run_evaluation
    from .task.loading import load_env, noise_model

    names = ("episodes", "replan_episodes", "replan_every", "replan_iterations")
    names += ("u_limit", "model_error", "measurement_ratio", "seed")
    settings = EvaluateSettings.sized(size_of(args)).changed(
        levels=None if args.noise is None else _parse_levels(args.noise),
        replan=False if args.no_replan else None,
        estimator=False if args.no_estimator else None,
        **{name: getattr(args, name) for name in names},
    )
    result = load_result(args.result)
    env = load_env(args.task or result.task)
    if args.system_noise is not None:
        settings = settings.changed(system_noise=noise_model(args.system_noise, env))
    train_env = env.replace(noise=result.noise) if result.noisy else env
    check_writable(os.path.join(args.out, "evaluate.json"))
    print(f"evaluating {args.result} ({result.task}, {result.variant}) into {args.out}", file=sys.stderr)
    report = run_evaluation(
        result,
        env,
        args.out,
        settings,
        train_env=train_env,
        progress=lambda msg: print(msg, file=sys.stderr, flush=True),
    )
    print("mean cost / model-based optimum +- std (success rate):")
    print(format_table(report))
    print(f"wrote {args.out}/evaluate.json, evaluate.png, table.md", file=sys.stderr)
    return 0


def _cmd_animate(args: argparse.Namespace) -> int:
    from .errors import ConfigError
    from .ilqr.result import load_result
    from .viz.animate import animate, task_env

    result = load_result(args.result)
    if args.compare and args.vs_open_loop:
        raise ConfigError("Give either --compare OTHER or --vs-open-loop, not both: there are two panels.")
    other = load_result(args.compare) if args.compare else "open_loop" if args.vs_open_loop else None
    env = task_env(result, args.task)
    check_writable(args.out)
    info = animate(
        result,
        args.out,
        env=env,
        episodes=args.episodes,
        noise=args.noise,
        seed=args.seed,
        open_loop=args.open_loop,
        compare=other,
        compare_env=env if args.task and args.compare else None,
        width=args.width,
        height=args.height,
        fps=args.fps,
        hold=args.hold,
        renderer=args.renderer,
    )
    print(
        f"wrote {info.path}: {info.frames} frames of {info.frame_s:g} s, {info.size[0]}x{info.size[1]} "
        f"({info.renderer})",
        file=sys.stderr,
    )
    return 0


def _cmd_solve(args: argparse.Namespace) -> int:
    from .ilqr.interrupts import deferred_interrupts

    # A Ctrl-C or a scheduler's stop anywhere in here, solves or writing, ends with a complete result file.
    with deferred_interrupts as interrupts:
        return _solve_and_write(args, interrupts)


def _solve_and_write(args: argparse.Namespace, interrupts) -> int:
    import podilqr_jax as pj

    from .sim import engines
    from .task.loading import load_env

    sets = _parse_sets(args.set)
    check_writable(args.out)
    env = load_env(args.task, args.noise)
    horizon = sets.pop("horizon", None)
    if horizon is not None:
        env = env.replace(horizon=horizon)
    if args.restarts is not None:
        sets["restarts"] = args.restarts
    cfg = pj.default_config(env, **sets)
    # The options switched off for MJX, or why `auto` runs the C engine (Result.warnings keeps them too).
    for note in engines.on_engine(env, cfg.engine).model_notes:
        print(f"note: {note}", file=sys.stderr)

    runs = [args.method] + (["model-based"] if args.compare and args.method != "model-based" else [])
    if "model-based" in runs:
        env.full_state_view()  # refuses, before any solve, a task the reference cannot take
    results = []
    for i, method in enumerate(runs):
        fn = pj.solve if method == "pod-ilqr" else pj.solve_model_based
        options = {}
        if i == 0:  # checkpoints and resume belong to the main solve
            options = dict(checkpoint=args.checkpoint, checkpoint_every=args.every, resume=args.resume)
        with _Progress(
            method, env.name, cfg.max_iterations, quiet=args.quiet, starts=cfg.resolved_restarts(env)
        ) as progress:
            results.append(fn(env, cfg, callback=progress.update, **options))
        print(results[-1].summary(), file=sys.stderr)
        if results[-1].status == pj.Status.INTERRUPTED or interrupts.requested:
            break

    main_result = results[0]
    payload = main_result.to_dict()
    if len(results) > 1 and results[1].status != pj.Status.INTERRUPTED:
        reference = results[1]
        payload["model_based_cost"] = reference.final_cost
        payload["model_based"] = {k: v for k, v in reference.to_dict().items() if k not in ("K", "k")}
        if reference.status in (pj.Status.NONFINITE, pj.Status.NO_RESPONSE):
            # A reference that could not linearise the model is no optimum: no ratio against it.
            payload["ratio_to_model_based"] = None
            print(
                f"no ratio: the model-based reference stopped {reference.status} ({reference.message}), "
                "so its cost is not an optimum to compare with",
                file=sys.stderr,
            )
        else:
            # Under noise the comparison is the policy's true (noiseless, closed-loop) cost.
            payload["ratio_to_model_based"] = main_result.final_true_cost / reference.final_cost
            what = "true cost (noiseless, closed loop)" if main_result.noisy else "cost"
            print(f"POD-iLQR {what} / model-based cost: {payload['ratio_to_model_based']:.6f}", file=sys.stderr)
            if not main_result.noisy and abs(payload["ratio_to_model_based"] - 1.0) > BASIN_RATIO:
                gap = main_result.largest_state_gap(reference)
                payload["largest_state_gap"] = gap
                both = main_result.converged and reference.converged
                print(_apart(payload["ratio_to_model_based"], gap, both), file=sys.stderr)
    from .atomic import write_json_atomic

    write_json_atomic(args.out, payload)
    print(f"wrote {args.out}", file=sys.stderr)
    if not args.no_plots:
        from .viz.plots import plot_convergence, plot_trajectory

        stem = os.path.splitext(args.out)[0]
        paths = [
            plot_convergence(results, stem + "_cost.png"),
            plot_trajectory(main_result, stem + "_trajectory.png"),
        ]
        paths.append(_solve_animation(main_result, env, stem + "_motion.gif"))
        print("wrote " + ", ".join(p for p in paths if p), file=sys.stderr)
    if interrupts.requested or any(r.status == pj.Status.INTERRUPTED for r in results):
        from .ilqr.interrupts import signal_name

        by = f" by {signal_name(interrupts.signal)}" if interrupts.signal is not None else ""
        print(f"interrupted{by}: {args.out} holds the result after the last completed iteration", file=sys.stderr)
        return interrupts.exit_status
    return 1 if main_result.status in (pj.Status.NONFINITE, pj.Status.NO_RESPONSE) else 0


# Noiseless costs further apart than this (relative) are not one optimum reached twice
# (``ilqr.result.BASIN_RATIO``, kept here so that the CLI's parser loads no JAX).
BASIN_RATIO = 0.01


def _apart(ratio: float, gap: dict, both_converged: bool) -> str:
    """The line `--compare` prints when the two solvers' costs differ by more than BASIN_RATIO:
    where their trajectories part most, and whether both converged (two local minima, and
    then that other starts may find others: docs/robustness.md, "Basins on multi-modal tasks")."""
    which = "above" if ratio > 1 else "below"
    text = (
        f"POD-iLQR ends {abs(ratio - 1):.1%} {which} the model-based solve"
        f"{', both converged: two local minima (basins)' if both_converged else ''}; their trajectories are "
        f"farthest apart in {gap['state']} at step {gap['step']} (POD-iLQR {gap['this']:.4g}, "
        f"model-based {gap['other']:.4g})"
    )
    if both_converged:
        text += "; other starts may end in other basins, lower ones too: try `--set seed=N` (other sysid draws)"
    return text


def _solve_animation(result, env, path: str) -> str:
    """The solve's motion GIF beside its plots (small frames); a note, not a failure, if it cannot be drawn."""
    from .errors import PodIlqrError
    from .viz.animate import animate

    try:
        return animate(result, path, env=env).path
    except PodIlqrError as exc:
        print(f"note: no animation: {exc}", file=sys.stderr)
        return ""


class _Progress:
    """Live progress: a rich bar on a terminal, a line every 10 iterations otherwise."""

    def __init__(self, method: str, task: str, total: int, quiet: bool, starts: int = 1) -> None:
        from rich.console import Console

        self.console = Console(stderr=True)
        self.quiet = quiet
        self.method, self.task, self.total = method, task, total
        self.bar = None
        self.bar_ids: dict[int, Any] = {}  # a bar per start (``restarts``)
        self.starts = starts

    def __enter__(self) -> "_Progress":
        if not self.quiet and self.console.is_terminal:
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

            self.bar = Progress(
                TextColumn("{task.description}"),
                BarColumn(),
                TextColumn("{task.fields[stats]}"),
                TimeElapsedColumn(),
                console=self.console,
            )
            self.bar.start()
        return self

    def update(self, info) -> None:
        if self.quiet:
            return
        stats = (
            f"it {info.iteration:4d}  cost {info.cost:12.6g}  alpha {info.alpha:6.3g}  "
            f"mu {info.mu:8.2g}  |g| {_figure(info.grad_norm)}  {info.rollouts_per_s:9.0f} rollouts/s ({info.engine})"
        )
        if info.sigma == info.sigma:
            stats += f"  sigma {info.sigma:7.2g}"
        if info.fit_error == info.fit_error:
            stats += f"  B err {info.fit_error:6.2g}"
        if info.true_cost == info.true_cost and info.true_cost != info.cost:
            stats += f"  true {info.true_cost:10.6g}"
        if info.note:
            stats += f"  ({info.note})"
        name = f"{self.method} {self.task}" + (f" start {info.start}" if self.starts > 1 else "")
        if self.bar is not None:
            if info.start not in self.bar_ids:
                self.bar_ids[info.start] = self.bar.add_task(name, total=self.total, stats="")
            self.bar.update(self.bar_ids[info.start], completed=info.iteration, stats=stats)
        elif info.iteration == 1 or info.iteration % 10 == 0 or info.note:
            self.console.print(f"{name}: {stats}", highlight=False, soft_wrap=True)

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.stop()


def _figure(x: float) -> str:
    """A gradient norm for the progress line: past float's range (the costate of a
    long horizon through an unstable nominal) is "overflow", none yet is "-"."""
    if x == x and abs(x) != float("inf"):
        return f"{x:8.2g}"
    return f"{'overflow' if x == x else '-':>8}"


if __name__ == "__main__":
    sys.exit(main())
