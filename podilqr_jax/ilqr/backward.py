"""The iLQR backward pass (Riccati recursion) on an information-state model.

Given dZ_{t+1} = A_t dZ_t + B_t du_t about the nominal (Z_bar, u_bar) and the
cost of ``cost.py`` with z = S Z, sweep t = T-1 .. 0 with v_T, V_T from the
terminal cost:

  Q_Z  = l_Z + A' v        Q_u  = l_u + B' v
  Q_ZZ = l_ZZ + A' V A     Q_uu = l_uu + B' V B     Q_uZ = B' V A
  k_t  = -Qr_uu^{-1} Q_u    K_t  = -Qr_uu^{-1} Qr_uZ
  v    = Q_Z + K' Q_uu k + K' Q_u + Q_uZ' k
  V    = Q_ZZ + K' Q_uu K + K' Q_uZ + Q_uZ' K

The regularised Qr_uu = l_uu + B' (V + mu I) B and Qr_uZ = B' (V + mu I) A
(Levenberg-Marquardt on the value function's Hessian, as in Tassa et al.); mu
grows until every Qr_uu is positive definite. With our sign convention the
policy update is u = u_bar + alpha k + K (Z - Z_bar); the paper writes
du = -k - K dZ with the opposite signs.

The expected cost change of a step alpha is alpha dV1 + alpha^2 dV2 with
dV1 = sum k' Q_u and dV2 = 1/2 sum k' Q_uu k. The exact gradient of J with
respect to the open-loop controls on the identified model, g_t = l_u +
B' lambda_{t+1} (lambda the costate), is returned for the convergence test
(the paper's R u_bar + B' v ~ 0).

Shapes: A [T, nZ, nZ], B [T, nZ, nu], Z_bar [T+1, nZ], u_bar [T, nu];
k [T, nu], K [T, nu, nZ], g [T, nu].
"""

from __future__ import annotations

import functools
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
from jax.scipy.linalg import cho_solve

from ..compilation.stages import stage
from ..identify.sysid import LinearModel
from .cost import running_weights


class QuadraticCost(NamedTuple):
    """The cost on the information state: e = S Z - z*."""

    S: jnp.ndarray  # [nz, nZ]
    z_target: jnp.ndarray  # [nz]
    Q: jnp.ndarray  # [nz, nz]
    QT: jnp.ndarray  # [nz, nz]
    R: jnp.ndarray  # [nu, nu]
    goal_step: Optional[jnp.ndarray] = None  # steps t >= goal_step weigh QT (cost.running_weights)
    u_low: Optional[jnp.ndarray] = None  # [nu] control box (box-DDP); None: unconstrained
    u_high: Optional[jnp.ndarray] = None  # [nu]


class Regularisation(NamedTuple):
    """Levenberg-Marquardt schedule (traced values: sweeping them never recompiles)."""

    mu_min: jnp.ndarray
    mu_max: jnp.ndarray
    factor: jnp.ndarray


class BackwardResult(NamedTuple):
    k: jnp.ndarray  # [T, nu] feed-forward step
    K: jnp.ndarray  # [T, nu, nZ] feedback gains
    dV1: jnp.ndarray  # scalar, first-order expected change
    dV2: jnp.ndarray  # scalar, second-order expected change
    grad: jnp.ndarray  # [T, nu] dJ/du_t on the identified model
    mu: jnp.ndarray  # regularisation used
    ok: jnp.ndarray  # every Qr_uu was positive definite (and mu <= mu_max)


BOX_QP_ITERATIONS = 12
BOX_QP_STEPS = 10


def box_qp(H, g, lower, upper):
    """min_x 1/2 x' H x + g' x  subject to  lower <= x <= upper (H positive definite).

    Projected Newton (Bertsekas; as in Tassa, Mansard & Todorov 2014, box-DDP):
    start from the unconstrained minimiser clipped to the box; at each
    iteration the *clamped* set holds the coordinates at a bound whose gradient
    pushes outward, a Newton step is taken on the free ones and a projected
    backtracking search (steps 1, 1/2, ..., one batch) keeps the first that
    lowers the objective. A fixed number of iterations (``BOX_QP_ITERATIONS``;
    nu is small, so a few suffice) keeps it a static loop.

    Returns (x, free [n] bool, Cholesky factor of H on the free block, with
    the identity on the clamped rows and columns).
    """
    n = g.shape[0]
    eye = jnp.eye(n, dtype=g.dtype)
    betas = 0.5 ** jnp.arange(BOX_QP_STEPS, dtype=g.dtype)

    def objective(x):
        return 0.5 * x @ H @ x + g @ x

    def free_block(x):
        grad = g + H @ x
        clamped = ((x <= lower) & (grad > 0)) | ((x >= upper) & (grad < 0))
        free = ~clamped
        H_free = jnp.where(free[:, None] & free[None, :], H, eye)
        return grad, free, jnp.linalg.cholesky(H_free)

    def iterate(_, x):
        grad, free, L = free_block(x)
        step = -cho_solve((L, True), jnp.where(free, grad, 0.0))
        candidates = jnp.clip(x[None] + betas[:, None] * step[None], lower, upper)
        values = jax.vmap(objective)(candidates)
        better = values < objective(x)
        return jnp.where(jnp.any(better), candidates[jnp.argmax(better)], x)

    x0 = jnp.clip(-cho_solve((jnp.linalg.cholesky(H), True), g), lower, upper)
    x = jax.lax.fori_loop(0, BOX_QP_ITERATIONS, iterate, x0)
    _, free, L = free_block(x)
    return x, free, L


