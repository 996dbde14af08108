"""Which engine runs a solve's rollouts: MJX or MuJoCo's C engine (``native``).

``SolverConfig.engine`` is ``mjx``, ``native`` or ``auto``. ``auto`` keeps
MJX wherever JAX runs on an accelerator (a GPU or TPU: MJX is the engine of
the design there) or over several devices (the native engine does not
shard), and on a single CPU device picks by the model (:func:`auto_engine`):

- MJX where the model is small and smooth: no constraint rows that MJX's
  step carries for contacts, limits or friction (``contacts.constraint_rows``
  below ``MANY_ROWS``), the Euler or implicit integrator, and at most
  ``SMALL_NV`` degrees of freedom. There MJX's compiled batch runs 1.0-1.7x
  as fast per iteration as the native one (the bundled pendulum, cart-pole and
  double pendulum), and its compile of a few seconds is paid once per machine
  (the persistent cache);
- native everywhere else: on contact models, RK4 and the field's robots MJX
  on a CPU runs tens of times slower than MuJoCo's C engine and compiles for
  tens of seconds to minutes (docs/performance.md has the figures and the
  command that measures them, ``podilqr bench --sections engines``).
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
