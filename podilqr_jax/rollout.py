"""Batched closed-loop rollouts through MJX.

One rollout applies, at every control step t,

  u_t = u_bar_t + offset_t + K_t (Z_t - Z_bar_t) + du_t

where Z_t is the information state built online from the rollout's own
observations and applied controls (see ``info_state``). Sysid rollouts use
``offset = 0`` and ``du ~ N(0, sigma^2 I)``; line-search rollouts use
``offset = alpha k`` and ``du = 0``; with ``K = 0`` the rollout is open loop.

A batch is one ``vmap`` over the leading axis of whichever of ``offset`` and
``du`` carry one; nothing loops over rollouts in Python, so the
batch axis can be sharded across devices.

Shapes: u_bar [T, nu], Z_bar [T, nZ], K [T, nu, nZ]; per rollout z [T+1, nz],
u [T, nu] and, when recorded, x = [qpos, qvel] [T+1, nx].
"""

from __future__ import annotations

import functools
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
from mujoco import mjx

from .env import EnvData, EnvDims
from .info_state import initial_info_state, shift


class Policy(NamedTuple):
    """Nominal controls with affine feedback on the information state."""

    u_bar: jnp.ndarray  # [T, nu]
    Z_bar: jnp.ndarray  # [T, nZ]
    K: jnp.ndarray  # [T, nu, nZ]


class Trajectory(NamedTuple):
    """A (batch of) rollout(s)."""

    z: jnp.ndarray  # [..., T+1, nz] observations (as measured)
    u: jnp.ndarray  # [..., T, nu] applied controls
    x: Optional[jnp.ndarray]  # [..., T+1, nx] states, when recorded


def open_loop_policy(u_bar: jnp.ndarray, nZ: int) -> Policy:
    """A policy with no feedback: u_t = u_bar_t."""
    T, nu = u_bar.shape
    return Policy(u_bar, jnp.zeros((T, nZ), u_bar.dtype), jnp.zeros((T, nu, nZ), u_bar.dtype))


def physics_step(dims: EnvDims, model, d, u: jnp.ndarray):
    """One control step: hold ``u`` for ``dims.substeps`` MuJoCo steps."""
    d = d.replace(ctrl=u)
    return jax.lax.fori_loop(0, dims.substeps, lambda _, dd: mjx.step(model, dd), d)


def state_of(d) -> jnp.ndarray:
    return jnp.concatenate([d.qpos, d.qvel])


def with_state(dims: EnvDims, d, x: jnp.ndarray):
    return d.replace(qpos=x[: dims.nq], qvel=x[dims.nq :])


def _rollout_one(dims: EnvDims, q: int, data: EnvData, policy: Policy, offset, du, record_state: bool) -> Trajectory:
    model = data.model
    d = with_state(dims, mjx.make_data(model), data.x0)
    z0 = data.C @ data.x0
    Z0 = initial_info_state(z0, dims.nu, q)

    def step(carry, inp):
        d, Z = carry
        u_bar_t, Z_bar_t, K_t, offset_t, du_t = inp
        u = u_bar_t + offset_t + K_t @ (Z - Z_bar_t) + du_t
        d = physics_step(dims, model, d, u)
        x = state_of(d)
        z = data.C @ x
        Z = shift(Z, z, u, dims.nz, dims.nu, q)
        return (d, Z), (z, u, x if record_state else None)

    T = dims.horizon
    offset = jnp.broadcast_to(offset, (T, dims.nu))
    du = jnp.broadcast_to(du, (T, dims.nu))
    _, (z, u, x) = jax.lax.scan(step, (d, Z0), (policy.u_bar, policy.Z_bar, policy.K, offset, du))
    z = jnp.concatenate([z0[None], z])
    if record_state:
        x = jnp.concatenate([data.x0[None], x])
    return Trajectory(z, u, x)


def simulate(
    dims: EnvDims,
    q: int,
    data: EnvData,
    policy: Policy,
    offset: jnp.ndarray,
    du: jnp.ndarray,
    record_state: bool = False,
) -> Trajectory:
    """A batch of rollouts (traceable; call it inside a jitted function).

    ``offset`` and ``du`` are each either shared, [T, nu], or per rollout,
    [B, T, nu]; the batch size B is taken from whichever is batched.
    """
    in_offset = 0 if offset.ndim == 3 else None
    in_du = 0 if du.ndim == 3 else None
    if in_offset is None and in_du is None:
        return _rollout_one(dims, q, data, policy, offset, du, record_state)
    one = functools.partial(_rollout_one, dims, q, data, policy, record_state=record_state)
    return jax.vmap(one, in_axes=(in_offset, in_du))(offset, du)


rollout_batch = jax.jit(simulate, static_argnames=("dims", "q", "record_state"))
rollout_batch.__doc__ = """Jitted :func:`simulate`: a batch of rollouts for given perturbations ``du``
[B, T, nu] (and/or offsets), returning observations z [B, T+1, nz] and applied
controls u [B, T, nu] (and states x when ``record_state``)."""


@functools.partial(jax.jit, static_argnames=("dims", "q", "n_s"))
def perturbation_rollouts(
    dims: EnvDims, q: int, n_s: int, data: EnvData, policy: Policy, key: jax.Array, sigma: jnp.ndarray
) -> Trajectory:
    """The n_s sysid rollouts: u = u_bar + K dZ + du, du ~ N(0, sigma^2 I)."""
    du = sigma * jax.random.normal(key, (n_s, dims.horizon, dims.nu), dtype=policy.u_bar.dtype)
    zero = jnp.zeros((dims.horizon, dims.nu), policy.u_bar.dtype)
    return simulate(dims, q, data, policy, zero, du)
