"""The policy object: the learnt controller, its Kalman estimator, and the LQ check.

Acceptance criterion 2 of the closed-loop issue: on a linear-quadratic problem
with noise, the closed-loop policy from POD-iLQR equals the LQR feedback law of
the true system. The true system is a MuJoCo mass on a spring (slide joint,
Euler integrator, no gravity: exactly linear); its (A, B) are read off
``mujoco.mj_step`` in numpy and the LQR gains come from a numpy Riccati
recursion, both independent of the library.
"""

from __future__ import annotations

import jax
import mujoco
import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax.compilation.compile_watch import CompileWatch
from podilqr_jax.control.kalman import kalman_gains
from podilqr_jax.control.policy import run_on_measurements
from podilqr_jax.sim.rollout import Policy, rollout_batch
from podilqr_jax.task.noise import noise_levels, sample

SPRING_XML = """
<mujoco>
  <option timestep="0.05" integrator="Euler" gravity="0 0 0"/>
  <worldbody>
    <body>
      <joint name="x" type="slide" axis="1 0 0" stiffness="2" damping="0.3"/>
      <geom type="sphere" size="0.1" mass="1"/>
    </body>
  </worldbody>
  <actuator><motor joint="x" gear="1" ctrllimited="false"/></actuator>
</mujoco>
"""
SUBSTEPS = 2
HORIZON = 15
Q, QT, R = 1.0, 50.0, 0.1


def spring_env(noise=None, horizon=HORIZON):
    model = mujoco.MjModel.from_xml_string(SPRING_XML)
    return pj.Env.from_model(
        model,
        observation="full",
        substeps=SUBSTEPS,
        horizon=horizon,
        x0={"qpos": [1.0], "qvel": [0.0]},
        target=[0.0, 0.0],
        Q=Q,
        QT=QT,
        R=R,
        name="spring",
        noise=noise,
    )


def true_linear_system():
    """(A, B) of one control step, x = [qpos, qvel], from mujoco.mj_step (numpy)."""
    model = mujoco.MjModel.from_xml_string(SPRING_XML)
    data = mujoco.MjData(model)

    def step(x, u):
        data.qpos[:], data.qvel[:], data.ctrl[:] = x[:1], x[1:], u
        for _ in range(SUBSTEPS):
            mujoco.mj_step(model, data)
        return np.concatenate([data.qpos, data.qvel])

    A = np.stack([step(e, [0.0]) for e in np.eye(2)], axis=1)
    B = step(np.zeros(2), [1.0])[:, None]
    return A, B


def lqr_gains(A, B, T):
    """Finite-horizon LQR for J = sum x'Qx + u'Ru + x_T' QT x_T: u_t = K_t x_t."""
    P = QT * np.eye(2)
    K = np.empty((T, 1, 2))
    for t in reversed(range(T)):
        K[t] = -np.linalg.solve(R * np.eye(1) + B.T @ P @ B, B.T @ P @ A)
        P = Q * np.eye(2) + A.T @ P @ (A + B @ K[t])
        P = 0.5 * (P + P.T)
    return K


def test_closed_loop_policy_equals_the_lqr_law_under_noise():
    """POD-iLQR on the noisy spring (start deviation and process noise, the
    feedback variant with the IV estimator): its policy's gains are the true
    system's LQR gains at every step.

    Why these settings (measured, docs/evaluation.md): the start deviation
    (std 0.05) excites dZ_0, without which K_0 is not identifiable (all
    rollouts would start alike); least squares about the single noisy nominal
    keeps a 1-2% gain error that does not shrink with n_s (the nominal's noise
    is an offset common to all sysid rollouts), while IV centres the data and
    its error falls with n_s (0.3-0.9% at n_s = 100 .. 400, seeds 0-2).
    """
    env = spring_env(noise={"initial": 0.05, "process": 1e-3})
    cfg = pj.default_config(env, q=1, n_s=200, sigma=1.0, variant="feedback", estimator="iv", max_iterations=4)
    result = pj.solve(env, cfg)
    K_true = lqr_gains(*true_linear_system(), HORIZON)
    policy = result.policy()
    K = np.asarray(policy.controller.K)
    # 2% against the 0.3-0.9% measured; a biased model, a missing step or a
    # sign error is off by 10-100%. Over seeds 0-9 (this config): 0.37-0.88%,
    # seed 0 the largest; a linear system, so no rounding is amplified.
    err = np.max(np.abs(K - K_true)) / np.max(np.abs(K_true))
    assert err < 2e-2, err
    # ... and the policy applies them: u = u_bar + K (x - x_bar) for any measurements.
    rng = np.random.default_rng(0)
    x = result.info_states + 0.1 * rng.standard_normal(result.info_states.shape)
    u = np.asarray(run_on_measurements(policy.controller, x))
    dx = x[:-1] - result.info_states[:-1]
    np.testing.assert_allclose(u, result.controls + np.einsum("tij,tj->ti", K, dx), rtol=0, atol=1e-12)
    u_lqr = result.controls + np.einsum("tij,tj->ti", K_true, dx)
    bound = 2e-2 * np.max(np.abs(K_true)) * np.sum(np.abs(dx), axis=1, keepdims=True)
    assert np.all(np.abs(u - u_lqr) <= bound)


