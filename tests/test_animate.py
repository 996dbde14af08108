"""Animations: frames, the fallback renderer, every geom type, the CLI (issue 17)."""

import importlib
import json
import os
import subprocess
import sys

import mujoco
import numpy as np
import pytest
from PIL import Image, ImageSequence

import podilqr_jax as pj
from podilqr_jax.cli import main
from podilqr_jax.errors import ConfigError
from podilqr_jax.task.tasks import MODELS_DIR
from podilqr_jax.viz import render
from podilqr_jax.viz.animate import (
    Panel,
    _durations_ms,
    animate,
    cost_so_far,
    frame_steps,
    prepare,
    render_frames,
    target_pose,
)

animate_module = importlib.import_module("podilqr_jax.viz.animate")  # `pj.animate` is the function

T = 10  # horizon of the solved fixture (control_dt 0.1 s)


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    """`podilqr solve` of pendulum-full at horizon 10 (the settings of test_cli's
    solve, so the compiled solver is shared through the test compile cache)."""
    out = tmp_path_factory.mktemp("solve") / "r.json"
    code = main(["solve", "pendulum-full", "--set", "max_iterations=4", "--set", "horizon=10", "--out", str(out)])
    assert code == 0
    return out


def _gif(path):
    im = Image.open(path)
    frames = [f.convert("RGB") for f in ImageSequence.Iterator(im)]
    durations = [f.info["duration"] for f in ImageSequence.Iterator(Image.open(path))]
    return im.format, frames, durations


def test_solve_writes_the_motion_gif_at_real_time(solved):
    fmt, frames, durations = _gif(str(solved).replace(".json", "_motion.gif"))
    assert fmt == "GIF"
    assert len(frames) == T + 1  # one frame per control step
    assert frames[0].size == (320, 240)
    assert durations[:-1] == [100] * T  # control_dt = 0.1 s
    assert durations[-1] == 1000  # the last frame held 1 s


def test_cost_so_far_is_the_solvers_cost(solved):
    result = pj.load_result(solved)
    env = pj.make_task("pendulum-full", horizon=T)
    panel = prepare(result, env)
    assert panel.cost[0] == 0.0
    assert np.all(np.diff(panel.cost) >= 0)
    assert panel.cost[-1] == pytest.approx(result.final_cost, rel=1e-9)
    # a batch of trajectories gives one row each
    z = np.asarray(result.observations)
    u = np.asarray(result.controls)
    both = cost_so_far(env, np.stack([z, z]), np.stack([u, u]))
    np.testing.assert_allclose(both[1], panel.cost)
    np.testing.assert_allclose(panel.target, [0.0])  # upright


def test_frames_count_size_and_motion(solved):
    result = pj.load_result(solved)
    env = pj.make_task("pendulum-full", horizon=T)
    panel = prepare(result, env)
    frames, stride, note = render_frames([panel], env.mj_model, width=160, height=120, renderer="matplotlib")
    assert stride == 1 and "matplotlib" in note
    assert len(frames) == T + 1
    assert all(f.shape == (120, 160, 3) and f.dtype == np.uint8 for f in frames)
    # Below the text box the picture changes where the pendulum moves and only there.
    moving = np.abs(np.diff(result.states[:, 0])) > 0.05
    assert moving.sum() >= 5  # the solve swings it
    lower = [f[50:] for f in frames]
    for i in range(T):
        if moving[i]:
            assert np.any(lower[i] != lower[i + 1]), i
    still = Panel("still", np.full((4, 1), 2.0), np.zeros(4), None, None, None, "", 0.1)
    frames, _, _ = render_frames([still], env.mj_model, width=160, height=120, renderer="matplotlib")
    assert all(np.array_equal(frames[0][50:], f[50:]) for f in frames)


def test_episodes_and_compare_side_by_side(solved, tmp_path):
    result = pj.load_result(solved)
    out = tmp_path / "cmp.gif"
    info = result.animate(
        out, episodes=3, noise=0.2, compare=result, width=160, height=120, renderer="matplotlib", hold=0.0
    )
    fmt, frames, durations = _gif(out)
    assert fmt == "GIF" and info.frames == len(frames) == T + 1
    assert frames[0].size == (2 * 160, 120)  # two panels
    assert durations == [100] * (T + 1)
    # the faded episodes add pixels that the nominal alone does not draw
    plain = animate(result, tmp_path / "plain.gif", width=160, height=120, renderer="matplotlib")
    _, alone, _ = _gif(plain.path)
    assert not np.array_equal(np.asarray(frames[-1])[40:, :160], np.asarray(alone[-1])[40:])


