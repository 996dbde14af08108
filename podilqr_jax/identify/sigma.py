"""The sysid scale sigma, adapted between identifications from the fit's own numbers
(``SolverConfig.adapt_sigma``): noiseless from the fit's residual (docs/robustness.md),
under noise from the fit's own estimate of B's error (docs/noise.md)."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the settings are read, never built, here
    from ..ilqr.config import SolverConfig


def adapted_sigma(sigma: float, rho: float, floor: float, order: int, cfg: "SolverConfig") -> float:
    """The sysid scale for the next identification, from the last one's fit.

    ``rho`` is the fit's relative residual (RMS of the residual over the RMS
    of the response, all steps), ``floor`` the round-off's share of it
    (``eps x`` RMS of the nominal's observations over the RMS of the
    response) and ``order`` how the curvature part grows with sigma (1 for
    least squares on the raw rollouts; 2 for mirrored pairs, whose even
    terms cancel). Noiseless, rho is curvature (``~ sigma^order``) plus
    round-off (``~ 1 / sigma``):

    - rho above ``cfg.max_residual``: curvature; shrink sigma to put rho a
      decade below it (by 10x at most per identification);
    - rho within 10x of the floor: round-off; grow sigma 10x;
    - else keep sigma.

    The result stays within ``cfg.sigma_range`` of ``cfg.sigma``.
    """
    new = sigma
    if rho > cfg.max_residual:
        new = sigma * max(0.1, (0.1 * cfg.max_residual / rho) ** (1.0 / order))
    elif rho < 10.0 * floor:
        new = sigma * 10.0
    return float(min(max(new, cfg.sigma / cfg.sigma_range), cfg.sigma * cfg.sigma_range))


def noisy_sigma(sigma: float, b_error: float, cfg: "SolverConfig") -> float:
    """The sysid scale for the next identification of a noisy solve, from the
    last fit's estimated relative error of B (``identify.quality``).

    While the residual is the noise's, that error falls like 1 / sigma: a fit
    above ``cfg.max_fit_error`` grows sigma to put it at half the target (by
    10x at most per identification; 10x where no signal was seen at all).
    A fit below the target keeps its sigma: the estimate cannot tell curvature
    from noise, so it gives no reason to shrink (on a linear system the
    largest sigma is the best one). At most ``cfg.sigma_range`` times ``cfg.sigma``.
    """
    if not b_error > cfg.max_fit_error:  # below the target, or NaN (no estimate): keep
        return float(sigma)
    new = sigma * min(10.0, b_error / (0.5 * cfg.max_fit_error))
    return float(min(new, cfg.sigma * cfg.sigma_range))
