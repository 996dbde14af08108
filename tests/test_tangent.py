"""State deviations on free and ball joints (``task.tangent``).

The tangent-space maps against MuJoCo's own ``mj_integratePos`` and
``mj_differentiatePos``; state noise on a floating body (refused before the
tangent space) turning its quaternion on both engines; and the model-based
reference on a floating box, whose central differences in the tangent space
turn the box where MJX's forward-mode derivative at rest does not.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import podilqr_jax as pj
from podilqr_jax.identify.info_state import info_dim
from podilqr_jax.sim import engines
from podilqr_jax.sim.rollout import open_loop_policy, rollout_batch
from podilqr_jax.task import tangent
from podilqr_jax.task.env import EnvDims
from podilqr_jax.task.noise import sample

# Every kind of joint: a free base, a hinge, a ball and a slide.
CHAIN = """<mujoco><worldbody>
<body><freejoint/><geom size=".1"/>
 <body pos="0 0 .3"><joint type="hinge"/><geom size=".1"/>
  <body pos="0 0 .3"><joint type="ball"/><geom size=".1"/>
   <body pos="0 0 .3"><joint type="slide"/><geom size=".1"/></body></body></body></body>
</worldbody></mujoco>"""

# A box floating without gravity, pushed along x and y and turned about z.
BOX = """<mujoco model="floating-box">
  <option timestep="0.02" gravity="0 0 0"/>
  <worldbody>
    <body name="box">
      <freejoint name="root"/>
      <geom type="box" size="0.1 0.05 0.02" mass="1"/>
      <site name="c"/>
    </body>
  </worldbody>
  <actuator>
    <motor site="c" gear="1 0 0 0 0 0"/>
    <motor site="c" gear="0 1 0 0 0 0"/>
    <motor site="c" gear="0 0 0 0 0 1"/>
  </actuator>
