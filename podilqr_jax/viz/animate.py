"""Animations of a solve: the nominal motion, noisy closed-loop episodes, two results side by side.

``podilqr animate RESULT.json --out swingup.gif`` and ``Result.animate(path)``
call :func:`animate`. A frame shows the system at one control step (the
task's real time: each frame lasts ``control_dt``; when that is shorter than
``1 / fps`` every few steps are shown and each frame lasts as many steps),
with

- the time and the cost so far: the task's running cost (the solver's
  ``cost.trajectory_cost``, with the task's Q, R, QT, target and goal step)
  summed over the steps before the frame's, plus the terminal cost on the
  last frame, which then shows the trajectory's cost;
- the target pose as a translucent green ghost: the nominal's final pose
  moved the least amount that makes its observation the target
  (x = x_T + C^+ (z* - C x_T); observed sensors that are not state
  coordinates are left out);
- with ``episodes=N``, N noisy closed-loop episodes of the learnt policy
  (``episodes.run_episodes``) as faded copies behind the nominal, under the
  noise ``podilqr evaluate`` applies at level ``noise``: actuator noise of
  standard deviation ``noise`` x max|u_bar| per actuator plus measurement
  noise (``episodes.noise_at_level``); the frame shows their mean cost so far.

``compare=OTHER`` draws a second result of the same task beside the first,
through the same camera. Frames come from :mod:`podilqr_jax.viz.render`
(MuJoCo's renderer where an OpenGL backend loads, otherwise the matplotlib
drawing of the geoms). A ``.gif`` is written with Pillow; ``.mp4`` needs an
ffmpeg binary (on PATH, or from ``pip install imageio-ffmpeg``, the
``video`` extra).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import shutil
import subprocess
from typing import NamedTuple, Optional, Sequence

import numpy as np

from ..errors import ConfigError
from .render import Layer, choose_view, make_renderer

_TARGET_TINT = (0.15, 0.7, 0.3)
_EPISODE_TINT = (0.2, 0.4, 0.8)  # the colour of the episodes' text line
_MAX_FPS = 25.0  # GIF viewers play delays under 20 ms slowly; 25 fps is smooth enough


class Animation(NamedTuple):
    """What :func:`animate` wrote."""

    path: str
    frames: int  # frames in the file (the held last frame counted once)
    frame_s: float  # seconds of motion per frame (a multiple of control_dt)
    stride: int  # control steps per frame
    size: tuple[int, int]  # (width, height) in pixels
    renderer: str  # which renderer drew it, and why


class Panel(NamedTuple):
    """One result prepared for drawing."""

    title: str
    qpos: np.ndarray  # [T+1, nq] nominal
    cost: np.ndarray  # [T+1] cost so far at each step
    target: Optional[np.ndarray]  # [nq] target pose, or None
    episode_qpos: Optional[np.ndarray]  # [E, T+1, nq]
    episode_cost: Optional[np.ndarray]  # [T+1] mean cost so far over the episodes
    episode_label: str
    control_dt: float


# ------------------------------------------------------------------ the task
def task_env(result, task: Optional[str] = None):
    """The task ``result`` was solved on, rebuilt from its recorded name (or
    ``task``: a bundled name or a task file), at the result's horizon."""
    from ..errors import PodIlqrError
    from ..task.taskfile import load_task
    from ..task.tasks import make_task

    name = task or result.task
    is_file = name.endswith((".toml", ".json")) or os.path.sep in name
    try:
        env = load_task(name) if is_file else make_task(name)
    except PodIlqrError as exc:
        raise ConfigError(
            f"Cannot rebuild the task {name!r} of the result: {exc} Pass the task (`--task` on the command "
            "line, `env=` in Python)."
        ) from None
    return fit_env(env, result)


def fit_env(env, result):
    """``env`` at the result's horizon, after checking the result belongs to it."""
    states = np.asarray(result.states)
    controls = np.asarray(result.controls)
    if states.ndim != 2 or states.shape[1] != env.dims.nx or controls.ndim != 2 or controls.shape[1] != env.dims.nu:
        raise ConfigError(
            f"The result ({result.task!r}: states {states.shape}, controls {controls.shape}) does not fit the "
            f"task {env.name!r} (nq + nv = {env.dims.nx}, nu = {env.dims.nu}): pass the task the result was "
            "solved on (--task)."
        )
    T = controls.shape[0]
    if states.shape[0] != T + 1:
        raise ConfigError(f"The result's states {states.shape} and controls {controls.shape} disagree on T.")
    return env if env.dims.horizon == T else env.replace(horizon=T)


