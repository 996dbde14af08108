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
With ``paired`` (``SolverConfig.paired_line_search``) every candidate runs on
the same ``n_fwd`` noise draws and is judged against that alpha = 0
candidate instead of the nominal's earlier cost: a paired comparison, in
which the noise both share cancels from the difference of their costs.

Memory: a batch larger than ``chunk`` rollouts (the solver's memory budget,
``SolverConfig.resolved_chunk``) runs as a ``lax.map`` over chunks
(``_chunked_candidates``): whole candidates per chunk when a candidate's
``n_fwd`` rollouts fit in one, else each candidate in sub-chunks of ``chunk``
rollouts whose sums are accumulated. The noise is drawn for the whole batch
as without chunks (a small share of a rollout's memory: its inputs, not its
MJX data), so the chunked batch runs the same rollouts and gives the same
result to round-off.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp

from ..compilation.stages import stage
from ..identify.info_state import info_states
from ..sim.rollout import Policy, Trajectory, average_repeats, shard_batch, simulate
from ..task.env import EnvData, EnvDims
from ..task.noise import Disturbance, sample
from .cost import batch_costs


class LineSearchResult(NamedTuple):
    accepted: jnp.ndarray  # bool
    alpha: jnp.ndarray  # chosen step (the smallest tried when none accepted)
    cost: jnp.ndarray  # cost of the chosen candidate
    trajectory: Trajectory  # chosen candidate's rollout (z, u, x)
    Z: jnp.ndarray  # [T+1, nZ] chosen candidate's information states
    costs: jnp.ndarray  # [n_alphas] every candidate's cost
    expected: jnp.ndarray  # [n_alphas] predicted decrease (positive is good)
    n_diverged: jnp.ndarray  # int: candidates with a non-finite rollout or cost (never accepted)


class Search(NamedTuple):
    """How every line search of a solve runs, fixed before its first iteration
    (a static argument: a new one compiles a new program)."""

    dims: EnvDims
    q: int
    n_fwd: int = 1  # rollouts per candidate; their mean is the candidate's trajectory
    noisy: bool = False  # noisy rollouts (the task's ``Disturbance``)
    chunk: Optional[int] = None  # at most this many rollouts at once (``ExecutionPlan.ls_chunk``); None: one batch
    paired: bool = False  # under noise: one noise draw for every candidate, each judged against alpha = 0's cost


class Candidates(NamedTuple):
    """The step sizes tried (descending; alpha = 0 last under noise) and the
    acceptance ratio, on the device."""

    alphas: jnp.ndarray  # [n_alphas]
    accept_ratio: jnp.ndarray


class Step(NamedTuple):
    """A step proposed about a nominal of cost ``cost0``: feed-forward ``k``
    [T, nu] and the predicted decrease -(alpha dV1 + alpha^2 dV2). With ``k``,
    ``dV1`` and ``dV2`` zero nothing is predicted and every candidate is the
    policy as it is: a measurement (the driver's ``Context.hold``)."""

    k: jnp.ndarray
    cost0: jnp.ndarray
    dV1: jnp.ndarray
    dV2: jnp.ndarray


@stage(static_argnames=("search",), outputs=(LineSearchResult, Trajectory))
def line_search(
    search: Search, data: EnvData, policy: Policy, step: Step, candidates: Candidates, key: jax.Array
) -> LineSearchResult:
    dims, q, n_fwd = search.dims, search.q, search.n_fwd
    alphas = candidates.alphas
    batch = alphas.shape[0] * n_fwd
    candidate_offsets = alphas[:, None, None] * step.k[None]
    no_perturbation = jnp.zeros((dims.horizon, dims.nu), step.k.dtype)
    paired = search.noisy and search.paired
    noise = None
    if paired:  # the candidates' common draws, candidate-major as the batch is
        draws = sample(key, data.noise, n_fwd, dims.horizon)
        noise = jax.tree_util.tree_map(lambda a: jnp.tile(a, (alphas.shape[0],) + (1,) * (a.ndim - 1)), draws)
    elif search.noisy:
        noise = sample(key, data.noise, batch, dims.horizon)
    if search.chunk is not None and batch > search.chunk:
        traj = _chunked_candidates(dims, q, data, policy, candidate_offsets, noise, n_fwd, search.chunk)
    else:
        offsets = jnp.repeat(candidate_offsets, n_fwd, axis=0) if n_fwd > 1 else candidate_offsets
        offsets, noise = shard_batch((offsets, noise), batch, dims)
        traj = simulate(dims, q, data, policy, offsets, no_perturbation, record_state=True, noise=noise)
        traj = average_repeats(traj, n_fwd)
    return _choose(q, data, traj, alphas, step, candidates.accept_ratio, paired)