def riccati(model: LinearModel, Z_bar, u_bar, cost: QuadraticCost, mu) -> BackwardResult:
    """One backward sweep at a fixed regularisation ``mu`` (a ``lax.scan``).

    With a control box (``cost.u_low``/``u_high``) the step k_t solves the box
    QP u_low <= u_bar_t + k_t <= u_high (``box_qp``) and the feedback acts on
    the free controls only: K_t = -[Qr_uu]_ff^{-1} [Qr_uZ]_f, zero rows for the
    clamped ones (box-DDP). The gradient for the convergence test is then the
    projected one (zero where a control sits on its bound and the gradient
    pushes outward).
    """
    S, zt, Q, QT, R, goal, u_low, u_high = cost
    box = u_low is not None
    nZ = S.shape[1]
    Q_t = running_weights(Q, QT, u_bar.shape[0], goal)
    eye = jnp.eye(nZ, dtype=Z_bar.dtype)
    e_T = S @ Z_bar[-1] - zt
    v_T = 2.0 * S.T @ QT @ e_T
    V_T = 2.0 * S.T @ QT @ S
    l_uu = 2.0 * R

    def step(carry, inp):
        v, V, lam, ok = carry
        A, B, Z_t, u_t, Q = inp
        l_ZZ = 2.0 * S.T @ Q @ S
        l_Z = 2.0 * S.T @ Q @ (S @ Z_t - zt)
        l_u = 2.0 * R @ u_t
        Q_Z = l_Z + A.T @ v
        Q_u = l_u + B.T @ v
        Q_ZZ = l_ZZ + A.T @ V @ A
        Q_uu = l_uu + B.T @ V @ B
        Q_uZ = B.T @ V @ A
        V_reg = V + mu * eye
        Qr_uu = l_uu + B.T @ V_reg @ B
        Qr_uZ = B.T @ V_reg @ A
        H = 0.5 * (Qr_uu + Qr_uu.T)
        L = jnp.linalg.cholesky(H)
        pd = jnp.all(jnp.isfinite(L))
        L = jnp.where(pd, L, jnp.eye(L.shape[0], dtype=L.dtype))
        if box:
            H = jnp.where(pd, H, jnp.eye(H.shape[0], dtype=H.dtype))
            k, free, L_free = box_qp(H, Q_u, u_low - u_t, u_high - u_t)
            K = -cho_solve((L_free, True), jnp.where(free[:, None], Qr_uZ, 0.0))
        else:
            k = -cho_solve((L, True), Q_u)
            K = -cho_solve((L, True), Qr_uZ)
        v_new = Q_Z + K.T @ Q_uu @ k + K.T @ Q_u + Q_uZ.T @ k
        V_new = Q_ZZ + K.T @ Q_uu @ K + K.T @ Q_uZ + Q_uZ.T @ K
        V_new = 0.5 * (V_new + V_new.T)
        g = l_u + B.T @ lam
        if box:  # projected: no descent direction out of the box
            g = jnp.where(((u_t <= u_low) & (g > 0)) | ((u_t >= u_high) & (g < 0)), 0.0, g)
        lam_new = l_Z + A.T @ lam
        dv = jnp.stack([k @ Q_u, 0.5 * k @ Q_uu @ k])
        return (v_new, V_new, lam_new, ok & pd), (k, K, g, dv)

    init = (v_T, V_T, v_T, jnp.array(True))
    (_, _, _, ok), (k, K, g, dv) = jax.lax.scan(step, init, (model.A, model.B, Z_bar[:-1], u_bar, Q_t), reverse=True)
    dV = jnp.sum(dv, axis=0)
    return BackwardResult(k, K, dV[0], dV[1], g, jnp.asarray(mu, Z_bar.dtype), ok)


@stage(outputs=(BackwardResult,))
def backward_pass(model: LinearModel, Z_bar, u_bar, cost: QuadraticCost, mu, reg: Regularisation) -> BackwardResult:
    """Backward sweep at ``mu``, raising mu by ``reg.factor`` until it succeeds.

    ``ok`` is False when mu would pass ``reg.mu_max`` (or the model is not
    finite); the gains are then zero, never NaN.
    """
    finite = jnp.all(jnp.isfinite(model.A)) & jnp.all(jnp.isfinite(model.B))
    mu = jnp.maximum(mu, reg.mu_min)
    first = riccati(model, Z_bar, u_bar, cost, mu)

    def cond(res):
        return finite & (~res.ok) & (res.mu * reg.factor <= reg.mu_max)

    def body(res):
        return riccati(model, Z_bar, u_bar, cost, res.mu * reg.factor)

    res = jax.lax.while_loop(cond, body, first)
    ok = res.ok & finite
    zero = functools.partial(jnp.where, ok)
    return res._replace(
        k=zero(res.k, 0.0),
        K=zero(res.K, 0.0),
        dV1=zero(res.dV1, 0.0),
        dV2=zero(res.dV2, 0.0),
        grad=jnp.where(finite, res.grad, 0.0),
        ok=ok,
    )
