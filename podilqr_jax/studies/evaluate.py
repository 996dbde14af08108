"""Monte Carlo evaluation of a solve's controllers over a sweep of noise levels.

``podilqr evaluate RESULT --out DIR`` (and :func:`evaluate`) runs, at every
noise level eps, the same noisy episodes (common random numbers) for

  open_loop              the nominal controls u_bar alone
  closed_loop            u_bar + K (Z - Z_bar), Z the raw measured information state
  closed_loop_estimator  u_bar + K xi, xi a Kalman filter on the ARMA model (kalman.py)
  replan                 receding-horizon POD-iLQR (replan.py), fewer episodes
  model_based            the exact-derivative iLQR's nominal and full-state gains

and reports the mean, spread and median of the task's cost of the true
trajectory, the success rate (final observation within ``success_tol``
of the target in every component) and, on a robot that can fall
(``control/falls.py``: a root body on a free joint or a vertical slide), the
share of episodes that stayed up and the mean time they stayed up.

The noise at level eps (docs/evaluation.md):
- actuator noise N(0, (eps u_max)^2) added to every commanded control, u_max
  the largest |u_bar| of each actuator in the solve's nominal: eps is "a
  fraction of the maximum control";
- measurement noise with std eps x ``measurement_ratio`` x the range of each
  measured channel along its nominal (the task's observations for the
  data-based controllers, the full state for the model-based one);
- the optional ``system_noise`` (the paper's start deviation, process and
  measurement noise) at every level, eps = 0 included.
Commands are clipped to the actuator's ``ctrlrange`` where the model limits
it, else to +- ``u_limit`` x u_max (``inf``: no limit).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from typing import Any, Callable, NamedTuple, Optional

import jax
import numpy as np

from ..control.episodes import (
    MEASUREMENT_RATIO,
    U_LIMIT,
    EpisodeNoise,
    Episodes,
    actuator_limits,
    noise_at_level,
    run_episodes,
)
from ..control.falls import FALL_RATIO, falls, root_body, root_heights
from ..control.kalman import EstimatorNoise, estimator_policy, identify_about_nominal
from ..control.policy import FeedbackPolicy
from ..control.replan import replan_episodes
from ..errors import ConfigError
from ..ilqr.config import SolverConfig, check_int, check_nonnegative
from ..ilqr.result import Result
from ..ilqr.solver import solve_model_based
from ..task.env import Env
from ..task.noise import NoiseModel
from .report import header, write
from .settings import Sized

CONTROLLERS = ("open_loop", "closed_loop", "closed_loop_estimator", "replan", "model_based")

Progress = Callable[[str], None]


@dataclasses.dataclass(frozen=True)
class EvaluateSettings(Sized):
    """What ``evaluate`` runs (see the module docstring; sizes and changes as every study's:
    ``studies/settings.py``)."""

    levels: tuple[float, ...] = (0.0, 0.1, 0.2, 0.3, 0.5)
    episodes: int = 256
    measurement_ratio: float = MEASUREMENT_RATIO
    u_limit: float = U_LIMIT
    system_noise: NoiseModel = NoiseModel()
    estimator: bool = True
    estimator_n_s: Optional[int] = None
    model_error: float = 0.1
    replan: bool = True
    replan_episodes: int = 16
    replan_every: Optional[int] = None  # default horizon // 3
    replan_iterations: int = 5
    replan_feedback: bool = False
    model_based: bool = True
    success_tol: float = 0.1
    seed: int = 0

    @classmethod
    def quick(cls) -> "EvaluateSettings":
        """Three levels, 64 episodes, 4 replanning episodes: a few minutes on a CPU."""
        return cls(levels=(0.0, 0.1, 0.3), episodes=64, replan_episodes=4)

    @classmethod
    def tiny(cls) -> "EvaluateSettings":
        """Two levels, 8 episodes, one replanning episode of one iteration: a smoke run."""
        return cls(levels=(0.0, 0.2), episodes=8, replan_episodes=1, replan_iterations=1)

    def validate(self, horizon: int) -> "EvaluateSettings":
        levels = tuple(self.levels)
        if not levels or any(not _finite(v) or v < 0 for v in levels):
            raise ConfigError(
                f"Noise levels must be finite numbers >= 0 (fractions of the maximum control); got {levels}."
            )
        for name in ("episodes", "replan_episodes", "replan_iterations"):
            check_int(name, getattr(self, name), 1)
        every = self.replan_every if self.replan_every is not None else max(1, horizon // 3)
        if isinstance(every, bool) or not isinstance(every, int) or not 1 <= every < horizon:
            raise ConfigError(f"`replan_every` must be an integer in 1 .. horizon-1 = {horizon - 1}; got {every!r}.")
        for name in ("measurement_ratio", "model_error", "success_tol"):
            check_nonnegative(name, getattr(self, name))
        if not isinstance(self.u_limit, (int, float)) or math.isnan(self.u_limit) or self.u_limit <= 0:
            raise ConfigError(
                f"`u_limit` must be > 0 (a multiple of the largest nominal control, or inf); got {self.u_limit!r}."
            )
        return dataclasses.replace(self, levels=levels, replan_every=every)

    def as_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["system_noise"] = self.system_noise.as_dict()
        return d


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _row(
    name: str,
    eps: float,
    ep: Episodes,
    tol: float,
    reference: float,
    wall: float,
    levels: EpisodeNoise,
    fall: Optional[_FallCheck] = None,
) -> dict:
    """One controller at one level (``fall``: the fall check, or None where the robot cannot fall)."""
    cost = np.asarray(ep.cost)
    error = np.asarray(ep.final_error)
    finite = np.isfinite(cost)
    c = cost[finite]
    return {
        "controller": name,
        "noise_level": float(eps),
        "mean_cost": float(np.mean(c)) if finite.all() else math.inf,
        "std_cost": float(np.std(c)) if c.size else math.nan,
        "median_cost": float(np.median(cost)),
        "mean_cost_ratio": (float(np.mean(c)) if finite.all() else math.inf) / reference,
        "success_rate": float(np.mean(error <= tol)),
        "episodes": int(cost.size),
        "nonfinite": int((~finite).sum()),
        "actuator_std": np.asarray(levels.a).tolist(),
        "measurement_std": np.asarray(levels.v).tolist(),
        "wall_s": wall,
        **_fall_figures(ep, fall),
    }


class _FallCheck(NamedTuple):
    """What the fall figures of a sweep need (``_fall_check``)."""

    model: Any  # mujoco.MjModel
    body: int  # the root body (``falls.root_body``)
    nominal_heights: np.ndarray  # [T+1] its height along the result's nominal
    dt: float  # the control step, s


def _fall_figures(ep: Episodes, fall: Optional[_FallCheck]) -> dict:
    if fall is None:
        return {}
    f = falls(root_heights(fall.model, fall.body, np.asarray(ep.x)), fall.nominal_heights)
    return {"stayed_up_rate": float(np.mean(f.stayed_up)), "mean_up_s": float(np.mean(f.up_steps) * fall.dt)}


def evaluate(
    env: Env,
    result: Result,
    settings: EvaluateSettings = EvaluateSettings(),
    *,
    train_env: Optional[Env] = None,
    progress: Optional[Progress] = None,
) -> dict[str, Any]:
    """Run the sweep (module docstring). ``env`` is the task (its own noise
    is ignored: the sweep sets the noise); ``train_env`` the system replanning
    re-solves on (default: ``env``). Returns the report written to
    evaluate.json: ``rows`` and what they were made with."""
    say = progress or (lambda _msg: None)
    if result.method != "pod-ilqr":
        raise ConfigError(f"`podilqr evaluate` takes a POD-iLQR result; this one is {result.method!r}.")
    controls = np.asarray(result.controls)
    if controls.ndim != 2 or controls.shape[1] != env.dims.nu:
        raise ConfigError(
            f"The result's controls have shape {controls.shape} but the task {env.name!r} has {env.dims.nu} "
            "control(s): pass the task the result was solved on (--task)."
        )
    T = controls.shape[0]
    if T != env.dims.horizon:  # the result was solved with another horizon (--set horizon=...)
        env = env.replace(horizon=T)
        train_env = train_env.replace(horizon=T) if train_env is not None else None
    settings = settings.validate(T)
    train_env = train_env or env
    cfg = SolverConfig().replace(**result.config)
    key = jax.random.PRNGKey(settings.seed)
    clean = env.replace(noise=NoiseModel())

    policy = FeedbackPolicy.from_result(result)
    if policy.nz != env.dims.nz:
        raise ConfigError(
            f"The result observes {policy.nz} number(s) per step but the task {env.name!r} observes "
            f"{env.dims.nz}: pass the task the result was solved on (--task)."
        )
    u_max = np.max(np.abs(np.asarray(result.controls)), axis=0)
    limits = actuator_limits(env, u_max, settings.u_limit)
    obs_range = np.ptp(np.asarray(result.observations), axis=0)

    t0 = time.perf_counter()
    reference = solve_model_based(clean)
    say(f"model-based reference: cost {reference.final_cost:.6g} ({time.perf_counter() - t0:.1f} s)")
    mb_policy = FeedbackPolicy.from_result(reference)
    state_range = np.ptp(np.asarray(reference.states), axis=0)
    model = None
    if settings.estimator:
        t0 = time.perf_counter()
        model = identify_about_nominal(clean, policy, cfg, n_s=settings.estimator_n_s, seed=settings.seed)
        say(f"estimator: ARMA model identified about the nominal ({time.perf_counter() - t0:.1f} s)")

    fall = _fall_check(env, result)
    rows: list[dict] = []
    replan_compiles = 0
    system = {"measurement_ratio": settings.measurement_ratio, "system_noise": settings.system_noise}
    for i, eps in enumerate(settings.levels):
        level_key = jax.random.fold_in(key, i)
        # the level's noise for a policy whose measured channels span a given range
        at_level = functools.partial(noise_at_level, clean, eps, u_max, limits=limits, **system)
        obs_levels = at_level(obs_range)
        runs: list[tuple[str, FeedbackPolicy, EpisodeNoise]] = [
            ("open_loop", policy.open_loop(), obs_levels),
            ("closed_loop", policy, obs_levels),
        ]
        if model is not None:
            design = EstimatorNoise(
                actuator=np.asarray(obs_levels.a),
                measurement=np.asarray(obs_levels.v),
                process=settings.system_noise.process,
                initial=settings.system_noise.initial,
                model_error=settings.model_error,
            )
            runs.append(("closed_loop_estimator", estimator_policy(clean, policy, model, design), obs_levels))
        if settings.model_based:
            runs.append(("model_based", mb_policy, at_level(state_range)))
        for name, pol, lv in runs:
            t0 = time.perf_counter()
            ep = run_episodes(clean.dims, clean.data, pol, level_key, lv, settings.episodes)
            ep.cost.block_until_ready()
            rows.append(
                _row(name, eps, ep, settings.success_tol, reference.final_cost, time.perf_counter() - t0, lv, fall)
            )
        if settings.replan:
            t0 = time.perf_counter()
            rp = replan_episodes(
                train_env,
                result,
                cfg,
                level_key,
                obs_levels,
                settings.replan_episodes,
                settings.replan_every,
                settings.replan_iterations,
                feedback=settings.replan_feedback,
            )
            replan_compiles += rp.compiles_after_first
            row = _row(
                "replan",
                eps,
                rp.episodes,
                settings.success_tol,
                reference.final_cost,
                time.perf_counter() - t0,
                obs_levels,
                fall,
            )
            row["replans"] = rp.replans
            row["replan_compiles_after_first"] = rp.compiles_after_first
            rows.append(row)
        say(_level_line(eps, [r for r in rows if r["noise_level"] == eps]))

    return {
        "task": env.name,
        "result_task": result.task,
        "variant": result.variant,
        **header(settings),
        "model_based_cost": reference.final_cost,
        "nominal_cost": result.final_true_cost,
        "u_max": u_max.tolist(),
        "actuator_limits": [limits[0].tolist(), limits[1].tolist()],
        "replan_compiles_after_first": replan_compiles,
        "fall": None if fall is None else _fall_info(env, fall, T),
        "controllers": [c for c in CONTROLLERS if any(r["controller"] == c for r in rows)],
        "rows": rows,
    }


def _fall_info(env: Env, fall: _FallCheck, T: int) -> dict:
    """The report's ``fall``: which body, the ratio that counts as a fall, the episode's length."""
    return {"root_body": env.mj_model.body(fall.body).name, "fall_ratio": FALL_RATIO, "episode_s": T * fall.dt}


def _fall_check(env: Env, result: Result) -> Optional[_FallCheck]:
    """The fall check where the robot can fall (``falls.py``) and the result's nominal is of this model, else None."""
    body = root_body(env.mj_model)
    states = np.asarray(result.states, float)
    if body is None or states.ndim != 2 or states.shape[1] != env.dims.nx:
        return None
    heights = root_heights(env.mj_model, body, states)
    if not np.all(heights > 0):
        return None  # a root at or below the floor's height: no height to fall from
    return _FallCheck(env.mj_model, body, heights, env.control_dt)


