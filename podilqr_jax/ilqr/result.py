"""What a solve returns: the solution, its history and why it stopped."""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import os
from typing import Any

import numpy as np

from ..atomic import write_json_atomic
from .state import Record


class Status(str, enum.Enum):
    """Why a solve stopped."""

    CONVERGED = "converged"
    MAX_ITERATIONS = "max_iterations"
    LINE_SEARCH_FAILED = "line_search_failed"
    NONFINITE = "nonfinite"
    NO_RESPONSE = "no_response"
    INTERRUPTED = "interrupted"
    OUTRACED = "outraced"  # a start of several, stopped at a race's rung (``race``)

    def __str__(self) -> str:
        return self.value


BASIN_RATIO = 0.01
"""Final costs of one task further apart than this (relative) are different local minima."""


@dataclasses.dataclass(frozen=True)
class IterationInfo:
    """One row of the live report (handed to the ``callback`` of a solve)."""

    iteration: int
    cost: float
    alpha: float
    mu: float
    grad_norm: float
    accepted: bool
    rollouts: int
    rollouts_per_s: float
    wall_s: float
    true_cost: float = float("nan")  # the policy's cost on the noiseless system
    note: str = ""  # what happened out of the ordinary (a retry, left-out rollouts)
    sigma: float = float("nan")  # the sysid scale of the iteration's identification (NaN: none, or model-based)
    fit_error: float = float("nan")  # under noise: its fit's estimated relative error of B (identify.quality)
    engine: str = "mjx"  # the engine of the rollouts (``SolverConfig.engine``): mjx or native
    start: int = 0  # which start of a solve with restarts (``SolverConfig.restarts``); 0 without


