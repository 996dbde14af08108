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

A model MJX cannot convert (``Env.mjx_problem``: a geom pair without an MJX
collision function, the implicit integrator, a sensor MJX does not compute)
runs on the native engine under ``auto`` wherever JAX runs on a CPU, with a
one-line note saying why (``Env.model_notes``, ``Result.warnings``); on an
accelerator, and under ``engine = "mjx"``, it is refused with MJX's reason
and the way to the C engine.

Measured by ``podilqr bench --sections engines`` on 2 cores
(benchmarks/journal.md): the rule picks the faster engine on 18 of the 20
models there. The two it misses, dm_control's acrobot and cart-pole (RK4, 2
degrees of freedom), step 1.36x and 1.20x faster on MJX; over a solve of a
few hundred iterations that gain is of the order of MJX's 3 s longer compile.
"""

from __future__ import annotations

import jax
import mujoco

from ..errors import ModelLoadError
from ..task.env import Env, MJXUnavailable
from . import contacts
from .native import native_model

SMALL_NV = 6
"""The most degrees of freedom of a model ``auto`` keeps on MJX on a CPU (with no contacts and no RK4)."""


def auto_engine(env: Env) -> str:
    """``mjx`` or ``native`` for ``env`` under ``engine = "auto"`` (module docstring)."""
    return _auto(env)[0]


def _auto(env: Env) -> tuple[str, str]:
    """The engine ``auto`` picks for ``env``, and why it is the C engine where the rule
    picked MJX but MJX cannot convert the model ("" otherwise). MJX's copy is built only
    where the rule picks MJX."""
    if jax.default_backend() != "cpu":
        if env.mjx_problem:
            raise ModelLoadError(
                f'{env.mjx_problem} JAX runs on {jax.default_backend().upper()} here, where `engine = "auto"` '
                f"runs MJX; MuJoCo's C engine runs {env.name!r} on the host's CPU cores: set `engine` to 'native' "
                "(--set engine=native), or run on a CPU (JAX_PLATFORMS=cpu)."
            )
        return "mjx", ""
    m = env.mj_model
    smooth = not contacts.contact_rich(m)
    small = m.nv <= SMALL_NV and m.opt.integrator != mujoco.mjtIntegrator.mjINT_RK4
    if not (jax.device_count() > 1 or (smooth and small)):
        return "native", ""
    problem = env.mjx_models.get("jax", sensors=env.dims.sensors)
    if isinstance(problem, MJXUnavailable):
        return "native", f"MuJoCo's C engine runs {env.name!r} (engine auto): {problem.short}"
    return "mjx", ""


def resolve(setting: str, env: Env) -> str:
    """The engine a solve of ``env`` runs for the ``engine`` setting."""
    return auto_engine(env) if setting == "auto" else setting


def on_engine(env: Env, setting: str) -> Env:
    """``env`` with its rollouts on the engine ``setting`` resolves to; MJX's
    reason where ``mjx`` is asked of a model it cannot convert."""
    engine, why = _auto(env) if setting == "auto" else (setting, "")
    if engine == "mjx":
        env.mjx_model()  # built here, or refused with MJX's reason (ModelLoadError)
        return env.on_engine(None)
    return env.on_engine(native_model(env.mj_model), (why,) if why else ())
