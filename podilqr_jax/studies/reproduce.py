"""Reproduction of the paper's study (Section VI, Fig. 2) and a sweep of sigma.

For each system (pendulum, cart-pole) and observation (full with process
noise; partial with process and measurement noise) every variant runs over
several seeds on the task's noisy version (``make_task(name, noise="paper")``)
with the task's noisy solver defaults; only ``variant`` (and ``seed``) change
between the runs of a panel. Each run's *true cost* (its policy, closed loop,
on the noiseless system; see ``evaluation``) is compared with

  - ``nominal``: the same settings with the noise switched off (same seed),
  - the model-based optimum (exact derivatives, noiseless, the core solver).

The sigma sweep repeats the partially and fully observed runs at several
perturbation sizes (multiples of the task's default) to show the window in
which each variant works.

``run_study`` writes into ``out``:
  summary.json           rows (one per run) with the fields documented below
  fig2_true_cost.png     2x2 figure like the paper's Fig. 2
  sigma_sweep.png        final true cost / optimum vs sigma, per variant
  table.md               the table of the study (also printed)
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from typing import Callable, Optional, Sequence

import numpy as np

from ..errors import ConfigError
from ..ilqr.config import PAPER_SETTINGS, check_int
from ..ilqr.solver import default_config, solve, solve_model_based
from ..task.noise import NoiseModel
from ..task.tasks import PAPER_S0, make_task
from ..viz.plots import agg_pyplot
from .report import header, write
from .settings import Sized

PANELS = (
    ("full", ("nominal", "plain", "feedback")),
    ("partial", ("nominal", "plain", "feedback", "averaged", "iv")),
)
# Study rows that are not a plain ``variant``: the instrumental-variables
# estimator (docs/estimators.md), with feedback in the sysid rollouts, n_avg = 1.
ROW_SETTINGS = {"iv": dict(variant="feedback", estimator="iv")}
PAPER_NOISELESS = {k: v for k, v in PAPER_SETTINGS.items() if k != "variant"}
"""What the study's noiseless rows run as in the paper, the variant aside
(``config.PAPER_SETTINGS``): one fixed sigma, every direction above rcond, no
change of experiment (noisy solves ignore these)."""
SYSTEMS = ("pendulum", "cartpole")
SWEEP_FACTORS = (0.1, 0.3, 1.0, 3.0)
LABELS = {
    "nominal": "nominal (noiseless)",
    "plain": "POD-iLQR",
    "feedback": "POD-iLQR modified (feedback)",
    "averaged": "POD-iLQR-Avg",
    "iv": "feedback + instrumental variables",
}
COLORS = {"nominal": "k", "plain": "tab:red", "feedback": "tab:blue", "averaged": "tab:green", "iv": "tab:purple"}


@dataclasses.dataclass(frozen=True)
class ReproduceSettings(Sized):
    """What the study runs (sizes and changes as every study's: ``studies/settings.py``).

    Attributes:
      seeds: seeds per (system, observation, variant).
      systems: which systems.
      max_iterations: per system; None keeps the task's noisy default.
      sweep_factors: multiples of the default sigma for the sweep (empty: no sweep).
      sweep_seeds: seeds per sweep point.
      horizon: control steps of every task.
      s0: initial-state deviation std; process and measurement noise are 10% of it.
    """

    seeds: int = 5
    systems: tuple[str, ...] = SYSTEMS
    max_iterations: Optional[dict] = None
    sweep_factors: tuple[float, ...] = SWEEP_FACTORS
    sweep_seeds: int = 2
    horizon: int = 30
    s0: float = PAPER_S0

    @classmethod
    def quick(cls) -> "ReproduceSettings":
        """A few minutes on 2 CPU cores: 2 seeds, shorter runs, a 3-point sweep."""
        return cls(
            seeds=2,
            max_iterations={"pendulum": 50, "cartpole": 100},
            sweep_factors=(0.1, 1.0, 3.0),
            sweep_seeds=1,
        )

    @classmethod
    def tiny(cls) -> "ReproduceSettings":
        """A smoke run of every panel and the sweep (seconds per system, numbers meaningless):
        1 seed, 2 iterations, horizon 8, a 2-point sweep."""
        return cls(
            seeds=1,
            max_iterations={"pendulum": 2, "cartpole": 2},
            sweep_factors=(1.0, 3.0),
            sweep_seeds=1,
            horizon=8,
        )

    def validate(self) -> "ReproduceSettings":
        """Raise a ConfigError for settings the study cannot run; return them otherwise."""
        unknown = [s for s in self.systems if s not in SYSTEMS]
        if unknown or not self.systems:
            raise ConfigError(f"`systems` is a non-empty subset of {', '.join(SYSTEMS)}; got {self.systems!r}.")
        for name, minimum in (("seeds", 1), ("sweep_seeds", 1), ("horizon", 2)):
            check_int(name, getattr(self, name), minimum)
        return self


def run_study(
    out: str | os.PathLike,
    settings: ReproduceSettings = ReproduceSettings(),
    progress: Optional[Callable[[str], None]] = None,
) -> list[dict]:
    """Run the study and write summary.json, the figures and table.md into ``out``."""
    settings.validate()
    out = os.fspath(out)
    os.makedirs(out, exist_ok=True)
    say = progress or (lambda msg: None)
    rows: list[dict] = []
    t0 = time.perf_counter()
    for system in settings.systems:
        for observation, variants in PANELS:
            name = f"{system}-{observation}"
            clean = make_task(name, horizon=settings.horizon)
            optimum = solve_model_based(clean, default_config(clean, max_iterations=500)).final_cost
            env = make_task(
                name, horizon=settings.horizon, noise=NoiseModel.paper(settings.s0, partial=observation == "partial")
            )
            # The paper compares the variants at one sigma: the noiseless reference row (``nominal``)
            # keeps it too, with the paper's fit (no adaptive scale, rank cap or change of experiment),
            # and the paper's forward pass: one rollout per candidate but for the averaged variant.
            base = default_config(env).replace(**PAPER_NOISELESS)
            if settings.max_iterations and system in settings.max_iterations:
                base = base.replace(max_iterations=settings.max_iterations[system])
            points = [("main", 1.0, settings.seeds)]
            points += [("sigma_sweep", f, settings.sweep_seeds) for f in settings.sweep_factors if f != 1.0]
            for study, factor, n_seeds in points:
                for seed in range(n_seeds):
                    nominal_true = None
                    for variant in variants:
                        settings_v = ROW_SETTINGS.get(variant, dict(variant=variant))
                        if variant != "averaged":  # the paper's forward pass: one rollout per candidate
                            settings_v = {"n_forward": 1} | settings_v
                        cfg = base.replace(seed=seed, sigma=base.sigma * factor, **settings_v)
                        r = solve(env, cfg)
                        if variant == "nominal":
                            nominal_true = r.final_true_cost
                        row = _row(system, observation, study, r, cfg, nominal_true, optimum)
                        rows.append(row | {"variant": variant, "estimator": cfg.estimator})
                        say(
                            f"{name:17s} {study:11s} sigma={cfg.sigma:<7.3g} seed={seed} {variant:9s} "
                            f"true/optimum={r.final_true_cost / optimum:.5f} ({r.wall_s:.1f} s)"
                        )
    summary = {**header(settings), "wall_s": time.perf_counter() - t0, "rows": rows}
    figures = {"fig2_true_cost.png": lambda path: plot_fig2(rows, path)}
    if any(r["study"] == "sigma_sweep" for r in rows):
        figures["sigma_sweep.png"] = lambda path: plot_sigma_sweep(rows, path)
    write(out, "summary", summary, table=format_table(rows), figures=figures)
    return rows


def _row(system, observation, study, r, cfg, nominal_true, optimum) -> dict:
    fed = max(r.iterations, 1)
    # the nominal run of a panel compares with itself
    reference = r.final_true_cost if nominal_true is None else nominal_true
    return {
        "system": system,
        "observation": observation,
        "study": study,
        "variant": r.variant,
        "seed": cfg.seed,
        "sigma": float(cfg.sigma),
        "n_s": cfg.n_s,
        "n_avg": cfg.resolved_n_avg(),
        "final_true_cost": r.final_true_cost,
        "nominal_true_cost": reference,
        "model_based_cost": optimum,
        "ratio_to_nominal": r.final_true_cost / reference,
        "ratio_to_model_based": r.final_true_cost / optimum,
        "final_open_loop_cost": r.open_loop_cost_history[-1],
        "final_training_cost": r.final_cost,
        "rollouts_per_iteration": r.rollouts / fed,
        "total_rollouts": r.rollouts,
        "iterations": r.iterations,
        "wall_s": r.wall_s,
        "compile_s": r.compile_s,
        "status": str(r.status),
        "rejected_steps": r.rejected_steps,
        "remeasured": r.remeasured,
        "longest_rejection_streak": r.longest_rejection_streak,
        "noise": r.noise or {},
        "true_cost_history": r.true_cost_history,
    }


def _select(rows, **match):
    return [r for r in rows if all(r[k] == v for k, v in match.items())]


def format_table(rows: Sequence[dict]) -> str:
    """Markdown table of the main study: final true cost relative to nominal."""
    lines = [
        "| system | observation | variant | true cost / nominal (mean +- std, [min, max]) | true cost / optimum "
        "(mean) | open-loop replay / optimum (median) | rollouts / iteration | total rollouts (mean) | iterations "
        "| wall s (mean) | seeds |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    main = _select(rows, study="main")
    keys = []
    for r in main:
        key = (r["system"], r["observation"], r["variant"])
        if key not in keys:
            keys.append(key)
    for system, observation, variant in keys:
        group = _select(main, system=system, observation=observation, variant=variant)
        rel = np.array([g["ratio_to_nominal"] for g in group])
        opt = np.array([g["ratio_to_model_based"] for g in group])
        lines.append(
            f"| {system} | {observation} | {variant} | {rel.mean():.5f} +- {rel.std():.5f} "
            f"[{rel.min():.5f}, {rel.max():.5f}] | {opt.mean():.5f} | "
            f"{np.median([g['final_open_loop_cost'] / g['model_based_cost'] for g in group]):.4g} | "
            f"{np.mean([g['rollouts_per_iteration'] for g in group]):.0f} | "
            f"{np.mean([g['total_rollouts'] for g in group]):.0f} | "
            f"{np.mean([g['iterations'] for g in group]):.0f} | {np.mean([g['wall_s'] for g in group]):.1f} | "
            f"{len(group)} |"
        )
    sweep = [r for r in rows if r["study"] == "sigma_sweep"] + main
    if any(r["study"] == "sigma_sweep" for r in rows):
        lines += ["", "Sigma sweep: true cost / model-based optimum (mean over seeds)", ""]
        sigmas = sorted({(r["system"], r["observation"], r["sigma"]) for r in sweep})
        variants = [v for _, vs in PANELS for v in vs]
        variants = list(dict.fromkeys(variants))
        lines.append("| system | observation | sigma | " + " | ".join(variants) + " |")
        lines.append("|---|---|---|" + "---|" * len(variants))
        for system, observation, sigma in sigmas:
            cells = []
            for v in variants:
                g = _select(sweep, system=system, observation=observation, sigma=sigma, variant=v)
                cells.append(f"{np.mean([x['ratio_to_model_based'] for x in g]):.4f}" if g else "")
            lines.append(f"| {system} | {observation} | {sigma:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot_fig2(rows: Sequence[dict], path: str) -> str:
    """2x2 like the paper's Fig. 2: rows full/partial, columns pendulum/cart-pole.

    True cost / model-based optimum vs iteration: mean over seeds with a
    min-max band, and a zoomed inset over the last half of the iterations.
    """
    plt = agg_pyplot()
    main = _select(rows, study="main")
    systems = [s for s in SYSTEMS if _select(main, system=s)]
    fig, axes = plt.subplots(2, len(systems), figsize=(6.2 * len(systems), 8.2), squeeze=False)
    for i, (observation, variants) in enumerate(PANELS):
        for j, system in enumerate(systems):
            ax = axes[i, j]
            inset = ax.inset_axes([0.5, 0.5, 0.47, 0.4])
            panel = _select(main, system=system, observation=observation)
            # runs that stopped early (converged) keep their last value to the end
            length = max((len(g["true_cost_history"]) for g in panel), default=0)
            lows, highs, n_it = [], [], 0
            for variant in variants:
                group = _select(panel, variant=variant)
                if not group:
                    continue
                hist = np.array([_pad(g["true_cost_history"], length) for g in group]) / group[0]["model_based_cost"]
                mean, lo, hi = hist.mean(0), hist.min(0), hist.max(0)
                it = np.arange(length)
                n_it = max(n_it, length)
                for a in (ax, inset):
                    a.plot(it, mean, color=COLORS[variant], lw=1.4, label=LABELS[variant])
                    a.fill_between(it, lo, hi, color=COLORS[variant], alpha=0.2, lw=0)
                half = length // 2
                lows.append(np.min(lo[half:]))
                highs.append(np.max(mean[half:]))
            ax.set_yscale("log")
            ax.set_xlabel("iteration")
            ax.set_ylabel("true cost / model-based optimum")
            ax.set_title(f"{system}, {observation} observation")
            ax.grid(True, which="both", alpha=0.3)
            if lows:
                # Zoom on the variants that end near the best one; the others
                # leave the inset (they are visible in the main axes).
                lo = min(lows)
                near = [h for h in highs if h < 1.2 * lo]
                hi = max(near) if near else 1.05 * lo
                span = max(hi - lo, 1e-3 * lo)
                inset.set_xlim(n_it // 2, n_it - 1)
                inset.set_ylim(lo - 0.2 * span, hi + 0.6 * span)
                inset.tick_params(labelsize=7)
                inset.grid(True, alpha=0.3)
                inset.set_title("zoom: second half", fontsize=7)
            ax.legend(loc="lower left", fontsize=7)
    fig.suptitle("True cost (policy closed loop on the noiseless system), mean and min-max band over seeds")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_sigma_sweep(rows: Sequence[dict], path: str) -> str:
    """Final true cost / optimum vs the perturbation sigma, per variant."""
    plt = agg_pyplot()
    systems = [s for s in SYSTEMS if _select(rows, system=s)]
    fig, axes = plt.subplots(2, len(systems), figsize=(6.2 * len(systems), 7.4), squeeze=False)
    for i, (observation, variants) in enumerate(PANELS):
        for j, system in enumerate(systems):
            ax = axes[i, j]
            for variant in variants:
                group = _select(rows, system=system, observation=observation, variant=variant)
                sigmas = sorted({g["sigma"] for g in group})
                if not sigmas:
                    continue
                vals = [[g["ratio_to_model_based"] for g in group if g["sigma"] == s] for s in sigmas]
                mean = [np.mean(v) for v in vals]
                ax.plot(sigmas, mean, marker="o", color=COLORS[variant], label=LABELS[variant])
                for s, v in zip(sigmas, vals, strict=True):
                    ax.scatter([s] * len(v), v, color=COLORS[variant], s=8, alpha=0.5)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("sysid perturbation sigma")
            ax.set_ylabel("final true cost / model-based optimum")
            ax.set_title(f"{system}, {observation} observation")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7)
    fig.suptitle("The excitation window: where each variant reaches the optimum")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def _pad(history: Sequence[float], length: int) -> np.ndarray:
    h = np.asarray([np.nan if v is None else v for v in history], dtype=float)
    if h.size < length:  # a run that stopped early keeps its last value
        h = np.concatenate([h, np.full(length - h.size, h[-1])])
    return h


def load_rows(path: str | os.PathLike) -> list[dict]:
    with open(path) as f:
        return json.load(f)["rows"]