@dataclasses.dataclass
class Result:
    """The outcome of :func:`podilqr_jax.solve` or :func:`solve_model_based`.

    Arrays are NumPy (host) arrays. The learnt policy is
    u_t = controls_t + K_t (Z_t - info_states_t): ``K`` are the gains that go
    with the nominal (those of the backward pass that produced it), ``k`` the
    last backward pass's feed-forward step. ``states`` are the nominal's full
    MuJoCo states [T+1, nq + nv] and ``observations`` their noise-free C x.

    The counters and histories are ``record`` (a :class:`~podilqr_jax.ilqr.state.Record`),
    held as the solve counted them and read as attributes of the result too
    (``result.cost_history`` is ``result.record.cost_history``).
    ``cost_history`` is the cost the algorithm sees (under noise: the cost of
    a noisy nominal). ``true_cost_history`` is the policy's cost run closed
    loop on the noiseless system and ``open_loop_cost_history`` the nominal
    controls replayed open loop on it (equal to ``cost_history`` without
    noise). Under noise a rejected step re-measures the nominal
    (``remeasured``); ``longest_rejection_streak`` shows a frozen run.
    """

    method: str
    task: str
    status: Status
    message: str
    controls: np.ndarray  # [T, nu]
    observations: np.ndarray  # [T+1, nz]
    states: np.ndarray  # [T+1, nx]
    info_states: np.ndarray  # [T+1, nZ]
    K: np.ndarray  # [T, nu, nZ]
    k: np.ndarray  # [T, nu]
    q: int
    record: Record  # the counters and histories (iterations, rollouts, cost_history, ...)
    wall_s: float
    compile_s: float  # tracing, lowering and compiling
    run_s: float
    compiles_per_iteration: list[int]
    phase_s: dict[str, float]  # seconds per phase (driver.PHASES)
    config: dict[str, Any]
    control_dt: float
    observation_labels: tuple[str, ...] = ()
    state_labels: tuple[str, ...] = ()
    variant: str = "plain"
    noisy: bool = False
    noise: dict[str, float] = dataclasses.field(default_factory=dict)
    warnings: list[str] = dataclasses.field(default_factory=list)  # also the options switched off for MJX
    control_limits: list = dataclasses.field(default_factory=list)  # [nu][low, high] ctrlrange; [] when unlimited
    sigma_units: list = dataclasses.field(default_factory=list)  # [nu] (cfg.sigma_scale)
    mirrored: bool = False  # the identification ran mirrored pairs at the end (cfg.mirrored or a recovery)
    open_loop: bool = False  # ... and open loop (variant plain, or a recovery switched to it)
    engine: str = "mjx"  # the engine that ran the rollouts (``SolverConfig.engine``): mjx or native
    plan: dict[str, Any] = dataclasses.field(default_factory=dict)  # how it ran (``ilqr.plan.ExecutionPlan``)
    # with restarts (``SolverConfig.restarts``), every start's outcome (``ilqr.restarts.START_FIELDS``);
    # this result is the start of ``best_start``; [] without restarts
    starts: list = dataclasses.field(default_factory=list)
    best_start: int = 0

    def __getattr__(self, name: str):
        """The record's counters and histories as attributes of the result."""
        record = self.__dict__.get("record")
        if record is not None and name in _RECORD_NAMES:
            return getattr(record, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def final_cost(self) -> float:
        return self.cost_history[-1]

    @property
    def final_true_cost(self) -> float:
        """The final policy's cost on the noiseless system (closed loop)."""
        return self.true_cost_history[-1] if self.true_cost_history else self.final_cost

    def policy(self, name: str | None = None):
        """This solve as a controller (:class:`~podilqr_jax.control.policy.FeedbackPolicy`):
        u_t = controls_t + K_t (Z_t - info_states_t) on the measured
        information state (on the full state for a model-based result)."""
        from ..control.policy import FeedbackPolicy

        return FeedbackPolicy.from_result(self, name)

    def animate(self, path: str | os.PathLike, env=None, **options):
        """Write the nominal motion as a GIF (or MP4) at real time, with the
        time and the cost so far on each frame; ``options`` as
        :func:`podilqr_jax.viz.animate.animate` (``episodes``, ``noise``,
        ``compare``, ``width``, ``height``, ``fps``, ``renderer`` ...).
        ``env``: the task (default: rebuilt from ``task``)."""
        from ..viz.animate import animate

        return animate(self, path, env=env, **options)

    def largest_state_gap(self, other: "Result") -> dict[str, Any]:
        """Where this solve's nominal trajectory is farthest from ``other``'s
        (both of one task): the state entry and control step of the largest
        |x_t - x'_t|, with both values. Two solves whose costs differ by more
        than round-off and whose trajectories part by a swing's width ended in
        different local minima (basins)."""
        a, b = np.asarray(self.states, dtype=float), np.asarray(other.states, dtype=float)
        if a.shape != b.shape:
            raise ValueError(f"the two results' states differ in shape: {a.shape} and {b.shape} (not one task?)")
        gap = np.abs(a - b)
        step, entry = np.unravel_index(int(np.argmax(gap)), gap.shape)
        labels = self.state_labels or other.state_labels
        return {
            "gap": float(gap[step, entry]),
            "state": labels[entry] if entry < len(labels) else f"x[{entry}]",
            "step": int(step),
            "this": float(a[step, entry]),
            "other": float(b[step, entry]),
        }

    @property
    def converged(self) -> bool:
        return self.status == Status.CONVERGED

    @property
    def recompiles_after_first(self) -> int:
        return int(sum(self.compiles_per_iteration[1:]))

    def summary(self) -> str:
        text = (
            f"{self.method} on {self.task}: {self.status} after {self.iterations} iterations "
            f"({self.message}); cost {self.cost_history[0]:.6g} -> {self.final_cost:.6g}; "
            f"{self.rollouts} rollouts on {self.engine}; {self.wall_s:.2f} s wall ({self.compile_s:.2f} s compiling)"
        )
        if self.noisy:
            text += (
                f"; variant {self.variant} under noise {self.noise}: true cost (policy, closed loop, "
                f"noiseless) {self.final_true_cost:.6g}, open-loop replay {self.open_loop_cost_history[-1]:.6g}; "
                f"{self.rejected_steps} rejected steps, longest streak {self.longest_rejection_streak}, "
                f"nominal re-measured {self.remeasured} times"
            )
        if len(self.starts) > 1:
            key = "true_cost" if self.noisy else "cost"
            costs = ", ".join(f"{s[key]:.6g} ({s['status']})" for s in self.starts)
            text += f"; {len(self.starts)} starts, the best is start {self.best_start}; their costs: {costs}"
            by_start = {s["start"]: s for s in self.starts}
            first, best = by_start.get(0, {}).get(key, math.nan), by_start[self.best_start][key]
            outraced = by_start.get(0, {}).get("status") == str(Status.OUTRACED)
            if self.best_start != 0 and not first <= best * (1 + BASIN_RATIO):  # also a NaN first
                ratio = f", {first / best:.3g}x the best" if best > 0 else ""
                where = f"was outraced at {first:.6g}" if outraced else "ended in a worse local minimum"
                text += f"; the first guess given (start 0) {where}{ratio}"
        return text

    def to_dict(self) -> dict[str, Any]:
        return {
            "method": self.method,
            "task": self.task,
            "status": str(self.status),
            "message": self.message,
            "final_cost": self.final_cost,
            "final_true_cost": self.final_true_cost,
            "variant": self.variant,
            "noisy": self.noisy,
            "noise": self.noise,
            **self.record.as_dict(),
            "sigma_units": self.sigma_units,
            "mirrored": self.mirrored,
            "open_loop": self.open_loop,
            "engine": self.engine,
            "plan": self.plan,
            "starts": self.starts,
            "best_start": self.best_start,
            "warnings": list(self.warnings),
            "control_limits": [[float(lo), float(hi)] for lo, hi in self.control_limits],
            "controls": self.controls.tolist(),
            "observations": self.observations.tolist(),
            "states": self.states.tolist(),
            "info_states": self.info_states.tolist(),
            "K": self.K.tolist(),
            "k": self.k.tolist(),
            "q": self.q,
            "wall_s": self.wall_s,
            "compile_s": self.compile_s,
            "run_s": self.run_s,
            "compiles_per_iteration": self.compiles_per_iteration,
            "recompiles_after_first": self.recompiles_after_first,
            "phase_s": self.phase_s,
            "config": self.config,
            "control_dt": self.control_dt,
            "observation_labels": list(self.observation_labels),
            "state_labels": list(self.state_labels),
        }

    def save_json(self, path: str | os.PathLike) -> None:
        """Write the result as JSON atomically (a temporary file, then rename)."""
        write_json_atomic(path, self.to_dict())

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Result":
        """The inverse of :meth:`to_dict` (JSON nulls become NaN)."""
        fields = {f.name for f in dataclasses.fields(cls)}
        kwargs = {k: v for k, v in d.items() if k in fields}
        for name in ("controls", "observations", "states", "K", "k"):
            kwargs[name] = np.asarray(d[name], dtype=float)
        if "info_states" in d:
            kwargs["info_states"] = np.asarray(d["info_states"], dtype=float)
        else:  # written before info_states were saved: rebuild them from the nominal
            from ..identify.info_state import info_states

            kwargs["info_states"] = np.asarray(info_states(kwargs["observations"], kwargs["controls"], int(d["q"])))
        kwargs["record"] = Record.from_dict(d)
        kwargs["control_limits"] = [
            [-math.inf if lo is None else float(lo), math.inf if hi is None else float(hi)]
            for lo, hi in d.get("control_limits", [])
        ]
        kwargs["status"] = Status(d["status"])
        kwargs["observation_labels"] = tuple(d.get("observation_labels", ()))
        kwargs["state_labels"] = tuple(d.get("state_labels", ()))
        return cls(**kwargs)


_RECORD_NAMES = Record.names()


def load_result(path: str | os.PathLike) -> Result:
    """A result written by ``Result.save_json`` or ``podilqr solve --out``."""
    from ..errors import ConfigError

    try:
        with open(path) as f:
            d = json.load(f)
    except FileNotFoundError:
        raise ConfigError(
            f"No result file at {os.fspath(path)!r}; write one with `podilqr solve TASK --out PATH`."
        ) from None
    except (OSError, json.JSONDecodeError) as exc:
        raise ConfigError(f"Cannot read the result file {os.fspath(path)!r}: {exc}.") from None
    required = ("method", "task", "status", "controls", "observations", "states", "K", "k", "q", "cost_history")
    missing = [k for k in required if k not in d] if isinstance(d, dict) else list(required)
    if missing:
        raise ConfigError(
            f"{os.fspath(path)!r} is not a podilqr result (missing {', '.join(missing)}); "
            "give the JSON written by `podilqr solve --out`."
        )
    try:
        return Result.from_dict(d)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"The result file {os.fspath(path)!r} is malformed: {exc}.") from None
