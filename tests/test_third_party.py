"""Models as they ship in dm_control's suite and Gymnasium's MuJoCo assets.

They are read in place from the installed packages (``pkg://...``; the
``test`` extra installs dm-control and gymnasium), never copied here. Short
horizons keep the compiles few: each model compiles its own rollouts.
"""

import math
import os
import struct
import zlib

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax.cli import main as cli_main
from podilqr_jax.identify.model_based import nonfinite_hint
from podilqr_jax.sim import engines
from podilqr_jax.sim.rollout import open_loop_policy, physics_step, rollout_batch, with_state
from podilqr_jax.task.noise import sample
from podilqr_jax.task.package_files import resolve_model_path
from podilqr_jax.task.taskfile import load_task

pytest.importorskip("dm_control", reason="the `test` extra installs dm-control")
pytest.importorskip("gymnasium", reason="the `test` extra installs gymnasium")

GALLERY = os.path.join(os.path.dirname(os.path.dirname(__file__)), "examples", "tasks", "third_party")
PENDULUM = "pkg://dm_control/suite/pendulum.xml"
POINT_MASS = "pkg://dm_control/suite/point_mass.xml"


# ------------------------------------------------------------ pkg:// paths
def test_pkg_path_resolves_inside_the_installed_package():
    path = resolve_model_path("pkg://dm_control/suite/cartpole.xml")
    assert path.endswith(os.path.join("dm_control", "suite", "cartpole.xml")) and os.path.isfile(path)
    gym = resolve_model_path("pkg://gymnasium/envs/mujoco/assets/inverted_pendulum.xml")
    assert os.path.isfile(gym)
    assert resolve_model_path("model.xml", "/some/dir") == os.path.join("/some/dir", "model.xml")


def test_pkg_path_errors_say_what_to_install_or_fix():
    with pytest.raises(pj.ModelLoadError, match="not installed.*pip install dm-control"):
        _resolve_with_missing("dm_control")
    with pytest.raises(pj.ModelLoadError, match="no file 'suite/nope.xml'.*cartpole.xml"):
        resolve_model_path("pkg://dm_control/suite/nope.xml")
    for bad in ("pkg://dm_control", "pkg://../x.xml", "pkg://dm_control/suite/../x.xml"):
        with pytest.raises(pj.ModelLoadError, match="pkg://PACKAGE/PATH"):
            resolve_model_path(bad)


def _resolve_with_missing(package):
    """Resolve with ``package`` looked up as if it were not installed."""
    import importlib.util

    real = importlib.util.find_spec
    importlib.util.find_spec = lambda name, *a: None if name == package else real(name, *a)
    try:
        return resolve_model_path(f"pkg://{package}/suite/cartpole.xml")
    finally:
        importlib.util.find_spec = real


def test_every_gallery_task_loads_from_the_installed_packages():
    files = sorted(f for f in os.listdir(GALLERY) if f.endswith(".toml"))
    assert len(files) >= 10
    for name in files:
        env = load_task(os.path.join(GALLERY, name))
        assert env.limited  # every gallery model has a ctrlrange
        assert all("`energy` flag" in note for note in env.model_notes)
        assert bool(env.model_notes) == bool(env.mj_model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_ENERGY)


# ------------------------------------------------------ loading as shipped
def test_energy_flag_is_switched_off_for_mjx_with_a_note():
    env = pj.Env.from_xml(PENDULUM, horizon=3)
    assert env.mj_model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_ENERGY  # the model as shipped
    assert not env.data.model.opt.enableflags & mujoco.mjtEnableBit.mjENBL_ENERGY  # MJX's copy
    (note,) = env.model_notes
    assert "`energy` flag is switched off" in note
    assert env.replace(horizon=4).model_notes == env.model_notes


def test_pgs_solver_is_replaced_by_newton_with_a_note():
    model = mujoco.MjModel.from_xml_path(resolve_model_path("pkg://gymnasium/envs/mujoco/assets/humanoid.xml"))
    assert model.opt.solver == mujoco.mjtSolver.mjSOL_PGS
    env = pj.Env.from_model(model, horizon=3, name="humanoid")
    assert int(env.data.model.opt.solver) == int(mujoco.mjtSolver.mjSOL_NEWTON)
    assert any("PGS is replaced by Newton" in n for n in env.model_notes)


_ONE_LINK = """
<mujoco>
  <option integrator="{integrator}"/>
  <worldbody><body><joint name="j" type="hinge" axis="0 1 0"/>
    <geom type="capsule" fromto="0 0 0 0 0 0.5" size="0.02" mass="1"/></body></worldbody>
  <actuator>{actuator}</actuator>
</mujoco>
"""


