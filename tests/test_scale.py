"""Scale: chunked sysid batches and sharding over several devices.

The speed and memory figures are in benchmarks (``podilqr bench``,
benchmarks/journal.md); here: chunking does not change the result, and a solve
sharded over 4 (virtual CPU) devices gives the same result as on one.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import sharded_solve

import podilqr_jax as pj
from podilqr_jax.identify.info_state import info_dim
from podilqr_jax.sim.rollout import open_loop_policy, perturbation_rollouts

HORIZON = 8


def _sysid(env, n_s, chunk, n_avg=1, noisy=False):
    dims, q = env.dims, 2
    policy = open_loop_policy(jnp.zeros((HORIZON, dims.nu)), info_dim(dims.nz, dims.nu, q))
    key, sigma = jax.random.PRNGKey(3), jnp.asarray(0.1)
    return perturbation_rollouts(dims, q, n_s, env.data, policy, key, sigma, n_avg=n_avg, noisy=noisy, chunk=chunk)


def test_chunked_sysid_batch_equals_one_batch():
    env = pj.make_task("pendulum-partial", horizon=HORIZON)
    whole = _sysid(env, 20, None)
    for chunk in (7, 20, 64):  # a remainder chunk, exactly one chunk, no chunking
        part = _sysid(env, 20, chunk)
        # Bit-identical here, but a batch of 7 compiles to other code than one of 20, which another
        # CPU may round differently: equal to round-off (the tolerance of test_line_search_chunks.py).
        np.testing.assert_allclose(part.z, whole.z, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(part.u, whole.u, rtol=1e-12, atol=1e-14)


def test_chunked_noisy_batch_does_not_depend_on_the_chunk_size():
    env = pj.make_task("pendulum-partial", horizon=HORIZON, noise="paper")
    a = _sysid(env, 12, 4, n_avg=2, noisy=True)  # 2 sequences per chunk
    b = _sysid(env, 12, 10, n_avg=2, noisy=True)  # 5 per chunk, a remainder of 2
    np.testing.assert_allclose(a.z, b.z, rtol=0, atol=1e-13)
    assert a.z.shape == (12, HORIZON + 1, 1)
    assert np.std(np.asarray(a.z[:, -1])) > 0  # noise and perturbations did act


def test_solve_with_a_small_chunk_matches_the_default():
    env = pj.make_task("pendulum-full", horizon=HORIZON)
    cfg = pj.default_config(env, max_iterations=5, sigma=1e-1)
    whole = pj.solve(env, cfg)
    chunked = pj.solve(env, cfg.replace(rollout_chunk=7))
    # The same rollouts, but XLA may order a batched product differently for a
    # batch of 7 than of 40 (here they are bit-identical; another CPU need not
    # be): round-off, which the fit amplifies by 1 / sigma (at the task's
    # sigma = 1e-5 the histories part at 1e-11 relative after two iterations
    # and 1e-5 after three). A change of sigma by 1 .. 4.5 ulp, a stand-in for
    # other rounding, moved this history by up to 1.2e-9 at sigma = 1e-2 (too
    # close to the bound) and by <= 7.9e-12 at sigma = 1e-1, hence 1e-1.
    np.testing.assert_allclose(chunked.cost_history, whole.cost_history, rtol=1e-9)


def test_memory_budget_sets_the_chunk():
    cfg = pj.SolverConfig(variant="averaged", n_avg=4, memory_budget_mb=1.0)
    assert cfg.resolved_chunk(10_000) == 104  # 1 MiB / 10 kB = 104.8 -> whole groups of 4
    assert cfg.replace(rollout_chunk=9).resolved_chunk(10_000) == 9
    with pytest.raises(pj.ConfigError, match="`memory_budget_mb` must be > 0"):
        pj.SolverConfig(memory_budget_mb=0).validate(pj.make_task("pendulum-full"))


_SHARDED_RUN = (
    "import json\nimport jax\nimport podilqr_jax as pj\nimport sharded_solve\n"
    "from podilqr_jax.sim.rollout import batch_sharding\n"
    + sharded_solve.SOLVE
    + "sharding = batch_sharding(sharded_solve.BATCH)\n"
    "print(json.dumps({'devices': jax.device_count(), "
    "'sharded_over': 0 if sharding is None else len(sharding.device_set), **sharded_solve.summary(r)}))\n"
)


def _run_four_devices() -> dict:
    env = dict(os.environ)
    env["XLA_FLAGS"] = "--xla_force_host_platform_device_count=4"
    env["JAX_PLATFORMS"] = "cpu"
    env = sharded_solve.child_environment(env)
    out = subprocess.run(
        [sys.executable, "-c", _SHARDED_RUN], env=env, capture_output=True, text=True, timeout=600, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_sharded_over_four_devices_gives_the_same_result():
    """Same seed, same result on 1 and on 4 devices, to round-off: each device
    runs a quarter of the batch, and XLA's CPU code for a batch of 4 rollouts
    orders some floating-point operations differently than for 16 (measured:
    3e-13 relative on the cost history), as with chunking above. A 1-ulp
    change of sigma moves the same histories by 2.9e-13 (K: 4.7e-13): other
    rounding stays far inside 1e-9."""
    one, four = sharded_solve.one_device(), _run_four_devices()
    assert four["devices"] == 4 and four["sharded_over"] == 4
    for key in ("cost", "true", "K", "controls"):
        a, b = np.asarray(four[key]), np.asarray(one[key])
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * np.max(np.abs(b)), err_msg=key)


def test_bench_cli_refuses_unknown_tasks(capsys):
    from podilqr_jax.cli import main

    assert main(["bench", "--tasks", "rocket-full"]) == 2
    assert "--tasks takes a comma-separated subset" in capsys.readouterr().err
