"""Forward pass with a batched line search.

Every candidate step size alpha_i (descending) is rolled out at once, as one
batch through MJX, with the closed-loop update

  u_t = u_bar_t + alpha_i k_t + K_t (Z_t - Z_bar_t).

A candidate is accepted only if its cost really decreased, J_i < J, and the
decrease is at least ``accept_ratio`` times the predicted decrease
-(alpha dV1 + alpha^2 dV2). The largest accepted alpha wins. With ``k = 0`` and
``K = 0`` every candidate is the open-loop rollout of u_bar, which is how the
driver measures the first nominal without compiling another function.

Under noise (``noisy``) every candidate is a noisy rollout, or the mean of
``n_fwd`` noisy rollouts (the averaged variant), one batch of
n_alphas x n_fwd; the driver then also passes alpha = 0 as the last candidate.
It can never be accepted (its predicted decrease is zero), so when nothing is
accepted the chosen candidate is a fresh measurement of the current policy:
that is how the driver re-measures a nominal whose cost was a lucky draw.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from .cost import batch_costs
from .env import EnvData, EnvDims
from .info_state import info_states
from .noise import sample_noise
from .rollout import Policy, Trajectory, average_repeats, shard_batch, simulate


class LineSearchResult(NamedTuple):
    accepted: jnp.ndarray  # bool
    alpha: jnp.ndarray  # chosen step (the smallest tried when none accepted)
    cost: jnp.ndarray  # cost of the chosen candidate
    trajectory: Trajectory  # chosen candidate's rollout (z, u, x)
    Z: jnp.ndarray  # [T+1, nZ] chosen candidate's information states
    costs: jnp.ndarray  # [n_alphas] every candidate's cost
    expected: jnp.ndarray  # [n_alphas] predicted decrease (positive is good)
    n_diverged: jnp.ndarray  # int: candidates with a non-finite rollout or cost (never accepted)


@functools.partial(jax.jit, static_argnames=("dims", "q", "n_fwd", "noisy"))
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
    key: jax.Array,
    n_fwd: int = 1,
    noisy: bool = False,
) -> LineSearchResult:
    offsets = alphas[:, None, None] * k[None]
    if n_fwd > 1:
        offsets = jnp.repeat(offsets, n_fwd, axis=0)
    no_perturbation = jnp.zeros((dims.horizon, dims.nu), k.dtype)
    noise = sample_noise(key, data.noise, offsets.shape[0], dims.horizon) if noisy else None
    offsets, noise = shard_batch((offsets, noise), offsets.shape[0])
    traj = simulate(dims, q, data, policy, offsets, no_perturbation, record_state=True, noise=noise)
    traj = average_repeats(traj, n_fwd)
    cost, finite = batch_costs(traj.z, traj.u, data)
    expected = -(alphas * dV1 + alphas**2 * dV2)
    ratio = (cost0 - cost) / jnp.where(expected > 0, expected, jnp.inf)
    ok = finite & (cost < cost0) & (ratio > accept_ratio)
    accepted = jnp.any(ok)
    i = jnp.where(accepted, jnp.argmax(ok), alphas.shape[0] - 1)
    chosen = jax.tree_util.tree_map(lambda a: a[i], traj)
    Z = info_states(chosen.z, chosen.u, q)
    return LineSearchResult(accepted, alphas[i], cost[i], chosen, Z, cost, expected, jnp.sum(~finite))
