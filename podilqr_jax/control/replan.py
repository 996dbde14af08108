"""Receding-horizon replanning: re-solve from where the system is, every few steps.

An episode starts with the solved policy. Every ``every`` steps, each episode
runs POD-iLQR again (``iterations`` iterations, the solve's settings) from its
current state, warm-started from its previous plan shifted by ``every`` steps
(the tail padded with the last control), and continues with the new plan's
policy u = u_bar' + K' (Z - Z_bar') on a fresh information state (the new
plan assumes the rest history at its start, as every solve does).

Choices, documented in docs/evaluation.md:

- The window keeps the solve's horizon T (the plan made at step t ends at
  t + T), so every replan has the same shapes and reuses the compiled stages:
  no replan after the first compiles anything
  (``ReplanEpisodes.compiles_after_first``, a test). The episode still ends
  at T: the plan's goal step (``Env.with_goal_step``) is T - t, so the target
  is to be reached when the episode ends and held over the rest of the window
  (the terminal weight QT on those steps). A plain moving window (goal at
  t + T) optimises a later swing-up than the episode is scored on.
- The re-solve's rollouts start from the system's current true state, as a
  data-based method that runs its rollouts on the system (or on a simulator
  reset to it) would; the controller itself still sees only noisy
  measurements.
- The re-solve runs on ``train_env``: the training system with its own noise
  (none for a noiseless solve), not the evaluation's noise.

The episodes are one MJX batch per segment (``episodes.run_segment``, one
controller per episode); the solves between segments run one episode at a
time through the Python driver.
"""

from __future__ import annotations

import time
from typing import Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from ..compilation.compile_watch import CompileWatch
from ..errors import ConfigError
from ..ilqr.config import SolverConfig
from ..ilqr.solver import solve
from ..task import tangent
from ..task.env import Env
from ..task.noise import Disturbance, sample
from .episodes import EpisodeNoise, Episodes, run_segment, summarise
from .policy import FeedbackPolicy


class ReplanEpisodes(NamedTuple):
    episodes: Episodes
    replans: int  # solves run (all episodes)
    compiles_after_first: int  # compilations during every replan after the first
    solve_s: float  # time spent re-solving


def shifted(u: np.ndarray, every: int) -> np.ndarray:
    """The previous plan's controls advanced by ``every`` steps, the tail
    padded with the last control."""
    return np.concatenate([u[every:], np.repeat(u[-1:], every, axis=0)])


def replan_episodes(
    train_env: Env,
    result,
    cfg: SolverConfig,
    key: jax.Array,
    levels: EpisodeNoise,
    episodes: int,
    every: int,
    iterations: int,
    feedback: bool = True,
    progress: Optional[Callable[[str], None]] = None,
) -> ReplanEpisodes:
    """``episodes`` noisy episodes of receding-horizon POD-iLQR (see module docstring)."""
    T = train_env.dims.horizon
    if not 1 <= every < T:
        raise ConfigError(f"`every` (steps between replans) must be in 1 .. horizon-1 = {T - 1}; got {every}.")
    if iterations < 1:
        raise ConfigError(f"`iterations` per replan must be >= 1; got {iterations}.")
    cfg = cfg.replace(max_iterations=iterations, restarts=1)  # a local refinement of the shifted plan

    base = FeedbackPolicy.from_result(result)
    if not feedback:
        base = base.open_loop()

    def policy_of(res) -> FeedbackPolicy:
        """The re-solve's nominal and gains on the base policy's filter arrays."""
        K = res.K if feedback else np.zeros_like(res.K)
        return base.with_nominal(res.controls, res.info_states[:, : base.nz], K)

    segments = -(-T // every)
    noise = sample(key, levels.noise, episodes, segments * every)
    dims, data = train_env.dims, train_env.data
    x = np.asarray(tangent.integrate(dims, data.x0[None], noise.dx0))
    plans = [np.asarray(result.controls)] * episodes
    policies = [base] * episodes
    zs, us, xs = [], [], []
    replans = compiles_after_first = 0
    solve_s = 0.0
    for j in range(segments):
        if j > 0:
            t0 = time.perf_counter()
            for e in range(episodes):
                if not np.all(np.isfinite(x[e])):
                    continue  # a diverged episode keeps its plan (its cost is already inf)
                with CompileWatch() as watch:
                    window = train_env.with_start_state(x[e]).with_goal_step(T - j * every)
                    res = solve(window, cfg, u_init=shifted(plans[e], every))
                    policies[e] = policy_of(res)
                if replans > 0:
                    compiles_after_first += watch.compiles
                plans[e] = res.controls
                replans += 1
            solve_s += time.perf_counter() - t0
            if progress is not None:
                progress(f"replan {j}/{segments - 1}: {episodes} solves, {time.perf_counter() - t0:.1f} s")
        stacked = jax.tree.map(lambda *a: jnp.stack(a), *policies)
        s = slice(j * every, (j + 1) * every)
        segment = Disturbance(w=noise.w[:, s], v=noise.v[:, j * every : (j + 1) * every + 1], a=noise.a[:, s])
        z, u, xx = run_segment(dims, data, stacked, levels.limits, jnp.asarray(x), segment)
        x = np.asarray(xx[:, -1])
        zs.append(z if j == 0 else z[:, 1:])
        us.append(u)
        xs.append(xx if j == 0 else xx[:, 1:])
    z, u, xx = (jnp.concatenate(a, axis=1) for a in (zs, us, xs))
    out = summarise(data, z[:, : T + 1], u[:, :T], xx[:, : T + 1])
    return ReplanEpisodes(out, replans, compiles_after_first, solve_s)
