"""Any MJCF model: sensor observations, control limits (box-DDP), divergent rollouts."""

import itertools
import math
import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax.identify.sysid import fit_information_model
from podilqr_jax.ilqr.backward import box_qp
from podilqr_jax.ilqr.line_search import Candidates, Search, Step, line_search
from podilqr_jax.sim.rollout import Policy, observations_of

PENDULUM = """
<mujoco model="sensed-pendulum">
  <option timestep="0.02" integrator="Euler"><flag contact="disable"/></option>
  <worldbody>
    <body name="pole">
      <joint name="hinge" type="hinge" axis="0 1 0" damping="0.01"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.5" size="0.02" mass="0"/>
      <geom type="sphere" pos="0 0 0.5" size="0.05" mass="0.5"/>
      <site name="tip" pos="0 0 0.5"/>
    </body>
  </worldbody>
  <actuator><motor name="torque" joint="hinge" {limits}/></actuator>
  <sensor>
    <jointpos name="angle" joint="hinge"/>
    <framepos name="tip_pos" objtype="site" objname="tip"/>
    <accelerometer name="acc" site="tip"/>
  </sensor>
</mujoco>
"""


def _write(tmp_path, limits='ctrllimited="false"', name="pendulum.xml"):
    path = tmp_path / name
    path.write_text(PENDULUM.format(limits=limits))
    return path


def _task(path, **kw):
    args = dict(
        substeps=5, horizon=12, x0={"qpos": [math.pi]}, Q=1.0, QT=100.0, R=2.0, solver_defaults=dict(sigma=1e-4)
    )
    args.update(kw)
    return pj.Env.from_xml(path, **args)


def test_joint_sensor_is_a_state_coordinate(tmp_path):
    env = _task(_write(tmp_path), observation={"sensors": ["angle"]}, target=[0.0])
    assert not env.dims.sensors
    np.testing.assert_array_equal(np.asarray(env.data.C), [[1.0, 0.0]])
    assert env.observation_labels == ("sensor:angle",)


def test_sensor_observations_match_native_mujoco(tmp_path):
    path = _write(tmp_path)
    env = _task(path, observation={"sensors": ["tip_pos"], "qvel": ["hinge"]}, target=[0.0, 0.0, 0.5, 0.0])
    assert env.dims.sensors and env.dims.nz == 4
    assert env.observation_labels == ("qvel:hinge", "sensor:tip_pos[0]", "sensor:tip_pos[1]", "sensor:tip_pos[2]")
    xs = np.array([[math.pi, 0.0], [0.3, -1.0], [-2.0, 4.0]])
    got = np.asarray(observations_of(env.dims, env.data, jnp.asarray(xs)))
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    for x, z in zip(xs, got, strict=True):
        d.qpos[:], d.qvel[:] = x[:1], x[1:]
        mujoco.mj_forward(m, d)
        np.testing.assert_allclose(z, np.concatenate([d.qvel, d.sensordata[1:4]]), rtol=1e-12, atol=1e-12)


def test_solve_on_a_tip_position_sensor(tmp_path):
    """Partially observed through a nonlinear sensor (the tip's position): the
    solve lowers the cost and its observations are the sensor's readings of
    the returned states."""
    path = _write(tmp_path)
    # Hanging straight down is a stationary point of a cost on the tip's
    # position (the height's derivative vanishes there): start off it.
    env = _task(path, observation={"sensors": ["tip_pos"]}, target=[0.0, 0.0, 0.5], x0={"qpos": [3.0]})
    r = pj.solve(env, pj.default_config(env, max_iterations=40, n_s=30))
    assert r.status == pj.Status.CONVERGED, r.summary()
    # Seeds 0-5 and x0 = 3 (1 +- 1e-12) all converged in 24 iterations to the same optimum:
    # final / first cost 0.5634, tip height 0.4358 (the margins are the optimum's, not noise).
    assert r.final_cost < 0.6 * r.cost_history[0]
    assert r.observations[-1, 2] > 0.4  # the tip ends high (1.2 s is too short to settle upright)
    m = mujoco.MjModel.from_xml_path(str(path))
    d = mujoco.MjData(m)
    for x, z in zip(r.states, r.observations, strict=True):
        d.qpos[:], d.qvel[:] = x[:1], x[1:]
        mujoco.mj_forward(m, d)
        np.testing.assert_allclose(z, d.sensordata[1:4], rtol=1e-9, atol=1e-12)
    with pytest.raises(pj.TaskError, match="model-based reference needs a cost on the state"):
        pj.solve_model_based(env)


