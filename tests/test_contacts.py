"""Contact-rich models (sim/contacts.py): the model-based reference's Jacobians
by central differences, equal to forward mode where that is finite (at an
active contact too) and finite where it is not (the elliptic cone)."""

from __future__ import annotations

import os

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

# Central differences (h = eps^(1/3)) against forward mode: truncation h^2 and
# round-off eps / h, both near 1e-10 of the entries. Measured: the resting arm
# 9.6e-9 at a largest entry of 24 (4e-10 relative), the cart-pole and the
# pendulum 1.7e-10 at 1.5 and 9.4e-11 at 1.9. Required: 1e-7 relative.
DIFFERENCES_VS_EXACT_REL = 1e-7


def _hopper():
    pytest.importorskip("gymnasium", reason="the `test` extra installs gymnasium")
    from podilqr_jax.task.taskfile import load_task

    gallery = os.path.join(os.path.dirname(os.path.dirname(__file__)), "examples", "tasks", "third_party")
    return load_task(os.path.join(gallery, "gym_hopper_balance.toml"))


def _exact_of(monkeypatch, env, cfg=None):
    """The identification ``solve_model_based`` sets up for ``env`` on MJX (nothing compiles):
    these tests are of MJX's contact machinery, which ``engine="auto"`` leaves for the
    native engine on a contact model on a CPU (tests/test_native.py)."""
    cfg = pj.default_config(env, engine="mjx") if cfg is None else cfg
    captured = {}
    with monkeypatch.context() as patch:
        patch.setattr(solver, "_run", lambda ctx, *args: captured.setdefault("identify", ctx.identify))
        solver.solve_model_based(env, cfg)
    return captured["identify"]


def _resting_arm(tmp_path, cone="pyramidal"):
    """The arm with its foot on the floor, its task arrays on the device and a nominal of HORIZON steps."""
    path = tmp_path / f"resting_arm_{cone}.xml"
    path.write_text(RESTING_ARM.replace('cone="pyramidal"', f'cone="{cone}"'))
    env = pj.Env.from_xml(path, horizon=HORIZON, x0={"qpos": RESTING, "qvel": [0.0, 0.0]})
    probe = mujoco.MjData(env.mj_model)
    probe.qpos[:] = RESTING
    mujoco.mj_forward(env.mj_model, probe)
    assert probe.ncon >= 1  # the foot touches the floor
    # Few rows: the solver's `auto` would take forward mode here, so the tests call `linearise` directly.
    assert contacts.constraint_rows(env.mj_model) < contacts.MANY_ROWS
    dims, data = env.dims, on_device(env.data)
    return dims, data, *_nominal(dims, data, np.linspace(-0.5, 0.5, HORIZON * dims.nu).reshape(HORIZON, dims.nu))


def _nominal(dims, data, u_bar):
    """(x_bar, u_bar): MJX's step from the task's start under the controls ``u_bar``."""
    u_bar = jnp.asarray(u_bar)
    d0 = make_data(data.model)
    xs = [data.x0]
    for t in range(u_bar.shape[0]):
        xs.append(state_of(physics_step(dims, data.model, with_state(dims, d0, xs[-1]), u_bar[t])))
    return jnp.stack(xs), u_bar


def _assert_close(model, reference, rel):
    for a, b in ((reference.A, model.A), (reference.B, model.B)):
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape and np.all(np.isfinite(a)) and np.all(np.isfinite(b))
        assert np.max(np.abs(a - b)) <= rel * np.max(np.abs(a))


@pytest.fixture(scope="module")
def resting_arm(tmp_path_factory):
    """The pyramidal-cone resting arm and its exact (forward-mode) linearisation."""
    dims, data, x_bar, u_bar = _resting_arm(tmp_path_factory.mktemp("arm"))
    return dims, data, x_bar, u_bar, pj.linearise(dims, data, x_bar, u_bar)


def test_auto_linearises_a_contact_rich_model_by_central_differences(monkeypatch):
    pendulum, hopper = pj.make_task("pendulum-full"), _hopper()
    assert contacts.jacobian("auto", pendulum.data.model) == "exact"
    assert contacts.jacobian("auto", hopper.data.model) == "differences"
    assert _exact_of(monkeypatch, pendulum).jacobian == "exact"
    assert _exact_of(monkeypatch, hopper).jacobian == "differences"
    # The setting forces either, whatever the model.
    for setting in ("exact", "differences"):
        assert contacts.jacobian(setting, pendulum.data.model) == setting
        cfg = pj.default_config(hopper, engine="mjx", jacobian=setting)
        assert _exact_of(monkeypatch, hopper, cfg).jacobian == setting
    with pytest.raises(pj.ConfigError, match="Unknown `jacobian` 'fd'; choose one of auto, exact, differences"):
        solver.solve_model_based(pendulum, pj.default_config(pendulum, jacobian="fd"))


@pytest.mark.parametrize("task", ["cartpole-full", "pendulum-full"])
def test_central_differences_equal_forward_mode_on_a_smooth_model(task):
    view = pj.make_task(task).full_state_view()
    dims, data = view.dims, on_device(view.data)
    rng = np.random.default_rng(0)
    x_bar, u_bar = _nominal(dims, data, rng.uniform(-0.5, 0.5, (dims.horizon, dims.nu)))
    exact = pj.linearise(dims, data, x_bar, u_bar)
    _assert_close(pj.linearise(dims, data, x_bar, u_bar, jacobian="differences"), exact, DIFFERENCES_VS_EXACT_REL)


def test_central_differences_are_finite_where_the_elliptic_cone_makes_forward_mode_nan(resting_arm, tmp_path):
    dims, data, x_bar, u_bar, exact = resting_arm
    differences = pj.linearise(dims, data, x_bar, u_bar, jacobian="differences")
    _assert_close(differences, exact, DIFFERENCES_VS_EXACT_REL)  # at an active contact, pyramidal cone
    dims, data, x_bar, u_bar = _resting_arm(tmp_path, cone="elliptic")
    assert not np.all(np.isfinite(np.asarray(pj.linearise(dims, data, x_bar, u_bar).A)))
    differences = pj.linearise(dims, data, x_bar, u_bar, jacobian="differences")
    assert np.all(np.isfinite(np.asarray(differences.A))) and np.all(np.isfinite(np.asarray(differences.B)))
    # The contact is in them: the lift's velocity answers the lift's force otherwise in the air.
    lifted = pj.linearise(dims, data, x_bar.at[:, 0].add(0.3), u_bar, jacobian="differences")
    assert abs(float(differences.B[0, 2, 0]) - float(lifted.B[0, 2, 0])) > 0.1 * abs(float(lifted.B[0, 2, 0]))


def test_a_checkpoint_fingerprint_leaves_out_jacobian_at_its_default():
    from podilqr_jax.ilqr.checkpoint import fingerprint

    env = pj.make_task("pendulum-full")
    auto = fingerprint("model-based", env, env.dims, pj.default_config(env))["config"]
    exact = fingerprint("model-based", env, env.dims, pj.default_config(env, jacobian="exact"))["config"]
    assert "jacobian" not in auto and exact["jacobian"] == "exact"
    assert {k: v for k, v in exact.items() if k != "jacobian"} == auto
