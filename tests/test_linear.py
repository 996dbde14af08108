"""Linear-system checks of the identification and the backward pass.

Acceptance criterion 1: on a linear system the ARMA fit recovers the exact LTV
model and the assembled (A_t, B_t) reproduce held-out rollouts to float
tolerance (q = 1 with full observation, q = 2 with partial observation); the
first backward pass on a linear-quadratic problem equals the finite-horizon
LQR solution.

Everything here is a small numpy-simulated linear system (no MuJoCo): the
reference values (simulations, the LQR Riccati recursion) are computed
independently in numpy float64.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from linear_gaussian import random_ltv, rel_err

import podilqr_jax  # noqa: F401  (enables float64 in JAX)
from podilqr_jax.identify.info_state import companion, info_dim, info_states, initial_info_state, shift
from podilqr_jax.identify.sysid import LinearModel, fit_information_model
from podilqr_jax.ilqr.backward import QuadraticCost, Regularisation, backward_pass, riccati

# Tolerances. Everything runs in float64 (eps ~ 2.2e-16). The fits are SVD
# least-squares solves of small, well-conditioned problems (condition numbers
# ~1e2..1e3) and the propagations are a handful of matrix products, so the
# errors sit around 1e-13 relative; 1e-9 leaves four orders of margin while
# still being far below anything a wrong model or a wrong sign would give.
FIT_RTOL = 1e-9
# Riccati recursions / gains / costs of a T ~ 10 LQ problem: a few dozen
# products and Cholesky solves of O(1) matrices, errors ~1e-14 relative.
LQR_RTOL = 1e-9
# Structural results (companion blocks, zeroed gains) are exact.
EXACT = 0.0
# rcond of the fit: drop only singular values that are numerically zero.
RCOND = 1e-10


# ---------------------------------------------------------------------------
# helpers (numpy, independent of the library; random_ltv and rel_err are in
# linear_gaussian.py, shared with the noise and estimator tests)
# ---------------------------------------------------------------------------


def simulate(F, G, x0, u):
    """x_{t+1} = F_t x_t + G_t u_t for a batch u [..., T, nu] -> x [..., T+1, nx]."""
    T = F.shape[0]
    x = np.empty(u.shape[:-2] + (T + 1, x0.shape[0]))
    x[..., 0, :] = x0
    for t in range(T):
        x[..., t + 1, :] = x[..., t, :] @ F[t].T + u[..., t, :] @ G[t].T
    return x


def propagate(A, B, du):
    """dZ_{t+1} = A_t dZ_t + B_t du_t from dZ_0 = 0; du [n, T, nu] -> dZ [n, T+1, nZ]."""
    A, B = np.asarray(A), np.asarray(B)
    T, nZ = A.shape[0], A.shape[1]
    dZ = np.zeros(du.shape[:-2] + (T + 1, nZ))
    for t in range(T):
        dZ[..., t + 1, :] = dZ[..., t, :] @ A[t].T + du[..., t, :] @ B[t].T
    return dZ


def range_basis(X, tol=1e-10):
    """Orthonormal basis [n, r] of the span of the rows of X [m, n]."""
    _, s, Vt = np.linalg.svd(X, full_matrices=True)
    r = int(np.sum(s > tol * s[0])) if s.size and s[0] > 0 else 0
    return Vt[:r].T


# ---------------------------------------------------------------------------
# 1. full observation, q = 1: exact recovery of (F_t, G_t)
# ---------------------------------------------------------------------------


def test_fit_full_observation_q1_recovers_ltv_model():
    rng = np.random.default_rng(0)
    nx, nu, T, n_s = 4, 2, 8, 24
    F, G = random_ltv(rng, nx, nu, T)
    x0 = rng.standard_normal(nx)
    u_bar = rng.standard_normal((T, nu))
    z_bar = simulate(F, G, x0, u_bar)
    du = 0.1 * rng.standard_normal((n_s, T, nu))
    z = simulate(F, G, x0, u_bar + du)

    model, report = fit_information_model(
        jnp.asarray(z), jnp.asarray(u_bar + du), jnp.asarray(z_bar), jnp.asarray(u_bar), 1, RCOND
    )
    A, B = np.asarray(model.A), np.asarray(model.B)
    assert A.shape == (T, nx, nx) and B.shape == (T, nx, nu)
    assert bool(report.all_finite)

    # B_t is identified at every step (du_t is always excited).
    assert rel_err(B, G) < FIT_RTOL

    # A_t is identified on the span of the data dz_t: at t = 0 that span is
    # {0} (deterministic x_0), at t = 1 it is range(G_0) (2 of 4 directions),
    # from t = 2 on it is all of R^4. The min-norm fit gives the all-zero
    # dz_0 columns zero weight, up to SVD round-off (~1e-17 is observed: the
    # right singular vectors of the kept values carry eps-level components in
    # the zero columns), which multiplies exactly-zero data anyway.
    assert np.max(np.abs(A[0])) <= FIT_RTOL * np.max(np.abs(F[0]))
    dz = z - z_bar
    for t in range(1, T):
        V = range_basis(dz[:, t, :])
        expected_rank = min(nx, t * nu)
        assert V.shape[1] == expected_rank
        assert rel_err(A[t] @ V, F[t] @ V) < FIT_RTOL
        if expected_rank == nx:
            assert rel_err(A[t], F[t]) < FIT_RTOL

    # exact linear data: zero residual, full rank nZ + nu from t = 2 on
    tgt = np.asarray(report.target_rms)
    assert np.all(np.asarray(report.residual_rms) <= FIT_RTOL * tgt)
    np.testing.assert_array_equal(np.asarray(report.rank), [nu, nu + nu] + [nx + nu] * (T - 2))

    # held-out rollouts (fresh perturbations, larger than in the fit)
    du_new = rng.standard_normal((10, T, nu))
    dz_new = simulate(F, G, x0, u_bar + du_new) - z_bar
    assert rel_err(propagate(A, B, du_new), dz_new) < FIT_RTOL


# ---------------------------------------------------------------------------
# 2. partial observation z = C x, q = 2: held-out rollouts reproduced
# ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("nx", "nz", "nu", "seed"),
    [
        (2, 1, 1, 1),  # oscillator-like: one position observed
        (4, 2, 1, 2),  # q = 2 is exactly the observability index
    ],
)
def test_fit_partial_observation_q2_reproduces_heldout(nx, nz, nu, seed):
    rng = np.random.default_rng(seed)
    T, q, n_s = 8, 2, 30
    F, G = random_ltv(rng, nx, nu, T)
    C = rng.standard_normal((nz, nx))
    # q = 2 must suffice: [C; C F_t] invertible at every step.
    for t in range(T):
        assert np.linalg.matrix_rank(np.vstack([C, C @ F[t]])) == nx
    x0 = rng.standard_normal(nx)
    u_bar = rng.standard_normal((T, nu))
    z_bar = simulate(F, G, x0, u_bar) @ C.T
    du = 0.1 * rng.standard_normal((n_s, T, nu))
    z = simulate(F, G, x0, u_bar + du) @ C.T

    model, report = fit_information_model(
        jnp.asarray(z), jnp.asarray(u_bar + du), jnp.asarray(z_bar), jnp.asarray(u_bar), q, RCOND
    )
    nZ = info_dim(nz, nu, q)
    A, B = np.asarray(model.A), np.asarray(model.B)
    assert A.shape == (T, nZ, nZ) and B.shape == (T, nZ, nu)

    # the LTV-ARMA(2) model is exact: no fit residual
    assert np.all(np.asarray(report.residual_rms) <= FIT_RTOL * np.asarray(report.target_rms))
    # the observation enters through du_0 only at t = 0: B_0 top block = C G_0
    assert rel_err(B[0, :nz], C @ G[0]) < FIT_RTOL

    # held-out rollouts: the whole information state (observations and the
    # shifted history), over the whole horizon, from dZ_0 = 0
    du_new = rng.standard_normal((10, T, nu))
    u_new = u_bar + du_new
    z_new = simulate(F, G, x0, u_new) @ C.T
    dZ_sim = np.asarray(jax.vmap(info_states, in_axes=(0, 0, None))(z_new, u_new, q)) - np.asarray(
        info_states(jnp.asarray(z_bar), jnp.asarray(u_bar), q)
    )
    dZ_fit = propagate(A, B, du_new)
    assert rel_err(dZ_fit[..., :nz], z_new - z_bar) < FIT_RTOL
    assert rel_err(dZ_fit, dZ_sim) < FIT_RTOL


# ---------------------------------------------------------------------------
# companion form and information state: structure by hand
# ---------------------------------------------------------------------------


def test_companion_q2_hand_example():
    nz, nu, q = 2, 1, 2  # Z = [z_t (2), z_{t-1} (2), u_{t-1} (1)], nZ = 5
    theta = np.arange(1.0, 13.0).reshape(2, 6)
    A, B = companion(jnp.asarray(theta), nz, nu, q)
    A_hand = np.array(
        [
            [1, 2, 3, 4, 5],
            [7, 8, 9, 10, 11],
            [1, 0, 0, 0, 0],  # z_{t} -> z_{t-1} slot
            [0, 1, 0, 0, 0],
            [0, 0, 0, 0, 0],  # u_t enters through B
        ],
        dtype=float,
    )
    B_hand = np.array([[6], [12], [0], [0], [1]], dtype=float)
    np.testing.assert_array_equal(np.asarray(A), A_hand)
    np.testing.assert_array_equal(np.asarray(B), B_hand)


def test_companion_q3_hand_example():
    nz, nu, q = 1, 1, 3  # Z = [z_t, z_{t-1}, z_{t-2}, u_{t-1}, u_{t-2}], nZ = 5
    theta = np.array([[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]])
    A, B = companion(jnp.asarray(theta), nz, nu, q)
    A_hand = np.array(
        [
            [1, 2, 3, 4, 5],
            [1, 0, 0, 0, 0],  # z_t     -> z_{t-1}
            [0, 1, 0, 0, 0],  # z_{t-1} -> z_{t-2}
            [0, 0, 0, 0, 0],  # u_t (from B) -> u_{t-1}
            [0, 0, 0, 1, 0],  # u_{t-1} -> u_{t-2}
        ],
        dtype=float,
    )
    B_hand = np.array([[6], [0], [0], [1], [0]], dtype=float)
    np.testing.assert_array_equal(np.asarray(A), A_hand)
    np.testing.assert_array_equal(np.asarray(B), B_hand)


@pytest.mark.parametrize("q", [1, 2, 3])
def test_companion_matches_info_states_of_an_arma_trajectory(q):
    """Z_{t+1} = A Z_t + B u_t on the information states of a trajectory
    generated by the ARMA recursion z_{t+1} = Theta [Z_t; u_t] (rest history
    z_{-k} = z_0, u_{-k} = 0), and ``shift`` agrees with ``info_states``."""
    rng = np.random.default_rng(10 + q)
    nz, nu, T = 2, 2, 6
    nZ = info_dim(nz, nu, q)
    theta = 0.5 * rng.standard_normal((nz, nZ + nu))
    A, B = (np.asarray(m) for m in companion(jnp.asarray(theta), nz, nu, q))
    u = rng.standard_normal((T, nu))
    z0 = rng.standard_normal(nz)

    Z_t = np.asarray(initial_info_state(jnp.asarray(z0), nu, q))
    zs, Zs = [z0], [Z_t]
    for t in range(T):
        z_next = theta @ np.concatenate([Z_t, u[t]])
        Z_t = np.asarray(shift(jnp.asarray(Z_t), jnp.asarray(z_next), jnp.asarray(u[t]), nz, nu, q))
        zs.append(z_next)
        Zs.append(Z_t)
    Z = np.asarray(info_states(jnp.asarray(np.array(zs)), jnp.asarray(u), q))
    np.testing.assert_allclose(Z, np.array(Zs), rtol=0, atol=EXACT)
    # newest first: Z_t = [z_t, z_{t-1}, ..., u_{t-1}, ...]
    np.testing.assert_array_equal(Z[:, :nz], np.array(zs))
    for t in range(T):
        np.testing.assert_allclose(Z[t + 1], A @ Z[t] + B @ u[t], rtol=1e-14, atol=1e-14)


# ---------------------------------------------------------------------------
# 4. backward pass on a linear-quadratic problem = finite-horizon LQR
# ---------------------------------------------------------------------------


def lqr_numpy(F, G, Q, QT, R):
    """Finite-horizon LQR for sum x'Qx + u'Ru + x_T'QT x_T: P [T+1], L [T] with u = -L x."""
    T = F.shape[0]
    P = np.empty((T + 1,) + Q.shape)
    L = np.empty((T, G.shape[2], F.shape[1]))
    P[T] = QT
    for t in reversed(range(T)):
        Ft, Gt, Pn = F[t], G[t], P[t + 1]
        L[t] = np.linalg.solve(R + Gt.T @ Pn @ Gt, Gt.T @ Pn @ Ft)
        P[t] = Q + Ft.T @ Pn @ Ft - Ft.T @ Pn @ Gt @ L[t]
        P[t] = 0.5 * (P[t] + P[t].T)
    return P, L


