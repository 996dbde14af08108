"""The quadratic tracking cost on observations and controls.

  J = sum_{t<T} e_t' Q e_t + u_t' R u_t + e_T' QT e_T,   e_t = z_t - z*

No factor 1/2: the cost is written as in the paper. Derivatives with respect to
an information state Z (z = S Z) are l_Z = 2 S' Q e and l_ZZ = 2 S' Q S.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def trajectory_cost(
    z: jnp.ndarray, u: jnp.ndarray, z_target: jnp.ndarray, Q: jnp.ndarray, QT: jnp.ndarray, R: jnp.ndarray
) -> jnp.ndarray:
    """Cost of one trajectory: z [T+1, nz], u [T, nu] -> scalar."""
    e = z - z_target
    running = jnp.einsum("ti,ij,tj->", e[:-1], Q, e[:-1]) + jnp.einsum("ti,ij,tj->", u, R, u)
    return running + e[-1] @ QT @ e[-1]


def batch_costs(z: jnp.ndarray, u: jnp.ndarray, data) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Costs of a batch z [B, T+1, nz], u [B, T, nu] under ``data``'s cost.

    Returns (cost [B], finite [B]); a rollout with any non-finite number costs inf.
    """
    cost = jax.vmap(trajectory_cost, in_axes=(0, 0, None, None, None, None))(
        z, u, data.z_target, data.Q, data.QT, data.R
    )
    finite = jnp.isfinite(cost) & jnp.all(jnp.isfinite(z), axis=(1, 2)) & jnp.all(jnp.isfinite(u), axis=(1, 2))
    return jnp.where(finite, cost, jnp.inf), finite