def test_model_based_policy_is_the_exact_lqr_law():
    env = spring_env()
    result = pj.solve_model_based(env, pj.default_config(env, max_iterations=5))
    # The backward pass regularises V by mu_min = 1e-6, which moves the gains
    # by ~mu / |V| ~ 1e-7 relative (measured 7.6e-8); nothing else differs.
    np.testing.assert_allclose(result.policy().controller.K, lqr_gains(*true_linear_system(), HORIZON), rtol=1e-6)
    assert result.policy().measures == "state"


@pytest.fixture(scope="module")
def pendulum_result():
    env = pj.make_task("pendulum-partial", horizon=10)
    return env, pj.solve(env, pj.default_config(env, max_iterations=8))


def test_policy_reproduces_the_solvers_closed_loop_rollout(pendulum_result):
    """The policy fed the (noisy) measurements of the solver's own closed-loop
    MJX rollout of u_bar + K (Z - Z_bar) commands exactly the controls that
    rollout applied."""
    env, result = pendulum_result
    policy = result.policy()
    nominal = Policy(np.asarray(result.controls), np.asarray(result.info_states[:-1]), np.asarray(result.K))
    levels = noise_levels(pj.NoiseModel(initial=0.05, process=0.01, measurement=0.02), env.dims.nx, env.dims.nz)
    noise = sample(jax.random.PRNGKey(0), levels, 3, 10)
    zero = np.zeros((10, 1))
    traj = rollout_batch(env.dims, result.q, env.data, nominal, zero, zero, noise=noise)
    for j in range(3):
        u = np.asarray(run_on_measurements(policy.controller, traj.z[j]))
        np.testing.assert_allclose(u, traj.u[j], rtol=0, atol=1e-12)
    assert np.max(np.abs(np.asarray(traj.u) - result.controls)) > 0.01  # the feedback did act


def test_stepping_from_python_matches_and_compiles_once(pendulum_result):
    env, result = pendulum_result
    policy = result.policy()
    z = result.info_states[:, :1] + 0.01
    expected = np.asarray(run_on_measurements(policy.controller, z))
    state = policy.reset(z[0])
    with CompileWatch() as first:
        u0 = policy.act(state)
        state = policy.update(state, u0, z[1])
    us = [u0]
    with CompileWatch() as rest:
        for t in range(1, 10):
            us.append(policy.act(state))
            if t < 9:
                state = policy.update(state, us[-1], z[t + 1])
    np.testing.assert_allclose(np.stack(us), expected, atol=1e-12)
    assert first.compiles >= 1 and rest.compiles == 0


def test_policy_refuses_bad_input(pendulum_result):
    _, result = pendulum_result
    policy = result.policy()
    with pytest.raises(pj.ConfigError, match=r"`z0` must have shape \[1\]"):
        policy.reset(np.zeros(2))
    state = policy.reset(np.zeros(1))
    with pytest.raises(pj.ConfigError, match=r"`u` must have shape \[nu\] = \[1\]"):
        policy.update(state, np.zeros(3), np.zeros(1))
    late = state._replace(t=np.asarray(10))
    with pytest.raises(pj.ConfigError, match="controls for steps 0 .. 9; the state is at step 10"):
        policy.act(late)


def numpy_kalman(A, W, R, P0):
    """A textbook Kalman filter's gains (numpy, covariance form)."""
    nz = R.shape[0]
    S = np.eye(nz, A.shape[1])
    gains = []
    P = P0
    for t in range(A.shape[0] + 1):
        if t > 0:
            P = A[t - 1] @ P @ A[t - 1].T + W[t - 1]
        L = P @ S.T @ np.linalg.inv(S @ P @ S.T + R)
        P = (np.eye(len(P)) - L @ S) @ P
        gains.append(L)
    return np.stack(gains)


def test_kalman_gains_match_a_textbook_filter():
    rng = np.random.default_rng(2)
    T, nZ = 6, 3
    A = 0.5 * rng.standard_normal((T, nZ, nZ))
    M = rng.standard_normal((T, nZ, nZ))
    W = np.einsum("tij,tkj->tik", M, M) * 0.1
    R = np.array([[0.3]])
    P0 = np.eye(nZ)
    L, P = kalman_gains(A, W, R, P0)
    np.testing.assert_allclose(np.asarray(L), numpy_kalman(A, W, R, P0), rtol=1e-10, atol=1e-12)
