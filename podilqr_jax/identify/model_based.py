"""Linearisation of the MJX dynamics (the model-based reference).

The control-step map x_{t+1} = f(x_t, u_t) (``substeps`` MuJoCo steps) is
linearised at every nominal (x_bar_t, u_bar_t), giving the LTV model
A_t = df/dx, B_t = df/du on the full state, one column per state or control
direction, in one of two ways (``JACOBIANS``):

- ``exact``: forward mode, one JVP through ``mjx.step`` per column;
- ``differences``: central differences of the same step, (f(. + h e_j) -
  f(. - h e_j)) / 2h with h = eps^(1/3) of the dtype (6.1e-6 in float64),
  the step size that balances the truncation error (h^2) against round-off
  (eps / h); MuJoCo's own ``mjd_transitionFD`` differentiates so.

On a model with a free or ball joint the state's directions are those of its
tangent space (``task.tangent``), 2 nv of them: x_bar (+) h e_j and the
difference f(+) (-) f(-) as ``mj_integratePos`` and ``mj_differentiatePos``
form them (forward mode: along the tangent basis J, read back through J+),
and (A~_t, B~_t) on the tangent space are carried back to the full state as
A_t = J_{t+1} A~_t J+_t, B_t = J_{t+1} B~_t. A quaternion's four entries are
never perturbed one by one, off the unit sphere.

The model-based iLQR runs the same backward pass and line search on it; it is
the reference optimum for tests, benchmarks and the noisy studies.

Shapes: x_bar [T+1, nx], u_bar [T, nu]; A [T, nx, nx], B [T, nx, nu].
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco

from ..compilation.stages import stage
from ..sim.rollout import physics_step, start_data, state_of, with_state
from ..task import tangent
from ..task.env import EnvData, EnvDims
from .sysid import LinearModel

JACOBIANS = ("exact", "differences")
"""How :func:`linearise` computes the Jacobians (module docstring)."""


@stage(static_argnames=("dims", "jacobian"), outputs=(LinearModel,))
def linearise(dims: EnvDims, data: EnvData, x_bar, u_bar, jacobian: str = "exact") -> LinearModel:
    """(A_t, B_t) = Jacobians of the control-step map along (x_bar, u_bar).

    ``jacobian``: ``exact`` (forward mode) or ``differences`` (central
    differences), module docstring; the solver's ``auto`` picks differences
    on a contact-rich model (``sim.contacts.jacobian``)."""
    if jacobian not in JACOBIANS:
        raise ValueError(f"`jacobian` must be one of {', '.join(JACOBIANS)}; got {jacobian!r}.")
    d0 = start_data(dims, data)

    def f(x, u):
        return state_of(physics_step(dims, data.model, with_state(dims, d0, x), u))

    # A control on its ctrlrange bound is moved inside by 1e-9 of the range
    # (by the difference step h for differences, so that neither side of the
    # difference is clamped): MuJoCo's clamp has no derivative there, and B
    # must be the interior one (the backward pass's box QP handles the bound).
    h = float(jnp.finfo(x_bar.dtype).eps) ** (1.0 / 3.0)
    span = jnp.where(jnp.isfinite(data.u_high - data.u_low), data.u_high - data.u_low, 0.0)
    inset = jnp.minimum(jnp.maximum(1e-9 * span, h), 0.5 * span) if jacobian == "differences" else 1e-9 * span
    u_lin = jnp.clip(u_bar, data.u_low + inset, data.u_high - inset)
    # Column j of [A_t B_t] is the JVP of f at (x_bar_t, u_t) along the unit
    # vector e_j: one vmap over the T (nx + nu) pairs (t, j) of a single JVP.
    # The same columns as ``vmap(jacfwd(f))`` to round-off (the model-based
    # solves of the bundled tasks end at the same costs to 1e-15 relative),
    # with one batching level instead of two: a cheaper trace and XLA compile
    # (benchmarks/journal.md). The primal is recomputed per column.
    T, nx, nu = u_bar.shape[0], dims.nx, dims.nu
    # A free or ball joint's state directions are the tangent space's 2 nv
    # (module docstring): nd columns per step, nx on hinges and slides.
    curved = bool(dims.quats)
    nd = dims.ndx if curved else nx
    n = nd + nu
    if curved:  # the tangent basis J and cobasis J+ at every nominal state, once
        J, J_plus = tangent.basis(dims, x_bar), tangent.cobasis(dims, x_bar)
    x_rep = jnp.repeat(x_bar[:-1], n, axis=0)
    u_rep = jnp.repeat(u_lin, n, axis=0)
    e = jnp.tile(jnp.eye(n, dtype=x_bar.dtype), (T, 1))

    def column(x, u, e_j):
        return jax.jvp(f, (x, u), (e_j[:nx], e_j[nx:]))[1]

    if jacobian == "differences":
        # Both sides of every column as one batch of 2 T (nx + nu) steps: one
        # copy of the step in the program (the forward-mode program holds the
        # step and its tangent; benchmarks/journal.md).
        if curved:
            x_pm = tangent.integrate(dims, jnp.concatenate([x_rep, x_rep]), h * jnp.concatenate([e, -e])[:, :nd])
        else:
            x_pm = jnp.concatenate([x_rep + h * e[:, :nx], x_rep - h * e[:, :nx]])
        u_pm = jnp.concatenate([u_rep + h * e[:, nd:], u_rep - h * e[:, nd:]])
        x_next = jax.vmap(f)(x_pm, u_pm)
        if curved:
            cols = tangent.difference(dims, x_next[: T * n], x_next[T * n :]) / (2.0 * h)
        else:
            cols = (x_next[: T * n] - x_next[T * n :]) / (2.0 * h)
    else:
        if curved:  # the state's columns along the tangent basis J(x_bar_t), read back through J+(x_bar_t+1)
            J_rep = jnp.repeat(J[:-1], n, axis=0)
            e = jnp.concatenate([jnp.einsum("bij,bj->bi", J_rep, e[:, :nd]), e[:, nd:]], axis=1)
        cols = jax.vmap(column)(x_rep, u_rep, e)
        if curved:
            cols = jnp.einsum("bij,bj->bi", jnp.repeat(J_plus[1:], n, axis=0), cols)
    AB = jnp.swapaxes(cols.reshape(T, n, nd), 1, 2)  # [T, nd, nd + nu]
    if not curved:
        return LinearModel(AB[:, :, :nx], AB[:, :, nx:])
    # Back on the full state x = [qpos, qvel] the backward pass and the line
    # search work on: A_t = J(x_bar_t+1) A~_t J+(x_bar_t), B_t = J(x_bar_t+1) B~_t,
    # which map every deviation onto the tangent plane of the unit quaternions.
    return LinearModel(J[1:] @ AB[:, :, :nd] @ J_plus[:-1], J[1:] @ AB[:, :, nd:])


def nonfinite_hint(mj_model: mujoco.MjModel) -> str:
    """Why MJX's exact Jacobian may hold NaN, where the model says so (for the
    message of a model-based solve that stops ``nonfinite``)."""
    if mj_model.opt.cone == mujoco.mjtCone.mjCONE_ELLIPTIC:
        return (
            " (the model uses the elliptic friction cone, whose forward-mode derivative in MJX is NaN at an "
            'active contact; with <option cone="pyramidal"/> it is finite, and so is jacobian="differences" '
            "(central differences of the step). POD-iLQR itself needs no derivative)"
        )
    return ""
