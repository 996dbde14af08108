"""Solver settings, validated in Python before anything is traced.

Static fields (shapes and loop bounds: ``q``, ``n_s``, ``n_alphas``) are
compiled into the jitted functions; the rest enter as traced scalars, so
sweeping ``sigma`` or a tolerance never recompiles.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Optional

from ..errors import ConfigError
from ..identify.estimators import ESTIMATORS, n_instruments
from ..identify.info_state import n_regressors
from ..sim import contacts
from ..task.env import Env

IMPLS = ("jax", "warp")
"""MJX's implementations a solve can run its rollouts on (``SolverConfig.impl``):
``jax`` (the default, any device) and ``warp`` (NVIDIA Warp kernels, on a CUDA
GPU or the CPU; needs ``warp-lang``: ``pip install 'podilqr_jax[cuda]'``).
MJX 3.17 also has ``cpp`` (MuJoCo's C engine as a JAX call), which its
``make_data`` ties to host-side references that a jitted, vmapped rollout
cannot carry; it is not offered."""

ENGINES = ("auto", "mjx", "native")
"""The engine a solve's rollouts run on (``SolverConfig.engine``, ``sim.engines``):
``mjx`` (MJX, jitted and batched by ``vmap``: the engine of accelerators),
``native`` (MuJoCo's C engine, batched over the host's cores by
``mujoco.rollout``, no compilation) or ``auto`` (the default: MJX on an
accelerator; on a CPU the engine that is faster for the model, by the rule of
``sim.engines.auto_engine``)."""

JACOBIAN_SETTINGS = ("auto", "exact", "differences")
"""How the model-based reference linearises the dynamics
(``SolverConfig.jacobian``, ``model_based.linearise``): ``exact`` (forward
mode through MJX's step), ``differences`` (central differences of the same
step) or ``auto`` (the default: differences on a contact-rich model or one
with a free or ball joint, exact otherwise; ``sim.contacts.jacobian``)."""

MIN_N_S = 40
"""The fewest sysid rollouts of the default ``n_s`` (``SolverConfig.resolved_n_s``)."""

MAX_FIT_ERROR = 0.1
"""Under noise, the fit's estimated relative error of B that ``adapt_sigma`` aims
below (``SysidSettings.max_fit_error``; benchmarks/noise_fit.py, docs/noise.md)."""

NOISY_N_FORWARD = 8
"""The default ``n_forward`` of ``plain`` and ``feedback`` under noise: each
line-search candidate is the mean of this many noisy rollouts (docs/noise.md,
"On the robots")."""

RACE_RUNG = 32
"""The default ``race_rung``: the first rung of the race between starts (``ilqr.race``)."""

RACE_MARGIN = 1.5
"""The default ``race_margin``: a start of the worse half at a rung races on within this factor of the best."""

CONTACT_RESTARTS = 4
"""The starts of a solve of a contact-rich model under the default ``restarts``
(``SolverConfig.resolved_restarts``). Contacts make the cost piecewise smooth,
with a local minimum wherever a contact that comes or goes stalls the line
search; where one start lands is a matter of its sysid draws and of round-off
(Gymnasium's walker2d landing: 0.82-1.14x the reference over four seeds). With
four starts of each solver every contact model of the robot suite ends
converged, within 1% of the reference or below it (docs/engines.md;
benchmarks/journal.md, "Several starts by default on contact-rich models")."""

SIGMA_SCALES = ("actuator", "absolute")
"""The units of ``SolverConfig.sigma``: each actuator's half ctrlrange where it
is limited (``actuator``), or one sigma for every actuator (``absolute``)."""

PAPER_SETTINGS = {
    "variant": "plain",
    "cap_rank": False,
    "adapt_sigma": False,
    "sigma_scale": "absolute",
    "escalate": False,
}
"""The settings that make ``solve`` the paper's POD-iLQR as is (and the
defaults before the robustness work): open-loop identification, every
direction above rcond, one fixed sigma for every actuator, no change of
experiment before ``line_search_failed``. The serial reference
(``bench.serial_reference``), the benchmark of what the defaults cost
(``bench.defaults_cost``) and the paper's study (``reproduce``) use them."""

VARIANTS = ("plain", "feedback", "averaged", "nominal")
"""The paper's variants (docs/noise.md):

- ``plain``: POD-iLQR as is (open-loop sysid rollouts u = u_bar + du), under
  whatever noise the task has.
- ``feedback``: the paper's "modified" POD-iLQR: the sysid rollouts carry the
  previous backward pass's feedback on their own information-state deviation,
  u = u_bar + du + K_t (Z_t - Z_bar_t). No gain exists before the first
  backward pass, so iteration 1 identifies open loop (K = 0), like ``plain``.
- ``averaged``: ``feedback`` plus brute-force averaging: each perturbation
  sequence runs ``n_avg`` times and the mean trajectory enters the fit, and
  every line-search candidate is the mean of ``n_forward`` noisy rollouts.
- ``nominal``: the same task with all noise switched off (the reference
  curve), identified with feedback like ``feedback``.
"""


@dataclasses.dataclass(frozen=True)
class ILQRSettings:
    """The paper's iLQR: iterations, stopping tolerances, regularisation, line search.

    Attributes:
      max_iterations: iLQR iterations at most.
      rtol: stop when an accepted step lowers the cost by less than rtol x J,
        or when no step can and the predicted decrease is below rtol x J.
      gtol: stop when max_t |dJ/du_t| on the identified model is below gtol.
      mu_init, mu_min, mu_max, mu_factor: Levenberg-Marquardt regularisation:
        start, floor, ceiling (past it the solve stops) and growth factor.
      n_alphas: line-search candidates alpha = 1, 1/2, ..., 2^-(n_alphas-1),
        all rolled out as one batch.
      accept_ratio: accept a step only if the actual decrease is at least this
        fraction of the predicted one (and strictly positive).
      seed: PRNG seed of the perturbations and of the noise (same seed, same
        result).
      restarts: solve from this many first guesses at once and return the
        lowest cost (``ilqr.restarts``). None (the default): 1, or
        ``CONTACT_RESTARTS`` on a contact-rich model (``resolved_restarts``).
        Start 0 runs from the given controls
        with ``seed``, start j from them plus Gaussian noise of
        ``restart_scale`` times each actuator's half ctrlrange (1 where it is
        unlimited), clipped to the range, with ``seed + j``. The starts run
        in lockstep, each stage of theirs one batched call
        (``compilation.lockstep``); every start's cost is in ``Result.starts``.
      restart_scale: the size of the other starts' perturbation, above.
      race_rung: with several starts, the iteration of the race's first rung
        (``ilqr.race``): at iterations race_rung, 2 race_rung, 4 race_rung, ...
        the starts of the worse half of those still racing, ranked by their
        cost there, stop (status ``outraced``) where their cost is above
        ``race_margin`` times the best's. 0: every start runs to its own end.
      race_margin: how far behind the best (a factor >= 1 on its cost) a
        start of the worse half may be at a rung and race on.
    """

    max_iterations: int = 300
    rtol: float = 1e-9
    gtol: float = 1e-9
    mu_init: float = 1e-6
    mu_min: float = 1e-6
    mu_max: float = 1e10
    mu_factor: float = 2.0
    n_alphas: int = 10
    accept_ratio: float = 1e-4
    seed: int = 0
    restarts: Optional[int] = None
    restart_scale: float = 0.3
    race_rung: int = RACE_RUNG
    race_margin: float = RACE_MARGIN

    def validate(self) -> None:
        """Raise a ``ConfigError`` for the first of this group's settings out of its range, saying what it takes."""
        check_int("max_iterations", self.max_iterations, 1)
        check_int("n_alphas", self.n_alphas, 1)
        check_int("seed", self.seed, 0)
        if self.restarts is not None:
            check_int("restarts", self.restarts, 1)
        check_nonnegative("restart_scale", self.restart_scale)
        check_int("race_rung", self.race_rung, 0)
        margin = self.race_margin
        if isinstance(margin, bool) or not isinstance(margin, (int, float)) or not 1 <= margin < math.inf:
            raise ConfigError(f"`race_margin` must be a finite number >= 1, a factor on the best cost; got {margin!r}.")
        for name in ("mu_max", "mu_factor"):
            _positive(name, getattr(self, name))
        for name in ("rtol", "gtol", "mu_init", "mu_min", "accept_ratio"):
            check_nonnegative(name, getattr(self, name))
        if self.mu_factor <= 1:
            raise ConfigError(f"`mu_factor` must be > 1 so that regularisation can grow; got {self.mu_factor!r}.")
        if self.mu_min > self.mu_max:
            raise ConfigError(
                f"`mu_min` ({self.mu_min:g}) is above `mu_max` ({self.mu_max:g}); choose mu_min <= mu_max."
            )


@dataclasses.dataclass(frozen=True)
class IdentificationSettings:
    """POD-iLQR's system identification: the information state, the sysid
    batch, its perturbations and the least-squares fit.

    Attributes:
      q: past observations in the information state; None picks 1 when the
        task observes the full state and 2 otherwise.
      n_s: sysid rollouts per iteration (must be >= q (nz + nu), the number of
        regressors of the least-squares fit). None (the default) scales with
        the model: ``MIN_N_S`` = 40 or twice the regressors, whichever is more
        (40 on every bundled and gallery task; ``SolverConfig.resolved_n_s``).
      sigma: standard deviation of the sysid control perturbations du, in
        the units ``sigma_scale`` says; with ``adapt_sigma`` the start of an
        adaptive scale.
      sigma_scale: ``"actuator"`` (the default): actuator j is perturbed
        with sigma x s_j, s_j its half ``ctrlrange`` where the actuator is
        limited (1 otherwise), so a model's units do not set the experiment;
        ``"absolute"``: sigma for every actuator (the paper's).
      adapt_sigma: in a noiseless data-based solve, set sigma afresh after
        every identification from the fit's own diagnostics
        (``identify.sigma.adapted_sigma``): smaller where the relative fit residual (the
        response's curvature) is above ``max_residual``, larger where the
        residual sits on the round-off floor, always inside
        [sigma / sigma_range, sigma x sigma_range]. The scale used at
        every iteration is in ``Result.sigma_history`` and the progress line.
        Under noise the residual is the noise's, not curvature: sigma is
        set instead from the fit's estimate of B's relative error
        (``identify.quality``), grown while it is above ``max_fit_error``
        (``identify.sigma.noisy_sigma``; docs/noise.md).
      max_fit_error: under noise, the estimated relative error of B above
        which ``adapt_sigma`` grows sigma, and above 1 of which the result
        warns that the fit could not see the controls through the noise.
      max_residual: the fit residual (RMS over the response's, all steps)
        above which ``adapt_sigma`` reads curvature and shrinks sigma.
      sigma_range: the adapted sigma stays within this factor of ``sigma``.
      rcond: relative singular-value cut-off of the least-squares fit.
      estimator: the identification's estimator: ``"ols"`` (least squares, the
        paper's) or ``"iv"`` (instrumental variables with the injected
        perturbations and older outputs as instruments, consistent under
        measurement noise at n_avg = 1; see ``estimators`` and
        docs/estimators.md). Works with every variant.
      mirrored: roll out every sysid perturbation sequence as the pair +du,
        -du (2 n_s x n_avg rollouts) and fit on the half-differences, which
        cancel the response's even-order terms in du: the curvature bias of
        the fit drops from O(sigma) to O(sigma^2), so larger perturbations
        (above round-off and noise) still give the linear model, and the
        nominal's own noisy measurement is never subtracted (docs/robustness.md).
      cap_rank: in a noiseless solve, fit at each step t only as many
        directions as the perturbations can have excited from the fixed start
        state (``sysid.excited_rank``: nu (t + 1) in the first steps), so no
        gain is read out of the response's curvature where nothing was
        measured; the model and the gains are zero there. False keeps every
        direction above ``rcond`` (the behaviour before; docs/robustness.md).
    """

    q: Optional[int] = None
    n_s: Optional[int] = None
    sigma: float = 1e-4
    sigma_scale: str = "actuator"
    adapt_sigma: bool = True
    max_fit_error: float = MAX_FIT_ERROR
    max_residual: float = 1e-3
    sigma_range: float = 1e3
    rcond: float = 1e-10
    estimator: str = "ols"
    mirrored: bool = False
    cap_rank: bool = True

    def validate(self) -> None:
        """Raise a ``ConfigError`` for the first of this group's settings out of its range, saying what it takes."""
        for name in ("mirrored", "cap_rank"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"`{name}` must be true or false; got {getattr(self, name)!r}.")
        if self.estimator not in ESTIMATORS:
            raise ConfigError(
                f"Unknown estimator {self.estimator!r}; choose one of {', '.join(ESTIMATORS)} (see docs/estimators.md)."
            )
        if self.n_s is not None:
            check_int("n_s", self.n_s, 1)
        if self.q is not None:
            check_int("q", self.q, 1)
        if self.sigma_scale not in SIGMA_SCALES:
            raise ConfigError(
                f"Unknown `sigma_scale` {self.sigma_scale!r}; choose one of {', '.join(SIGMA_SCALES)} "
                "(per actuator's ctrlrange, or one absolute sigma)."
            )
        if _finite_number("sigma_range", self.sigma_range) < 1:
            raise ConfigError(f"`sigma_range` must be >= 1 (a factor either side of sigma); got {self.sigma_range!r}.")
        for name in ("sigma", "max_residual", "max_fit_error"):
            _positive(name, getattr(self, name))
        check_nonnegative("rcond", self.rcond)


@dataclasses.dataclass(frozen=True)
class NoiseSettings:
    """The paper's variants of POD-iLQR under noise (docs/noise.md).

    Attributes:
      variant: one of ``VARIANTS`` (see there): plain, feedback (the default:
        closed-loop identification measures better gains, noiseless too; see
        docs/robustness.md), averaged or nominal. ``plain`` is the paper's
        POD-iLQR as is, kept as its ablation.
      n_avg: repeats of each sysid perturbation sequence averaged before the
        fit (``averaged`` only); None picks 10 for ``averaged`` and 1 otherwise.
      n_forward: noisy rollouts averaged into each line-search candidate
        (every variant under noise; not ``nominal``); None picks ``n_s`` for
        ``averaged``, ``NOISY_N_FORWARD`` for ``plain`` and ``feedback`` on a
        noisy task, 1 without noise (``resolved_n_forward``).
      mu_cap: under noise a rejected step never ends the solve: the nominal is
        re-measured, mu grows but never above mu_cap, and the solve goes on.
      paired_line_search: under noise, every line-search candidate runs on the
        same noise draw (common random numbers: the ``n_forward`` draws of the
        averaged variant, shared by all candidates), and a candidate is judged
        against the alpha = 0 candidate of that draw, the current policy, not
        against the nominal's own earlier, independent draw. False (the
        default): each candidate draws its own noise and is judged against
        the nominal's cost, the paper's forward pass; paired with one draw
        measured worse on the robots (docs/noise.md).
    """

    variant: str = "feedback"
    n_avg: Optional[int] = None
    n_forward: Optional[int] = None
    mu_cap: float = 1e3
    paired_line_search: bool = False

    def validate(self) -> None:
        """Raise a ``ConfigError`` for the first of this group's settings out of its range, saying what it takes."""
        if self.variant not in VARIANTS:
            raise ConfigError(
                f"Unknown variant {self.variant!r}; choose one of {', '.join(VARIANTS)} (see docs/noise.md)."
            )
        for name, takes in (("n_avg", ("averaged",)), ("n_forward", ("plain", "feedback", "averaged"))):
            value = getattr(self, name)
            if value is not None:
                check_int(name, value, 1)
                if value > 1 and self.variant not in takes:
                    raise ConfigError(
                        f"`{name}`={value} only applies to variant={' or '.join(repr(v) for v in takes)} "
                        f"(got variant={self.variant!r}); set one of them or drop {name}."
                    )
        _positive("mu_cap", self.mu_cap)
        if not isinstance(self.paired_line_search, bool):
            raise ConfigError(f"`paired_line_search` must be true or false; got {self.paired_line_search!r}.")


@dataclasses.dataclass(frozen=True)
class RecoverySettings:
    """What a noiseless data-based solve tries before it stops ``line_search_failed``
    (docs/robustness.md).

    Attributes:
      reidentify: re-identifications a noiseless data-based solve makes when no
        step lowers the cost and mu has passed mu_max, before it stops
        ``line_search_failed``: each one draws fresh perturbations at another
        scale (``reidentify_scale``: sigma x 0.1, then x 10, x 0.01, x 100, ...)
        and starts mu afresh; an accepted step returns to sigma. When they
        are spent and ``escalate`` is on, the solve changes the experiment
        for the rest of the solve, and goes through the scales again each
        time: first to mirrored perturbation pairs (``mirrored``), then to
        the paper's open-loop identification without pairs (``plain``).
      escalate: the last recoveries before ``line_search_failed``, above
        (measured on dm_control's cart-pole and pendulum, docs/robustness.md).
      saturated_open_loop: in closed-loop identification, no feedback on a
        control that sits on its ctrlrange bound in the nominal, so every
        perturbation of it acts on one side as in open loop (with the
        feedback the response pushed it outward and the fit lost the
        control's column; docs/robustness.md). False: the gains as they are.
    """

    reidentify: int = 2
    escalate: bool = True
    saturated_open_loop: bool = True

    def validate(self) -> None:
        """Raise a ``ConfigError`` for the first of this group's settings out of its range, saying what it takes."""
        check_int("reidentify", self.reidentify, 0)


@dataclasses.dataclass(frozen=True)
class ExecutionSettings:
    """How a solve runs, not what it computes (the rest is decided by the
    solver's ``ExecutionPlan`` and the environment variables, docs/environment.md).

    Attributes:
      engine: the engine of every rollout of the solve, one of ``ENGINES``:
        ``auto`` (the default: MJX on a GPU or TPU; on a CPU MuJoCo's C
        engine where it is faster, ``sim.engines``), ``mjx`` or ``native``.
        The engine that ran is in the result (``Result.engine``).
        The native engine has no derivative: its model-based reference
        takes central differences (``jacobian`` auto or differences).
      impl: MJX implementation of the solve's rollouts, one of ``IMPLS``
        (``jax`` or ``warp``). The model-based reference differentiates
        through MJX and always runs ``jax``.
      memory_budget_mb: the sysid batch (n_s x n_avg rollouts) and the line
        search's ((n_alphas + 1) x n_forward under noise) run in chunks that
        fit this budget (``rollout.bytes_per_rollout`` estimates a rollout's
        share); a batch that fits runs at once. With ``restarts`` the starts'
        batches run together and share it.
      rollout_chunk: rollouts per chunk (of both batches, per start), overriding the budget.
    """

    engine: str = "auto"
    impl: str = "jax"
    memory_budget_mb: float = 2048.0
    rollout_chunk: Optional[int] = None

    def validate(self) -> None:
        """Raise a ``ConfigError`` for the first of this group's settings out of its range, saying what it takes."""
        if self.engine not in ENGINES:
            raise ConfigError(
                f"Unknown `engine` {self.engine!r}; choose one of {', '.join(ENGINES)} (MJX, MuJoCo's C engine "
                "batched on the CPU's cores, or auto: MJX on an accelerator, the faster of the two on a CPU)."
            )
        if self.engine == "native" and self.impl != "jax":
            raise ConfigError(
                f"`impl`={self.impl!r} picks an MJX implementation, but `engine`='native' runs MuJoCo's C engine; "
                "drop impl, or use engine='mjx' (or auto) with it."
            )
        check_impl(self.impl)
        _positive("memory_budget_mb", self.memory_budget_mb)
        if self.rollout_chunk is not None:
            check_int("rollout_chunk", self.rollout_chunk, 1)


@dataclasses.dataclass(frozen=True)
class ReferenceSettings:
    """The model-based reference's own settings (POD-iLQR does not read them).

    Attributes:
      jacobian: how the model-based reference linearises the dynamics, one of
        ``JACOBIAN_SETTINGS``: ``auto`` (the default) takes central
        differences of MJX's step on a contact-rich model (at least
        ``sim.contacts.MANY_ROWS`` constraint rows) or one with a free or
        ball joint, and the exact forward-mode derivative otherwise;
        ``exact`` or ``differences`` force one. At an active contact the
        forward-mode derivative is NaN under the elliptic friction cone, at
        zero angular rate a quaternion's is zero, and its program compiles
        for about twice as long (benchmarks/journal.md).
    """

    jacobian: str = "auto"

    def validate(self) -> None:
        """Raise a ``ConfigError`` for the first of this group's settings out of its range, saying what it takes."""
        if self.jacobian not in JACOBIAN_SETTINGS:
            raise ConfigError(
                f"Unknown `jacobian` {self.jacobian!r}; choose one of {', '.join(JACOBIAN_SETTINGS)} (the model-based "
                "reference's linearisation: forward mode, central differences, or auto by the model)."
            )


GROUPS: dict[str, type] = {
    "ilqr": ILQRSettings,
    "identification": IdentificationSettings,
    "noise": NoiseSettings,
    "recovery": RecoverySettings,
    "execution": ExecutionSettings,
    "reference": ReferenceSettings,
}
"""The groups of ``SolverConfig``: its field name and the record of each."""

SETTINGS: dict[str, str] = {f.name: group for group, cls in GROUPS.items() for f in dataclasses.fields(cls)}
"""Every flat setting name (``--set KEY=VALUE``, ``default_config(env, **flat)``,
a task file's ``[solver]`` table) and the group that holds it."""


@dataclasses.dataclass(frozen=True, init=False)
class SolverConfig:
    """Settings of POD-iLQR (and of the model-based reference solver), in groups.

    Each group is a frozen record that validates itself. Every setting also
    has its flat name (``SETTINGS``), as a keyword and as an attribute:
    ``SolverConfig(n_s=80, variant="averaged")`` is
    ``SolverConfig(identification=IdentificationSettings(n_s=80),
    noise=NoiseSettings(variant="averaged"))``, and ``cfg.n_s`` reads
    ``cfg.identification.n_s``. ``replace`` takes either, and a group may
    also be given as a dict of its settings (a task file's
    ``[solver.identification]`` table). Results and checkpoints record the
    flat settings (:meth:`flat`).

    Attributes:
      ilqr: the paper's iLQR: iterations, tolerances, regularisation, line
        search, seed (:class:`ILQRSettings`).
      identification: q, n_s, the sysid perturbations and the fit
        (:class:`IdentificationSettings`).
      noise: the paper's variants under noise (:class:`NoiseSettings`).
      recovery: what a solve tries before ``line_search_failed``
        (:class:`RecoverySettings`).
      execution: the engine, MJX's implementation, memory
        (:class:`ExecutionSettings`).
      reference: the model-based reference's own (:class:`ReferenceSettings`).
    """

    ilqr: ILQRSettings
    identification: IdentificationSettings
    noise: NoiseSettings
    recovery: RecoverySettings
    execution: ExecutionSettings
    reference: ReferenceSettings

    def __init__(self, **settings: Any) -> None:
        unknown = set(settings) - set(SETTINGS) - set(GROUPS)
        if unknown:
            raise ConfigError(
                f"Unknown solver setting(s) {sorted(unknown)}; known settings: {sorted(SETTINGS)} "
                f"(or a group: {', '.join(GROUPS)})."
            )
        for group, cls in GROUPS.items():
            record = settings.get(group)
            if record is None:
                record = cls()
            elif isinstance(record, dict):  # a task file's [solver.<group>] table
                known = {f.name for f in dataclasses.fields(cls)}
                if set(record) - known:
                    raise ConfigError(
                        f"Unknown setting(s) {sorted(set(record) - known)} in the group `{group}`; "
                        f"it holds {', '.join(sorted(known))}."
                    )
                record = cls(**record)
            elif not isinstance(record, cls):
                raise ConfigError(
                    f"`{group}` must be a {cls.__name__} (or a table of its settings); got {type(record).__name__}. "
                    f"Build it as {cls.__name__}(...), or give its settings by their flat names."
                )
            changes = {name: value for name, value in settings.items() if SETTINGS.get(name) == group}
            object.__setattr__(self, group, dataclasses.replace(record, **changes) if changes else record)

    def __getattr__(self, name: str) -> Any:
        group = SETTINGS.get(name)
        if group is None:
            raise AttributeError(f"'SolverConfig' has no setting {name!r}")
        return getattr(object.__getattribute__(self, group), name)

    def flat(self) -> dict[str, Any]:
        """Every setting by its flat name (``SETTINGS``), as results and checkpoints record them."""
        return {name: getattr(getattr(self, group), name) for name, group in SETTINGS.items()}

    def replace(self, **changes: Any) -> "SolverConfig":
        """A copy with ``changes``: flat settings or whole groups (a group and
        one of its flat settings together: the setting wins)."""
        groups = {group: getattr(self, group) for group in GROUPS}
        return SolverConfig(**(groups | changes))

    def resolved_q(self, env: Env) -> int:
        """``q``, or where it is None 1 on a fully observed task and 2 otherwise."""
        if self.q is not None:
            return self.q
        return 1 if env.fully_observed else 2

    def resolved_n_s(self, env: Env) -> int:
        """``n_s``, or where it is None the default that scales with the fit:
        ``MIN_N_S`` or twice the ARMA fit's regressors q (nz + nu), whichever is more."""
        if self.n_s is not None:
            return self.n_s
        return max(MIN_N_S, 2 * n_regressors(env.dims.nz, env.dims.nu, self.resolved_q(env)))

    def resolved_restarts(self, env: Env) -> int:
        """``restarts``, or where it is None ``CONTACT_RESTARTS`` on a contact-rich
        model (``sim.contacts.contact_rich``: floor contacts) and 1 otherwise."""
        if self.restarts is not None:
            return self.restarts
        return CONTACT_RESTARTS if contacts.contact_rich(env.mj_model) else 1

    def resolved_n_avg(self) -> int:
        """``n_avg``, or where it is None 10 for the averaged variant and 1 otherwise."""
        if self.n_avg is not None:
            return self.n_avg
        return 10 if self.variant == "averaged" else 1

    def resolved_chunk(self, bytes_per_rollout: int, group: Optional[int] = None) -> int:
        """Rollouts per chunk of a batch: ``rollout_chunk`` when set, else as
        many whole groups of ``group`` rollouts (default: the sysid batch's
        repeat groups, n_avg) as ``memory_budget_mb`` holds. The line search
        asks with ``group=1`` and arranges its candidates itself."""
        if self.rollout_chunk is not None:
            return self.rollout_chunk
        fit = int(self.memory_budget_mb * 2**20 // max(1, bytes_per_rollout))
        group = self.resolved_n_avg() if group is None else group
        return max(group, fit - fit % group)

    def resolved_n_forward(self, noisy: bool = True) -> int:
        """``n_forward``, or where it is None ``n_s`` for the averaged variant,
        ``NOISY_N_FORWARD`` for plain and feedback on a ``noisy`` task, else 1."""
        if self.n_forward is not None:
            return self.n_forward
        if self.variant == "averaged":
            return self.n_s
        return NOISY_N_FORWARD if noisy and self.variant in ("plain", "feedback") else 1

    def validate(self, env: Env, data_based: bool = True) -> int:
        """Check every group, then the settings against each other and the task; returns the q to use."""
        self.noise.validate()
        self.execution.validate()
        if self.engine == "native" and self.jacobian == "exact" and not data_based:
            raise ConfigError(
                "`jacobian`='exact' differentiates through MJX, but `engine`='native' runs MuJoCo's C engine, "
                "which has no derivative; use jacobian='differences' (or auto), or engine='mjx'."
            )
        self.reference.validate()
        self.identification.validate()
        self.ilqr.validate()
        self.recovery.validate()
        n_s = self.resolved_n_s(env)
        q = self.resolved_q(env) if data_based else 1
        T = env.dims.horizon
        if T <= q:
            raise ConfigError(
                f"The horizon T={T} must exceed q={q}: the information state spans q "
                f"steps. Use a horizon of at least {q + 1} or lower q."
            )
        if data_based and self.estimator == "iv":
            m = n_instruments(env.dims.nz, env.dims.nu, q)
            if n_s < 2 * m:
                raise ConfigError(
                    f"`n_s`={n_s} is too small for estimator='iv': its {m} instruments (q={q}, "
                    f"nz={env.dims.nz}, nu={env.dims.nu}) need n_s >= {2 * m}, and n_s >= {10 * m} keeps the "
                    "estimate from leaning toward least squares. Raise n_s or use estimator='ols'."
                )
        if data_based:
            p = n_regressors(env.dims.nz, env.dims.nu, q)
            if n_s < p:
                raise ConfigError(
                    f"`n_s`={n_s} is below the {p} regressors of the ARMA fit at "
                    f"q={q} (q x (nz + nu) with nz={env.dims.nz}, nu={env.dims.nu}): the "
                    f"least squares would be underdetermined. Use n_s >= {p} (a few "
                    "times more is better), or lower q."
                )
        return q


def check_impl(impl: Any) -> None:
    """Refuse an MJX implementation that is unknown or not installed, saying how to get it."""
    if impl not in IMPLS:
        raise ConfigError(
            f"Unknown `impl` {impl!r}; choose one of {', '.join(IMPLS)} (MJX's JAX or Warp implementation)."
        )
    if impl == "warp":
        from mujoco.mjx import warp as mjx_warp  # imported (quietly) with the package

        if not getattr(mjx_warp, "WARP_INSTALLED", False):
            raise ConfigError(
                "`impl`='warp' runs MJX's Warp implementation, which needs the `warp-lang` package (not "
                "installed here). Install it with `pip install 'podilqr_jax[cuda]'` (GPU builds of JAX and "
                "Warp) or `pip install warp-lang`, or use impl='jax'."
            )


def check_int(name: str, value: Any, minimum: int) -> None:
    """Raise a ConfigError unless ``value`` is an integer >= ``minimum`` (settings checks, also ``evaluate``'s)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"`{name}` must be an integer >= {minimum}; got {value!r}.")


def _finite_number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"`{name}` must be a finite number; got {value!r}.")
    return float(value)


def _positive(name: str, value: Any) -> None:
    if _finite_number(name, value) <= 0:
        raise ConfigError(f"`{name}` must be > 0; got {value!r}.")


def check_nonnegative(name: str, value: Any) -> None:
    """Raise a ConfigError unless ``value`` is a finite number >= 0."""
    if _finite_number(name, value) < 0:
        raise ConfigError(f"`{name}` must be >= 0; got {value!r}.")


def reidentify_scale(attempt: int) -> float:
    """The factor on sigma of re-identification ``attempt`` (1, 2, ...): 0.1, 10, 0.01, 100, ...
    (0 is the configured sigma). Smaller first: a step that the model promised
    and the system refused is most often the curvature a large perturbation
    read as slope; larger next, for a fit lost in round-off or noise."""
    if attempt <= 0:
        return 1.0
    decades = (attempt + 1) // 2
    return 10.0 ** (-decades if attempt % 2 else decades)
