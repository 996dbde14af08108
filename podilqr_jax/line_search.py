"""Forward pass with a batched line search.

Every candidate step size alpha_i (descending) is rolled out at once, as one
batch through MJX, with the closed-loop update

  u_t = u_bar_t + alpha_i k_t + K_t (Z_t - Z_bar_t).

A candidate is accepted only if its cost really decreased, J_i < J, and the
decrease is at least ``accept_ratio`` times the predicted decrease
-(alpha dV1 + alpha^2 dV2). The largest accepted alpha wins. With ``k = 0`` and
``K = 0`` every candidate is the open-loop rollout of u_bar, which is how the
driver measures the first nominal without compiling another function.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from .cost import trajectory_cost
from .env import EnvData, EnvDims
from .info_state import info_states
from .rollout import Policy, Trajectory, simulate


class LineSearchResult(NamedTuple):
    accepted: jnp.ndarray  # bool
    alpha: jnp.ndarray  # chosen step (the smallest tried when none accepted)
    cost: jnp.ndarray  # cost of the chosen candidate
    trajectory: Trajectory  # chosen candidate's rollout (z, u, x)
    Z: jnp.ndarray  # [T+1, nZ] chosen candidate's information states
    costs: jnp.ndarray  # [n_alphas] every candidate's cost
    expected: jnp.ndarray  # [n_alphas] predicted decrease (positive is good)


@functools.partial(jax.jit, static_argnames=("dims", "q"))
def line_search(
    dims: EnvDims,
    q: int,
    data: EnvData,
    policy: Policy,
    k: jnp.ndarray,
    alphas: jnp.ndarray,
    cost0: jnp.ndarray,
    dV1: jnp.ndarray,
    dV2: jnp.ndarray,
    accept_ratio: jnp.ndarray,
) -> LineSearchResult:
    offsets = alphas[:, None, None] * k[None]
    no_perturbation = jnp.zeros((dims.horizon, dims.nu), k.dtype)
    traj = simulate(dims, q, data, policy, offsets, no_perturbation, record_state=True)
    cost = jax.vmap(trajectory_cost, in_axes=(0, 0, None, None, None, None))(
        traj.z, traj.u, data.z_target, data.Q, data.QT, data.R
    )
    finite = (
        jnp.isfinite(cost) & jnp.all(jnp.isfinite(traj.z), axis=(1, 2)) & jnp.all(jnp.isfinite(traj.u), axis=(1, 2))
    )
    cost = jnp.where(finite, cost, jnp.inf)
    expected = -(alphas * dV1 + alphas**2 * dV2)
    ratio = (cost0 - cost) / jnp.where(expected > 0, expected, jnp.inf)
    ok = finite & (cost < cost0) & (ratio > accept_ratio)
    accepted = jnp.any(ok)
    i = jnp.where(accepted, jnp.argmax(ok), alphas.shape[0] - 1)
    chosen = jax.tree_util.tree_map(lambda a: a[i], traj)
    Z = info_states(chosen.z, chosen.u, q)
    return LineSearchResult(accepted, alphas[i], cost[i], chosen, Z, cost, expected)