@pytest.mark.parametrize(
    "observation, match",
    [
        ({"sensors": ["nope"]}, "Unknown sensor 'nope'.*'angle', 'tip_pos', 'acc'"),
        ({"sensors": ["acc"]}, "depends on accelerations"),
        ({"sensors": ["angle"], "qpos": ["hinge"]}, "twice"),
        ({"sensors": []}, "size 0"),
        ({"sensor": ["angle"]}, "unknown key"),
    ],
)
def test_bad_sensor_observations(tmp_path, observation, match):
    with pytest.raises(pj.TaskError, match=match):
        _task(_write(tmp_path), observation=observation)


def _box_qp_by_enumeration(H, g, lo, hi):
    """The box QP's minimiser by trying every active set (small n)."""
    n = len(g)
    best, best_f = None, np.inf
    for sets in itertools.product((0, 1, 2), repeat=n):  # 0 free, 1 lower, 2 upper
        x = np.where(np.array(sets) == 1, lo, np.where(np.array(sets) == 2, hi, 0.0))
        free = np.array(sets) == 0
        if free.any():
            x[free] = np.linalg.solve(H[np.ix_(free, free)], -(g[free] + H[np.ix_(free, ~free)] @ x[~free]))
        if np.all(x >= lo - 1e-12) and np.all(x <= hi + 1e-12):
            f = 0.5 * x @ H @ x + g @ x
            if f < best_f:
                best, best_f = x, f
    return best


@pytest.mark.parametrize("seed", range(6))
def test_box_qp_finds_the_constrained_minimiser(seed):
    rng = np.random.default_rng(seed)
    n = 3
    M = rng.normal(size=(n, n))
    H = M @ M.T + 0.1 * np.eye(n)
    g = 3 * rng.normal(size=n)
    lo, hi = -rng.uniform(0.1, 1, n), rng.uniform(0.1, 1, n)
    x, free, _ = box_qp(jnp.asarray(H), jnp.asarray(g), jnp.asarray(lo), jnp.asarray(hi))
    expected = _box_qp_by_enumeration(H, g, lo, hi)
    np.testing.assert_allclose(np.asarray(x), expected, atol=1e-9)
    np.testing.assert_array_equal(np.asarray(free), (expected > lo) & (expected < hi))


def test_control_limits_are_respected_and_reach_the_constrained_optimum(tmp_path):
    """ctrlrange +-1.5 N m is below the 2.45 N m that holds the pendulum level:
    the swing-up must pump. Controls stay in range; the data-based solve
    reaches the box-constrained model-based optimum."""
    env = _task(_write(tmp_path, 'ctrllimited="true" ctrlrange="-1.5 1.5"'), horizon=30, target=[0.0, 0.0])
    assert env.limited
    cfg = pj.default_config(env, max_iterations=150, n_s=20)
    r = pj.solve(env, cfg)
    m = pj.solve_model_based(env, cfg)
    for res in (r, m):
        assert np.all(np.abs(res.controls) <= 1.5), res.summary()
        assert np.all(np.isfinite(res.K))
    # Seeds 0-5 and x0 = pi (1 +- 1e-12): box active on 0.40 of the steps, POD / model-based cost
    # 1.000008 .. 1.00014, final angle <= 0.013 rad; each bound has a wide margin.
    assert np.mean(np.isclose(np.abs(r.controls), 1.5)) > 0.2  # the box is active
    assert r.final_cost <= 1.01 * m.final_cost, (r.summary(), m.summary())
    assert abs(r.observations[-1, 0]) < 0.2  # swung up within the limits