# ----------------------------------------------------------------- the cost
def cost_so_far(env, z: np.ndarray, u: np.ndarray) -> np.ndarray:
    """[..., T+1]: the running cost of the steps before t (t = 0 .. T) of
    z [..., T+1, nz], u [..., T, nu], the terminal cost added at t = T (so
    the last entry is ``cost.trajectory_cost``)."""
    d = env.data
    e = np.asarray(z, dtype=float) - np.asarray(d.z_target)
    u = np.asarray(u, dtype=float)
    T = u.shape[-2]
    goal = int(d.goal_step)
    Q, QT, R = (np.asarray(a) for a in (d.Q, d.QT, d.R))
    Qt = np.where((np.arange(T) >= goal)[:, None, None], QT, Q)
    step = np.einsum("...ti,tij,...tj->...t", e[..., :-1, :], Qt, e[..., :-1, :])
    step = step + np.einsum("...ti,ij,...tj->...t", u, R, u)
    zero = np.zeros(step.shape[:-1] + (1,))
    out = np.concatenate([zero, np.cumsum(step, axis=-1)], axis=-1)
    out[..., -1] += np.einsum("...i,ij,...j->...", e[..., -1, :], QT, e[..., -1, :])
    return out


def _observations(env, x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if not env.dims.sensors:
        return x @ np.asarray(env.data.C).T
    from ..sim.rollout import observations_of

    flat = x.reshape(-1, x.shape[-1])
    return np.asarray(observations_of(env.dims, env.data, flat)).reshape(x.shape[:-1] + (env.dims.nz,))


def target_pose(env, x_final: np.ndarray) -> Optional[np.ndarray]:
    """qpos of the pose closest to ``x_final`` whose state-coordinate
    observations equal the target (None if the task observes no state)."""
    C = np.asarray(env.data.C)
    rows = np.flatnonzero(np.any(C != 0, axis=1))  # rows that are sensors only (D) have C = 0
    if rows.size == 0 or not np.all(np.isfinite(x_final)):
        return None
    Cs = C[rows]
    z_star = np.asarray(env.data.z_target)[rows]
    x = x_final + np.linalg.pinv(Cs) @ (z_star - Cs @ x_final)
    return x[: env.dims.nq]


# --------------------------------------------------------------- episodes
def _check_episodes(n, minimum: int = 0) -> None:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < minimum:
        raise ConfigError(f"`episodes` must be an integer >= {minimum}; got {n!r}.")


def _check_noise(noise) -> None:
    if isinstance(noise, bool) or not isinstance(noise, (int, float)) or not math.isfinite(noise) or noise < 0:
        raise ConfigError(
            f"`noise` must be a finite number >= 0 (actuator noise as a fraction of the largest control); "
            f"got {noise!r}."
        )


def noisy_episodes(result, env, n: int, noise: float, seed: int = 0, open_loop: bool = False):
    """``n`` episodes of the result's policy under evaluate's noise level
    ``noise`` (module docstring): ``episodes.Episodes``."""
    import jax
    import jax.numpy as jnp

    from ..control.episodes import U_LIMIT, actuator_limits, noise_at_level, run_episodes
    from ..task.noise import NoiseModel

    _check_episodes(n, minimum=1)
    _check_noise(noise)
    policy = result.policy()
    if open_loop:  # K = 0, as policy.open_loop(), but under the same name: run_episodes does not recompile
        policy = dataclasses.replace(
            policy, controller=policy.controller._replace(K=jnp.zeros_like(policy.controller.K))
        )
    clean = env.replace(noise=NoiseModel())
    u_max = np.max(np.abs(np.asarray(result.controls)), axis=0)
    limits = actuator_limits(clean, u_max, U_LIMIT)
    measured = np.asarray(result.states if policy.measures == "state" else result.observations)
    if measured.shape[1] != policy.nz:
        raise ConfigError(
            f"The result measures {policy.nz} number(s) per step but the task {env.name!r} observes "
            f"{measured.shape[1]}: pass the task the result was solved on (--task)."
        )
    levels = noise_at_level(clean, float(noise), u_max, np.ptp(measured, axis=0), limits)
    key = jax.random.PRNGKey(int(seed))
    return run_episodes(clean.dims, clean.data, policy, key, levels, int(n))


def prepare(
    result,
    env,
    *,
    episodes: int = 0,
    noise: float = 0.1,
    seed: int = 0,
    open_loop: bool = False,
    title: Optional[str] = None,
) -> Panel:
    """A result's panel: nominal poses, cost so far, target, episodes."""
    env = fit_env(env, result)
    nq = env.dims.nq
    x = np.asarray(result.states, dtype=float)
    u = np.asarray(result.controls, dtype=float)
    cost = cost_so_far(env, _observations(env, x), u)
    ep_q = ep_cost = None
    label = ""
    if episodes:
        ep = noisy_episodes(result, env, episodes, noise, seed=seed, open_loop=open_loop)
        ep_x = np.asarray(ep.x)
        ep_q = ep_x[..., :nq]
        c = cost_so_far(env, np.asarray(ep.z), np.asarray(ep.u))
        finite = np.all(np.isfinite(c), axis=1)
        ep_cost = np.mean(c[finite], axis=0) if finite.any() else np.full(c.shape[1], np.inf)
        kind = "open-loop" if open_loop else "closed-loop"
        level = f"noise {noise:g}" if noise else "noiseless"
        label = f"{int(episodes)} {kind} episode{'s' if episodes > 1 else ''}, {level}"
        if not finite.all():  # the mean is over the finite ones
            label += f" ({int((~finite).sum())} non-finite left out)"
    name = title if title is not None else f"{result.method} on {result.task}"
    return Panel(name, x[:, :nq], cost, target_pose(env, x[-1]), ep_q, ep_cost, label, float(result.control_dt))


# ---------------------------------------------------------------- frames
def frame_steps(T: int, control_dt: float, fps: Optional[float] = None) -> tuple[np.ndarray, int]:
    """The control steps shown (0 .. T, the last always) and the stride:
    one frame per step unless that is faster than ``fps`` (default 25)."""
    rate = _MAX_FPS if fps is None else float(fps)
    if not math.isfinite(rate) or rate <= 0:
        raise ConfigError(f"`fps` must be a positive number; got {fps!r}.")
    stride = max(1, int(math.ceil(1.0 / (rate * control_dt) - 1e-9)))
    steps = np.arange(0, T + 1, stride)
    if steps[-1] != T:
        steps = np.append(steps, T)
    return steps, stride


@functools.lru_cache(maxsize=8)
def _font(size: int):
    from matplotlib import font_manager
    from PIL import ImageFont

    try:
        return ImageFont.truetype(font_manager.findfont("DejaVu Sans"), size)
    except OSError:
        return ImageFont.load_default()


def _text_metrics(w: int, h: int) -> tuple[int, int, int]:
    """Font size, line height and padding of the frame text."""
    size = max(9, int(round(min(h / 19, w / 26))))
    return size, size + max(2, size // 4), max(3, size // 3)


def header_height(w: int, h: int, lines: int) -> int:
    """Pixels the text box takes at the top of a w x h frame."""
    _, line_h, pad = _text_metrics(w, h)
    return pad + line_h * lines + pad // 2


def _annotate(frame: np.ndarray, lines: Sequence[tuple[str, tuple[int, int, int]]], legend: str) -> np.ndarray:
    from PIL import Image, ImageDraw

    h, w = frame.shape[:2]
    size, line_h, pad = _text_metrics(w, h)
    font = _font(size)
    small = _font(max(8, size - 2))
    img = Image.fromarray(frame).convert("RGBA")
    over = Image.new("RGBA", img.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(over)
    width = max([draw.textlength(t, font=font) for t, _ in lines] + [0])
    draw.rectangle((0, 0, width + 2 * pad, pad + line_h * len(lines) + pad // 2), fill=(255, 255, 255, 190))
    for i, (text, colour) in enumerate(lines):
        draw.text((pad, pad + i * line_h), text, font=font, fill=colour + (255,))
    if legend:
        lw = draw.textlength(legend, font=small)
        draw.text((w - lw - pad, h - size - pad), legend, font=small, fill=(60, 120, 70, 255))
    return np.asarray(Image.alpha_composite(img, over).convert("RGB"))


def _fmt(c: float) -> str:
    return f"{c:.4g}" if math.isfinite(c) else "inf"


def render_frames(
    panels: Sequence[Panel],
    model,
    *,
    width: int = 320,
    height: int = 240,
    fps: Optional[float] = None,
    renderer: str = "auto",
) -> tuple[list[np.ndarray], int, str]:
    """The frames [height, width x len(panels), 3] (uint8), the stride and the renderer's note."""
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 32 <= v <= 4096:
            raise ConfigError(f"`{name}` must be an integer number of pixels in 32 .. 4096; got {v!r}.")
    dt = panels[0].control_dt
    T = max(p.qpos.shape[0] for p in panels) - 1
    steps, stride = frame_steps(T, dt, fps)
    main = [p.qpos for p in panels] + [p.target[None] for p in panels if p.target is not None]
    extra = [p.episode_qpos.reshape(-1, p.episode_qpos.shape[-1]) for p in panels if p.episode_qpos is not None]
    lines = 3 if extra else 2
    view = choose_view(model, main, width, height, extra=extra, header=header_height(width, height, lines))
    drawer, note = make_renderer(model, view, width, height, renderer)
    frames = []
    try:
        for t in steps:
            tiles = []
            for p in panels:
                i = min(int(t), p.qpos.shape[0] - 1)
                layers = []
                if p.target is not None:
                    layers.append(Layer(p.target, alpha=0.3, tint=_TARGET_TINT, static=False))
                if p.episode_qpos is not None:
                    alpha = float(np.clip(2.4 / len(p.episode_qpos), 0.12, 0.35))
                    for q in p.episode_qpos[:, min(i, p.episode_qpos.shape[1] - 1)]:
                        if np.all(np.isfinite(q)):
                            layers.append(Layer(q, alpha=alpha, tint=_EPISODE_TINT, static=False))
                layers.append(Layer(p.qpos[i]))
                image = drawer.render(layers)
                lines = [(p.title, (30, 30, 34)), (f"t = {i * dt:.2f} s   cost so far {_fmt(p.cost[i])}", (30, 30, 34))]
                if p.episode_cost is not None:
                    j = min(i, len(p.episode_cost) - 1)
                    lines.append((f"{p.episode_label}: mean {_fmt(p.episode_cost[j])}", (40, 80, 150)))
                legend = "green ghost: target" if p.target is not None else ""
                tiles.append(_annotate(image, lines, legend))
            frames.append(np.concatenate(tiles, axis=1) if len(tiles) > 1 else tiles[0])
    finally:
        drawer.close()
    return frames, stride, note


# ----------------------------------------------------------------- writing
def ffmpeg_binary() -> Optional[str]:
    """An ffmpeg executable: on PATH, or imageio-ffmpeg's (the ``video`` extra)."""
    exe = shutil.which("ffmpeg")
    if exe:
        return exe
    try:
        import imageio_ffmpeg
    except ImportError:
        return None
    try:
        return imageio_ffmpeg.get_ffmpeg_exe()
    except Exception:  # installed without its binary
        return None


def _durations_ms(steps: np.ndarray, dt: float, hold: float) -> list[int]:
    """Per-frame GIF delays (GIF counts in 10 ms): rounded on the cumulative
    time, so the whole animation keeps real time; the last frame holds ``hold`` s."""
    times = np.append(steps * dt, steps[-1] * dt + max(dt, hold))
    ticks = np.round(times * 100).astype(int)
    return [int(10 * max(2, d)) for d in np.diff(ticks)]


def write_gif(frames: Sequence[np.ndarray], path: str, durations_ms: Sequence[int]) -> None:
    from PIL import Image

    images = [Image.fromarray(f) for f in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=list(durations_ms), loop=0, optimize=False)


def write_mp4(frames: Sequence[np.ndarray], path: str, frame_s: float, hold: float) -> None:
    exe = ffmpeg_binary()
    if exe is None:
        raise ConfigError(
            f"Writing {path!r} needs an MP4 encoder: install ffmpeg, or `pip install imageio-ffmpeg` "
            "(`pip install podilqr_jax[video]`); or write a .gif."
        )
    h, w = frames[0].shape[:2]
    extra = int(round(max(0.0, hold - frame_s) / frame_s))
    cmd = [
        exe, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}",
        "-framerate", f"{1.0 / frame_s:.6g}", "-i", "-",
        "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", "-c:v", "libx264", path,
    ]  # fmt: skip
    raw = b"".join(np.ascontiguousarray(f).tobytes() for f in list(frames) + [frames[-1]] * extra)
    done = subprocess.run(cmd, input=raw, capture_output=True)
    if done.returncode != 0:
        raise ConfigError(f"ffmpeg ({exe}) could not write {path!r}: {done.stderr.decode(errors='replace')[-300:]}")


# ------------------------------------------------------------------ the call
def animate(
    result,
    path: str | os.PathLike,
    *,
    env=None,
    episodes: int = 0,
    noise: float = 0.1,
    seed: int = 0,
    open_loop: bool = False,
    compare=None,
    compare_env=None,
    titles: Optional[Sequence[str]] = None,
    width: int = 320,
    height: int = 240,
    fps: Optional[float] = None,
    hold: float = 1.0,
    renderer: str = "auto",
) -> Animation:
    """Animate ``result`` (a :class:`~podilqr_jax.ilqr.result.Result`) into
    ``path`` (.gif, or .mp4 where ffmpeg is installed). See the module docstring.

    Args:
      env: the task (default: rebuilt from ``result.task``).
      episodes, noise, seed, open_loop: overlay ``episodes`` noisy episodes
        of the policy (its nominal alone with ``open_loop``) at evaluate's
        noise level ``noise``, drawn with PRNG seed ``seed``.
      compare: a second result of the same task, drawn on the right (with
        its own episodes when ``episodes`` is set); ``compare_env`` its task.
        ``"open_loop"``: the same result on the right with the same noisy
        episodes (same seed) run open loop, the nominal controls alone.
      titles: a title per panel (default ``"METHOD on TASK"``).
      width, height: pixels per panel.
      fps: the highest frame rate (default 25); each frame stays real time.
      hold: seconds the last frame is held before the animation loops.
      renderer: ``"auto"``, ``"mujoco"`` or ``"matplotlib"`` (see
        :func:`podilqr_jax.viz.render.make_renderer`).
    """
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".gif", ".mp4"):
        raise ConfigError(f"The animation path must end in .gif or .mp4; got {path!r}.")
    if not isinstance(hold, (int, float)) or not math.isfinite(hold) or hold < 0:
        raise ConfigError(f"`hold` must be a number of seconds >= 0; got {hold!r}.")
    _check_episodes(episodes)
    _check_noise(noise)
    if ext == ".mp4" and ffmpeg_binary() is None:
        write_mp4([np.zeros((2, 2, 3), np.uint8)], path, 1.0, 0.0)  # raises the install hint
    env = task_env(result) if env is None else fit_env(env, result)
    results = [result]
    envs = [env]
    loops = [open_loop]
    if isinstance(compare, str):
        if compare != "open_loop":
            raise ConfigError(f"`compare` must be a Result or 'open_loop'; got {compare!r}.")
        if not episodes:
            raise ConfigError(
                "Comparing with open loop draws the same noisy episodes run open loop: give episodes >= 1 "
                "(--episodes N)."
            )
        results.append(result)
        envs.append(env)
        loops = [False, True]
        if titles is None:
            titles = [f"{result.method}: closed loop", f"{result.method}: open loop (nominal controls)"]
    elif compare is not None:
        if compare.task != result.task and compare_env is None:
            raise ConfigError(
                f"--compare needs a result of the same task: {result.task!r} vs {compare.task!r}. "
                "Solve both on one task."
            )
        other = fit_env(compare_env if compare_env is not None else env, compare)
        if other.mj_model.nq != env.mj_model.nq or abs(compare.control_dt - result.control_dt) > 1e-12:
            raise ConfigError(
                f"The compared results have different models or control steps ({result.task!r}, "
                f"dt {result.control_dt:g} s vs {compare.task!r}, dt {compare.control_dt:g} s)."
            )
        results.append(compare)
        envs.append(other)
        loops.append(open_loop)
    if titles is not None and len(titles) != len(results):
        raise ConfigError(f"`titles` needs {len(results)} entries (one per panel); got {len(titles)}.")
    panels = [
        prepare(r, e, episodes=episodes, noise=noise, seed=seed, open_loop=ol, title=t)
        for r, e, ol, t in zip(results, envs, loops, titles or [None] * len(results), strict=True)
    ]
    frames, stride, note = render_frames(panels, env.mj_model, width=width, height=height, fps=fps, renderer=renderer)
    dt = panels[0].control_dt
    T = max(p.qpos.shape[0] for p in panels) - 1
    steps, _ = frame_steps(T, dt, fps)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    if ext == ".gif":
        write_gif(frames, path, _durations_ms(steps, dt, hold))
    else:
        write_mp4(frames, path, stride * dt, hold)
    h, w = frames[0].shape[:2]
    return Animation(path, len(frames), stride * dt, stride, (w, h), note)
