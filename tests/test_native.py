"""The native engine (MuJoCo's C step batched by ``mujoco.rollout``) against MJX, and its settings.

Tolerances: on a model without constraints the two engines run the same
floating-point operations up to reassociation, so states agree to round-off
amplified over the horizon (measured 5e-15 on the cart-pole over 30 control
steps of random controls); ``ROUND_OFF`` leaves three orders of margin. A
contact model agrees to the constraint solver's tolerance (its warm start
differs, sim/native.py), so it is compared by cost, not state.
"""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax.compilation import stages
from podilqr_jax.errors import ConfigError
from podilqr_jax.ilqr.config import CONTACT_RESTARTS
from podilqr_jax.sim import engines
from podilqr_jax.sim.native import NativeModel, native_model
from podilqr_jax.sim.rollout import Policy, observations_of, open_loop_policy, rollout_batch
from podilqr_jax.task.noise import sample
from podilqr_jax.task.taskfile import load_task

ROUND_OFF = 1e-11  # relative to the largest state entry
SOLVE_RTOL = 1e-8  # final costs of the same solve on the two engines (round-off through 30-60 fits)
HOPPER = "examples/tasks/third_party/gym_hopper_balance.toml"


def _native(env):
    return env.on_engine(native_model(env.mj_model))


def _random_batch(env, batch=8, scale=0.5, seed=0):
    T, nu = env.dims.horizon, env.dims.nu
    du = scale * jax.random.normal(jax.random.PRNGKey(seed), (batch, T, nu))
    return open_loop_policy(jnp.zeros((T, nu)), env.dims.nz), jnp.zeros((T, nu)), du


@pytest.mark.parametrize("task", ["cartpole-full", "doublependulum-partial"])
def test_native_rollouts_equal_mjx_to_round_off(task):
    env = pj.make_task(task)
    policy, zero, du = _random_batch(env)
    mjx = rollout_batch(env.dims, 1, env.data, policy, zero, du, record_state=True)
    nat = _native(env)
    native = rollout_batch(nat.dims, 1, nat.data, policy, zero, du, record_state=True)
    scale = float(np.abs(mjx.x).max())
    assert np.abs(np.asarray(native.x) - np.asarray(mjx.x)).max() <= ROUND_OFF * scale
    assert np.abs(np.asarray(native.z) - np.asarray(mjx.z)).max() <= ROUND_OFF * scale
    np.testing.assert_array_equal(native.u, mjx.u)


def test_native_rollouts_take_the_same_noise_draws_and_feedback():
    """Initial-state, process and measurement noise (the one sampler's draws)
    and information-state feedback reach the native step as they reach MJX's."""
    env = pj.make_task("cartpole-partial").replace(noise={"initial": 0.01, "process": 0.001, "measurement": 0.001})
    T, nu, nz = env.dims.horizon, env.dims.nu, env.dims.nz
    nZ = 2 * nz + nu
    K = 0.1 * jax.random.normal(jax.random.PRNGKey(3), (T, nu, nZ))
    policy = Policy(jnp.zeros((T, nu)), jnp.zeros((T, nZ)), K)
    noise = sample(jax.random.PRNGKey(4), env.data.noise, 6, T)
    du = 0.1 * jax.random.normal(jax.random.PRNGKey(5), (6, T, nu))
    zero = jnp.zeros((T, nu))
    mjx = rollout_batch(env.dims, 2, env.data, policy, zero, du, record_state=True, noise=noise)
    nat = _native(env)
    native = rollout_batch(nat.dims, 2, nat.data, policy, zero, du, record_state=True, noise=noise)
    scale = float(np.abs(mjx.x).max())
    assert np.abs(np.asarray(native.x) - np.asarray(mjx.x)).max() <= ROUND_OFF * scale
    assert np.abs(np.asarray(native.u) - np.asarray(mjx.u)).max() <= ROUND_OFF * scale


def test_native_sensors_are_read_at_the_state_after_the_step():
    env = load_task("examples/tasks/reacher.toml")
    assert env.dims.sensors
    xs = np.asarray(rollout_batch(env.dims, 1, env.data, *_random_batch(env, 2), record_state=True).x[0])
    nat = _native(env)
    got = np.asarray(observations_of(nat.dims, nat.data, jnp.asarray(xs)))
    want = np.asarray(observations_of(env.dims, env.data, jnp.asarray(xs)))
    np.testing.assert_allclose(got, want, rtol=0, atol=ROUND_OFF * np.abs(want).max())