def lq_cost(x, u, Q, QT, R):
    """sum_{t<T} x'Qx + u'Ru + x_T'QT x_T (numpy or jax arrays)."""
    run = jnp.einsum("ti,ij,tj->", x[:-1], Q, x[:-1]) + jnp.einsum("ti,ij,tj->", u, R, u)
    return run + x[-1] @ QT @ x[-1]


def random_psd(rng, n, rank=None, shift_=0.0):
    M = rng.standard_normal((n, rank or n))
    return M @ M.T / n + shift_ * np.eye(n)


def lq_problem(u_bar_kind):
    rng = np.random.default_rng(42)
    nx, nu, T = 4, 2, 10
    F, G = random_ltv(rng, nx, nu, T, radius=1.05)  # mildly unstable: feedback matters
    Q = random_psd(rng, nx, rank=2)  # PSD, singular
    QT = random_psd(rng, nx, shift_=0.5)
    R = random_psd(rng, nu, shift_=0.1)  # PD
    x0 = rng.standard_normal(nx)
    u_bar = np.zeros((T, nu)) if u_bar_kind == "zero" else rng.standard_normal((T, nu))
    x_bar = simulate(F, G, x0, u_bar)
    return F, G, Q, QT, R, x0, u_bar, x_bar


@pytest.mark.parametrize("u_bar_kind", ["zero", "random"])
def test_first_backward_pass_equals_finite_horizon_lqr(u_bar_kind):
    F, G, Q, QT, R, x0, u_bar, x_bar = lq_problem(u_bar_kind)
    T, nx, nu = G.shape
    model = LinearModel(jnp.asarray(F), jnp.asarray(G))
    cost = QuadraticCost(jnp.eye(nx), jnp.zeros(nx), jnp.asarray(Q), jnp.asarray(QT), jnp.asarray(R))
    res = riccati(model, jnp.asarray(x_bar), jnp.asarray(u_bar), cost, 0.0)
    assert bool(res.ok)
    k, K = np.asarray(res.k), np.asarray(res.K)

    P, L = lqr_numpy(F, G, Q, QT, R)
    # feedback gains: u = u_bar + k + K dZ  <->  u = -L x
    assert rel_err(K, -L) < LQR_RTOL

    # the full step (alpha = 1) from the nominal reproduces the LQR trajectory
    x_star = np.empty((T + 1, nx))
    u_star = np.empty((T, nu))
    x_star[0] = x0
    for t in range(T):
        u_star[t] = -L[t] @ x_star[t]
        x_star[t + 1] = F[t] @ x_star[t] + G[t] @ u_star[t]
    u_step = u_bar + k + np.einsum("tij,tj->ti", K, x_star[:-1] - x_bar[:-1])
    assert rel_err(u_step, u_star) < LQR_RTOL
    # ... and so does the open-loop rollout of the full step's controls
    x_step = np.empty((T + 1, nx))
    x_step[0] = x0
    u_rollout = np.empty((T, nu))
    for t in range(T):
        u_rollout[t] = u_bar[t] + k[t] + K[t] @ (x_step[t] - x_bar[t])
        x_step[t + 1] = F[t] @ x_step[t] + G[t] @ u_rollout[t]
    assert rel_err(x_step, x_star) < LQR_RTOL

    # optimal cost x_0' P_0 x_0, and the quadratic model of the change is exact
    J_bar = float(lq_cost(x_bar, u_bar, Q, QT, R))
    J_star = float(lq_cost(x_star, u_star, Q, QT, R))
    assert abs(J_star - x0 @ P[0] @ x0) <= LQR_RTOL * abs(J_star)
    dV = float(res.dV1 + res.dV2)
    assert J_star < J_bar
    assert abs(dV - (J_star - J_bar)) <= LQR_RTOL * abs(J_bar)

    # grad = dJ/du of the open-loop controls at u_bar (jax.grad of an
    # independent rollout + cost)
    Fj, Gj, x0j = jnp.asarray(F), jnp.asarray(G), jnp.asarray(x0)

    def J_of_u(u):
        def step(x, inp):
            Ft, Gt, ut = inp
            x_next = Ft @ x + Gt @ ut
            return x_next, x_next

        _, xs = jax.lax.scan(step, x0j, (Fj, Gj, u))
        return lq_cost(jnp.concatenate([x0j[None], xs]), u, Q, QT, R)

    g_ref = np.asarray(jax.grad(J_of_u)(jnp.asarray(u_bar)))
    assert rel_err(res.grad, g_ref) < LQR_RTOL

    # the jitted driver with mu_min = 0 gives the same first pass
    res2 = backward_pass(model, jnp.asarray(x_bar), jnp.asarray(u_bar), cost, 0.0, Regularisation(0.0, 1e10, 10.0))
    assert bool(res2.ok) and float(res2.mu) == 0.0
    for name in ("k", "K", "dV1", "dV2", "grad"):
        np.testing.assert_allclose(getattr(res2, name), getattr(res, name), rtol=1e-12, atol=1e-14)


