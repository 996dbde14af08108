"""Monte Carlo episodes: a policy run closed loop on the noisy system, as one MJX batch.

One episode of a :class:`~podilqr_jax.control.policy.FeedbackPolicy` from the start
state x_0 = x0 (+) dx_0 (``tangent.integrate``: a rotation on a free or ball joint):

  m_t     = z_t + v_t                        measured, z_t = C x_t (+ D s(x_t)),
                                             or x_t + v_t for a full-state policy
  u_t     = u_bar_t + K_t xi_t               commanded (xi from the m's)
  x_{t+1} = f(x_t, u_t + a_t) (+) w_t        a_t actuator noise, w_t process noise

Its cost is the task's cost of the *true* observations z_t and the
commanded controls, and its final error is max_i |z_T - z*|_i. The noise
levels (:class:`EpisodeNoise`) are traced, so a sweep over them compiles once.

Episodes run on the package's one rollout engine (``rollout.run``) with the
policy's :class:`~podilqr_jax.control.policy.Controller` as the controller and one
``noise.Disturbance`` per episode, drawn by ``noise.sample``.

``run_segment`` runs the first ``steps`` steps of one controller per episode
from given states: the building block of receding-horizon replanning.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from ..compilation.xla_options import jit
from ..ilqr.cost import batch_costs
from ..sim.rollout import run_batch
from ..task.env import Env, EnvData, EnvDims
from ..task.noise import Disturbance, NoiseLevels, NoiseModel, sample
from .policy import FeedbackPolicy


class EpisodeNoise(NamedTuple):
    """Standard deviations of an episode's noise and the actuator limits (traced)."""

    x0: jnp.ndarray  # [2 nv] start-state deviation (tangent space, ``task.tangent``)
    w: jnp.ndarray  # [2 nv] process noise on qpos, qvel after each step
    v: jnp.ndarray  # [nm] measurement noise on what the policy measures
    a: jnp.ndarray  # [nu] actuator noise added to the commanded control
    u_low: jnp.ndarray  # [nu] actuator limits: the command is clipped to [u_low, u_high]
    u_high: jnp.ndarray  # [nu]

    @property
    def noise(self) -> NoiseLevels:
        """The standard deviations alone, for ``noise.sample``."""
        return NoiseLevels(self.x0, self.w, self.v, self.a)

    @property
    def limits(self) -> tuple[jnp.ndarray, jnp.ndarray]:
        return self.u_low, self.u_high


MEASUREMENT_RATIO = 0.1
"""Measurement noise per unit of actuator noise level, as a fraction of each channel's range."""

U_LIMIT = 2.0
"""An actuator without a ctrlrange is clipped to +- U_LIMIT x its largest nominal control."""


def actuator_limits(env: Env, u_max: np.ndarray, u_limit: float) -> tuple[np.ndarray, np.ndarray]:
    """The model's ctrlrange where it limits a control (the box MuJoCo and the
    solver clamp to, ``env.data.u_low/u_high``), else +- u_limit u_max."""
    bound = np.where(u_max > 0, u_limit * u_max, np.inf)
    low, high = np.asarray(env.data.u_low), np.asarray(env.data.u_high)
    return np.where(np.isfinite(low), low, -bound), np.where(np.isfinite(high), high, bound)


def noise_at_level(
    env: Env,
    eps: float,
    u_max,
    channel_range,
    limits,
    measurement_ratio: float = MEASUREMENT_RATIO,
    system_noise: Optional[NoiseModel] = None,
) -> EpisodeNoise:
    """The episodes' noise at level ``eps``: actuator noise ``eps x u_max``,
    measurement noise ``eps x measurement_ratio x channel_range`` (with the
    system noise's added), commands clipped to ``limits`` (``podilqr
    evaluate``'s levels, and the noisy episodes of an animation)."""
    sys = NoiseModel() if system_noise is None else system_noise
    ndx = env.dims.ndx  # state noise lives in the tangent space (task.tangent)
    meas = eps * measurement_ratio * channel_range
    meas = np.sqrt(meas**2 + sys.measurement**2)
    return EpisodeNoise(
        x0=jnp.full((ndx,), sys.initial),
        w=jnp.full((ndx,), sys.process),
        v=jnp.asarray(meas),
        a=jnp.asarray(eps * u_max),
        u_low=jnp.asarray(limits[0]),
        u_high=jnp.asarray(limits[1]),
    )


class Episodes(NamedTuple):
    """What a batch of episodes returns."""

    cost: jnp.ndarray  # [E] task cost (true observations, commanded controls); inf if not finite
    final_error: jnp.ndarray  # [E] max_i |C x_T - z*|_i
    z: jnp.ndarray  # [E, S+1, nz] true observations C x
    u: jnp.ndarray  # [E, S, nu] commanded controls
    x: jnp.ndarray  # [E, S+1, nx] true states


def _summarise(data: EnvData, z, u, x) -> Episodes:
    cost, _ = batch_costs(z, u, data)
    error = jnp.max(jnp.abs(z[:, -1] - data.z_target), axis=-1)
    return Episodes(cost, jnp.where(jnp.isfinite(error), error, jnp.inf), z, u, x)


def _policy_batch(dims: EnvDims, data: EnvData, policy: FeedbackPolicy, noise, x_start, limits, in_axes, steps):
    """The engine's batch of ``policy``'s controller (true z, commanded u, true x)."""
    batch = noise.w.shape[0]
    measures_state = policy.measures == "state"
    return run_batch(
        dims,
        data,
        policy.controller,
        noise,
        x_start,
        limits,
        batch=batch,
        in_axes=in_axes,
        steps=steps,
        measures_state=measures_state,
        record_state=True,
    )


@jit(static_argnames=("dims", "episodes"))
def run_episodes(
    dims: EnvDims, data: EnvData, policy: FeedbackPolicy, key: jax.Array, levels: EpisodeNoise, episodes: int
) -> Episodes:
    """``episodes`` noisy episodes of ``policy`` over its whole horizon, one MJX batch."""
    noise = sample(key, levels.noise, episodes, policy.horizon)
    z, u, x = _policy_batch(dims, data, policy, noise, data.x0, levels.limits, (None, 0, None), policy.horizon)
    return _summarise(data, z, u, x)


@jit(static_argnames=("dims",))
def run_segment(dims: EnvDims, data: EnvData, policy: FeedbackPolicy, limits, x_start, noise: Disturbance):
    """One segment per episode: ``policy`` holds one controller per episode
    (leading axis E on every array), run from x_start [E, nx] for
    ``noise.w.shape[1]`` steps under ``noise`` (no ``dx0``: x_start is where
    the episode is). Returns (z, u, x) of the segment, true observations and states."""
    return tuple(_policy_batch(dims, data, policy, noise, x_start, limits, (0, 0, 0), noise.w.shape[1]))


summarise = jax.jit(_summarise)
