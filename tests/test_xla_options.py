"""The package's XLA compiler options (``xla_options``): applied to its top-level
MJX programs, never to nested calls, switchable, and the same numbers."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np

import podilqr_jax as pj
from podilqr_jax.compilation import xla_options
from podilqr_jax.identify.info_state import info_dim
from podilqr_jax.sim.rollout import open_loop_policy, rollout_batch


def _options_of(lowered) -> dict:
    return dict(lowered._lowering._compiler_options_kvs)


def _batch_args(env, batch=3):
    dims, data = env.dims, env.data
    policy = open_loop_policy(jnp.zeros((dims.horizon, dims.nu)), info_dim(dims.nz, dims.nu, 1))
    du = 0.1 * jax.random.normal(jax.random.PRNGKey(0), (batch, dims.horizon, dims.nu))
    return dims, data, policy, jnp.zeros((dims.horizon, dims.nu)), du


def test_top_level_programs_carry_the_options_and_nested_calls_run():
    env = pj.make_task("pendulum-full", horizon=4)
    dims, data, policy, zero, du = _batch_args(env)
    assert xla_options.options() == xla_options.COMPILER_OPTIONS
    lowered = rollout_batch.lower(dims, 1, data, policy, zero, du)
    assert _options_of(lowered) == xla_options.COMPILER_OPTIONS
    top = rollout_batch(dims, 1, data, policy, zero, du)
    # JAX refuses compiler options on a nested jit: inside another trace the plain jit runs
    nested = jax.jit(lambda d: rollout_batch(dims, 1, data, policy, zero, d).z)(du)
    np.testing.assert_allclose(np.asarray(nested), np.asarray(top.z), rtol=1e-12, atol=1e-12)


def test_the_options_change_the_compile_not_the_solve():
    """A short noiseless solve with the options (in this process) and with
    XLA's defaults (``PODILQR_XLA_DEFAULTS=1``, a fresh process) takes the same
    steps: the same iterations and costs to round-off."""
    solve = (
        "env = pj.make_task('cartpole-partial', horizon=12)\n"
        "r = pj.solve(env, pj.default_config(env, max_iterations=4))\n"
    )
    report = "{'options': xla_options.options(), 'costs': r.cost_history, 'K': r.K.ravel().tolist()}"
    ns = {"pj": pj, "xla_options": xla_options}
    exec(solve + f"out = {report}", ns)
    imports = "import json, podilqr_jax as pj\nfrom podilqr_jax.compilation import xla_options\n"
    child = f"{imports}{solve}print(json.dumps({report}))\n"
    env = dict(os.environ, PODILQR_XLA_DEFAULTS="1")  # the cache keys on the options: nothing is mixed
    out = subprocess.run([sys.executable, "-c", child], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    runs = {"0": ns["out"], "1": json.loads(out.stdout.strip().splitlines()[-1])}
    assert runs["0"]["options"] == xla_options.COMPILER_OPTIONS, "run without PODILQR_XLA_DEFAULTS set"
    assert runs["1"]["options"] == {}
    a, b = runs["0"], runs["1"]
    assert len(a["costs"]) == len(b["costs"]) == 5
    np.testing.assert_allclose(a["costs"], b["costs"], rtol=1e-9)
    np.testing.assert_allclose(a["K"], b["K"], rtol=1e-6, atol=1e-9)