# ---------------------------------------------------------------------------
# 5. regularisation and failure handling
# ---------------------------------------------------------------------------


def scalar_problem(R_val, T=1):
    """nZ = nu = 1, A = B = 1, zero state cost: Qr_uu = 2 R + B'(V + mu) B."""
    model = LinearModel(jnp.ones((T, 1, 1)), jnp.ones((T, 1, 1)))
    cost = QuadraticCost(jnp.eye(1), jnp.zeros(1), jnp.zeros((1, 1)), jnp.zeros((1, 1)), jnp.full((1, 1), R_val))
    Z_bar = jnp.ones((T + 1, 1))
    u_bar = jnp.ones((T, 1))
    return model, Z_bar, u_bar, cost


def test_regularisation_grows_until_positive_definite():
    # R = -1 (not allowed by the config; fine for the bare backward pass):
    # Qr_uu = -2 + mu at T = 1, positive definite iff mu > 2. From 1e-3 with
    # factor 10 the schedule tries 1e-3, 1e-2, 1e-1, 1 and stops at 10.
    model, Z_bar, u_bar, cost = scalar_problem(-1.0)
    assert not bool(riccati(model, Z_bar, u_bar, cost, 1.0).ok)
    assert bool(riccati(model, Z_bar, u_bar, cost, 10.0).ok)
    res = backward_pass(model, Z_bar, u_bar, cost, 0.0, Regularisation(1e-3, 1e6, 10.0))
    assert bool(res.ok)
    np.testing.assert_allclose(float(res.mu), 10.0, rtol=1e-12)
    # k = -Qr_uu^{-1} Q_u with Q_u = 2 R u_bar = -2, Qr_uu = 8: k = 0.25
    np.testing.assert_allclose(np.asarray(res.k), [[0.25]], rtol=1e-12)
    assert np.all(np.isfinite(np.asarray(res.K)))


