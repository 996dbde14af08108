"""Contact-rich models (sim/contacts.py): the model-based reference's Jacobians
one JVP at a time, equal to the batched ones on a model with an active contact."""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax.ilqr import solver
from podilqr_jax.sim import contacts
from podilqr_jax.sim.rollout import make_data, on_device, physics_step, state_of, with_state

# A slider-and-hinge arm whose ball foot rests on the floor: one active contact
# (pyramidal cone, so MJX's derivative is finite), 12 constraint rows.
RESTING_ARM = """<mujoco>
  <option timestep="0.01" cone="pyramidal"/>
  <worldbody>
    <geom type="plane" size="2 2 0.1"/>
    <body name="arm" pos="0 0 0.3">
      <joint name="lift" type="slide" axis="0 0 1"/>
      <joint name="hinge" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.05"/>
      <geom type="sphere" pos="0.3 0 -0.1" size="0.06"/>
    </body>
  </worldbody>
  <actuator><motor joint="lift"/><motor joint="hinge"/></actuator>
</mujoco>"""
RESTING = [-0.145, 0.0]  # qpos: the foot 5 mm into the floor
HORIZON = 6

# One JVP at a time against one vmap of all: the same operations, grouped
# otherwise by XLA. Measured on this arm: 7.5e-14 at a largest entry of 24
# (3e-15 relative; Gymnasium's hopper: 5.7e-14 at 43). Required: 1e-12 relative.
LOOP_VS_BATCH_REL = 1e-12


def _hopper():
    pytest.importorskip("gymnasium", reason="the `test` extra installs gymnasium")
    from podilqr_jax.task.taskfile import load_task

    gallery = os.path.join(os.path.dirname(os.path.dirname(__file__)), "examples", "tasks", "third_party")
    return load_task(os.path.join(gallery, "gym_hopper_balance.toml"))


def _exact_of(monkeypatch, env):
    """The identification ``solve_model_based`` sets up for ``env`` (nothing compiles)."""
    captured = {}
    with monkeypatch.context() as patch:
        patch.setattr(solver, "run", lambda ctx, *args: captured.setdefault("identify", ctx.identify))
        solver.solve_model_based(env)
    return captured["identify"]


def test_only_a_contact_rich_model_on_one_cpu_runs_its_jacobians_one_at_a_time(monkeypatch):
    pendulum = pj.make_task("pendulum-full")
    assert contacts.constraint_rows(pendulum.data.model) == 0
    assert not contacts.one_at_a_time(pendulum.data.model)
    assert _exact_of(monkeypatch, pendulum).one_at_a_time is False
    hopper = _hopper()
    assert contacts.contact_rich(hopper.data.model)
    assert contacts.one_at_a_time(hopper.data.model)
    assert _exact_of(monkeypatch, hopper).one_at_a_time is True
    # On a GPU the batch is what the device is for.
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert not contacts.one_at_a_time(hopper.data.model)


def test_the_jacobians_one_at_a_time_equal_the_batched_ones_at_an_active_contact(tmp_path):
    path = tmp_path / "resting_arm.xml"
    path.write_text(RESTING_ARM)
    env = pj.Env.from_xml(path, horizon=HORIZON, x0={"qpos": RESTING, "qvel": [0.0, 0.0]})
    probe = mujoco.MjData(env.mj_model)
    probe.qpos[:] = RESTING
    mujoco.mj_forward(env.mj_model, probe)
    assert probe.ncon >= 1  # the foot touches the floor
    assert contacts.constraint_rows(env.data.model) < contacts.MANY_ROWS  # the solver would batch: called directly
    dims, data = env.dims, on_device(env.data)
    u_bar = jnp.asarray(np.linspace(-0.5, 0.5, HORIZON * dims.nu).reshape(HORIZON, dims.nu))
    d0 = make_data(data.model)
    xs = [data.x0]
    for t in range(HORIZON):
        xs.append(state_of(physics_step(dims, data.model, with_state(dims, d0, xs[-1]), u_bar[t])))
    x_bar = jnp.stack(xs)
    batched = pj.linearise(dims, data, x_bar, u_bar)
    looped = pj.linearise(dims, data, x_bar, u_bar, one_at_a_time=True)
    for a, b in ((batched.A, looped.A), (batched.B, looped.B)):
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape and np.all(np.isfinite(a)) and np.all(np.isfinite(b))
        assert np.max(np.abs(a - b)) <= LOOP_VS_BATCH_REL * np.max(np.abs(a))
    # The contact is in the Jacobian: lifted off the floor (the mass matrix
    # depends on the hinge angle only), the lift's velocity answers the lift's
    # force otherwise.
    lifted = pj.linearise(dims, data, x_bar.at[:, 0].add(0.3), u_bar, one_at_a_time=True)
    on_floor, in_air = float(looped.B[0, 2, 0]), float(lifted.B[0, 2, 0])
    assert abs(on_floor - in_air) > 0.1 * abs(in_air)
