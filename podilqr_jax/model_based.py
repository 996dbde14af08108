"""Exact linearisation of the MJX dynamics (the model-based reference).

The control-step map x_{t+1} = f(x_t, u_t) (``substeps`` MuJoCo steps) is
differentiated with ``jax.jacfwd`` at every nominal (x_bar_t, u_bar_t), giving
the true LTV model A_t = df/dx, B_t = df/du on the full state. The model-based
iLQR runs the same backward pass and line search on it; it is the reference
optimum for tests, benchmarks and the noisy studies.

Shapes: x_bar [T+1, nx], u_bar [T, nu]; A [T, nx, nx], B [T, nx, nu].
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from .env import EnvData, EnvDims
from .rollout import physics_step, state_of, with_state
from .stages import stage
from .sysid import LinearModel


@stage(static_argnames=("dims",), outputs=(LinearModel,))
def linearise(dims: EnvDims, data: EnvData, x_bar, u_bar) -> LinearModel:
    """(A_t, B_t) = Jacobians of the control-step map along (x_bar, u_bar)."""
    d0 = mjx.make_data(data.model)

    def f(x, u):
        return state_of(physics_step(dims, data.model, with_state(dims, d0, x), u))

    # A control on its ctrlrange bound is moved inside by 1e-9 of the range:
    # MuJoCo's clamp has no derivative there, and B must be the interior one
    # (the backward pass's box QP handles the bound).
    span = jnp.where(jnp.isfinite(data.u_high - data.u_low), data.u_high - data.u_low, 0.0)
    u_lin = jnp.clip(u_bar, data.u_low + 1e-9 * span, data.u_high - 1e-9 * span)
    A, B = jax.vmap(jax.jacfwd(f, argnums=(0, 1)))(x_bar[:-1], u_lin)
    return LinearModel(A, B)


def nonfinite_hint(mj_model: mujoco.MjModel) -> str:
    """Why MJX's exact Jacobian may hold NaN, where the model says so (for the
    message of a model-based solve that stops ``nonfinite``)."""
    if mj_model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC:
        return (
            " (the model uses the elliptic friction cone, whose forward-mode derivative in MJX is NaN at an "
            'active contact; with <option cone="pyramidal"/> it is finite. POD-iLQR itself needs no derivative)'
        )
    return ""
