"""The system's randomness: initial-state deviation, process and measurement noise.

The true system of the paper (Section II) is

  x_0     = x0 + dx_0,        dx_0 ~ N(0, s0^2 I)
  x_{t+1} = f(x_t, u_t) + w_t,  w_t ~ N(0, sw^2 I)
  z_t     = C x_t + v_t,        v_t ~ N(0, sv^2 I)

with the state x = [qpos, qvel]. ``w_t`` is written into MuJoCo's ``qpos`` and
``qvel`` after each control step (all ``substeps`` physics steps), inside the
batched rollout; ``v_t`` corrupts every measurement, z_0 included, and the
information state and the feedback are built from the corrupted measurements.

dx_0 and w_t are deviations in the state's tangent space, 2 nv numbers
(``task.tangent``): on a model with a free or ball joint "+" turns its
quaternion as ``mj_integratePos`` does, by a rotation vector of std s0 (or sw)
rad per axis; on hinges and slides it is the plain sum.

Every rollout draws its own noise from its own PRNG key (``sample`` splits
one key over the batch), so the same seed gives the same result and different
rollouts, iterations or seeds see different noise.

:class:`NoiseModel` holds the standard deviations as plain floats (part of the
task, validated in Python); :class:`NoiseLevels` is their traced form inside
``EnvData``, so changing a noise level never recompiles.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, NamedTuple, Optional

import jax
import jax.numpy as jnp

from ..errors import TaskError


@dataclasses.dataclass(frozen=True)
class NoiseModel:
    """Standard deviations of the system's noise (all zero: a deterministic system).

    Attributes:
      initial: s0, std of the start-state deviation dx_0 (each of its 2 nv
        tangent components: positions, rotation angles in rad, velocities).
      process: std of w_t, added to the state after each control step (in the
        same tangent components).
      measurement: std of v_t, added to each observed component.
    """

    initial: float = 0.0
    process: float = 0.0
    measurement: float = 0.0

    @classmethod
    def paper(cls, s0: float = 0.01, *, partial: bool = True) -> "NoiseModel":
        """The paper's setting: process (and, when ``partial``, measurement)
        noise with 10% of the initial-state deviation's std ``s0``.

        Fully observed, the paper measures perfectly (no measurement noise).
        """
        return cls(initial=s0, process=0.1 * s0, measurement=0.1 * s0 if partial else 0.0)

    @property
    def is_zero(self) -> bool:
        return self.initial == 0.0 and self.process == 0.0 and self.measurement == 0.0

    def validate(self) -> "NoiseModel":
        for name in ("initial", "process", "measurement"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise TaskError(f"Noise `{name}` must be a finite number (a standard deviation); got {value!r}.")
            if value < 0:
                raise TaskError(
                    f"Noise `{name}` is a standard deviation and must be >= 0; got {value!r}. "
                    "Use 0 to switch that noise off."
                )
        return dataclasses.replace(
            self, initial=float(self.initial), process=float(self.process), measurement=float(self.measurement)
        )

    def as_dict(self) -> dict[str, float]:
        return dataclasses.asdict(self)

    @classmethod
    def from_any(cls, value: Any) -> "NoiseModel":
        """A NoiseModel from None, a NoiseModel, or a mapping of its fields."""
        if value is None:
            return cls()
        if isinstance(value, NoiseModel):
            return value
        if isinstance(value, dict):
            unknown = set(value) - {f.name for f in dataclasses.fields(cls)}
            if unknown:
                raise TaskError(
                    f"Unknown noise setting(s) {sorted(unknown)}; known: initial, process, measurement "
                    "(standard deviations)."
                )
            return cls(**value)
        raise TaskError(
            f"`noise` must be a NoiseModel or a mapping with keys initial, process, measurement; got {value!r}."
        )


class NoiseLevels(NamedTuple):
    """Traced standard deviations, one per component.

    ``a`` (actuator noise on the commanded control) is None for the paper's
    system, which has none; the closed-loop evaluation sets it
    (:class:`~podilqr_jax.control.episodes.EpisodeNoise`)."""

    x0: jnp.ndarray  # [2 nv] start-state deviation (tangent space, ``task.tangent``)
    w: jnp.ndarray  # [2 nv] process noise
    v: jnp.ndarray  # [nm] measurement noise
    a: Optional[jnp.ndarray] = None  # [nu] actuator noise


class Disturbance(NamedTuple):
    """One noise realisation per rollout (leading batch axis when batched):
    every rollout of the engine (``rollout.run``) takes one, or None for a
    deterministic rollout. A None field is a noise the rollout does not have.

    ``dx0`` moves the start state, ``w_t`` is added to the state after control
    step t, ``v_t`` to the measurement m_t and ``a_t`` to the control the
    physics receives at step t (the rollout records the commanded one)."""

    dx0: Optional[jnp.ndarray] = None  # [..., 2 nv] (tangent space, ``task.tangent``)
    w: Optional[jnp.ndarray] = None  # [..., S, 2 nv]
    v: Optional[jnp.ndarray] = None  # [..., S+1, nm]
    a: Optional[jnp.ndarray] = None  # [..., S, nu]


def noise_levels(model: NoiseModel, ndx: int, nz: int) -> NoiseLevels:
    """The traced levels of ``model`` for a state deviation of ``ndx`` (2 nv) and ``nz`` measurements."""
    return NoiseLevels(
        x0=jnp.full((ndx,), model.initial), w=jnp.full((ndx,), model.process), v=jnp.full((nz,), model.measurement)
    )


def sample(key: jax.Array, levels: NoiseLevels, batch: int, steps: int) -> Disturbance:
    """Independent noise for ``batch`` rollouts of ``steps`` control steps:
    each component N(0, std^2) with the standard deviations of ``levels``
    (actuator noise only when ``levels.a`` is given).

    The key is split four ways whether or not there is actuator noise, and
    JAX's key splitting is partitionable (``jax_threefry_partitionable``, on by
    default), so the first three draws do not depend on the fourth's presence.
    """
    k0, kw, kv, ka = jax.random.split(key, 4)
    dtype = levels.x0.dtype

    def normal(k, shape, std):
        return std * jax.random.normal(k, shape + std.shape, dtype)

    return Disturbance(
        dx0=normal(k0, (batch,), levels.x0),
        w=normal(kw, (batch, steps), levels.w),
        v=normal(kv, (batch, steps + 1), levels.v),
        a=None if levels.a is None else normal(ka, (batch, steps), levels.a),
    )