def test_noiseless_episodes_are_the_true_cost_runs(solved):
    """With noise 0 an episode is the policy's run on the noiseless system
    (cost: the result's true cost) and, open loop, the open-loop replay."""
    result = pj.load_result(solved)
    env = pj.make_task("pendulum-full", horizon=T)
    closed = prepare(result, env, episodes=3, noise=0.0)
    opened = prepare(result, env, episodes=3, noise=0.0, open_loop=True)
    assert closed.episode_cost[-1] == pytest.approx(result.final_true_cost, rel=1e-9)
    assert opened.episode_cost[-1] == pytest.approx(result.open_loop_cost_history[-1], rel=1e-9)
    np.testing.assert_allclose(closed.episode_qpos[0], result.states[:, :1], atol=1e-9)


@pytest.mark.skipif(animate_module.ffmpeg_binary() is None, reason="no ffmpeg (pip install imageio-ffmpeg)")
def test_mp4_where_an_encoder_is_installed(solved, tmp_path):
    info = pj.load_result(solved).animate(tmp_path / "m.mp4", width=96, height=72, renderer="matplotlib")
    assert info.frames == T + 1
    with open(info.path, "rb") as f:
        assert f.read(12)[4:8] == b"ftyp"  # an MP4 container


def test_frame_steps_keep_real_time():
    steps, stride = frame_steps(100, 0.01)  # 100 fps of control steps: every 4th at 25 fps
    assert stride == 4 and steps[0] == 0 and steps[-1] == 100 and len(steps) == 26
    durations = _durations_ms(steps, 0.01, hold=0.5)
    assert sum(durations) == 1000 + 500  # 1 s of motion, then the held frame
    steps, stride = frame_steps(30, 0.1, fps=4)
    assert stride == 3 and list(steps[-2:]) == [27, 30]
    with pytest.raises(ConfigError, match="fps"):
        frame_steps(10, 0.1, fps=0)


ALL_GEOMS = """
<mujoco>
  <asset>
    <mesh name="tet" vertex="0 0 0  0.3 0 0  0 0.3 0  0 0 0.3"/>
    <hfield name="hill" nrow="3" ncol="3" size="0.3 0.3 0.1 0.05"/>
    <material name="paint" rgba="0.8 0.2 0.2 1"/>
  </asset>
  <worldbody>
    <geom type="plane" size="0 0 1" rgba="0.3 0.5 0.3 1"/>
    <geom type="hfield" hfield="hill" pos="-2 0 0" rgba="0.6 0.4 0.2 1"/>
    <body pos="0 0 1">
      <joint name="swing" type="hinge" axis="0 1 0"/>
      <geom type="sphere" size="0.1" pos="0 0 0.5" rgba="1 0 0 1"/>
      <geom type="capsule" fromto="0 0 0 0 0 0.4" size="0.05" rgba="0 1 0 1"/>
      <geom type="ellipsoid" size="0.2 0.1 0.05" pos="0.5 0 0" rgba="0 0 1 1"/>
      <geom type="cylinder" size="0.08 0.1" pos="-0.5 0 0" rgba="1 1 0 1"/>
      <geom type="box" size="0.1 0.1 0.1" pos="0 0 -0.5" rgba="0 1 1 1"/>
      <geom type="mesh" mesh="tet" pos="0.5 0 0.5" rgba="1 0 1 1"/>
      <geom type="sphere" size="0.1" pos="-0.5 0 0.5" material="paint"/>
      <geom type="box" size="0.1 0.1 0.1" pos="0.5 0 -0.5" group="3" rgba="0.2 0.4 0.6 1"/>
    </body>
  </worldbody>
</mujoco>
"""


def test_every_geom_type_renders_in_its_colour():
    model = mujoco.MjModel.from_xml_string(ALL_GEOMS)
    qpos = np.linspace(0.0, 1.0, 4)[:, None]
    panel = Panel("all geoms", qpos, np.zeros(4), np.array([0.3]), None, None, "", 0.1)
    frames, _, note = render_frames([panel], model, width=200, height=150, renderer="matplotlib")
    assert len(frames) == 4 and frames[0].shape == (150, 200, 3)
    pixels = {tuple(p) for p in frames[0].reshape(-1, 3)}
    for rgb in [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (0, 1, 1), (1, 0, 1), (0.8, 0.2, 0.2), (0.6, 0.4, 0.2)]:
        assert tuple(int(round(255 * c)) for c in rgb) in pixels, rgb  # each face drawn in its colour
    assert (51, 102, 153) not in pixels  # group 3 is hidden, as MuJoCo hides it


def test_view_plane_follows_the_motion():
    cart = mujoco.MjModel.from_xml_path(os.path.join(MODELS_DIR, "cartpole.xml"))
    q = np.stack([np.linspace(-1, 1, 9), np.linspace(np.pi, 0, 9)], axis=1)
    view = render.choose_view(cart, [q], 320, 240)
    np.testing.assert_allclose(np.abs(view.forward), [0, 1, 0], atol=1e-12)  # the x-z plane, face on
    np.testing.assert_allclose(view.right, [1, 0, 0], atol=1e-12)
    assert not view.top and view.floor is not None
    arm = mujoco.MjModel.from_xml_string(
        """<mujoco><worldbody><body><joint type="hinge" axis="0 0 1"/>
        <geom type="capsule" fromto="0 0 0 1 0 0" size="0.05"/></body></worldbody></mujoco>"""
    )
    view = render.choose_view(arm, [np.linspace(0, 3, 9)[:, None]], 320, 240)
    assert view.top  # a horizontal planar arm is seen from above
    np.testing.assert_allclose(view.forward, [0, 0, -1], atol=1e-12)