def _choose(q, data, traj: Trajectory, alphas, step: Step, accept_ratio, paired: bool = False) -> LineSearchResult:
    """The largest accepted candidate of ``traj`` [n_cand, ...] (each candidate's mean rollout);
    ``paired``: judged against the last candidate (alpha = 0 on the same noise) instead of ``step.cost0``."""
    cost, finite = batch_costs(traj.z, traj.u, data)
    cost0 = cost[-1] if paired else step.cost0
    expected = -(alphas * step.dV1 + alphas**2 * step.dV2)
    ratio = (cost0 - cost) / jnp.where(expected > 0, expected, jnp.inf)
    ok = finite & (cost < cost0) & (ratio > accept_ratio)
    accepted = jnp.any(ok)
    i = jnp.where(accepted, jnp.argmax(ok), alphas.shape[0] - 1)
    chosen = jax.tree_util.tree_map(lambda a: a[i], traj)
    Z = info_states(chosen.z, chosen.u, q)
    return LineSearchResult(accepted, alphas[i], cost[i], chosen, Z, cost, expected, jnp.sum(~finite))


def _chunked_candidates(
    dims, q, data, policy, offsets, noise: Optional[Disturbance], n_fwd: int, chunk: int
) -> Trajectory:
    """The candidates' mean rollouts [n_cand, ...], at most ``chunk`` rollouts at a time.

    ``offsets`` [n_cand, T, nu]; ``noise`` per rollout, candidate-major
    ([n_cand n_fwd, ...], as the unchunked batch has it) or None."""
    n_cand, T, nu = offsets.shape
    zero = jnp.zeros((T, nu), offsets.dtype)
    per_cand = (
        None if noise is None else jax.tree_util.tree_map(lambda a: a.reshape((n_cand, n_fwd) + a.shape[1:]), noise)
    )

    def rollouts(offset, noise_part, count):
        """``count`` rollouts of one candidate (noiseless: one, broadcast)."""
        if noise_part is None:
            one = simulate(dims, q, data, policy, offset, zero, record_state=True)
            return jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (count,) + a.shape), one)
        return simulate(dims, q, data, policy, jnp.broadcast_to(offset, (count, T, nu)), zero, True, noise_part)

    if n_fwd <= chunk:  # whole candidates per chunk

        def candidate(args):
            offset, noise_c = args
            return average_repeats(rollouts(offset, noise_c, n_fwd), n_fwd)

        traj = jax.lax.map(candidate, (offsets, per_cand), batch_size=max(1, chunk // n_fwd))
        return jax.tree_util.tree_map(lambda a: a[:, 0] if a is not None else None, traj)

    # A candidate's n_fwd rollouts in sub-chunks of ``chunk`` (the last one
    # padded with zero noise and left out of the sum).
    n_sub = -(-n_fwd // chunk)
    pad = n_sub * chunk - n_fwd
    weights = (jnp.arange(n_sub * chunk) < n_fwd).astype(offsets.dtype).reshape(n_sub, chunk)

    def candidate(args):
        offset, noise_c = args
        if noise_c is not None:
            noise_c = jax.tree_util.tree_map(
                lambda a: jnp.pad(a, [(0, pad)] + [(0, 0)] * (a.ndim - 1)).reshape((n_sub, chunk) + a.shape[1:]),
                noise_c,
            )

        def sub(total, part):
            w, noise_s = part
            traj = rollouts(offset, noise_s, chunk)
            return jax.tree_util.tree_map(lambda acc, a: acc + jnp.tensordot(w, a, axes=1), total, traj), None

        init = Trajectory(
            jnp.zeros((T + 1, dims.nz), offsets.dtype),
            jnp.zeros((T, nu), offsets.dtype),
            jnp.zeros((T + 1, dims.nx), offsets.dtype),
        )
        total, _ = jax.lax.scan(sub, init, (weights, noise_c))
        return jax.tree_util.tree_map(lambda a: a / n_fwd, total)

    return jax.lax.map(candidate, (offsets, per_cand))
