"""The learnt controller against the exact one (issue 14, items 5 and 6).

The nominal can be exact while the feedback gains are wrong: in the first steps
the sysid perturbations excite only nu (t + 1) directions of the information
state, and a fit that keeps the rest reads slopes out of the curvature there.
``SolverConfig.cap_rank`` (default) fits only the excited directions
(``sysid.excited_rank``); docs/results.md has the bundled tasks
(``python benchmarks/controller_quality.py``). On the small problems here, over
PRNG keys 1-4 (64 episodes each), closed-loop cost of the learnt policy over the
model-based one, divided by the nominal costs' ratio:

- pendulum-partial, horizon 15, process noise 2e-3, exact measurements:
  1.0001-1.0002 (1.0014-1.0018 with cap_rank=False);
- cartpole-partial, horizon 20, 100 iterations: 0.9999-1.0013 (13.3-179 with
  cap_rank=False: ||K_1|| in the thousands).

We require 1.02 (the issue's bound for partial observation) and, as the
control, more than 5 without the cap.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax.control.episodes import EpisodeNoise, run_episodes
from podilqr_jax.identify.sysid import excited_rank

EPISODES = 64
PARTIAL_BOUND = 1.02


def _process_noise(env) -> EpisodeNoise:
    nx, nu = env.dims.nx, env.dims.nu
    z = jnp.zeros
    return EpisodeNoise(z(nx), jnp.full(nx, 2e-3), z(nx), z(nu), env.data.u_low, env.data.u_high)


def _gain_quality(env, reference, cap_rank: bool) -> float:
    """(closed-loop learnt / closed-loop exact) / (nominal learnt / nominal exact)."""
    learnt = pj.solve(env, pj.default_config(env, cap_rank=cap_rank, max_iterations=100))
    levels = _process_noise(env)
    costs = []
    for policy in (pj.FeedbackPolicy.from_result(reference), learnt.policy()):
        measured = env.dims.nx if policy.measures == "state" else env.dims.nz
        run = run_episodes(
            env.dims, env.data, policy, jax.random.PRNGKey(1), levels._replace(v=jnp.zeros(measured)), EPISODES
        )
        costs.append(float(np.mean(run.cost)))
    return (costs[1] / costs[0]) / (learnt.final_cost / reference.final_cost)


def test_excited_rank_counts_the_perturbations_that_acted():
    dims = pj.make_task("cartpole-partial", horizon=8).dims  # nz 2, nu 1, nv 2; q = 2: 6 regressors
    assert excited_rank(dims, 2).tolist() == [1, 2, 3, 4, 5, 6, 6, 6]
    dims = pj.make_task("pendulum-full", horizon=4).dims  # q = 1: 3 regressors
    assert excited_rank(dims, 1).tolist() == [1, 2, 3, 3]


@pytest.mark.parametrize("task, horizon", [("pendulum-partial", 15), ("cartpole-partial", 20)])
def test_learnt_gains_control_as_well_as_the_exact_ones(task, horizon):
    env = pj.make_task(task, horizon=horizon)
    reference = pj.solve_model_based(env)
    quality = _gain_quality(env, reference, cap_rank=True)
    assert quality < PARTIAL_BOUND, f"{task}: learnt closed loop / exact = {quality:.4f} x the nominal ratio"
    if task == "cartpole-partial":
        uncapped = _gain_quality(env, reference, cap_rank=False)
        assert uncapped > 5, f"without cap_rank the early gains were expected wrong; got {uncapped:.4f}"


def test_mirrored_solve_counts_pairs_and_chunks_alike():
    env = pj.make_task("pendulum-full", horizon=10)
    # At a fixed sigma the chunked batch gives the whole batch's costs bit for bit. With the adaptive
    # scale the second iteration runs at sigma = 1e-4, where the two XLA programs agree to 1e-12
    # (round-off) instead; the accounting and the chunking are what this checks.
    cfg = pj.default_config(env, mirrored=True, n_s=8, max_iterations=2, adapt_sigma=False)
    whole = pj.solve(env, cfg)
    single = pj.solve(env, cfg.replace(mirrored=False))
    assert whole.rollouts - single.rollouts == whole.iterations * 8  # each of the 8 sequences also as -du
    chunked = pj.solve(env, cfg.replace(rollout_chunk=6))
    np.testing.assert_allclose(chunked.cost_history, whole.cost_history, rtol=1e-12)
    with pytest.raises(pj.ConfigError, match="mirrored"):
        pj.solve(env, cfg.replace(mirrored="yes"))
