"""Which engine runs a solve's rollouts: MJX or MuJoCo's C engine (``native``).

``SolverConfig.engine`` is ``mjx``, ``native`` or ``auto``. ``auto`` keeps
MJX wherever JAX runs on an accelerator (a GPU or TPU: MJX is the engine of
the design there) or over several devices (the native engine does not
shard), and on a single CPU device picks by the model (:func:`auto_engine`):

- MJX where the model is small and smooth: fewer than ``MANY_ROWS``
  constraint rows in MJX's step (contacts, limits, friction;
  ``contacts.constraint_rows``), the Euler or implicit integrator, and at most
  ``SMALL_NV`` degrees of freedom. There MJX's compiled sysid batch runs
  1.4-4.3x the physics steps/s of the native one on 2 cores (the bundled
  pendulum and cart-pole, dm_control's pendulum, point mass and reacher), and
  its compile of 2-4 s is paid once per machine (the persistent cache);
- native everywhere else: 1.5-50x MJX's steps/s on contact models, RK4 models
  and the field's robots, where MJX compiles for 4-18 s (the manipulator: no
  result in 90 s) against the native engine's 0.3-1 s.

Measured by ``podilqr bench --sections engines`` on 2 cores
(benchmarks/journal.md): the rule picks the faster engine on 18 of the 20
models there. The two it misses, dm_control's acrobot and cart-pole (RK4, 2
degrees of freedom), step 1.36x and 1.20x faster on MJX; over a solve of a
few hundred iterations that gain is of the order of MJX's 3 s longer compile.
"""

from __future__ import annotations

from typing import Optional

import jax
import mujoco

from ..task.env import Env
from . import contacts
from .native import NativeModel, native_model

SMALL_NV = 6
"""The most degrees of freedom of a model ``auto`` keeps on MJX on a CPU (with no contacts and no RK4)."""


def auto_engine(env: Env) -> str:
    """``mjx`` or ``native`` for ``env`` under ``engine = "auto"`` (module docstring)."""
    if jax.default_backend() != "cpu" or jax.device_count() > 1:
        return "mjx"
    m = env.mj_model
    smooth = not contacts.many_rows(contacts.constraint_rows(env.data.model))
    small = m.nv <= SMALL_NV and m.opt.integrator != mujoco.mjtIntegrator.mjINT_RK4
    return "mjx" if smooth and small else "native"


def resolve(setting: str, env: Env) -> str:
    """The engine a solve of ``env`` runs for the ``engine`` setting."""
    return auto_engine(env) if setting == "auto" else setting


def on_engine(env: Env, setting: str) -> Env:
    """``env`` with its rollouts on the engine ``setting`` resolves to."""
    engine = resolve(setting, env)
    native: Optional[NativeModel] = native_model(env.mj_model) if engine == "native" else None
    return env.on_engine(native)
