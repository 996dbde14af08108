"""Monte Carlo episodes: a policy run closed loop on the noisy system, as one MJX batch.

One episode of a :class:`~podilqr_jax.policy.FeedbackPolicy` from the start
state x_0 = x0 + dx_0:

  m_t     = z_t + v_t                        measured, z_t = C x_t (+ D s(x_t)),
                                             or x_t + v_t for a full-state policy
  u_t     = u_bar_t + K_t xi_t               commanded (xi from the m's)
  x_{t+1} = f(x_t, u_t + a_t) + w_t          a_t actuator noise, w_t process noise

Its cost is the task's cost of the *true* observations z_t and the
commanded controls, and its final error is max_i |z_T - z*|_i. The noise
levels (:class:`EpisodeNoise`) are traced, so a sweep over them compiles once.

``run_segment`` runs the first ``steps`` steps of one controller per episode
from given states: the building block of receding-horizon replanning.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from mujoco import mjx

from .cost import batch_costs
from .env import EnvData, EnvDims
from .policy import Controller, FeedbackPolicy, control, initial_estimate, next_estimate
from .rollout import observe, physics_step, state_of, with_state
from .xla_options import jit


class EpisodeNoise(NamedTuple):
    """Standard deviations of an episode's noise (traced)."""

    x0: jnp.ndarray  # [nx] start-state deviation
    w: jnp.ndarray  # [nx] process noise on qpos, qvel after each step
    v: jnp.ndarray  # [nm] measurement noise on what the policy measures
    a: jnp.ndarray  # [nu] actuator noise added to the commanded control
    u_low: jnp.ndarray  # [nu] actuator limits: the command is clipped to [u_low, u_high]
    u_high: jnp.ndarray  # [nu]


class EpisodeDraw(NamedTuple):
    """One realisation per episode (leading batch axis)."""

    dx0: jnp.ndarray  # [E, nx]
    w: jnp.ndarray  # [E, S, nx]
    v: jnp.ndarray  # [E, S+1, nm]
    a: jnp.ndarray  # [E, S, nu]


class Episodes(NamedTuple):
    """What a batch of episodes returns."""

    cost: jnp.ndarray  # [E] task cost (true observations, commanded controls); inf if not finite
    final_error: jnp.ndarray  # [E] max_i |C x_T - z*|_i
    z: jnp.ndarray  # [E, S+1, nz] true observations C x
    u: jnp.ndarray  # [E, S, nu] commanded controls
    x: jnp.ndarray  # [E, S+1, nx] true states


def draw(key: jax.Array, levels: EpisodeNoise, episodes: int, steps: int) -> EpisodeDraw:
    k0, kw, kv, ka = jax.random.split(key, 4)
    dtype = levels.x0.dtype

    def normal(k, shape, std):
        return std * jax.random.normal(k, shape + std.shape, dtype)

    return EpisodeDraw(
        dx0=normal(k0, (episodes,), levels.x0),
        w=normal(kw, (episodes, steps), levels.w),
        v=normal(kv, (episodes, steps + 1), levels.v),
        a=normal(ka, (episodes, steps), levels.a),
    )


def _episode(dims: EnvDims, data: EnvData, full_state: bool, ctrl: Controller, limits, x_start, w, v, a):
    """One episode (or segment) of len(w) steps from the true state x_start.
    The policy measures x (``full_state``) or the task's observation z, plus v."""
    model = data.model

    def measure(d, x):
        z = observe(dims, data, d, x)  # the true observation, for the cost
        return z, x if full_state else z

    d = with_state(dims, mjx.make_data(model), x_start)
    z0, m0 = measure(d, x_start)
    xi = initial_estimate(ctrl, m0 + v[0])

    def step(carry, inp):
        d, xi = carry
        t, w_t, v_next, a_t = inp
        u = jnp.clip(control(ctrl, t, xi), *limits)
        d = physics_step(dims, model, d, u + a_t)
        x = state_of(d) + w_t
        d = with_state(dims, d, x)
        z, m = measure(d, x)
        xi = next_estimate(ctrl, t, xi, u, m + v_next)
        return (d, xi), (u, x, z)

    steps = w.shape[0]
    _, (u, x, z) = jax.lax.scan(step, (d, xi), (jnp.arange(steps), w, v[1:], a))
    return jnp.concatenate([z0[None], z]), u, jnp.concatenate([x_start[None], x])


def _summarise(data: EnvData, z, u, x) -> Episodes:
    cost, _ = batch_costs(z, u, data)
    error = jnp.max(jnp.abs(z[:, -1] - data.z_target), axis=-1)
    return Episodes(cost, jnp.where(jnp.isfinite(error), error, jnp.inf), z, u, x)


@jit(static_argnames=("dims", "episodes"))
def run_episodes(
    dims: EnvDims, data: EnvData, policy: FeedbackPolicy, key: jax.Array, levels: EpisodeNoise, episodes: int
) -> Episodes:
    """``episodes`` noisy episodes of ``policy`` over its whole horizon, one MJX batch."""
    noise = draw(key, levels, episodes, policy.horizon)
    run = functools.partial(
        _episode, dims, data, policy.measures == "state", policy.controller, (levels.u_low, levels.u_high)
    )
    z, u, x = jax.vmap(run)(data.x0 + noise.dx0, noise.w, noise.v, noise.a)
    return _summarise(data, z, u, x)


@jit(static_argnames=("dims",))
def run_segment(dims: EnvDims, data: EnvData, policy: FeedbackPolicy, limits, x_start, w, v, a):
    """One segment per episode: ``policy`` holds one controller per episode
    (leading axis E on every array), run from x_start [E, nx] for w.shape[1]
    steps. Returns (z, u, x) of the segment, true observations and states."""
    run = functools.partial(_episode, dims, data, policy.measures == "state")
    return jax.vmap(run, in_axes=(0, None, 0, 0, 0, 0))(policy.controller, limits, x_start, w, v, a)


summarise = jax.jit(_summarise)