def test_dynamics_changing_features_mjx_cannot_run_are_refused_by_name_on_mjx():
    """They load, and MuJoCo's C engine runs them (tests/test_mjx_optional.py); MJX refuses by name."""
    motor = '<motor joint="j"/>'
    implicit_xml = _ONE_LINK.format(integrator="implicit", actuator=motor)
    implicit = pj.Env.from_model(mujoco.MjModel.from_xml_string(implicit_xml))
    with pytest.raises(pj.ModelLoadError, match="integrator is 'implicit'.*implicitfast"):
        engines.on_engine(implicit, "mjx")
    dog_model = mujoco.MjModel.from_xml_path(resolve_model_path("pkg://dm_control/suite/dog.xml"))
    dog = pj.Env.from_model(dog_model, name="dog")
    with pytest.raises(pj.ModelLoadError, match="MJX cannot load the model 'dog'.*collisions not implemented"):
        engines.on_engine(dog, "mjx")
    assert dog.dims.na == 38 and dog.dims.nx == 87 + 85 + 38  # its filtered motors' activations are states


def test_model_based_nonfinite_message_names_the_elliptic_cone():
    # MJX's forward-mode derivative through an active elliptic-cone contact is
    # NaN (dm_control's finger at its gallery start; finite with cone="pyramidal").
    finger = load_task(os.path.join(GALLERY, "dmc_finger_turn.toml")).mj_model
    assert "elliptic friction cone" in nonfinite_hint(finger)
    assert nonfinite_hint(pj.Env.from_xml(PENDULUM, horizon=3).mj_model) == ""


def _png(path, rgb):
    """A 2 x 2 RGB PNG file (written by hand: no imaging library needed)."""
    raw = b"".join(b"\x00" + bytes(rgb) * 2 for _ in range(2))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", 2, 2, 8, 2, 0, 0, 0)
    body = chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + body)


def test_includes_meshes_textures_cameras_lights_and_materials_load(tmp_path):
    (tmp_path / "assets").mkdir()
    _png(tmp_path / "assets" / "wood.png", (150, 100, 50))
    (tmp_path / "assets" / "box.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
    )
    (tmp_path / "common.xml").write_text(
        """<mujoco><asset>
  <texture name="wood" type="2d" file="assets/wood.png"/>
  <texture name="sky" type="skybox" builtin="gradient" rgb1="1 1 1" rgb2="0 0 0" width="8" height="8"/>
  <material name="wood" texture="wood"/>
  <mesh name="box" file="assets/box.obj" scale="0.1 0.1 0.1"/>
</asset></mujoco>"""
    )
    (tmp_path / "robot.xml").write_text(
        """<mujoco model="dressed">
  <include file="common.xml"/>
  <visual><headlight ambient="0.3 0.3 0.3"/></visual>
  <worldbody>
    <light name="sun" pos="0 0 3" directional="true"/>
    <camera name="side" pos="0 -2 1" xyaxes="1 0 0 0 1 2"/>
    <body name="pole">
      <joint name="hinge" type="hinge" axis="0 1 0"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.5" size="0.02" mass="1" material="wood"/>
      <geom type="mesh" mesh="box" contype="0" conaffinity="0" mass="0"/>
    </body>
  </worldbody>
  <actuator><motor joint="hinge" ctrllimited="true" ctrlrange="-1 1"/></actuator>
</mujoco>"""
    )
    env = pj.Env.from_xml(tmp_path / "robot.xml", horizon=3)
    m = env.mj_model
    assert (m.nmesh, m.ntex, m.nmat, m.ncam, m.nlight) == (1, 2, 1, 1, 1)
    assert env.model_notes == ()


# ------------------------------------------------------------- tendons etc.
def test_physics_step_keeps_the_dtypes_of_a_tendon_model():
    """MJX's tendon stage writes its wrap indices as int64 under x64 where
    make_data made int32; physics_step hands back the dtypes it was given
    (else the rollouts' scan refuses its own carry)."""
    env = pj.Env.from_xml(POINT_MASS, substeps=2, horizon=3)
    d0 = with_state(env.dims, pj_make_data(env), env.data.x0)
    out = jax.eval_shape(lambda d: physics_step(env.dims, env.data.model, d, jnp.zeros(2)), d0)
    dtypes = jax.tree_util.tree_map(lambda a: a.dtype, d0)
    assert jax.tree_util.tree_map(lambda a: a.dtype, out) == dtypes
    assert d0._impl.ten_wrapadr.dtype == jnp.int32


def pj_make_data(env):
    from mujoco import mjx

    return mjx.make_data(env.data.model)


