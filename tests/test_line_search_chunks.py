"""The line search's batch in chunks (line_search._chunked_candidates) gives the
unchunked result: whole candidates per chunk, a candidate split in sub-chunks,
with and without noise; and the solver picks the chunk from the memory budget."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax.identify.info_state import info_dim
from podilqr_jax.ilqr.line_search import Candidates, Search, Step, line_search
from podilqr_jax.sim.rollout import Policy, bytes_per_rollout

HORIZON = 6
N_FWD = 5


def _search(env, chunk, noisy, n_fwd=N_FWD):
    dims, data = env.dims, env.data
    q = 1
    nZ = info_dim(dims.nz, dims.nu, q)
    rng = np.random.default_rng(0)
    policy = Policy(
        jnp.asarray(rng.normal(size=(HORIZON, dims.nu))),
        jnp.asarray(rng.normal(size=(HORIZON, nZ)) * 0.01),
        jnp.asarray(rng.normal(size=(HORIZON, dims.nu, nZ)) * 0.1),
    )
    k = jnp.asarray(rng.normal(size=(HORIZON, dims.nu)))
    alphas = jnp.asarray(np.append(0.5 ** np.arange(3), 0.0))
    step, candidates = Step(k, jnp.asarray(np.inf), -1.0, 0.0), Candidates(alphas, 1e-4)
    return line_search(Search(dims, q, n_fwd, noisy, chunk), data, policy, step, candidates, jax.random.PRNGKey(3))


@pytest.mark.parametrize("noisy", [True, False])
def test_chunked_line_search_equals_one_batch(noisy):
    env = pj.make_task("pendulum-full", horizon=HORIZON, noise="paper" if noisy else None)
    whole = _search(env, None, noisy)
    # 20 rollouts: 3 candidates per chunk of 15 (and a remainder of 1), and
    # sub-chunks of 2 rollouts (a candidate's 5 in 3, the last one padded).
    for chunk in (15, 2) if noisy else (2,):
        part = _search(env, chunk, noisy)
        np.testing.assert_allclose(part.costs, whole.costs, rtol=1e-12)
        np.testing.assert_allclose(part.trajectory.x, whole.trajectory.x, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(part.Z, whole.Z, rtol=1e-12, atol=1e-14)
        assert bool(part.accepted) == bool(whole.accepted) and float(part.alpha) == float(whole.alpha)
    if noisy:  # the noise did act: the candidates' means differ from a noiseless search
        quiet = _search(env.replace(noise=None), None, False)
        assert np.max(np.abs(np.asarray(quiet.costs - whole.costs))) > 1e-6


def test_solver_chunks_the_line_search_under_the_budget():
    env = pj.make_task("pendulum-full", horizon=HORIZON, noise="paper")
    cfg = pj.default_config(env, variant="averaged", n_s=4, n_avg=2, n_forward=8, n_alphas=3, max_iterations=3)
    # A budget of 12 line-search rollouts: its 4 x 8 run one candidate per
    # chunk, while the sysid batch (8 smaller rollouts) still runs at once
    # (a chunked sysid batch would draw other noise, see test_scale).
    per_rollout = bytes_per_rollout(env.dims, env.data, True, record_state=True)
    budget = cfg.replace(memory_budget_mb=12.5 * per_rollout / 2**20)
    assert budget.resolved_chunk(per_rollout, group=1) == 12
    assert budget.resolved_chunk(bytes_per_rollout(env.dims, env.data, True)) >= 4 * 2
    whole = pj.solve(env, cfg)
    chunked = pj.solve(env, budget)
    # The same draws: round-off only (the fit amplifies it by 1 / sigma, see test_scale).
    np.testing.assert_allclose(chunked.cost_history, whole.cost_history, rtol=1e-9)
    np.testing.assert_allclose(chunked.true_cost_history, whole.true_cost_history, rtol=1e-9)
    assert chunked.compiles_per_iteration[1:] == [0] * (chunked.iterations - 1)
