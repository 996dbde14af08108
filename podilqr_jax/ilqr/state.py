"""What the driver carries from one iteration to the next.

- :class:`Nominal`: the nominal trajectory (controls and their measured rollout).
- :class:`Record`: every counter and history a solve reports. The driver
  counts into it, a checkpoint saves it and :class:`~podilqr_jax.ilqr.result.Result`
  holds it as it is (``result.cost_history`` reads ``result.record``), so a
  new counter is one field here.
- :class:`SolverState`: the nominal, the current gains, the model kept for the
  next iteration, both PRNG keys, the regularisation and the sysid scale, the
  driver's own bookkeeping (failure streak, recovery switches) and the record.

Saving the state after an iteration and loading it gives the driver exactly
what it had (``checkpoint``).
"""

from __future__ import annotations

import dataclasses
from typing import Optional

import jax.numpy as jnp

from ..identify.sysid import LinearModel


@dataclasses.dataclass
class Nominal:
    """The nominal trajectory: controls and their measured rollout."""

    u_bar: jnp.ndarray  # [T, nu]
    z_bar: jnp.ndarray  # [T+1, nz] (as measured)
    x_bar: jnp.ndarray  # [T+1, nx]
    Z_bar: jnp.ndarray  # [T+1, nZ]
    cost: float

    @classmethod
    def measured(cls, ls) -> "Nominal":
        """The line search's chosen rollout as the new nominal."""
        return cls(ls.trajectory.u, ls.trajectory.z, ls.trajectory.x, ls.Z, float(ls.cost))


@dataclasses.dataclass
class Record:
    """The counters and histories of a solve (host numbers only).

    Histories: ``cost_history`` holds the nominal's cost before iteration 1,
    then after each iteration, as ``true_cost_history`` (the policy run closed
    loop on the noiseless system) and ``open_loop_cost_history`` (the nominal
    controls replayed open loop on it) do; ``alpha_history`` (0: rejected),
    ``mu_history`` and ``grad_norm_history`` hold one entry per backward pass,
    ``sigma_history`` the sysid scale of the model each data-based iteration used
    and ``fit_error_history`` that model's estimated relative error of B
    (``identify.quality``; under noise only, NaN otherwise).
    """

    iterations: int = 0  # iterations completed
    rollouts: int = 0
    rejected_steps: int = 0
    remeasured: int = 0  # under noise: nominals re-measured after a rejected step
    longest_rejection_streak: int = 0
    diverged_rollouts: int = 0  # sysid rollouts left out of the fit as non-finite
    diverged_candidates: int = 0  # line-search candidates rejected as non-finite
    mu_retries: int = 0  # backward passes redone with a larger mu after a rejected step
    reidentifications: int = 0  # fresh identifications (another sigma or experiment) after no step lowered the cost
    cost_history: list = dataclasses.field(default_factory=list)
    true_cost_history: list = dataclasses.field(default_factory=list)
    open_loop_cost_history: list = dataclasses.field(default_factory=list)
    alpha_history: list = dataclasses.field(default_factory=list)
    mu_history: list = dataclasses.field(default_factory=list)
    grad_norm_history: list = dataclasses.field(default_factory=list)
    sigma_history: list = dataclasses.field(default_factory=list)
    fit_error_history: list = dataclasses.field(default_factory=list)

    @classmethod
    def counters(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls) if f.type in ("int", int))

    @classmethod
    def histories(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(cls) if f.type in ("list", list))

    @classmethod
    def names(cls) -> frozenset[str]:
        return frozenset(f.name for f in dataclasses.fields(cls))

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, d: dict) -> "Record":
        """The fields ``d`` holds (missing ones default); histories as floats, nulls as NaN."""
        kwargs = {}
        for name in cls.counters():
            if name in d:
                kwargs[name] = int(d[name])
        for name in cls.histories():
            if name in d:
                kwargs[name] = [float("nan") if v is None else float(v) for v in d[name]]
        return cls(**kwargs)


@dataclasses.dataclass
class SolverState:
    """What the outer loop carries between iterations (host scalars, device arrays)."""

    nominal: Optional[Nominal]
    gains: jnp.ndarray  # K of the current policy [T, nu, nZ]
    key: jnp.ndarray  # sysid PRNG key
    ls_key: jnp.ndarray  # line-search PRNG key
    mu: float
    model: Optional[LinearModel] = None  # reused by the next iteration when not None
    back_k: Optional[jnp.ndarray] = None  # the last backward pass's k [T, nu]
    sigma: float = float("nan")  # the sysid scale (adapted with cfg.adapt_sigma) before re-identification factors
    mirrored: int = 0  # 1 once the identification runs mirrored pairs (configured, or a recovery)
    open_loop: int = 0  # 1 once a recovery switched a closed-loop identification to open loop
    failures: int = 0  # rejected steps since the last accepted one or fresh model (mu grows by factor^failures)
    streak: int = 0  # rejected steps since the last accepted one (the message of a failed line search)
    reidentified: int = 0  # re-identifications since the last accepted step (sets the sigma scale)
    stopped: Optional[list] = None  # [status, message] once a stopping rule fired
    record: Record = dataclasses.field(default_factory=Record)

    # the host scalars a checkpoint saves beside the arrays and the record
    SCALARS = ("mu", "sigma", "mirrored", "open_loop", "failures", "streak", "reidentified", "stopped")

    def snapshot(self) -> "SolverState":
        """A copy of the state at an iteration boundary, in O(1): arrays are
        immutable and the histories only grow, so their lengths are kept and
        ``restored`` cuts the shared lists back to them."""
        copy = dataclasses.replace(self, record=dataclasses.replace(self.record))
        copy._lengths = {name: len(getattr(self.record, name)) for name in Record.histories()}
        return copy

    def restored(self) -> "SolverState":
        """This snapshot, its histories cut back to their length when it was taken."""
        for name, n in self._lengths.items():
            del getattr(self.record, name)[n:]
        return self