def test_target_pose_moves_only_observed_coordinates():
    env = pj.make_task("cartpole-partial")  # observes the slider and the hinge angle
    np.testing.assert_allclose(target_pose(env, np.array([0.7, 0.2, 1.0, -1.0])), [0.0, 0.0])


def test_fallback_when_mujoco_cannot_render(monkeypatch):
    model = mujoco.MjModel.from_xml_string(ALL_GEOMS)
    view = render.choose_view(model, [np.zeros((1, 1))], 64, 48)

    def no_gl(*args, **kwargs):
        raise RuntimeError("no OpenGL here")

    monkeypatch.setattr(render, "_GL_FAILURE", None)
    monkeypatch.setattr(render, "MujocoRenderer", no_gl)
    drawer, note = render.make_renderer(model, view, 64, 48, "auto")
    assert isinstance(drawer, render.GeomRenderer) and "no OpenGL here" in note
    with pytest.raises(ConfigError, match="MUJOCO_GL"):
        render.make_renderer(model, view, 64, 48, "mujoco")


def test_fallback_without_a_display_is_silent(tmp_path):
    """MUJOCO_GL=glfw with no display: no OpenGL backend loads; the fallback
    draws, with no traceback or GLFW warning on stderr."""
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["MUJOCO_GL"] = "glfw"
    code = (
        "import mujoco, numpy as np\n"
        "from podilqr_jax.viz import render\n"
        "m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size=\"0.1\"/></worldbody></mujoco>')\n"
        "v = render.choose_view(m, [np.zeros((1, 0))], 64, 48)\n"
        "for _ in range(2):\n"
        "    r, note = render.make_renderer(m, v, 64, 48)\n"
        "    print(r.name, r.render([render.Layer(np.zeros(0))]).shape)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split("\n")[:2] == ["matplotlib (48, 64, 3)"] * 2
    assert "Traceback" not in done.stderr and "GLFW" not in done.stderr


def test_cli_animate(solved, tmp_path, capsys):
    out = tmp_path / "motion.gif"
    assert main(["animate", str(solved), "--out", str(out), "--width", "160", "--height", "120"]) == 0
    fmt, frames, _ = _gif(out)
    assert fmt == "GIF" and len(frames) == T + 1 and frames[0].size == (160, 120)
    assert "11 frames of 0.1 s" in capsys.readouterr().err
    both = tmp_path / "both.gif"
    args = ["animate", str(solved), "--out", str(both), "--episodes", "3", "--noise", "0.1", "--compare", str(solved)]
    assert main(args + ["--width", "96", "--height", "72", "--fps", "5"]) == 0
    fmt, frames, durations = _gif(both)
    assert frames[0].size == (192, 72) and len(frames) == 6 and durations[0] == 200  # 5 fps: every 2nd step


def test_cli_animate_bad_input(solved, tmp_path, capsys):
    other = json.loads(solved.read_text())
    other["task"] = "cartpole-full"
    mismatched = tmp_path / "other.json"
    mismatched.write_text(json.dumps(other))
    not_result = tmp_path / "x.json"
    not_result.write_text('{"a": 1}')
    gif = str(tmp_path / "a.gif")
    cases = [
        (["animate", str(tmp_path / "missing.json"), "--out", gif], "No result file"),
        (["animate", str(not_result), "--out", gif], "is not a podilqr result"),
        (["animate", str(solved), "--out", gif, "--compare", str(mismatched)], "same task"),
        (["animate", str(solved), "--out", str(tmp_path / "a.png")], ".gif or .mp4"),
        (["animate", str(solved), "--out", gif, "--episodes", "-1"], "episodes"),
        (["animate", str(solved), "--out", gif, "--task", "cartpole-full"], "does not fit"),
        (["animate", str(solved), "--out", gif, "--vs-open-loop"], "episodes >= 1"),
        (["animate", str(solved), "--out", gif, "--noise", "-0.1"], "noise"),
        (["animate", str(solved), "--out", gif, "--width", "8"], "width"),
    ]
    for argv, message in cases:
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert message in err.replace("\n", " ") and "Traceback" not in err, (argv, err)


def test_mp4_needs_an_encoder(solved, tmp_path, monkeypatch):
    monkeypatch.setattr(animate_module, "ffmpeg_binary", lambda: None)
    with pytest.raises(ConfigError, match="imageio-ffmpeg"):
        pj.load_result(solved).animate(tmp_path / "m.mp4")
