"""A finished solve as a controller you can run: feedback on the information state.

Sign convention (the backward pass's): the learnt policy is

  u_t = u_bar_t + K_t (Z_t - Z_bar_t)

with the nominal controls u_bar, the nominal information states Z_bar (for a
data-based solve: built from the nominal's *measured* observations, as the
solver saw them) and the gains K_t [nu, nZ]. A positive entry of K raises the
control when that component of the information state is above its nominal.

One recursion runs every controller here. The controller keeps an estimate
xi_t of the information-state deviation Z_t - Z_bar_t and updates it with each
new measurement dz = z - z_bar:

  xi_0     = L_0 dz_0
  u_t      = u_bar_t + K_t xi_t
  pred     = F_t xi_t + G_t (u_t - u_bar_t)
  xi_{t+1} = pred + L_{t+1} (dz_{t+1} - S pred)

with S the selector of the newest observation block. Three controllers are
this recursion with different (F, G, L):

- raw information-state feedback (``from_result``): F, G are the companion
  shifts with zero ARMA coefficients and L = S', so xi is exactly the measured
  deviation Z_t - Z_bar_t (L_0 copies dz_0 into the q observation slots: the
  rest history of ``info_state``);
- a Kalman filter on the identified ARMA model (``kalman.estimator_policy``):
  F, G the identified (A_t, B_t) and L the filter's gains, so xi is the
  filtered deviation of the noise-free information state (the authors'
  ARMA-LQG);
- full-state feedback (a model-based result, q = 1, ``measures="state"``):
  F = G = 0 and L = I.

``FeedbackPolicy`` wraps the arrays (:class:`Controller`, a pytree, traced) and
the shapes (static). ``reset``, ``act`` and ``update`` are jitted and
take the step index as a traced integer, so stepping a policy from Python
compiles once; ``episodes.run_episodes`` runs the same recursion inside a
batched MJX rollout (the rollout engine, ``rollout.run``, calls the
controller's ``start``, ``command`` and ``advance``).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from ..identify.info_state import companion, info_dim

MEASURES = ("observations", "state")


class Controller(NamedTuple):
    """The traced arrays of a policy (see the module docstring)."""

    u_bar: jnp.ndarray  # [T, nu] nominal controls
    z_bar: jnp.ndarray  # [T+1, nm] nominal measurements
    K: jnp.ndarray  # [T, nu, nZ] feedback gains
    F: jnp.ndarray  # [T, nZ, nZ] estimate propagation
    G: jnp.ndarray  # [T, nZ, nu] control input of the propagation
    L: jnp.ndarray  # [T+1, nZ, nm] measurement gains (L_0 initialises)

    # The controller interface of the rollout engine (``rollout.run``): the
    # carry is xi, the schedule the step index.
    def schedule(self, steps: int) -> jnp.ndarray:
        return jnp.arange(steps)

    def start(self, m0: jnp.ndarray) -> jnp.ndarray:
        return initial_estimate(self, m0)

    def command(self, xi: jnp.ndarray, t) -> jnp.ndarray:
        return control(self, t, xi)

    def advance(self, xi: jnp.ndarray, t, u: jnp.ndarray, m: jnp.ndarray) -> jnp.ndarray:
        return next_estimate(self, t, xi, u, m)


class PolicyState(NamedTuple):
    """What a running policy carries between steps."""

    t: jnp.ndarray  # int, the step whose control ``act`` returns
    xi: jnp.ndarray  # [nZ] estimate of Z_t - Z_bar_t


def raw_filter(T: int, nz: int, nu: int, q: int, dtype=jnp.float64) -> tuple[jnp.ndarray, jnp.ndarray, jnp.ndarray]:
    """(F, G, L) that make xi the measured information-state deviation exactly."""
    nZ = info_dim(nz, nu, q)
    F, G = companion(jnp.zeros((nz, nZ + nu), dtype), nz, nu, q)
    L_t = jnp.eye(nZ, nz, dtype=dtype)  # S'
    L_0 = jnp.tile(jnp.eye(nz, dtype=dtype), (q, 1))
    L_0 = jnp.concatenate([L_0, jnp.zeros(((q - 1) * nu, nz), dtype)])
    L = jnp.concatenate([L_0[None], jnp.broadcast_to(L_t, (T, nZ, nz))])
    return jnp.broadcast_to(F, (T, nZ, nZ)), jnp.broadcast_to(G, (T, nZ, nu)), L


@dataclasses.dataclass(frozen=True)
class FeedbackPolicy:
    """A controller u_t = u_bar_t + K_t xi_t, xi_t estimating Z_t - Z_bar_t.

    Attributes:
      controller: the traced arrays (:class:`Controller`).
      q: past measurements in the information state.
      nz: size of one measurement (the task's observation, or the full state
        when ``measures == "state"``).
      nu: controls.
      measures: ``"observations"`` (the task's noisy z = C x + v) or
        ``"state"`` (the full state x = [qpos, qvel], plus noise).
      estimator: ``"none"`` (raw information state) or ``"kalman"``.
      name: a label for reports (``closed_loop``, ``open_loop`` ...).

    Build one with :meth:`from_result` (or ``Result.policy()``),
    :meth:`open_loop`, or ``kalman.estimator_policy``.
    """

    controller: Controller
    q: int
    nz: int
    nu: int
    measures: str = "observations"
    estimator: str = "none"
    name: str = "closed_loop"

    # ------------------------------------------------------------ construction
    @classmethod
    def from_result(cls, result, name: str | None = None) -> "FeedbackPolicy":
        """The policy of a finished solve: nominal controls plus its gains K
        on the raw (measured) information state.

        A model-based result (exact derivatives, full state) gives a
        full-state feedback policy (``measures == "state"``).
        """
        u_bar = np.asarray(result.controls, dtype=float)
        Z_bar = np.asarray(result.info_states, dtype=float)
        K = np.asarray(result.K, dtype=float)
        q = int(result.q)
        T, nu = u_bar.shape
        measures = "state" if result.method == "model-based" else "observations"
        nZ = Z_bar.shape[1]
        nz = (nZ - (q - 1) * nu) // q
        if K.shape != (T, nu, nZ) or Z_bar.shape[0] != T + 1 or q * nz + (q - 1) * nu != nZ:
            raise ConfigError(
                f"Inconsistent result arrays: controls {u_bar.shape}, info_states {Z_bar.shape}, K {K.shape}, "
                f"q={q}; expected controls [T, nu], info_states [T+1, q nz + (q-1) nu], K [T, nu, nZ]."
            )
        F, G, L = raw_filter(T, nz, nu, q)
        ctrl = Controller(jnp.asarray(u_bar), jnp.asarray(Z_bar[:, :nz]), jnp.asarray(K), F, G, L)
        default = "model_based" if measures == "state" else "closed_loop"
        return cls(ctrl, q, nz, nu, measures=measures, name=name or default)

    def open_loop(self) -> "FeedbackPolicy":
        """The same nominal controls with no feedback (K = 0)."""
        ctrl = self.controller._replace(K=jnp.zeros_like(self.controller.K))
        return dataclasses.replace(self, controller=ctrl, name="open_loop", estimator="none")

    def with_nominal(self, u_bar, z_bar, K) -> "FeedbackPolicy":
        """A policy with the same shapes and estimator but a new nominal and
        gains (used by receding-horizon replanning; nothing recompiles)."""
        ctrl = self.controller._replace(
            u_bar=jnp.asarray(u_bar, self.controller.u_bar.dtype),
            z_bar=jnp.asarray(z_bar, self.controller.z_bar.dtype),
            K=jnp.asarray(K, self.controller.K.dtype),
        )
        return dataclasses.replace(self, controller=ctrl)

    # ------------------------------------------------------------------ shapes
    @property
    def horizon(self) -> int:
        return int(self.controller.u_bar.shape[0])

    @property
    def info_dim(self) -> int:
        return info_dim(self.nz, self.nu, self.q)

    # ----------------------------------------------------------------- running
    def reset(self, z0) -> PolicyState:
        """The state after the first measurement z_0 [nz]."""
        z0 = self._measurement(z0, "z0")
        return _reset(self.controller, z0)

    def act(self, state: PolicyState) -> jnp.ndarray:
        """The control u_t [nu] for the current state (does not advance)."""
        self._check_time(state)
        return _act(self.controller, state)

    def update(self, state: PolicyState, u, z_next) -> PolicyState:
        """Advance one step: ``u`` the control applied at t (as commanded),
        ``z_next`` the measurement z_{t+1}."""
        self._check_time(state)
        u = jnp.asarray(u, self.controller.u_bar.dtype)
        if u.shape != (self.nu,):
            raise ConfigError(f"`u` must have shape [nu] = [{self.nu}]; got {tuple(u.shape)}.")
        return _update(self.controller, state, u, self._measurement(z_next, "z_next"))

    def _measurement(self, z, what: str) -> jnp.ndarray:
        z = jnp.asarray(z, self.controller.z_bar.dtype)
        if z.shape != (self.nz,):
            kind = "the full state [qpos, qvel]" if self.measures == "state" else "the task's observation"
            raise ConfigError(f"`{what}` must have shape [{self.nz}] ({kind}); got {tuple(z.shape)}.")
        return z

    def _check_time(self, state: PolicyState) -> None:
        t = int(state.t)
        if not 0 <= t < self.horizon:
            raise ConfigError(
                f"The policy has controls for steps 0 .. {self.horizon - 1}; the state is at step {t}. "
                "Reset it for a new episode, or replan (see replan.py) to go beyond the horizon."
            )

    def __repr__(self) -> str:
        return (
            f"FeedbackPolicy({self.name}: horizon={self.horizon}, q={self.q}, nz={self.nz}, nu={self.nu}, "
            f"measures={self.measures}, estimator={self.estimator})"
        )


# Policies are pytrees: the controller is traced, the rest static.
jax.tree_util.register_dataclass(
    FeedbackPolicy, data_fields=["controller"], meta_fields=["q", "nz", "nu", "measures", "estimator", "name"]
)


def newest(xi: jnp.ndarray, nz: int) -> jnp.ndarray:
    """S xi: the newest measurement block."""
    return xi[:nz]


@jax.jit
def _reset(ctrl: Controller, z0: jnp.ndarray) -> PolicyState:
    return PolicyState(jnp.asarray(0), initial_estimate(ctrl, z0))


@jax.jit
def _act(ctrl: Controller, state: PolicyState) -> jnp.ndarray:
    return control(ctrl, state.t, state.xi)


@jax.jit
def _update(ctrl: Controller, state: PolicyState, u: jnp.ndarray, z_next: jnp.ndarray) -> PolicyState:
    return PolicyState(state.t + 1, next_estimate(ctrl, state.t, state.xi, u, z_next))


def initial_estimate(ctrl: Controller, z0: jnp.ndarray) -> jnp.ndarray:
    return ctrl.L[0] @ (z0 - ctrl.z_bar[0])


def control(ctrl: Controller, t, xi: jnp.ndarray) -> jnp.ndarray:
    return ctrl.u_bar[t] + ctrl.K[t] @ xi


def next_estimate(ctrl: Controller, t, xi: jnp.ndarray, u: jnp.ndarray, z_next: jnp.ndarray) -> jnp.ndarray:
    nz = ctrl.z_bar.shape[1]
    pred = ctrl.F[t] @ xi + ctrl.G[t] @ (u - ctrl.u_bar[t])
    return pred + ctrl.L[t + 1] @ (z_next - ctrl.z_bar[t + 1] - newest(pred, nz))


@jax.jit
def run_on_measurements(ctrl: Controller, z: jnp.ndarray) -> jnp.ndarray:
    """Controls [T, nu] the policy would command along a recorded measurement
    sequence z [T+1, nz] (the measured values fed back in turn). For checks."""

    def step(xi, inp):
        t, z_next = inp
        u = control(ctrl, t, xi)
        return next_estimate(ctrl, t, xi, u, z_next), u

    T = ctrl.u_bar.shape[0]
    _, u = jax.lax.scan(step, initial_estimate(ctrl, z[0]), (jnp.arange(T), z[1:]))
    return u