</mujoco>"""

HORIZON = 40
TURNED = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])  # 90 degrees about z


def _unit_quats(rng, qpos, quats):
    for qa, _ in quats:
        qpos[qa : qa + 4] /= np.linalg.norm(qpos[qa : qa + 4])
    return qpos


def test_integrate_and_difference_are_mujocos():
    m = mujoco.MjModel.from_xml_string(CHAIN)
    dims = EnvDims(nq=m.nq, nv=m.nv, nu=1, nz=1, substeps=1, horizon=1, quats=tangent.quaternions(m))
    assert dims.quats == ((3, 3), (8, 7)) and dims.ndx == 2 * m.nv == 22
    integrate = jax.jit(tangent.integrate, static_argnums=0)
    difference = jax.jit(tangent.difference, static_argnums=0)
    rng = np.random.default_rng(0)
    for trial in range(40):
        qpos = _unit_quats(rng, rng.standard_normal(m.nq), dims.quats)
        qvel = rng.standard_normal(m.nv)
        dq = rng.standard_normal(m.nv) * (2.0 if trial % 2 else 1e-4)  # large turns and small ones
        dv = rng.standard_normal(m.nv)
        expected = qpos.copy()
        mujoco.mj_integratePos(m, expected, dq, 1.0)
        got = np.asarray(integrate(dims, jnp.asarray(np.r_[qpos, qvel]), jnp.asarray(np.r_[dq, dv])))
        np.testing.assert_allclose(got, np.r_[expected, qvel + dv], rtol=0, atol=1e-14)

        other = _unit_quats(rng, rng.standard_normal(m.nq), dims.quats)
        rates = np.zeros(m.nv)
        mujoco.mj_differentiatePos(m, rates, 1.0, qpos, other)
        diff = difference(dims, jnp.asarray(np.r_[other, qvel + dv]), jnp.asarray(np.r_[qpos, qvel]))
        np.testing.assert_allclose(np.asarray(diff), np.r_[rates, dv], rtol=0, atol=1e-13)


def test_basis_and_cobasis_are_the_derivatives():
    m = mujoco.MjModel.from_xml_string(CHAIN)
    dims = EnvDims(nq=m.nq, nv=m.nv, nu=1, nz=1, substeps=1, horizon=1, quats=tangent.quaternions(m))
    rng = np.random.default_rng(1)
    x = jnp.asarray(np.r_[_unit_quats(rng, rng.standard_normal(m.nq), dims.quats), rng.standard_normal(m.nv)])
    J = jax.jit(jax.jacfwd(lambda d: tangent.integrate(dims, x, d)))(jnp.zeros(dims.ndx))
    P = jax.jit(jax.jacfwd(lambda y: tangent.difference(dims, y, x)))(x)
    assert np.all(np.isfinite(J)) and np.all(np.isfinite(P))  # differentiable at the zero rotation
    np.testing.assert_allclose(np.asarray(tangent.basis(dims, x)), np.asarray(J), rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.asarray(tangent.cobasis(dims, x)), np.asarray(P), rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.asarray(P @ J), np.eye(dims.ndx), rtol=0, atol=1e-14)


def _box(**kw) -> pj.Env:
    target = np.zeros(13)
    target[0], target[3:7] = 0.5, TURNED
    return pj.Env.from_model(
        mujoco.MjModel.from_xml_string(BOX),
        name="floating-box",
        horizon=HORIZON,
        substeps=2,
        target=target,
        Q=np.diag([1.0] * 7 + [0.01] * 6),
        QT=100.0 * np.eye(13),
        R=0.01 * np.eye(3),
        **kw,
    )


def test_state_noise_on_a_free_joint_turns_the_quaternion():
    """Start and process noise are rotations of the quaternion (x (+) dx,
    ``mj_integratePos``): it stays a unit quaternion, and the noisy state is
    the noiseless one moved by exactly the drawn deviation. The noise is
    applied by the one rollout scan (``rollout.run``) around either engine's
    step, so MuJoCo's C engine, which compiles in a second, tests it for both."""
    env = engines.on_engine(_box(noise={"initial": 0.2, "process": 0.05}), "native")
    dims, data = env.dims, env.data
    assert data.noise.x0.shape == data.noise.w.shape == (12,)  # 2 nv, not nq + nv
    policy = open_loop_policy(jnp.full((HORIZON, dims.nu), 0.01), info_dim(dims.nz, dims.nu, 1))
    zero = jnp.zeros((2, HORIZON, dims.nu))
    noise = sample(jax.random.PRNGKey(3), data.noise, 2, HORIZON)
    noisy = np.asarray(rollout_batch(dims, 1, data, policy, zero, zero, record_state=True, noise=noise).x)
    quat_norms = np.linalg.norm(noisy[:, :, 3:7], axis=-1)
    np.testing.assert_allclose(quat_norms, 1.0, rtol=0, atol=1e-12)
    x0 = np.asarray(data.x0)
    start_dev = np.asarray(tangent.difference(dims, jnp.asarray(noisy[:, 0]), jnp.asarray(x0)))
    np.testing.assert_allclose(start_dev, np.asarray(noise.dx0), rtol=0, atol=1e-12)
    assert np.abs(noisy[:, 0, 4:7]).max() > 0.05  # the start is turned, not only moved

    # one noiseless control step from the noisy run's own states, then (+) w_t
    clean = env.with_start_state(noisy[0, 0])
    one = np.asarray(rollout_batch(clean.dims, 1, clean.data, policy, zero[:1], zero[:1], record_state=True).x[0, 1])
    step_dev = tangent.difference(dims, jnp.asarray(noisy[0, 1]), jnp.asarray(one))
    np.testing.assert_allclose(np.asarray(step_dev), np.asarray(noise.w[0, 0]), rtol=0, atol=1e-10)


def test_the_reference_turns_a_floating_box():
    """At rest MJX's forward-mode derivative says a torque does not turn the
    box (the reference stops where it starts turning nothing, and says why);
    the default takes central differences in the tangent space, which turn it
    to where POD-iLQR goes."""
    env = _box()
    ref = pj.solve_model_based(env)
    assert ref.status == pj.Status.CONVERGED
    np.testing.assert_allclose(ref.states[-1, 3:7], TURNED, atol=0.02)
    exact = pj.solve_model_based(env, pj.default_config(env, jacobian="exact"))
    assert exact.final_cost > 5 * ref.final_cost
    assert any("free or ball joint" in w for w in exact.warnings)
    assert not any("free or ball joint" in w for w in ref.warnings)
    pod = pj.solve(env, pj.default_config(env, engine="native"))  # MuJoCo's C step: no second MJX compile
    assert pod.status == pj.Status.CONVERGED
    assert abs(pod.final_cost - ref.final_cost) <= 1e-6 * ref.final_cost


def test_a_noisy_solve_of_a_floating_box_lowers_its_true_cost():
    env = _box(noise=pj.NoiseModel.paper(partial=False))
    res = pj.solve(env, pj.default_config(env, max_iterations=20, engine="native"))
    true = np.asarray(res.record.true_cost_history)
    assert np.all(np.isfinite(true))
    assert true[-1] < 0.5 * true[0]
