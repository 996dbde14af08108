"""Identification as a strategy: what the driver calls for a model about the nominal.

:class:`DataBased` is POD-iLQR's: ``n_s`` perturbation rollouts about the
nominal (one MJX batch, closed loop through the current gains unless the
experiment is open loop, mirrored pairs where asked) and the per-step ARMA
fit in the information state (least squares or instrumental variables).
:class:`Exact` is the model-based reference's: the exact linearisation of the
MJX dynamics on the full state. Both return an :class:`Identified`.

The estimator's model (``kalman.identify_about_nominal``) is one
``DataBased`` identification too, open loop with the noise switched off.
"""

from __future__ import annotations

import dataclasses
import time
from typing import TYPE_CHECKING, Any, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from ..compilation import lockstep
from ..sim.rollout import (
    Policy,
    injected_perturbations,
    on_device,
    perturbation_rollouts,
    replicated,
)
from ..task.env import Env, EnvData, EnvDims
from .estimators import fit_information_model_iv
from .info_state import info_dim, n_regressors
from .model_based import linearise
from .quality import b_error
from .sigma import adapted_sigma, noisy_sigma
from .sysid import LinearModel, excited_rank, fit_information_model, fit_residual, model_is_finite

if TYPE_CHECKING:  # the settings are read, never built, here
    from ..ilqr.config import SolverConfig

PROBLEMS = ("diverged", "nonfinite", "no_response")
"""What can make an identified model unusable (``Identified.problem``):
fewer good sysid rollouts than the fit has regressors, a non-finite entry of
A_t or B_t, or no response (the perturbations moved no observation; the
linearisation's B_t = 0 at every step). The driver decides what follows
(``ilqr.stopping``)."""


class Experiment(NamedTuple):
    """How the perturbation rollouts are run: as mirrored +du/-du pairs, and/or open loop."""

    mirrored: bool = False
    open_loop: bool = False


class Identified(NamedTuple):
    """One identification: the model, what is wrong with it if anything, and what it cost."""

    model: LinearModel
    problem: Optional[str]  # one of ``PROBLEMS``, or None: a usable model
    rollouts: int  # rollouts run
    n_bad: int  # sysid rollouts left out of the fit as non-finite
    seconds: dict  # phase name -> seconds ("rollouts", "fit", "waiting": in lockstep with other starts)
    next_sigma: Optional[float]  # the adapted sysid scale for the next identification (cfg.adapt_sigma), or None
    needed: int = 0  # the fewest good rollouts the fit takes (its regressors; 0 for the linearisation)
    fit_error: float = float("nan")  # under noise: the fit's estimated relative error of B (identify.quality)


def fit_problem(model: LinearModel, n_good: int, needed: int, target_rms) -> Optional[str]:
    """What makes a data-based fit unusable (``PROBLEMS``), or None."""
    if n_good < needed:
        return "diverged"
    if not model_is_finite(model):
        return "nonfinite"
    if float(np.max(np.asarray(target_rms))) == 0.0:
        return "no_response"
    return None


def linearisation_problem(model: LinearModel) -> Optional[str]:
    """What makes the model-based linearisation unusable (``PROBLEMS``), or None."""
    if not model_is_finite(model):
        return "nonfinite"
    if not np.any(np.asarray(model.B)):
        return "no_response"
    return None


