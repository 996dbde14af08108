"""The quadratic tracking cost on observations and controls.

  J = sum_{t<T} e_t' Q e_t + u_t' R u_t + e_T' QT e_T,   e_t = z_t - z*

With a goal step g < T (``Env.with_goal_step``, used by receding-horizon
replanning) the running steps t >= g are weighted by QT instead of Q: the
target is to be reached by step g and held. g = T (the default) is the cost
above.

No factor 1/2: the cost is written as in the paper. Derivatives with respect to
an information state Z (z = S Z) are l_Z = 2 S' Q e and l_ZZ = 2 S' Q S.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def running_weights(Q: jnp.ndarray, QT: jnp.ndarray, T: int, goal_step=None) -> jnp.ndarray:
    """The running state weights Q_t [T, nz, nz]: Q before the goal step, QT from it on."""
    if goal_step is None:
        return jnp.broadcast_to(Q, (T,) + Q.shape)
    return jnp.where((jnp.arange(T) >= goal_step)[:, None, None], QT, Q)


def trajectory_cost(
    z: jnp.ndarray,
    u: jnp.ndarray,
    z_target: jnp.ndarray,
    Q: jnp.ndarray,
    QT: jnp.ndarray,
    R: jnp.ndarray,
    goal_step=None,
) -> jnp.ndarray:
    """Cost of one trajectory: z [T+1, nz], u [T, nu] -> scalar."""
    e = z - z_target
    Q_t = running_weights(Q, QT, u.shape[0], goal_step)
    running = jnp.einsum("ti,tij,tj->", e[:-1], Q_t, e[:-1]) + jnp.einsum("ti,ij,tj->", u, R, u)
    return running + e[-1] @ QT @ e[-1]


def batch_costs(z: jnp.ndarray, u: jnp.ndarray, data) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Costs of a batch z [B, T+1, nz], u [B, T, nu] under ``data``'s cost.

    Returns (cost [B], finite [B]); a rollout with any non-finite number costs inf.
    """
    cost = jax.vmap(trajectory_cost, in_axes=(0, 0, None, None, None, None, None))(
        z, u, data.z_target, data.Q, data.QT, data.R, data.goal_step
    )
    finite = jnp.isfinite(cost) & jnp.all(jnp.isfinite(z), axis=(1, 2)) & jnp.all(jnp.isfinite(u), axis=(1, 2))
    return jnp.where(finite, cost, jnp.inf), finite
