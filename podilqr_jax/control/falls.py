"""Did the robot stay up? The height of a free-moving root body along an episode.

A cost ratio says how much worse a controller did; for a standing robot the
user first asks whether it fell, and when. A model *can fall* when a body hangs
from the world by a free joint (the humanoids, the quadrupeds) or by a slide
along the world's vertical (the planar walkers' ``rootz``): the first such
body is its *root*. Along an episode the root's height is read from the true
states (``mj_kinematics`` per step, on the host), and the episode has *fallen*
at the first step the height is below ``FALL_RATIO`` x the nominal's root height
at that step. "Stayed up" means it never fell; ``up_s`` is the time until the
fall (the episode's length when it stayed up).

Models with nothing that can fall (a fixed-base arm, a cart-pole) have no root:
:func:`root_body` returns None and the evaluation reports no fall figures.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import mujoco
import numpy as np

FALL_RATIO = 0.7
"""An episode has fallen once its root body is below this share of the nominal's root height."""


class Falls(NamedTuple):
    """Fall figures of a batch of episodes."""

    stayed_up: np.ndarray  # [E] bool: never below FALL_RATIO x the nominal's height
    up_steps: np.ndarray  # [E] control steps before the first fall (S, the whole episode, when it stayed up)


def root_body(m: mujoco.MjModel) -> Optional[int]:
    """The first body on a free joint or on a slide along the world's z, or None."""
    for j in range(m.njnt):
        kind = m.jnt_type[j]
        body = int(m.jnt_bodyid[j])
        if kind == mujoco.mjtJoint.mjJNT_FREE:
            return body
        if kind == mujoco.mjtJoint.mjJNT_SLIDE and m.body_parentid[body] == 0:
            axis = np.asarray(m.jnt_axis[j], float)
            if abs(axis[2]) > 0.9 * np.linalg.norm(axis):
                return body
    return None


def root_heights(m: mujoco.MjModel, body: int, states: np.ndarray) -> np.ndarray:
    """The world height of ``body`` at each state x = [qpos, qvel, act] of ``states`` [..., nx]."""
    states = np.asarray(states, float)
    flat = states.reshape(-1, states.shape[-1])
    d = mujoco.MjData(m)
    out = np.empty(flat.shape[0])
    for i, x in enumerate(flat):
        if not np.all(np.isfinite(x[: m.nq])):
            out[i] = -np.inf  # a diverged episode has fallen
            continue
        d.qpos[:] = x[: m.nq]
        mujoco.mj_kinematics(m, d)
        out[i] = d.xpos[body, 2]
    return out.reshape(states.shape[:-1])


def falls(heights: np.ndarray, nominal_heights: np.ndarray) -> Falls:
    """Fall figures of episodes whose root heights are ``heights`` [E, S+1] (``root_heights``),
    against the nominal's root heights [>= S+1]."""
    h = np.asarray(heights)
    down = h < FALL_RATIO * np.asarray(nominal_heights)[None, : h.shape[1]]
    stayed = ~down.any(axis=1)
    return Falls(stayed, np.where(stayed, h.shape[1] - 1, np.argmax(down, axis=1)))
