"""Instrumental variables against averaging: the study of docs/estimators.md.

    python benchmarks/estimator_study.py --out docs/figures/estimators     # ~30 min on 2 CPU cores
    python benchmarks/estimator_study.py --quick --out runs/estimators      # a few minutes
    python benchmarks/estimator_study.py --tiny --out runs/estimators       # a smoke run

Two parts, on the partially observed pendulum and cart-pole under the paper's
noise (s0 = 0.01, process and measurement noise 1e-3):

1. Coefficient error at a fixed nominal: the identified model's Markov
   parameters (response of z_{t+k} to du_t, k = 1..3, t >= q) against those of
   the exact linearisation, as n_s grows, for least squares (n_avg = 1),
   least squares on averaged repeats (n_avg = 10) and instrumental variables
   (n_avg = 1), and least squares without noise (the floor set by the
   curvature of the dynamics). Horizon 12, a smooth open-loop push as nominal
   (as in tests/test_identification.py), the sigma of the solves (pendulum
   0.1, cart-pole 1).
2. True cost against total rollouts: full solves with each variant/estimator
   at several budgets, seeds and perturbation sizes; the true cost (policy,
   closed loop, noiseless) relative to the model-based optimum, averaged over
   the last 20 iterations (less noisy than the final iterate; the final one is
   in the JSON too).

Writes summary.json, coefficient_error.png, true_cost_vs_rollouts.png and
table.md into --out, the way every study of the package reports
(podilqr_jax/studies: settings with a quick and a tiny size, the JSON opening
with the settings and the machine).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

import podilqr_jax as pj
from podilqr_jax.identify.estimators import fit_information_model_iv
from podilqr_jax.identify.info_state import info_dim
from podilqr_jax.sim.rollout import injected_perturbations, open_loop_policy, perturbation_rollouts, rollout_batch
from podilqr_jax.studies.report import header, write
from podilqr_jax.studies.settings import Sized, add_size_flags, size_of

TASKS = ("pendulum-partial", "cartpole-partial")
# (label, solver settings); n_s, n_avg and the estimator set the rollouts per iteration.
CONFIGS = [
    ("plain", dict(variant="plain", n_s=40)),
    ("feedback", dict(variant="feedback", n_s=40)),
    ("feedback", dict(variant="feedback", n_s=200)),
    ("averaged", dict(variant="averaged", n_s=40, n_avg=2)),
    ("averaged", dict(variant="averaged", n_s=40, n_avg=5)),
    ("averaged", dict(variant="averaged", n_s=40, n_avg=10)),
    ("iv", dict(variant="feedback", estimator="iv", n_s=40)),
    ("iv", dict(variant="feedback", estimator="iv", n_s=100)),
    ("iv", dict(variant="feedback", estimator="iv", n_s=200)),
    ("iv", dict(variant="feedback", estimator="iv", n_s=400)),
    # IV in the sysid, and a forward pass that averages 10 noisy rollouts per step size
    ("iv+avg-forward", dict(variant="averaged", n_avg=1, n_forward=10, estimator="iv", n_s=100)),
]
SIGMAS = {"pendulum-partial": (0.03, 0.1), "cartpole-partial": (0.3, 1.0)}
COLORS = {
    "iv+avg-forward": "tab:orange",
    "plain": "tab:red",
    "feedback": "tab:blue",
    "averaged": "tab:green",
    "iv": "tab:purple",
    "ols": "tab:blue",
    "noiseless": "k",
}


def markov(A, B, S, q, K=3):
    """Markov parameters S A_{t+k-1} ... A_{t+1} B_t, k = 1..K, t = q .. T-K-1."""
    A, B = np.asarray(A), np.asarray(B)
    out = []
    for t in range(q, A.shape[0] - K):
        M = B[t]
        for k in range(K):
            out.append(S @ M)
            if k < K - 1:
                M = A[t + k + 1] @ M
    return np.array(out)


COEF_SIGMA = {"pendulum-partial": 0.1, "cartpole-partial": 1.0}


def coefficient_error(task: str, n_values, seeds: int) -> list[dict]:
    horizon, q, sigma = 12, 2, COEF_SIGMA[task]
    env = pj.make_task(task, horizon=horizon, noise="paper")
    dims, data = env.dims, env.data
    nZ = info_dim(dims.nz, dims.nu, q)
    u_bar = jnp.asarray(0.8 * np.sin(0.5 * np.arange(horizon)))[:, None] * jnp.ones((1, dims.nu))
    zero = jnp.zeros((horizon, dims.nu))
    nominal = rollout_batch(dims, q, data, open_loop_policy(u_bar, nZ), zero, zero, record_state=True)
    exact = pj.linearise(dims, data, nominal.x, nominal.u)
    truth = markov(exact.A, exact.B, np.asarray(data.C), q)
    S = np.eye(dims.nz, nZ)
    rcond, policy = jnp.asarray(1e-10), open_loop_policy(u_bar, nZ)

    def err(model):
        return float(np.linalg.norm(markov(model.A, model.B, S, q) - truth) / np.linalg.norm(truth))

    rows = []
    for n_s in n_values:
        for seed in range(seeds):
            key = jax.random.PRNGKey(seed)
            traj = perturbation_rollouts(dims, q, n_s, data, policy, key, jnp.asarray(sigma), noisy=True)
            ols, _ = pj.fit_information_model(traj.z, traj.u, nominal.z, nominal.u, q, rcond)
            du = injected_perturbations(key, sigma, n_s, horizon, dims.nu)
            iv, _ = fit_information_model_iv(traj.z, traj.u, du, nominal.z, nominal.u, q, rcond)
            avg = perturbation_rollouts(dims, q, n_s, data, policy, key, jnp.asarray(sigma), n_avg=10, noisy=True)
            ols_avg, _ = pj.fit_information_model(avg.z, avg.u, nominal.z, nominal.u, q, rcond)
            clean = perturbation_rollouts(dims, q, n_s, data, policy, key, jnp.asarray(sigma))
            ols_clean, _ = pj.fit_information_model(clean.z, clean.u, nominal.z, nominal.u, q, rcond)
            fits = (("ols", ols, n_s), ("iv", iv, n_s), ("averaged", ols_avg, 10 * n_s), ("noiseless", ols_clean, n_s))
            for method, model, rollouts in fits:
                rows.append(
                    {
                        "task": task,
                        "method": method,
                        "n_s": n_s,
                        "rollouts": rollouts,
                        "seed": seed,
                        "error": err(model),
                    }
                )
        print(
            task,
            n_s,
            {
                m: round(np.mean([r["error"] for r in rows if r["n_s"] == n_s and r["method"] == m]), 4)
                for m in ("ols", "iv", "averaged", "noiseless")
            },
            flush=True,
        )
    return rows


def solves(task: str, seeds: int, sigmas, configs, max_iterations=None) -> list[dict]:
    optimum = pj.solve_model_based(pj.make_task(task)).final_cost
    env = pj.make_task(task, noise="paper")
    rows = []
    for sigma in sigmas:
        for label, settings in configs:
            for seed in range(seeds):
                extra = {} if max_iterations is None else {"max_iterations": max_iterations}
                cfg = pj.default_config(env, sigma=sigma, seed=seed, **settings, **extra)
                r = pj.solve(env, cfg)
                history = np.asarray(r.true_cost_history) / optimum
                rows.append(
                    {
                        "task": task,
                        "label": label,
                        "settings": settings,
                        "sigma": sigma,
                        "seed": seed,
                        "rollouts_per_iteration": r.rollouts / r.iterations,
                        "total_rollouts": r.rollouts,
                        "final_true_cost_ratio": float(history[-1]),
                        "last20_true_cost_ratio": float(history[-20:].mean()),
                        "wall_s": r.wall_s,
                    }
                )
            group = rows[-seeds:]
            print(
                f"{task} sigma={sigma} {label:8s} {settings}: last-20 true/optimum "
                f"{np.mean([g['last20_true_cost_ratio'] for g in group]):.5f} "
                f"({group[0]['rollouts_per_iteration']:.0f} rollouts/iteration)",
                flush=True,
            )
    return rows


@dataclasses.dataclass(frozen=True)
class EstimatorStudySettings(Sized):
    """What the study runs: seeds per point, the sysid batch sizes of part 1, the
    largest n_s of part 2's configurations (None: all), whether part 2 runs both
    sigmas of each task (else the larger), and its iteration cap (None: the task's)."""

    seeds: int = 3
    n_values: tuple[int, ...] = (40, 160, 640, 2560)
    max_n_s: Optional[int] = None
    both_sigmas: bool = True
    max_iterations: Optional[int] = None

    @classmethod
    def quick(cls) -> "EstimatorStudySettings":
        return cls(seeds=1, n_values=(40, 160, 640), max_n_s=200, both_sigmas=False, max_iterations=50)

    @classmethod
    def tiny(cls) -> "EstimatorStudySettings":
        return cls(seeds=1, n_values=(40,), max_n_s=40, both_sigmas=False, max_iterations=2)


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_coefficients(coef_rows, path):
    plt = _pyplot()
    tasks = [t for t in TASKS if any(r["task"] == t for r in coef_rows)]
    fig, axes = plt.subplots(1, len(tasks), figsize=(6 * len(tasks), 4.2), squeeze=False)
    for ax, task in zip(axes[0], tasks, strict=True):
        methods = (
            ("ols", "least squares"),
            ("averaged", "least squares, n_avg = 10"),
            ("iv", "IV"),
            ("noiseless", "least squares, no noise (curvature floor)"),
        )
        for method, label in methods:
            rs = [r for r in coef_rows if r["task"] == task and r["method"] == method]
            xs = sorted({r["rollouts"] for r in rs})
            ys = [np.mean([r["error"] for r in rs if r["rollouts"] == x]) for x in xs]
            ax.loglog(xs, ys, marker="o", color=COLORS[method], label=label)
        ax.set_xlabel("sysid rollouts")
        ax.set_ylabel("relative Markov-parameter error")
        ax.set_title(f"{task}: identified vs exact linearisation")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_solves(solve_rows, path):
    plt = _pyplot()
    keys = sorted({(r["task"], r["sigma"]) for r in solve_rows}, key=lambda k: (TASKS.index(k[0]), k[1]))
    cols = min(2, len(keys))
    rows_n = -(-len(keys) // cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(6.2 * cols, 4.4 * rows_n), squeeze=False)
    for ax, (task, sigma) in zip(axes.flat, keys, strict=False):
        for label in ("plain", "feedback", "averaged", "iv", "iv+avg-forward"):
            rs = [r for r in solve_rows if r["task"] == task and r["sigma"] == sigma and r["label"] == label]
            xs = sorted({r["total_rollouts"] for r in rs})
            if not xs:
                continue
            budgets = sorted({r["rollouts_per_iteration"] for r in rs})
            ys = [
                np.mean([r["last20_true_cost_ratio"] for r in rs if r["rollouts_per_iteration"] == b]) for b in budgets
            ]
            xs = [np.mean([r["total_rollouts"] for r in rs if r["rollouts_per_iteration"] == b]) for b in budgets]
            ax.loglog(xs, np.asarray(ys) - 1.0, marker="o", color=COLORS[label], label=label)
            for r in rs:
                ax.scatter(r["total_rollouts"], r["last20_true_cost_ratio"] - 1.0, color=COLORS[label], s=8, alpha=0.4)
        ax.set_xlabel("total rollouts of the solve")
        ax.set_ylabel("true cost / optimum - 1 (last 20 iterations)")
        ax.set_title(f"{task}, sigma = {sigma:g}", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def table(solve_rows) -> str:
    lines = [
        "| task | sigma | method | n_s | n_avg | rollouts / iteration "
        "| true cost / optimum, last 20 (mean, [min, max]) | final true cost / optimum (mean) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    seen = []
    for r in solve_rows:
        key = (r["task"], r["sigma"], r["label"], r["settings"].get("n_s"), r["settings"].get("n_avg", 1))
        if key in seen:
            continue
        seen.append(key)
        g = [
            x
            for x in solve_rows
            if (x["task"], x["sigma"], x["label"], x["settings"].get("n_s"), x["settings"].get("n_avg", 1)) == key
        ]
        last = np.array([x["last20_true_cost_ratio"] for x in g])
        final = np.mean([x["final_true_cost_ratio"] for x in g])
        lines.append(
            f"| {key[0]} | {key[1]:g} | {key[2]} | {key[3]} | {key[4]} | {g[0]['rollouts_per_iteration']:.0f} | "
            f"{last.mean():.5f} [{last.min():.5f}, {last.max():.5f}] | {final:.5f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="runs/estimators")
    add_size_flags(parser, quick="1 seed, n_s <= 200, 50 iterations: a few minutes", tiny="a smoke run")
    parser.add_argument("--seeds", type=int, default=None, help="seeds per point (default 3; quick and tiny 1)")
    parser.add_argument(
        "--labels", default=None, help="comma-separated labels to (re)run, merged into an existing --out/summary.json"
    )
    args = parser.parse_args()
    settings = EstimatorStudySettings.sized(size_of(args)).changed(seeds=args.seeds)
    os.makedirs(args.out, exist_ok=True)
    t0 = time.perf_counter()
    configs = [c for c in CONFIGS if settings.max_n_s is None or c[1]["n_s"] <= settings.max_n_s]
    solve_rows = []
    if args.labels:
        import json

        labels = set(args.labels.split(","))
        with open(os.path.join(args.out, "summary.json")) as f:
            old = json.load(f)
        coef_rows = old["coefficient_error"]
        solve_rows = [r for r in old["solves"] if r["label"] not in labels]
        configs = [c for c in configs if c[0] in labels]
    else:
        coef_rows = [row for task in TASKS for row in coefficient_error(task, settings.n_values, settings.seeds)]
    for task in TASKS:
        sigmas = SIGMAS[task] if settings.both_sigmas else SIGMAS[task][-1:]
        solve_rows += solves(task, settings.seeds, sigmas, configs, max_iterations=settings.max_iterations)
    report = {
        **header(settings),
        "coefficient_error": coef_rows,
        "solves": solve_rows,
        "wall_s": time.perf_counter() - t0,
    }
    text = table(solve_rows)
    figures = {
        "coefficient_error.png": lambda path: plot_coefficients(coef_rows, path),
        "true_cost_vs_rollouts.png": lambda path: plot_solves(solve_rows, path),
    }
    write(args.out, "summary", report, table=text, figures=figures)
    print(text)
    print(f"wrote {args.out} in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