def test_fit_leaves_out_divergent_rollouts():
    rng = np.random.default_rng(0)
    n, T, nz, nu, q = 30, 6, 2, 1, 1
    z = rng.normal(size=(n, T + 1, nz))
    u = rng.normal(size=(n, T, nu))
    z_bar, u_bar = np.zeros((T + 1, nz)), np.zeros((T, nu))
    bad = np.array([3, 11, 20])
    z_nan = z.copy()
    z_nan[bad, 4:] = np.nan
    z_nan[bad[0], 2, 0] = np.inf
    good = np.setdiff1d(np.arange(n), bad)
    model, report = fit_information_model(z_nan, u, z_bar, u_bar, q, 1e-10)
    model_good, _ = fit_information_model(z[good], u[good], z_bar, u_bar, q, 1e-10)
    assert int(report.n_bad) == 3 and not bool(report.all_finite)
    np.testing.assert_allclose(model.A, model_good.A, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(model.B, model_good.B, rtol=1e-10, atol=1e-12)


UNSTABLE = """
<mujoco model="unstable">
  <option timestep="0.01" integrator="Euler"><flag contact="disable"/></option>
  <worldbody><body><joint name="s" type="slide" axis="1 0 0" stiffness="-1e10"/>
  <geom type="sphere" size="0.1" mass="1"/></body></worldbody>
  <actuator><motor joint="s"/></actuator>
</mujoco>
"""


def test_divergent_sysid_rollouts_stop_the_solve_with_finite_output(tmp_path):
    path = tmp_path / "unstable.xml"
    path.write_text(UNSTABLE)
    env = pj.Env.from_xml(path, substeps=10, horizon=8, target=[1.0, 0.0])
    r = pj.solve(env, pj.SolverConfig(n_s=10, sigma=1e-3, max_iterations=3))
    assert r.status == pj.Status.NONFINITE
    assert "10 of 10 sysid rollouts diverged" in r.message
    assert np.all(np.isfinite(r.controls)) and np.all(np.isfinite(r.K))


def test_partly_divergent_sysid_batch_is_reported(tmp_path):
    """A stiffer spring and sigma = 1: the larger perturbations overflow, the
    smaller do not. The diverged ones are left out and the result says so."""
    path = tmp_path / "unstable.xml"
    path.write_text(UNSTABLE.replace("-1e10", "-8e7"))
    env = pj.Env.from_xml(path, substeps=10, horizon=8, target=[1.0, 0.0])
    r = pj.solve(env, pj.SolverConfig(n_s=20, sigma=1.0, max_iterations=3))
    assert 0 < r.diverged_rollouts < 20  # seeds 0-9: 5 .. 11 (seed 0: 7, also with sigma 1 +- 1e-12)
    assert f"{r.diverged_rollouts} sysid rollouts diverged (non-finite) and were left out of the fit" in r.message
    assert np.all(np.isfinite(r.controls)) and np.all(np.isfinite(r.K))


def test_line_search_rejects_divergent_candidates():
    env = pj.make_task("pendulum-full", horizon=6)
    dims, data = env.dims, env.data
    T, nu, nZ = 6, 1, 2
    policy = Policy(jnp.zeros((T, nu)), jnp.zeros((T, nZ)), jnp.zeros((T, nu, nZ)))
    alphas = jnp.asarray(np.append(0.5 ** np.arange(4), 0.0))
    k = jnp.full((T, nu), 1e200)
    step, candidates = Step(k, jnp.asarray(np.inf), -1.0, 0.0), Candidates(alphas, 1e-4)
    ls = line_search(Search(dims, 1), data, policy, step, candidates, jax.random.PRNGKey(0))
    costs = np.asarray(ls.costs)
    assert not np.isfinite(costs[:4]).any() and np.isfinite(costs[4])
    assert not bool(ls.accepted)


def test_make_task_reads_a_task_file_as_its_message_says(tmp_path):
    """``make_task``'s error names task files; a path is one (the bundled tasks' noise and horizon too)."""
    path = os.path.join(
        os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
        "examples",
        "tasks",
        "basins",
        "gym_inverted_pendulum_tilted.toml",
    )
    env = pj.make_task(path, horizon=20, noise="paper")
    assert env.dims.horizon == 20 and env.noisy and env.name == "gym-inverted-pendulum-tilted"
    with pytest.raises(pj.TaskError, match="does not exist"):
        pj.make_task(str(tmp_path / "none.toml"))
