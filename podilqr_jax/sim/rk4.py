"""MuJoCo's RK4 step with the forward dynamics compiled once, not four times.

``mjx.step`` on a model with ``integrator="RK4"`` (most of dm_control's suite
and Gymnasium's pendula, reachers, swimmer and hopper) evaluates the forward
dynamics at four states per step: once at the current state, then at three
intermediate states inside a ``lax.scan`` that MJX unrolls fully. XLA
therefore compiles four copies of ``mjx.forward`` (collision, the constraint
solver's nested loops, sensors) into every program that steps the model,
and, under ``jax.jacfwd`` in the model-based reference, four copies of their
tangents. That is why those models compiled several times longer than Euler
ones (benchmarks/journal.md).

``step`` below takes the same step with one copy: a ``lax.scan`` over the
four stages of the classical tableau (stage i is evaluated at

  qpos_i = qpos_0 (+) a_i dt v_{i-1},  qvel_i = qvel_0 + a_i dt qacc_{i-1},

with a = (0, 1/2, 1/2, 1), stage 0 being the current state itself) whose body
calls ``mjx.forward`` once; the weighted sums of the stages' velocities,
accelerations and activation rates (b = 1/6, 1/3, 1/3, 1/6) are accumulated in
MJX's order and handed to MJX's own position/velocity/activation update, so
the step is MuJoCo's RK4 to round-off (``tests/test_rk4.py`` compares it with
``mjx.step`` on RK4 models of both packages). Only the JAX implementation is
rewritten; anything else goes through ``mjx.step``.

It uses two of MJX's internal functions (``_advance``, ``_integrate_pos``) and
its tableau; should a future MJX move them, ``available`` is False and the
rollouts fall back to ``mjx.step``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from mujoco import mjx

try:  # MJX internals, pinned by pyproject's mujoco-mjx version; checked by tests/test_rk4.py
    from mujoco.mjx._src import forward as _mjx_forward
    from mujoco.mjx._src import scan as _mjx_scan
    from mujoco.mjx._src.types import IntegratorType as _IntegratorType
    from mujoco.mjx._src.types import ModelJAX as _ModelJAX

    _A = np.concatenate([[0.0], np.diag(_mjx_forward._RK4_A)])  # (0, 1/2, 1/2, 1)
    _B = np.asarray(_mjx_forward._RK4_B)  # (1/6, 1/3, 1/3, 1/6)
    _advance = _mjx_forward._advance
    _integrate_pos = _mjx_forward._integrate_pos
    available = _A.shape == (4,) and _B.shape == (4,)
except (ImportError, AttributeError):  # pragma: no cover - depends on the MJX version
    available = False


def applies(model) -> bool:
    """True where ``step`` replaces ``mjx.step``: an RK4 model in MJX's JAX implementation."""
    return (
        available
        and isinstance(getattr(model, "_impl", None), _ModelJAX)
        and model.opt.integrator == _IntegratorType.RK4
    )


def step(model, d):
    """One RK4 step of ``model`` from ``d`` (what ``mjx.step`` does, one forward copy)."""
    dt = model.opt.timestep
    qpos0, qvel0, act0, time0 = d.qpos, d.qvel, d.act, d.time

    def stage(carry, tableau):
        sums, kqvel, prev = carry
        first, a, b = tableau
        dqvel = a * kqvel
        kqpos = _mjx_scan.flat(
            model,
            lambda *args: _integrate_pos(*args, dt=dt),
            "jqv",
            "q",
            model.jnt_type,
            qpos0,
            dqvel,
        )
        kqpos = jnp.where(first, qpos0, kqpos)  # stage 0 is the current state, exactly
        kqvel = jnp.where(first, qvel0, qvel0 + (a * prev.qacc) * dt)
        kact = jnp.where(first, act0, act0 + (a * prev.act_dot) * dt)
        cur = mjx.forward(model, prev.replace(qpos=kqpos, qvel=kqvel, act=kact, time=time0 + a * dt))
        cur = jax.tree_util.tree_map(lambda new, old: new.astype(old.dtype), cur, prev)  # one carry type
        sums = tuple(s + b * k for s, k in zip(sums, (kqvel, cur.qacc, cur.act_dot), strict=True))
        return (sums, kqvel, cur), None

    zero = tuple(jnp.zeros_like(a) for a in (qvel0, d.qacc, d.act_dot))
    tableau = (jnp.arange(4) == 0, jnp.asarray(_A, dtype=dt.dtype), jnp.asarray(_B, dtype=dt.dtype))
    (sums, _, last), _ = jax.lax.scan(stage, (zero, qvel0, d), tableau)
    qvel, qacc, act_dot = sums
    d = last.replace(qpos=qpos0, qvel=qvel0, act=act0, time=time0)
    return _advance(model, d, act_dot, qacc, qvel)