def _level_line(eps: float, rows: list[dict]) -> str:
    parts = [f"{r['controller']} {r['mean_cost_ratio']:.3g}x ({100 * r['success_rate']:.0f}%{_up(r)})" for r in rows]
    return f"noise {eps:g}: " + ", ".join(parts)


def _up(row: dict) -> str:
    if "stayed_up_rate" not in row:
        return ""
    return f", up {100 * row['stayed_up_rate']:.0f}% {row['mean_up_s']:.2g} s"


def format_table(report: dict[str, Any]) -> str:
    """Markdown: mean cost / model-based optimum (success rate) per controller and level; on a robot
    that can fall, also the share of episodes that stayed up and their mean time up."""
    rows = report["rows"]
    controllers = report["controllers"]
    levels = sorted({r["noise_level"] for r in rows})
    head = "| noise level | " + " | ".join(controllers) + " |"
    lines = [head, "|" + "---|" * (len(controllers) + 1)]
    for eps in levels:
        cells = []
        for c in controllers:
            match = [r for r in rows if r["controller"] == c and r["noise_level"] == eps]
            if not match:
                cells.append("")
                continue
            r = match[0]
            spread = r["std_cost"] / report["model_based_cost"]
            cells.append(f"{r['mean_cost_ratio']:.3g} +- {spread:.2g} ({100 * r['success_rate']:.0f}%{_up(r)})")
        lines.append(f"| {eps:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot_evaluation(report: dict[str, Any], path: str) -> str:
    """Mean cost (relative to the noiseless model-based optimum) and success
    rate against the noise level, one line per controller."""
    from ..viz.plots import agg_pyplot

    plt = agg_pyplot()
    fall = report.get("fall")
    fig, axes = plt.subplots(1, 3 if fall else 2, figsize=(16 if fall else 11, 4.2))
    ax, bx = axes[0], axes[1]
    ref = report["model_based_cost"]
    for c in report["controllers"]:
        rows = sorted((r for r in report["rows"] if r["controller"] == c), key=lambda r: r["noise_level"])
        eps = [r["noise_level"] for r in rows]
        mean = np.array([r["mean_cost"] for r in rows]) / ref
        se = np.array([r["std_cost"] / math.sqrt(r["episodes"]) for r in rows]) / ref
        ax.errorbar(eps, mean, yerr=se, marker="o", capsize=3, label=f"{c} ({rows[0]['episodes']} ep.)")
        bx.plot(eps, [100 * r["success_rate"] for r in rows], marker="o", label=c)
        if fall:
            axes[2].plot(eps, [100 * r["stayed_up_rate"] for r in rows], marker="o", label=c)
    ax.set_yscale("log")
    ax.set_xlabel("noise level (actuator std / max control)")
    ax.set_ylabel("mean cost / model-based optimum")
    ax.set_title(f"{report['task']}: mean cost (+- standard error)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    bx.set_xlabel("noise level (actuator std / max control)")
    bx.set_ylabel(f"success rate, % (final error <= {report['settings']['success_tol']:g})")
    bx.set_ylim(-3, 103)
    bx.grid(True, alpha=0.3)
    bx.set_title("success rate")
    if fall:
        cx = axes[2]
        cx.set_xlabel("noise level (actuator std / max control)")
        cx.set_ylabel(f"stayed up, % of episodes ({fall['episode_s']:g} s each)")
        cx.set_ylim(-3, 103)
        cx.grid(True, alpha=0.3)
        cx.set_title(f"{fall['root_body']} above {fall['fall_ratio']:g} x its nominal height")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def run_evaluation(
    result: Result, env: Env, out: str, settings: EvaluateSettings, *, train_env: Optional[Env] = None, progress=None
) -> dict[str, Any]:
    """:func:`evaluate`, then write ``out``/evaluate.json, evaluate.png and table.md."""
    report = evaluate(env, result, settings, train_env=train_env, progress=progress)
    figures = {"evaluate.png": lambda path: plot_evaluation(report, path)}
    write(out, "evaluate", report, table=format_table(report), figures=figures)
    return report
