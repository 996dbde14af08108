"""How well a noisy fit measured the controls' effect: the fit's own estimate of
the relative error of B (docs/noise.md, "Can the fit see the controls?").

At step t the least squares regresses dz_{t+1} on [dZ_t, du_t]. The injected
perturbation du_t is drawn afresh for every rollout, independently of dZ_t, so
whatever feedback the rollouts carry, the part of the applied deviation that
dZ_t does not explain has variance sigma_j^2 in actuator j. Output i's
residual r_i (noise, or curvature) then leaves coefficient B_ij with variance
about r_i^2 / ((n_s - p) sigma_j^2), p the regressors. Summed with the
weights sigma_j^2 over the nz x nu fitted entries:

    error power   E_t = nz nu rms_t^2 / (n_s - p)       rms_t = the residual's RMS
    signal power  S_t = ||B_t diag(sigma)||_F^2 - E_t   the response to du, less the noise's share of it

``b_error`` = sqrt(sum_t E_t / sum_t S_t): the expected relative error of B in
the norm the perturbations see. Near 1 or above, the controls' effect is
buried in the noise and the gains built on it are noise too; the sysid batch
or sigma must grow (the error falls like 1 / (sigma sqrt(n_s)) while the
residual is the noise's). Host-side numpy on a few kB; no tracing.
"""

from __future__ import annotations

import numpy as np


def b_error(model, report, sigma_t, n_s: int, q: int) -> float:
    """The estimated relative error of B of one fit (module docstring); inf
    where no signal is left above the residual. ``model`` and ``report`` of the
    fit (``sysid``), ``sigma_t`` [nu] the perturbations' standard deviations,
    ``n_s`` the rollouts fitted, ``q`` the information state's depth."""
    B = np.asarray(model.B)
    rms = np.asarray(report.residual_rms, dtype=float)
    nu = B.shape[2]
    nz = B.shape[1] if q == 1 else (B.shape[1] + nu) // q - nu  # nZ = q nz + (q - 1) nu
    fitted = B[:, :nz, :] * np.asarray(sigma_t, dtype=float)[None, None, :]
    dof = max(int(n_s) - q * (nz + nu), 1)
    error = nz * nu * rms**2 / dof
    total_e = float(np.sum(error))
    total_s = float(np.sum(np.sum(fitted**2, axis=(1, 2)) - error))
    if not (np.isfinite(total_e) and np.isfinite(total_s)) or total_s <= 0.0:
        return float("inf")
    return float(np.sqrt(total_e / total_s))