def test_regularisation_gives_up_at_mu_max_with_zero_gains():
    model, Z_bar, u_bar, cost = scalar_problem(-1.0, T=3)
    res = backward_pass(model, Z_bar, u_bar, cost, 0.0, Regularisation(1e-3, 5.0, 10.0))
    assert not bool(res.ok)
    for name in ("k", "K", "dV1", "dV2"):
        np.testing.assert_allclose(np.asarray(getattr(res, name)), 0.0, rtol=0, atol=EXACT)
    assert np.all(np.isfinite(np.asarray(res.grad))) and np.isfinite(float(res.mu))


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_model_returns_not_ok_and_zero_gains(bad):
    F, G, Q, QT, R, x0, u_bar, x_bar = lq_problem("random")
    T, nx, _ = G.shape
    F = F.copy()
    F[3, 1, 2] = bad
    model = LinearModel(jnp.asarray(F), jnp.asarray(G))
    cost = QuadraticCost(jnp.eye(nx), jnp.zeros(nx), jnp.asarray(Q), jnp.asarray(QT), jnp.asarray(R))
    res = backward_pass(model, jnp.asarray(x_bar), jnp.asarray(u_bar), cost, 0.0, Regularisation(1e-6, 1e10, 10.0))
    assert not bool(res.ok)
    for name in ("k", "K", "dV1", "dV2", "grad"):
        val = np.asarray(getattr(res, name))
        assert np.all(np.isfinite(val)), name
        np.testing.assert_allclose(val, 0.0, rtol=0, atol=EXACT)
