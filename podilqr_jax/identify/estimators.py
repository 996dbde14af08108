"""Consistent identification under noise without averaging: instrumental variables.

Ordinary least squares (``sysid.fit_information_model``) regresses dz_{t+1} on
X_t = [dZ_t, du_t]. Under partial observation with measurement noise the
regressors (past noisy outputs) are correlated with the equation error, so the
estimate converges to a biased value (the paper's Lemma 2) however many
rollouts are run. The paper's remedy averages n_avg repeats of every rollout.

Instrumental variables (two-stage least squares) use variables that are
correlated with the regressors but not with the error. At step t, with the
information state of depth q, the equation error of the ARMA model is a
combination of w_{t-q+1} .. w_t and v_{t-q+1} .. v_{t+1}. Independent of all of
them are

  - the *injected* perturbations du_t, du_{t-1}, ..., du_{t-L+1} (exogenous by
    construction; with feedback in the loop the applied control contains
    K (Z - Z_bar), which carries noise, so the injected du is the instrument,
    not the applied control), and
  - the outputs older than the information state, dz_{t-q}, ..., dz_{t-2q+1}
    (they only contain noise from before t-q+1). They carry the response to
    the start-state deviation, which the injected perturbations cannot explain.

Instrument count (static; ``instrument_lags``): L = q + ceil(q nz / nu)
injected lags (q for the control regressors, enough more to span the q nz
output regressors) plus q lagged outputs, m = L nu + q nz instruments, about
twice the p = q (nz + nu) regressors. Too few instruments leave the estimate
weak (large variance), too many for n_s pull it back toward ordinary least
squares (its finite-sample bias grows like m / n_s); with m ~ 2p the solver
refuses n_s < 2m and n_s >= 10 m is recommended. Before t = 0 the lags are
zero (perturbations) or the rest history (outputs), as in the information state.

Where it cannot help: the steps t < q. There the lagged outputs fall back to
dz_0, which holds v_0 and only the observed part of the start deviation, so the
instruments span fewer directions than the regressors (rank-deficient, the
minimum-norm solution is taken) and, at t = q - 1, dz_0 is correlated with the
error. Least squares is not identified there either; those steps' A_t only
shape the feedback on the first information states.

Numerics: regressors, targets and instruments are centred over the rollouts
(an intercept, which also absorbs the nominal's own noise, common to every
rollout's deviation); the instruments' column space is taken from an SVD
(rank cut 1e-10), the regressors and targets are projected on it, and the
projected problem is solved by the same column-scaled minimum-norm least
squares as the ordinary fit.

Shapes: z [n, T+1, nz], u [n, T, nu] (applied), du [n, T, nu] (injected).
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from ..compilation.stages import stage
from .sysid import FitReport, LinearModel, fit_each_step, least_squares, regression_data

ESTIMATORS = ("ols", "iv")


def instrument_lags(nz: int, nu: int, q: int) -> int:
    """Injected-perturbation lags L of the instrument set (see the module docstring)."""
    return q + math.ceil(q * nz / nu)


def n_instruments(nz: int, nu: int, q: int) -> int:
    """m = L nu injected lags + q nz lagged outputs."""
    return instrument_lags(nz, nu, q) * nu + q * nz


def instruments(du: jnp.ndarray, dz: jnp.ndarray, q: int) -> jnp.ndarray:
    """Time-major instruments W [T, n, m] from injected du [n, T, nu] and dz [n, T+1, nz]."""
    n, T, nu = du.shape
    nz = dz.shape[-1]
    L = instrument_lags(nz, nu, q)
    pad = jnp.concatenate([jnp.zeros((n, L - 1, nu), du.dtype), du], axis=1)
    blocks = [pad[:, L - 1 - i : L - 1 - i + T] for i in range(L)]  # du_{t-i}
    for j in range(q, 2 * q):  # dz_{t-j}, the rest history (dz_0) before t = 0
        blocks.append(dz[:, jnp.clip(jnp.arange(T) - j, 0, None)])
    return jnp.concatenate(blocks, axis=-1).transpose(1, 0, 2)


def two_stage_least_squares(X: jnp.ndarray, Y: jnp.ndarray, W: jnp.ndarray, rcond: jnp.ndarray):
    """Centred 2SLS of Y [n, k] on X [n, p] with instruments W [n, m].

    Returns (Theta' [p, k], rank, the centred residual [n, k]).
    """
    # Rows that are all zero are rollouts left out of the fit (``fit_each_step``):
    # centre over the others and keep them zero.
    used = jnp.any(X != 0, axis=1) | jnp.any(Y != 0, axis=1) | jnp.any(W != 0, axis=1)
    n_used = jnp.maximum(jnp.sum(used), 1)

    def centre(a):
        return jnp.where(used[:, None], a - jnp.sum(a, axis=0) / n_used, 0.0)

    X, Y, W = centre(X), centre(Y), centre(W)
    U, s, _ = jnp.linalg.svd(W, full_matrices=False)
    keep = s > 1e-10 * s[0]
    Q = U * keep  # orthonormal basis of the instruments' span (dropped directions zeroed)
    theta, rank = least_squares(Q.T @ X, Q.T @ Y, rcond)
    return theta, rank, Y - X @ theta


@stage(static_argnames=("q",), outputs=(LinearModel, FitReport))
def fit_information_model_iv(z, u, du, z_bar, u_bar, q: int, rcond) -> tuple[LinearModel, FitReport]:
    """The ARMA fit of ``sysid`` by instrumental variables (a ``lax.scan`` over time)."""
    X, Y = regression_data(z, u, z_bar, u_bar, q)
    W = instruments(du, z - z_bar, q)
    return fit_each_step(z, u, (X, Y, W), q, lambda X_t, Y_t, W_t: two_stage_least_squares(X_t, Y_t, W_t, rcond))