@dataclasses.dataclass(frozen=True)
class DataBased:
    """POD-iLQR's identification from perturbation rollouts (module docstring).

    ``units`` [nu] scales sigma per actuator; ``no_gains``, ``zero_z``,
    ``zero_u`` are device zeros of the gains' and the nominal's shapes (the
    open-loop policy, the zero nominal of mirrored half-differences);
    ``max_rank`` the rank cap of a noiseless fit (``sysid.excited_rank``) or None;
    ``unsaturate``: a function that zeroes the gains of saturated controls, or None.
    """

    dims: EnvDims
    q: int
    data: EnvData
    cfg: SolverConfig
    noisy: bool
    closed_loop: bool
    units: np.ndarray
    rcond: Any
    max_rank: Any
    no_gains: Any
    zero_z: Any
    zero_u: Any
    needed: int  # the fit's regressors: fewer good rollouts cannot be fitted
    adapt: bool  # adapt sigma from the fit's residual (cfg.adapt_sigma, noiseless)
    chunk: Optional[int]  # the sysid batch's chunk under the memory budget (None: one batch)
    unsaturate: Any = None

    @property
    def n_avg(self) -> int:
        return self.cfg.resolved_n_avg()

    def __call__(self, key: jax.Array, nominal, gains, sigma: float, experiment: Experiment) -> Identified:
        """One identification about ``nominal`` at scale ``sigma`` (times ``units``)."""
        cfg, dims = self.cfg, self.dims
        t0, w0 = time.perf_counter(), lockstep.waited()
        mirrored = experiment.mirrored and not experiment.open_loop
        closed = self.closed_loop and not experiment.open_loop
        if closed and self.unsaturate is not None:
            gains = self.unsaturate(gains, nominal.u_bar)
        policy = Policy(nominal.u_bar, nominal.Z_bar[:-1], gains if closed else self.no_gains)
        sigma_t = on_device(sigma * self.units)
        traj = perturbation_rollouts(
            dims, self.q, cfg.n_s, self.data, policy, key, sigma_t,
            n_avg=self.n_avg, noisy=self.noisy, chunk=self.chunk, mirrored=mirrored,
        )  # fmt: skip
        traj.z.block_until_ready()
        t1, w1 = time.perf_counter(), lockstep.waited()
        # mirrored rollouts come back as half-differences: deviations about a zero nominal
        z_bar, u_bar = (self.zero_z, self.zero_u) if mirrored else (nominal.z_bar, nominal.u_bar)
        if cfg.estimator == "iv":
            du = injected_perturbations(key, sigma_t, cfg.n_s, dims.horizon, dims.nu)
            model, report = fit_information_model_iv(traj.z, traj.u, du, z_bar, u_bar, self.q, self.rcond)
        else:
            model, report = fit_information_model(traj.z, traj.u, z_bar, u_bar, self.q, self.rcond, self.max_rank)
        n_bad = int(report.n_bad)
        problem = fit_problem(model, cfg.n_s - n_bad, self.needed, report.target_rms)
        following, fit_error = None, float("nan")
        if self.noisy and problem is None:
            fit_error = b_error(model, report, sigma * self.units, cfg.n_s - n_bad, self.q)
            if cfg.adapt_sigma:
                following = noisy_sigma(sigma, fit_error, cfg)
        elif self.adapt and problem is None:
            rho, floor = fit_residual(report, nominal.z_bar)
            if np.isfinite(rho):
                following = adapted_sigma(sigma, rho, floor, 2 if mirrored else 1, cfg)
        t2, w2 = time.perf_counter(), lockstep.waited()
        rollouts = cfg.n_s * self.n_avg * (2 if mirrored else 1)
        # with several starts in lockstep, the time their calls waited for each other is a phase of its own
        seconds = {"rollouts": (t1 - t0) - (w1 - w0), "fit": (t2 - t1) - (w2 - w1), "waiting": w2 - w0}
        return Identified(model, problem, rollouts, n_bad, seconds, following, self.needed, fit_error)


