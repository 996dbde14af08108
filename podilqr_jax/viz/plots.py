"""PNG plots of a solve: cost convergence and the swing-up trajectory."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Optional, Sequence

import numpy as np

if TYPE_CHECKING:  # results are read, never built, here: viz/ imports nothing of ilqr/
    from ..ilqr.result import Result


def agg_pyplot():
    """matplotlib.pyplot on the file-only Agg backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_convergence(results: Sequence[Result], path: str | os.PathLike, title: Optional[str] = None) -> str:
    """Cost per iteration (log scale) of one or more results, e.g. POD-iLQR and
    the model-based reference on the same task; with restarts each start's
    history too, thin, beside the best one's."""
    plt = agg_pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for r in results:
        label = f"{r.method} ({r.status})"
        if len(r.starts) > 1:
            label = f"{r.method}, best of {len(r.starts)} starts ({r.status})"
        (line,) = ax.semilogy(np.arange(len(r.cost_history)), r.cost_history, marker=".", ms=3, label=label)
        others = [s for s in r.starts if s["start"] != r.best_start and s.get("cost_history")]
        for i, s in enumerate(others):
            history = s["cost_history"]
            other_label = f"{r.method}, the other starts" if i == 0 else None
            ax.semilogy(np.arange(len(history)), history, color=line.get_color(), lw=0.6, alpha=0.4, label=other_label)
    ax.set_xlabel("iteration")
    ax.set_ylabel("cost J")
    ax.set_title(title or f"{results[0].task}: cost convergence")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return os.fspath(path)


def plot_trajectory(result: Result, path: str | os.PathLike) -> str:
    """The nominal trajectory: every state coordinate and the controls vs time."""
    plt = agg_pyplot()
    x, u = result.states, result.controls
    dt = result.control_dt
    t_x = dt * np.arange(x.shape[0])
    t_u = dt * np.arange(u.shape[0])
    n = x.shape[1]
    fig, axes = plt.subplots(n + 1, 1, figsize=(6.4, 1.6 * (n + 1)), sharex=True)
    labels = result.state_labels or tuple(f"x[{i}]" for i in range(n))
    for i in range(n):
        axes[i].plot(t_x, x[:, i], marker=".", ms=3)
        axes[i].set_ylabel(labels[i], fontsize=8)
        axes[i].grid(True, alpha=0.3)
    for j in range(u.shape[1]):
        (line,) = axes[-1].step(t_u, u[:, j], where="post", label=f"u[{j}]")
        if result.control_limits:
            for bound in result.control_limits[j]:
                if np.isfinite(bound):
                    axes[-1].axhline(bound, color=line.get_color(), ls="--", lw=0.8)
    if u.shape[1] > 1 or result.control_limits:
        axes[-1].legend(fontsize=7, title="dashed: ctrlrange" if result.control_limits else None, title_fontsize=7)
    axes[-1].set_ylabel("control", fontsize=8)
    axes[-1].set_xlabel("time [s]")
    axes[-1].grid(True, alpha=0.3)
    axes[0].set_title(f"{result.task}: {result.method}, cost {result.final_cost:.6g}")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return os.fspath(path)
