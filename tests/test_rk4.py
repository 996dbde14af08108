"""``rk4.step``: MuJoCo's RK4 with one compiled forward, against ``mjx.step``.

The rewrite exists for compile time (benchmarks/journal.md); these tests hold it
to MJX's own RK4 step, to round-off, on a model that exercises every path of
the position update (a free joint's quaternion, a hinge against its limit, a
contact with the floor, an actuator with an activation-free gain) and on a
model as dm_control ships it.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from podilqr_jax.sim import rk4
from podilqr_jax.task.package_files import resolve_model_path

XML = """
<mujoco>
  <option integrator="RK4" timestep="0.01"/>
  <worldbody>
    <geom type="plane" size="2 2 0.1"/>
    <body name="ball" pos="0 0 0.12">
      <freejoint/>
      <geom type="sphere" size="0.1" mass="0.5"/>
    </body>
    <body name="arm" pos="0.5 0 1">
      <joint name="hinge" type="hinge" axis="0 1 0" limited="true" range="-0.3 0.3" damping="0.05"/>
      <geom type="capsule" fromto="0 0 0 0.4 0 0" size="0.03"/>
    </body>
  </worldbody>
  <actuator><motor joint="hinge" gear="2"/></actuator>
</mujoco>
"""


def _run(model, d, stepper, n):
    def body(_, dd):
        return jax.tree_util.tree_map(lambda new, old: new.astype(old.dtype), stepper(model, dd), dd)

    return jax.jit(lambda dd: jax.lax.fori_loop(0, n, body, dd))(d)


def _compare(mj_model, qpos, qvel, ctrl, n):
    model = mjx.put_model(mj_model)
    assert rk4.applies(model)
    d = mjx.make_data(model).replace(qpos=jnp.asarray(qpos), qvel=jnp.asarray(qvel), ctrl=jnp.asarray(ctrl))
    ref, ours = _run(model, d, mjx.step, n), _run(model, d, rk4.step, n)
    scale = 1.0 + float(jnp.max(jnp.abs(ref.qvel)))
    for name in ("qpos", "qvel", "qacc_warmstart", "time"):
        err = float(jnp.max(jnp.abs(getattr(ours, name) - getattr(ref, name))))
        # measured: <= 3e-14 here and on the gallery's RK4 models (cart-pole, inverted pendulum, hopper)
        assert err <= 1e-10 * scale, (name, err)
    return ref


def test_rk4_step_is_mjx_rk4_on_a_free_body_a_limit_and_a_contact():
    m = mujoco.MjModel.from_xml_string(XML)
    qpos = np.concatenate([[0.0, 0.0, 0.12], [0.9, 0.1, 0.3, 0.2] / np.linalg.norm([0.9, 0.1, 0.3, 0.2]), [0.25]])
    qvel = np.array([0.3, -0.2, 0.0, 1.0, -2.0, 0.5, 2.0])
    ref = _compare(m, qpos, qvel, [1.0], n=40)
    assert float(ref.qpos[2]) > 0.05  # the contact held the ball on the floor (free fall: 0.78 m in 0.4 s)
    assert float(jnp.abs(ref.qpos[7])) <= 0.31  # the hinge, started at 0.25 rad and 2 rad/s, within its limit


def test_rk4_step_is_mjx_rk4_on_dm_control_cartpole_as_shipped():
    pytest.importorskip("dm_control", reason="the `test` extra installs dm-control")
    m = mujoco.MjModel.from_xml_path(resolve_model_path("pkg://dm_control/suite/cartpole.xml"))
    m.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_ENERGY)  # reporting only; MJX refuses it
    _compare(m, [0.2, 2.5], [0.5, -1.0], [0.7], n=25)


def test_other_integrators_and_implementations_keep_mjx_step():
    m = mujoco.MjModel.from_xml_string(XML.replace('integrator="RK4"', 'integrator="Euler"'))
    assert not rk4.applies(mjx.put_model(m))
    assert rk4.available  # the MJX internals it uses are where pyproject's mujoco-mjx puts them