def test_a_batch_is_the_same_on_one_thread_and_on_several():
    """Every control step starts the constraint solver cold, so which thread ran a rollout leaves no trace."""
    env = load_task(HOPPER)
    rng = np.random.default_rng(0)
    one, two = NativeModel(env.mj_model, threads=1), NativeModel(env.mj_model, threads=2)
    state = np.tile(one.template, (6, 1))
    state[:, 2] = 1.22 + 0.01 * rng.standard_normal(6)  # rootz: near the floor, some in contact
    ctrl = rng.uniform(-1, 1, (6, env.dims.nu))
    for _ in range(5):
        a, b = one.step(state, ctrl, 4), two.step(state, ctrl, 4)
        np.testing.assert_array_equal(a, b)
        state = a


def test_pod_ilqr_on_the_native_engine_reaches_the_mjx_solve():
    env = pj.make_task("pendulum-full")
    cfg = pj.default_config(env, max_iterations=60)
    mjx = pj.solve(env, cfg.replace(engine="mjx"))
    native = pj.solve(env, cfg.replace(engine="native"))
    assert (mjx.engine, native.engine) == ("mjx", "native")
    assert native.status == mjx.status
    assert abs(native.final_cost - mjx.final_cost) <= SOLVE_RTOL * mjx.final_cost
    assert "on native" in native.summary()
    assert native.to_dict()["engine"] == "native"


def test_the_model_based_reference_on_the_native_engine_takes_central_differences():
    env = pj.make_task("pendulum-full")
    cfg = pj.default_config(env)
    exact = pj.solve_model_based(env, cfg.replace(engine="mjx"))
    native = pj.solve_model_based(env, cfg.replace(engine="native"))
    assert exact.converged and native.converged and native.engine == "native"
    assert abs(native.final_cost - exact.final_cost) <= 1e-6 * exact.final_cost
    # jacobian="exact" needs MJX's derivatives: auto keeps the reference there
    assert pj.solve_model_based(env, cfg.replace(max_iterations=1, jacobian="exact")).engine == "mjx"


def test_a_contact_model_solves_on_the_native_engine_without_exporting_stages():
    env = load_task(HOPPER)
    assert engines.auto_engine(env) == "native"
    refused = dict(stages.fallbacks)
    result = pj.solve(env, pj.default_config(env, max_iterations=3))
    assert result.engine == "native"
    # a contact-rich model: several starts by default (SolverConfig.resolved_restarts)
    assert len(result.starts) == CONTACT_RESTARTS and result.config["restarts"] == CONTACT_RESTARTS
    assert np.isfinite(result.final_cost) and result.final_cost < result.cost_history[0]
    # a stage that runs the C engine is never offered to jax.export (host callbacks cannot be exported)
    assert stages.fallbacks == refused
    assert result.recompiles_after_first == 0


def test_auto_keeps_the_small_smooth_models_on_mjx_and_picks_native_for_rk4_and_contacts():
    assert engines.auto_engine(pj.make_task("cartpole-partial")) == "mjx"
    assert engines.auto_engine(pj.make_task("doublependulum-full")) == "mjx"
    assert engines.auto_engine(load_task("examples/tasks/third_party/dmc_acrobot_swingup.toml")) == "native"  # RK4
    assert engines.auto_engine(load_task("examples/tasks/robots/chain5_curl.toml")) == "native"  # RK4, 5 links


def test_a_native_checkpoint_resumes_bit_for_bit(tmp_path):
    env = pj.make_task("cartpole-partial")
    cfg = pj.default_config(env, engine="native", max_iterations=6)
    whole = pj.solve(env, cfg)
    pj.solve(env, cfg.replace(max_iterations=3), checkpoint=tmp_path / "ck")
    resumed = pj.solve(env, cfg, resume=tmp_path / "ck")
    np.testing.assert_array_equal(resumed.controls, whole.controls)
    assert resumed.cost_history == whole.cost_history


@pytest.mark.parametrize(
    "settings, words",
    [
        ({"engine": "gpu"}, ["engine", "mjx", "native"]),
        ({"engine": "native", "impl": "warp"}, ["impl", "native"]),
    ],
)
def test_engine_settings_are_checked_before_anything_runs(settings, words):
    env = pj.make_task("pendulum-full")
    with pytest.raises(ConfigError) as err:
        pj.solve(env, pj.default_config(env, **settings))
    assert all(w in str(err.value) for w in words)


def test_exact_jacobians_on_the_native_engine_are_refused_with_the_fix():
    env = pj.make_task("pendulum-full")
    with pytest.raises(ConfigError, match="differences"):
        pj.solve_model_based(env, pj.default_config(env, engine="native", jacobian="exact"))


def test_the_cli_runs_a_solve_on_the_native_engine(tmp_path):
    from podilqr_jax.cli import main

    out = tmp_path / "r.json"
    rc = main(["solve", "pendulum-full", "--set", "engine=native", "--set", "max_iterations=3", "--no-plots",
               "--quiet", "--out", str(out)])  # fmt: skip
    assert rc == 0
    assert json.loads(out.read_text())["engine"] == "native"
