"""Deviations of the state in its tangent space (free and ball joints).

The state x = [qpos, qvel, act] has nq + nv + na numbers (``act``: actuator
activations, na = 0 on most models), but the orientation of a free
or ball joint is a unit quaternion: four numbers for three degrees of freedom.
Adding a deviation to those four numbers leaves the unit sphere, and a
difference of two quaternions is no rotation. So wherever the package forms a
state deviation (the start-state and process noise of a rollout, the columns
of the model-based linearisation) it works in the tangent space, 2 nv + na numbers
dx = [dq, dv, da], as MuJoCo does:

  x (+) dx   qpos moved by dq as ``mj_integratePos`` moves it (a quaternion q
             becomes q exp(dq_r / 2), rotated by dq_r in its own body's frame),
             qvel + dv, act + da;
  x1 (-) x0  the dx with x0 (+) dx = x1, as ``mj_differentiatePos`` forms it.

The maps between the two at a state x are its ``basis`` J (d(x (+) dx)/d dx at
dx = 0, [nx, ndx]) and ``cobasis`` J+ (d(x (-) x0)/dx at x = x0, [ndx, nx]),
with J+ J = I.

On a model of hinges and slides (``EnvDims.quats`` empty, nq == nv) these are
the plain x + dx, x1 - x0 and identities, and the functions return exactly
those, so such a model's rollouts are unchanged bit for bit.

A quaternion is stored (w, x, y, z), MuJoCo's order; ``EnvDims.quats`` lists
(qpos address of w, dof address of the first angular rate) per free or ball
joint (:func:`quaternions`).
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import mujoco
import numpy as np

TINY = 1e-14
"""Below this rotation angle (rad) the quaternion maps use their series limit."""


def quaternions(m: mujoco.MjModel) -> tuple[tuple[int, int], ...]:
    """(qpos address of the quaternion, dof address of its three angular rates)
    for every free and ball joint of ``m``, in joint order."""
    out = []
    for j in range(m.njnt):
        kind = int(m.jnt_type[j])
        qa, va = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
        if kind == int(mujoco.mjtJoint.mjJNT_FREE):
            out.append((qa + 3, va + 3))
        elif kind == int(mujoco.mjtJoint.mjJNT_BALL):
            out.append((qa, va))
    return tuple(out)


@functools.lru_cache(maxsize=None)
def _linear(nq: int, nv: int, quats: tuple) -> tuple[np.ndarray, np.ndarray]:
    """The qpos and dof indices of the coordinates that add (everything but the
    quaternions and their rates), in matching order."""
    rot_q = {qa + i for qa, _ in quats for i in range(4)}
    rot_v = {va + i for _, va in quats for i in range(3)}
    lin_q = np.array([i for i in range(nq) if i not in rot_q], dtype=int)
    lin_v = np.array([i for i in range(nv) if i not in rot_v], dtype=int)
    assert lin_q.shape == lin_v.shape, (nq, nv, quats)
    return lin_q, lin_v


def _mul(a, b):
    """Quaternion product a b, (w, x, y, z), over leading axes."""
    return jnp.einsum("...ij,...j->...i", _left(a), b)


def _unit(q):
    return q / jnp.linalg.norm(q, axis=-1, keepdims=True)


def rotate(q, r):
    """q exp(r / 2): the unit quaternion q turned by the rotation vector r
    (rad) in its own frame (MuJoCo's ``mju_quatIntegrate`` with scale 1)."""
    a2 = jnp.sum(r * r, axis=-1, keepdims=True)
    big = a2 > TINY**2
    angle = jnp.sqrt(jnp.where(big, a2, 1.0))  # differentiable at r = 0 as well
    # cos(angle / 2) and sin(angle / 2) / angle, with their series near zero
    c = jnp.where(big, jnp.cos(0.5 * angle), 1.0 - a2 / 8.0)
    s = jnp.where(big, jnp.sin(0.5 * angle) / angle, 0.5 - a2 / 48.0)
    turn = jnp.concatenate([c, s * r], axis=-1)
    return _mul(_unit(q), turn)


def rotation_between(q1, q0):
    """The rotation vector r with q0 exp(r / 2) = q1 (MuJoCo's ``mju_subQuat``
    of normalised q1, q0): the shorter way round, |r| <= pi."""
    d = _mul(_unit(q0) * jnp.array([1.0, -1.0, -1.0, -1.0], q0.dtype), _unit(q1))
    w, v = d[..., :1], d[..., 1:]
    s2 = jnp.sum(v * v, axis=-1, keepdims=True)
    big = s2 > TINY**2
    s = jnp.sqrt(jnp.where(big, s2, 1.0))
    angle = 2.0 * jnp.arctan2(s, w)
    angle = jnp.where(angle > jnp.pi, angle - 2.0 * jnp.pi, angle)
    # angle / s, with its limit 2 / w near s = 0 (either sign of w)
    scale = jnp.where(big, angle / s, 2.0 / w)
    return scale * v


def integrate(dims, x, dx):
    """x (+) dx over leading axes: x [..., nx], dx [..., ndx] (the velocities and activations add)."""
    if not dims.quats:
        return x + dx
    nq, nv = dims.nq, dims.nv
    lin_q, lin_v = _linear(nq, nv, dims.quats)
    qpos, qvel = x[..., :nq], x[..., nq:]  # qvel: the velocities and the activations
    dq, dv = dx[..., :nv], dx[..., nv:]
    qpos = qpos.at[..., lin_q].add(dq[..., lin_v])
    for qa, va in dims.quats:
        qpos = qpos.at[..., qa : qa + 4].set(rotate(x[..., qa : qa + 4], dq[..., va : va + 3]))
    return jnp.concatenate([qpos, qvel + dv], axis=-1)


def difference(dims, x1, x0):
    """x1 (-) x0 over leading axes: [..., ndx]."""
    if not dims.quats:
        return x1 - x0
    nq, nv = dims.nq, dims.nv
    lin_q, lin_v = _linear(nq, nv, dims.quats)
    shape = jnp.broadcast_shapes(x1.shape, x0.shape)[:-1]
    dq = jnp.zeros(shape + (nv,), jnp.result_type(x1, x0))
    dq = dq.at[..., lin_v].set(x1[..., lin_q] - x0[..., lin_q])
    for qa, va in dims.quats:
        dq = dq.at[..., va : va + 3].set(rotation_between(x1[..., qa : qa + 4], x0[..., qa : qa + 4]))
    return jnp.concatenate([dq, x1[..., nq:] - x0[..., nq:]], axis=-1)


def basis(dims, x):
    """J = d(x (+) dx)/d dx at dx = 0: [..., nx, ndx] (a quaternion q's
    block is d(q exp(r / 2))/dr = q [0, I/2], its product matrix's last
    three columns halved)."""
    nq, nv, nx = dims.nq, dims.nv, dims.nx
    if not dims.quats:
        return jnp.broadcast_to(jnp.eye(nx, dtype=x.dtype), x.shape[:-1] + (nx, nx))
    lin_q, lin_v = _linear(nq, nv, dims.quats)
    tail = nx - nq  # the velocities and the activations: they add
    J = jnp.zeros(x.shape[:-1] + (nx, dims.ndx), x.dtype)
    J = J.at[..., lin_q, lin_v].set(1.0)
    J = J.at[..., nq + np.arange(tail), nv + np.arange(tail)].set(1.0)
    for qa, va in dims.quats:
        J = J.at[..., qa : qa + 4, va : va + 3].set(0.5 * _left(_unit(x[..., qa : qa + 4]))[..., :, 1:])
    return J


def cobasis(dims, x):
    """J+ = d(x (-) x0)/dx at x = x0: [..., ndx, nx], with J+ J = I (a
    quaternion's block is 2 [0, I] q*, the rows of J's block transposed, times 4)."""
    P = jnp.swapaxes(basis(dims, x), -1, -2)
    for qa, va in dims.quats:
        P = P.at[..., va : va + 3, qa : qa + 4].multiply(4.0)
    return P


def _left(q):
    """The matrix L(q) with q p = L(q) p (quaternion product as a matrix)."""
    w, x, y, z = (q[..., i] for i in range(4))
    rows = [
        jnp.stack([w, -x, -y, -z], axis=-1),
        jnp.stack([x, w, -z, y], axis=-1),
        jnp.stack([y, z, w, -x], axis=-1),
        jnp.stack([z, -y, x, w], axis=-1),
    ]
    return jnp.stack(rows, axis=-2)
