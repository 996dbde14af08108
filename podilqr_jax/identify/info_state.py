"""The information state and the companion-form model of Eq. (c4tab).

Notation (shapes), with q the number of past observations kept:
  Z_t = [z_t, z_{t-1}, ..., z_{t-q+1}, u_{t-1}, ..., u_{t-q+1}]   newest first
  nZ  = q nz + (q - 1) nu
  Z   : [T+1, nZ]   information states of one trajectory
  Theta_t = [Theta_Z | Theta_u] : [nz, nZ + nu]  ARMA coefficients at step t,
          dz_{t+1} = Theta_Z dZ_t + Theta_u du_t
          with Theta_Z = [alpha_1 ... alpha_q | beta_2 ... beta_q] and Theta_u = beta_1
  A_t : [nZ, nZ],  B_t : [nZ, nu]   dZ_{t+1} = A_t dZ_t + B_t du_t

History before t = 0 (our choice, documented in docs/algorithm.md): the system
rests at its start state with zero control, so z_{-k} = z_0 and u_{-k} = 0. Every
rollout shares that history, its deviations are exactly zero, and the controls
u_0 ... u_{q-2} are optimised like every other (the least-squares fit gives the
zero columns zero weight).
"""

from __future__ import annotations

import jax.numpy as jnp


def info_dim(nz: int, nu: int, q: int) -> int:
    """Size nZ of the information state."""
    return q * nz + (q - 1) * nu


def n_regressors(nz: int, nu: int, q: int) -> int:
    """Columns of the least-squares fit: nZ + nu = q (nz + nu)."""
    return q * (nz + nu)


def initial_info_state(z0: jnp.ndarray, nu: int, q: int) -> jnp.ndarray:
    """Z_0 built from the rest history: q copies of z_0 and q-1 zero controls."""
    return jnp.concatenate([jnp.tile(z0, q), jnp.zeros((q - 1) * nu, z0.dtype)])


def shift(Z: jnp.ndarray, z_next: jnp.ndarray, u: jnp.ndarray, nz: int, nu: int, q: int) -> jnp.ndarray:
    """Z_{t+1} from Z_t, the new observation z_{t+1} and the applied control u_t."""
    z_block = jnp.concatenate([z_next, Z[: (q - 1) * nz]])
    if q == 1:
        return z_block
    u_old = Z[q * nz : q * nz + (q - 2) * nu]
    return jnp.concatenate([z_block, u, u_old])


def info_states(z: jnp.ndarray, u: jnp.ndarray, q: int) -> jnp.ndarray:
    """All information states Z [T+1, nZ] of a trajectory (z [T+1, nz], u [T, nu]).

    Vectorised: pads the rest history in front, then stacks shifted copies.
    """
    T1, nz = z.shape
    nu = u.shape[1]
    z_pad = jnp.concatenate([jnp.broadcast_to(z[0], (q - 1, nz)), z], axis=0)  # index t + q - 1
    u_pad = jnp.concatenate([jnp.zeros((q, nu), u.dtype), u], axis=0)  # u_{t} at index t + q
    blocks = [z_pad[q - 1 - i : q - 1 - i + T1] for i in range(q)]  # z_{t-i}
    blocks += [u_pad[q - i : q - i + T1] for i in range(1, q)]  # u_{t-i}
    return jnp.concatenate(blocks, axis=1)


def companion(theta: jnp.ndarray, nz: int, nu: int, q: int) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Assemble (A_t, B_t) of Eq. (c4tab) from ARMA coefficients theta [nz, nZ + nu]."""
    nZ = info_dim(nz, nu, q)
    theta_Z, theta_u = theta[:, :nZ], theta[:, nZ:]
    A = jnp.zeros((nZ, nZ), theta.dtype).at[:nz].set(theta_Z)
    B = jnp.zeros((nZ, nu), theta.dtype).at[:nz].set(theta_u)
    if q > 1:
        # older observations move down one slot: z_{t-i} -> slot i+1
        A = A.at[nz : q * nz, : (q - 1) * nz].set(jnp.eye((q - 1) * nz, dtype=theta.dtype))
        # the control just applied enters the first control slot
        B = B.at[q * nz : q * nz + nu].set(jnp.eye(nu, dtype=theta.dtype))
        # older controls move down one slot
        if q > 2:
            A = A.at[q * nz + nu :, q * nz : q * nz + (q - 2) * nu].set(jnp.eye((q - 2) * nu, dtype=theta.dtype))
    return A, B


def observation_selector(nz: int, nu: int, q: int) -> jnp.ndarray:
    """S [nz, nZ] with z_t = S Z_t (the cost acts on the newest observation)."""
    return jnp.eye(nz, info_dim(nz, nu, q))