def _point_mass_task(**kw):
    # The target x = 0.35 lies beyond the joint range (+-0.29): the optimum
    # drives the mass into its limit, so the limit constraint acts.
    args = dict(substeps=5, horizon=12, x0={"qpos": [0.24, 0.0]}, target=[0.35, 0.0, 0.0, 0.0])
    args.update(Q=[10.0, 10.0, 0.1, 0.1], QT=1000.0, R=0.1)
    args.update(kw)
    return pj.Env.from_xml(POINT_MASS, **args)


def test_point_mass_tendons_and_joint_limit_solve_to_the_model_based_optimum():
    env = _point_mass_task()
    cfg = pj.default_config(env, max_iterations=30)
    pod = pj.solve(env, cfg)
    ref = pj.solve_model_based(env, cfg)
    # Both end pressed against the limit, not at the target 0.35 beyond it.
    assert ref.status == pj.Status.CONVERGED
    assert ref.states[-1, 0] == pytest.approx(0.29, abs=0.005)
    assert pod.states[-1, 0] == pytest.approx(0.29, abs=0.005)
    # The soft limit is a kink in the dynamics: the exact (local) linearisation
    # stops a little above what the data-based fit, whose perturbations span
    # the kink, reaches (measured before re-identification: POD-iLQR 4.89741,
    # model-based 4.90979; POD then stopped line_search_failed, and now
    # re-identifies at other sigmas first). No noise: deterministic up to round-off.
    assert pod.final_cost <= ref.final_cost * (1 + 1e-3)
    assert pod.final_cost < 0.5 * pod.cost_history[0]
    assert pod.recompiles_after_first == 0


def test_point_mass_rolls_out_under_noise():
    env = _point_mass_task(noise={"initial": 0.01, "process": 0.001})
    dims, data = env.dims, env.data
    noise = sample(jax.random.PRNGKey(0), data.noise, 4, 12)
    policy = open_loop_policy(jnp.full((12, 2), 1.0), dims.nz)
    zero = jnp.zeros((12, 2))
    traj = rollout_batch(dims, 1, data, policy, zero, zero, record_state=True, noise=noise)
    x = np.asarray(traj.x)
    assert np.all(np.isfinite(x))
    assert np.all(x[:, -1, :2].std(axis=0) > 1e-4)  # the noise acts
    assert np.all(x[:, :, 0] < 0.29 + 0.01)  # full force into the limit: it holds (soft, a few mm)
    assert x[:, -1, 0].min() > 0.28


def test_dm_control_pendulum_with_energy_flag_solves_and_reports_the_note():
    # Torque limited (+-1 N m): swing from 2.6 rad down to hanging (pi) at rest.
    env = pj.Env.from_xml(
        PENDULUM, substeps=5, horizon=12, x0={"qpos": [2.6]}, target=[math.pi, 0.0], Q=[1.0, 0.1], QT=100.0, R=0.1
    )
    pod = pj.solve(env, pj.default_config(env, max_iterations=30))
    assert pod.status == pj.Status.CONVERGED
    assert pod.final_cost < 0.5 * pod.cost_history[0]
    np.testing.assert_allclose(pod.states[-1], [math.pi, 0.0], atol=0.05)
    assert any("`energy` flag is switched off" in w for w in pod.warnings)
    assert any("`energy` flag is switched off" in w for w in pod.to_dict()["warnings"])


def test_cli_prints_the_energy_note(tmp_path, capsys):
    task = tmp_path / "pendulum.toml"
    task.write_text(
        f'model = "{PENDULUM}"\nsubsteps = 5\nhorizon = 12\ntarget = [3.141592653589793, 0.0]\n'
        "[start]\nqpos = [2.6]\n[cost]\nQ = [1.0, 0.1]\nR = 0.1\n[solver]\nmax_iterations = 2\n"
    )
    assert cli_main(["solve", str(task), "--quiet", "--no-plots", "--out", str(tmp_path / "r.json")]) == 0
    err = capsys.readouterr().err
    assert "note: MuJoCo's `energy` flag is switched off for MJX" in err


def test_dm_control_reacher_reaches_within_its_joint_limits():
    env = load_task(os.path.join(GALLERY, "dmc_reacher_reach.toml")).replace(horizon=12)
    pod = pj.solve(env, pj.default_config(env, max_iterations=30))
    assert pod.status == pj.Status.CONVERGED
    assert pod.final_cost < 0.2 * pod.cost_history[0]
    assert np.all(np.abs(pod.states[:, 1]) <= 2.7925268 + 0.01)  # the wrist stays within its +-160 degrees
    assert pod.recompiles_after_first == 0
