"""Simulated linear(-Gaussian) LTV systems shared by the identification tests (a helper module, no tests).

    x_{t+1} = F_t x_t + G_t u_t + w_t,    z_t = C x_t + v_t,

simulated in numpy float64, independently of the library, and the least-squares
fit wrapped for numpy data. Used by ``test_linear.py`` (``random_ltv``,
``rel_err``), ``test_noise_lemmas.py`` and ``test_estimators.py``. Every helper
that draws from ``rng`` does so in a fixed order, which the tests' seeds and
recorded numbers rely on.

Machine independence: the draws are numpy's (``default_rng(seed)``), the same
numbers on every CPU, and the systems are linear, so another processor's
rounding moves the tested errors and ratios by round-off (~1e-13 relative),
not by a Monte Carlo draw. The tests' margins are measured over 40 seeds all
the same (their comments; re-checked: Lemma 1 ratio 6.8 .. 9.7 and the
random-x_0 IV ratio 3.5 .. 3.8 over seeds 0-4 and 0-3).

Imported by its bare name (``import linear_gaussian as lg`` or ``from
linear_gaussian import ...``): ``tests/`` has no ``__init__.py``, so pytest
(default ``prepend`` import mode) puts ``tests/`` on ``sys.path`` when it
collects the test files. Not collected itself (no ``test_`` prefix).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

import podilqr_jax  # noqa: F401  (enables float64 in JAX)
from podilqr_jax.identify.sysid import fit_information_model

# rcond of the fits: drop only singular values that are numerically zero.
RCOND = 1e-10

# Std of the injected perturbations of the sysid controls, everywhere.
SIGMA_DU = 0.1


# ---------------------------------------------------------------------------
# systems
# ---------------------------------------------------------------------------


def random_ltv(rng, nx, nu, T, radius=0.95):
    """Random time-varying F_t [T, nx, nx] (spectral radius = radius) and G_t [T, nx, nu]."""
    F = np.empty((T, nx, nx))
    for t in range(T):
        M = rng.standard_normal((nx, nx))
        F[t] = radius * M / np.max(np.abs(np.linalg.eigvals(M)))
    G = rng.standard_normal((T, nx, nu))
    return F, G


def oscillator_ltv(rng, T):
    """Damped rotation F_t (angle 0.5 +- 0.2 rad, radius 0.95 +- 0.05), G_t ~ [0, 1], C = [1, 0].

    Well conditioned by construction: cond([C; C F_t]) ~ 6, so the true ARMA
    coefficients are O(1) and relative errors mean the same for every seed (a
    random F, G, C can make [C; C F] nearly singular).
    """
    th = 0.5 + 0.2 * rng.uniform(-1, 1, T)
    rho = 0.95 + 0.05 * rng.uniform(-1, 1, T)
    F = rho[:, None, None] * np.stack([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]]).transpose(2, 0, 1)
    G = np.stack([0.2 * rng.uniform(-1, 1, T), 1 + 0.2 * rng.uniform(-1, 1, T)], axis=1)[:, :, None]
    C = np.array([[1.0, 0.0]])
    return F, G, C


def nominal(F, G, x0, u_bar):
    """Noiseless trajectory x_bar [T+1, nx] under u_bar."""
    x = np.empty((F.shape[0] + 1, x0.shape[0]))
    x[0] = x0
    for t in range(F.shape[0]):
        x[t + 1] = F[t] @ x[t] + G[t] @ u_bar[t]
    return x


def true_arma(F, G, C, t):
    """[a1, a2, b2, b1] of z_{t+1} = a1 z_t + a2 z_{t-1} + b2 u_{t-1} + b1 u_t (noiseless, t >= 1).

    For nx = 2, nz = nu = 1 and an observable pair (C, F_{t-1}):
    x_{t-1} = O^{-1} [z_{t-1}; z_t - C G_{t-1} u_{t-1}] with O = [C; C F_{t-1}],
    x_t = F_{t-1} x_{t-1} + G_{t-1} u_{t-1}, z_{t+1} = C F_t x_t + C G_t u_t.
    """
    O = np.vstack([C, C @ F[t - 1]])
    P = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, -(C @ G[t - 1])[0, 0]]])  # (z_t, z_{t-1}, u_{t-1}) -> O x_{t-1}
    x_t = F[t - 1] @ np.linalg.solve(O, P) + np.outer(G[t - 1][:, 0], [0.0, 0.0, 1.0])
    return np.concatenate([(C @ F[t] @ x_t)[0], (C @ G[t])[0]])


def oscillator_problem(seed, T, k_scale, t_first=1):
    """The oscillator with feedback gains k_t = k_scale N(0, 1) on dz_t, a random x_0 and u_bar.

    Returns rng (to draw the rollouts from next), F, G, C, k [T, 1, 1], the
    nominal z_bar [T+1, 1], u_bar [T, 1] and the true ARMA coefficients [T, 4]
    (rows t < t_first zero).
    """
    rng = np.random.default_rng(seed)
    F, G, C = oscillator_ltv(rng, T)
    k = k_scale * rng.standard_normal((T, 1, 1))
    x0 = rng.standard_normal(F.shape[1])
    u_bar = rng.standard_normal((T, 1))
    z_bar = nominal(F, G, x0, u_bar) @ C.T
    truth = np.zeros((T, 4))
    for t in range(t_first, T):
        truth[t] = true_arma(F, G, C, t)
    return rng, F, G, C, k, z_bar, u_bar, truth


# ---------------------------------------------------------------------------
# rollouts
# ---------------------------------------------------------------------------


def full_obs_rollouts(rng, F, G, x_bar, u_bar, K, n, w_std, dx0_std, sigma_du=SIGMA_DU):
    """n rollouts with u = u_bar + K (x - x_bar) + du, process noise w_std, random x_0 (std dx0_std about x_bar_0).

    Draws du, then x_0, then w_t step by step. Returns x [n, T+1, nx], applied
    u [n, T, nu], injected du [n, T, nu].
    """
    T, nx, nu = G.shape
    du = sigma_du * rng.standard_normal((n, T, nu))
    x = np.empty((n, T + 1, nx))
    u = np.empty((n, T, nu))
    x[:, 0] = x_bar[0] + dx0_std * rng.standard_normal((n, nx))
    for t in range(T):
        u[:, t] = u_bar[t] + (x[:, t] - x_bar[t]) @ K[t].T + du[:, t]
        x[:, t + 1] = x[:, t] @ F[t].T + u[:, t] @ G[t].T + w_std * rng.standard_normal((n, nx))
    return x, u, du


def full_obs_fit_errors(fit, rng, F, G, K, x_bar, u_bar, ns, w_std, dx0_std):
    """Relative errors of the fitted [A_t | B_t] vs [F_t | G_t] for each n_s in ns, then ||G K|| (relative).

    ``fit(x, u, du, x_bar, u_bar) -> (A, B, rank)`` is given n_s fresh
    ``full_obs_rollouts`` each time (drawn from rng in the order of ns) and
    must have full rank nx + nu at every step.
    """
    truth = np.concatenate([F, G], axis=2)
    errs = []
    for n in ns:
        x, u, du = full_obs_rollouts(rng, F, G, x_bar, u_bar, K, n, w_std, dx0_std)
        A, B, rank = fit(x, u, du, x_bar, u_bar)
        assert np.all(rank == F.shape[1] + G.shape[2])
        errs.append(rel_fro(np.concatenate([A, B], axis=2), truth))
    return (*errs, np.linalg.norm(G @ K) / np.linalg.norm(truth))


def deviations(F, G, C, k, du, w, v, dx0=None):
    """Deviations from the nominal of rollouts with feedback on the measurement.

    u_t = u_bar_t + du_t + k_t dz_t, x_{t+1} = F x + G u + w_t, z_t = C x_t + v_t,
    x_0 = x_bar_0 + dx0 (dx0 = None: zero). Linear in du [n, T, nu], w [n, T, nx],
    v [n, T+1, nz] and dx0 [n, nx]; returns dz [n, T+1, nz] and the applied
    control deviation [n, T, nu].
    """
    n, T, _ = du.shape
    dx = np.zeros((n, F.shape[1])) if dx0 is None else dx0
    dz = np.empty((n, T + 1, C.shape[0]))
    du_app = np.empty_like(du)
    for t in range(T):
        dz[:, t] = dx @ C.T + v[:, t]
        du_app[:, t] = du[:, t] + dz[:, t] @ k[t].T
        dx = dx @ F[t].T + du_app[:, t] @ G[t].T + w[:, t]
    dz[:, T] = dx @ C.T + v[:, T]
    return dz, du_app


# ---------------------------------------------------------------------------
# fits and errors
# ---------------------------------------------------------------------------


def fit_ols(z, u, z_bar, u_bar, q):
    """Least-squares ``fit_information_model`` on numpy data: A, B, rank (asserts finite)."""
    model, report = fit_information_model(
        jnp.asarray(z), jnp.asarray(u), jnp.asarray(z_bar), jnp.asarray(u_bar), q, RCOND
    )
    assert bool(report.all_finite)
    return np.asarray(model.A), np.asarray(model.B), np.asarray(report.rank)


def arma_coefficients(A, B):
    """Top row of [A_t | B_t] = [a1, a2, b2 | b1], [T, 4] (q = 2, nz = nu = 1)."""
    return np.concatenate([A[:, 0], B[:, 0]], axis=1)


def rel_err(a, b):
    """max |a - b| / max |b|."""
    a, b = np.asarray(a), np.asarray(b)
    return np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300)


def rel_fro(a, b):
    """||a - b||_F / ||b||_F over all time steps and entries."""
    return np.linalg.norm(np.asarray(a) - b) / np.linalg.norm(b)
