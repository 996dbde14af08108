"""Least-squares identification of the time-varying ARMA model (LTV-ARMA sysid).

From n_s rollouts about the nominal, at every step t = 0 .. T-1 fit

  dz_{t+1}^(j) = Theta_t [dZ_t^(j); du_t^(j)] + residual,   j = 1 .. n_s

with dZ = Z - Z_bar the information-state deviation and du = u - u_bar the
applied control deviation (perturbation plus any feedback), then assemble
(A_t, B_t) of Eq. (c4tab). Regressing on the applied deviation makes the fit
return the open-loop model directly, also when the rollouts carry feedback
u = u_bar + du + K dZ: that is Lemma 1's recovery A = (A + B K) - B K done in
one step, because [dZ, K dZ + du] is an invertible linear map of [dZ, du].

Numerics (see docs/algorithm.md): columns are scaled to unit RMS, then the
minimum-norm solution is taken from an SVD, discarding singular values below
``rcond`` times the largest. Columns that are exactly zero (the rest history
before t = 0, the deterministic z_0) get zero weight instead of a NaN; the
Python driver refuses n_s below the number of regressors before tracing.

Directions nothing excited (``excited_rank``): from a fixed start state with no
noise, dZ_t is to first order a linear map of the t perturbations du_0 ..
du_{t-1} that acted before it, so the regressors [dZ_t, du_t] span at most
nu (t + 1) directions (and never more than the 2 nv + q nu that the tangent
state and the controls in Z_t can span). Whatever else the data hold there is
the response's curvature (second order in sigma) or round-off; a fit that keeps
it reads slopes out of curvature, and the gains built on them (K_1 of a
pendulum was 200x the exact one) are confident and wrong. With ``max_rank``
the fit keeps at most that many singular directions, so the model, and the
feedback, are zero along what was not measured.

Shapes: z [n_s, T+1, nz], u [n_s, T, nu]; Theta [T, nz, nZ + nu];
A [T, nZ, nZ], B [T, nZ, nu].
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..compilation.stages import stage
from .info_state import companion, info_states, n_regressors


class LinearModel(NamedTuple):
    """dZ_{t+1} = A_t dZ_t + B_t du_t, t = 0 .. T-1."""

    A: jnp.ndarray  # [T, nZ, nZ]
    B: jnp.ndarray  # [T, nZ, nu]


def model_is_finite(model: LinearModel) -> bool:
    """Every entry of A_t and B_t finite (read on the host: a few kB, and no eager kernel to compile)."""
    return bool(np.all(np.isfinite(np.asarray(model.A))) and np.all(np.isfinite(np.asarray(model.B))))


class FitReport(NamedTuple):
    """Diagnostics of the least-squares fit."""

    residual_rms: jnp.ndarray  # [T] RMS of the fit residual of dz_{t+1}
    target_rms: jnp.ndarray  # [T] RMS of dz_{t+1} itself
    rank: jnp.ndarray  # [T] numerical rank kept
    all_finite: jnp.ndarray  # scalar bool: every rollout finite
    n_bad: jnp.ndarray  # scalar int: rollouts with a non-finite number, left out of the fit


def fit_residual(report: FitReport, z_bar) -> tuple[float, float]:
    """On the host: (rho, floor) of a fit. rho is the RMS of the residual over
    the RMS of the response, all steps; floor the round-off's expected share of
    it, eps x the RMS of the nominal's observations ``z_bar`` over the RMS of
    the response (what ``sigma.adapted_sigma`` weighs; docs/robustness.md).
    Both NaN where the response is zero or the residual not finite."""
    res, target = np.asarray(report.residual_rms), np.asarray(report.target_rms)
    power = float(np.sum(target**2))
    if power == 0.0 or not np.all(np.isfinite(res)):
        return float("nan"), float("nan")
    response = float(np.sqrt(power / target.size))
    level = float(np.sqrt(np.mean(np.asarray(z_bar) ** 2)))
    return float(np.sqrt(np.sum(res**2) / power)), float(np.finfo(target.dtype).eps) * level / response


def excited_rank(dims, q: int) -> np.ndarray:
    """[T] the most directions the sysid data can excite at each step t from a
    fixed start state, noiseless: min(q (nz + nu), nu (t + 1), 2 nv + na + q nu)
    (see the module docstring)."""
    t = np.arange(dims.horizon)
    cap = min(n_regressors(dims.nz, dims.nu, q), dims.ndx + q * dims.nu)
    return np.minimum(cap, dims.nu * (t + 1)).astype(np.int32)


def least_squares(X: jnp.ndarray, Y: jnp.ndarray, rcond: jnp.ndarray, max_rank=None):
    """Minimum-norm least squares Y ~ X W with column scaling; X [n, p], Y [n, m].

    Keeps the singular directions above ``rcond`` times the largest, and at
    most ``max_rank`` of them when given. Returns (W [p, m], rank).
    """
    scale = jnp.sqrt(jnp.mean(X * X, axis=0))
    scale = jnp.where(scale > 0, scale, 1.0)
    U, s, Vt = jnp.linalg.svd(X / scale, full_matrices=False)
    keep = s > rcond * s[0]
    if max_rank is not None:
        keep = keep & (jnp.arange(s.shape[0]) < max_rank)
    s_inv = jnp.where(keep, 1.0 / jnp.where(keep, s, 1.0), 0.0)
    W = Vt.T @ (s_inv[:, None] * (U.T @ Y))
    return W / scale[:, None], jnp.sum(keep)


def regression_data(z, u, z_bar, u_bar, q: int):
    """Time-major regressors X [T, n_s, nZ + nu] and targets Y [T, n_s, nz]."""
    Z = jax.vmap(info_states, in_axes=(0, 0, None))(z, u, q)  # [n_s, T+1, nZ]
    Z_bar = info_states(z_bar, u_bar, q)
    dZ = Z[:, :-1] - Z_bar[:-1]
    du = u - u_bar
    dz_next = z[:, 1:] - z_bar[1:]
    X = jnp.concatenate([dZ, du], axis=-1).transpose(1, 0, 2)
    Y = dz_next.transpose(1, 0, 2)
    return X, Y


def finite_rollouts(z, u) -> jnp.ndarray:
    """[n] True for the rollouts whose observations and controls are all finite."""
    return jnp.all(jnp.isfinite(z), axis=(1, 2)) & jnp.all(jnp.isfinite(u), axis=(1, 2))


def fit_each_step(z, u, inputs, q: int, solve, per_step=()) -> tuple[LinearModel, FitReport]:
    """The per-step fit as a ``lax.scan`` over time, shared by every estimator.

    ``inputs`` are time-major arrays whose first two are the regressors X and
    targets Y of ``regression_data``; ``solve(X_t, Y_t, ...)`` returns
    (W [nZ + nu, nz], rank, residual [n_s, nz]); ``per_step`` are further
    time-major arrays (leading axis T, no rollout axis) passed after them.

    A rollout with any non-finite number (a divergent one) is left out: its
    rows of every input are zero, which removes them from the least squares,
    and ``FitReport.n_bad`` counts them (the driver reports them and stops
    when too few are left).
    """
    nz, nu = z.shape[-1], u.shape[-1]
    good = finite_rollouts(z, u)
    all_finite = jnp.all(good)
    inputs = tuple(jnp.where(good[None, :, None], a, 0.0) for a in inputs) + tuple(per_step)

    def step(_, xs):
        W, rank, res = solve(*xs)
        A_t, B_t = companion(W.T, nz, nu, q)  # theta = W' [nz, nZ + nu]
        return None, (A_t, B_t, jnp.sqrt(jnp.mean(res**2)), jnp.sqrt(jnp.mean(xs[1] ** 2)), rank)

    _, (A, B, res, tgt, rank) = jax.lax.scan(step, None, inputs)
    return LinearModel(A, B), FitReport(res, tgt, rank, all_finite, jnp.sum(~good))


@stage(static_argnames=("q",), outputs=(LinearModel, FitReport))
def fit_information_model(z, u, z_bar, u_bar, q: int, rcond, max_rank=None) -> tuple[LinearModel, FitReport]:
    """Fit Theta_t by least squares at every step (a ``lax.scan`` over time).

    ``max_rank`` [T] (optional, e.g. ``excited_rank``) caps the singular
    directions kept at each step."""

    def solve(X_t, Y_t, *max_rank_t):
        W, rank = least_squares(X_t, Y_t, rcond, *max_rank_t)
        return W, rank, Y_t - X_t @ W

    per_step = () if max_rank is None else (max_rank,)
    return fit_each_step(z, u, regression_data(z, u, z_bar, u_bar, q), q, solve, per_step)