@dataclasses.dataclass(frozen=True)
class Exact:
    """The model-based reference's identification: the linearisation
    (``model_based.linearise``) of the full-state dynamics, ``jacobian`` (one
    of ``model_based.JACOBIANS``) as ``sim.contacts.jacobian`` resolved the
    setting; ``hint`` says what in the model may make the exact one
    non-finite."""

    dims: EnvDims
    data: EnvData
    hint: str = ""
    jacobian: str = "exact"

    def __call__(self, key: jax.Array, nominal, gains, sigma: float, experiment: Experiment) -> Identified:
        t0, w0 = time.perf_counter(), lockstep.waited()
        model = linearise(self.dims, self.data, nominal.x_bar, nominal.u_bar, self.jacobian)
        problem = linearisation_problem(model)
        w = lockstep.waited() - w0
        seconds = {"rollouts": 0.0, "fit": time.perf_counter() - t0 - w, "waiting": w}
        return Identified(model, problem, 0, 0, seconds, None)


def data_based(env: Env, cfg: SolverConfig, q: int, data: EnvData, noisy: bool, chunk: Optional[int]) -> DataBased:
    """POD-iLQR's identification of ``env`` (its arrays ``data`` on the device)
    as ``cfg`` sets it up; ``noisy``: the rollouts draw the task's noise;
    ``chunk``: the most rollouts of one call (``ExecutionPlan.sysid_chunk``)."""
    dims = env.dims
    nZ = info_dim(dims.nz, dims.nu, q)
    return DataBased(
        dims=dims,
        q=q,
        data=data,
        cfg=cfg,
        noisy=noisy,
        closed_loop=cfg.variant != "plain",
        units=actuator_units(env, cfg),
        rcond=on_device(cfg.rcond),
        # noiseless sysid from a fixed start: fit only the directions the perturbations excite (sysid.excited_rank)
        max_rank=jax.device_put(excited_rank(dims, q), replicated()) if cfg.cap_rank and not noisy else None,
        no_gains=on_device(np.zeros((dims.horizon, dims.nu, nZ))),
        zero_z=on_device(np.zeros((dims.horizon + 1, dims.nz))),
        zero_u=on_device(np.zeros((dims.horizon, dims.nu))),
        needed=n_regressors(dims.nz, dims.nu, q),
        adapt=cfg.adapt_sigma and not noisy,
        chunk=chunk,
        unsaturate=_saturation_guard(data) if cfg.saturated_open_loop and env.limited else None,
    )


@jax.jit
def _unsaturated_gains(K, u_bar, u_low, u_high):
    """``K`` [T, nu, nZ] with the rows of controls that sit on their ctrlrange
    bound in the nominal set to zero, for the closed-loop sysid rollouts
    (``SolverConfig.saturated_open_loop``).

    Feedback on a saturated control cannot act past the bound, and it can
    keep the perturbations from acting at all: a clipped perturbation is
    one-sided, so the deviations after it have a mean of the order of sigma,
    which the gains turn into a push against the bound. On dm_control's
    cart-pole the applied control moved in 0-20% of the rollouts at the last
    saturated steps, the fit lost the control's column there (rank 4 of 5)
    and the step it proposed raised the cost (``benchmarks/saturated_sysid.py``).
    With those rows at zero each perturbation acts on one side, as open loop.
    """
    at_bound = (u_bar <= u_low) | (u_bar >= u_high)
    return jnp.where(at_bound[:, :, None], 0.0, K)


def actuator_units(env: Env, cfg: SolverConfig) -> np.ndarray:
    """[nu] the unit of each actuator's sysid perturbation (``cfg.sigma_scale``):
    half its ctrlrange where it is limited, else 1; all 1 for ``absolute``."""
    low, high = np.asarray(env.data.u_low, dtype=float), np.asarray(env.data.u_high, dtype=float)
    half = (high - low) / 2
    limited = np.isfinite(half) & (half > 0)
    if cfg.sigma_scale == "absolute":
        return np.ones(env.dims.nu)
    return np.where(limited, half, 1.0)


def _saturation_guard(data):
    """``K -> _unsaturated_gains(K, u_bar)`` within the task's control box."""

    def unsaturate(K, u_bar):
        return _unsaturated_gains(K, u_bar, data.u_low, data.u_high)

    return unsaturate
