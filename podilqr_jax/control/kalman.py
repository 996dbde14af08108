"""A Kalman filter on the identified ARMA model (the authors' ARMA-LQG estimator).

Raw information-state feedback differences noisy measurements: with q = 2 the
gains on z_t and z_{t-1} are a position gain plus a velocity gain over the
control step, so measurement noise reaches the control amplified by about
|K| sqrt(2) / dt. The estimator feeds back a filtered information state
instead.

Model. y_t = C x_t is the noise-free observation and Y_t its information state
(newest first, past commanded controls included). About the nominal, the
identified ARMA model (``sysid``) read as a state-space model is

  dY_{t+1} = A_t dY_t + B_t (du_t + a_t) + S' e_t,   a_t ~ N(0, diag(sa^2))
  dz_t     = S dY_t + v_t,                             v_t ~ N(0, R)

with S the selector of the newest block, so the filter's state is the
information-state deviation itself. The actuator noise a_t enters exactly as
the control does (B_t: the newest observation and the slot of the last
control, which the controller fills with its command); the rest is the
designer's allowance on the output equation:

  cov(e_t) = model_error tr(Theta_u diag(sa^2) Theta_u') / nz I   (what the
             linear model misses, a share of the actuator term)
           + sw^2 C J J' C'                  (process noise on the observed
                                              coordinates; J the tangent basis,
                                              the identity on hinges and slides)
  R        = diag(sv^2)

and the prior of dY_0 puts the start deviation's covariance s0^2 C J J' C' on each
of the q identical observation slots of the rest history. These are the
noise levels the designer states (the evaluation passes the levels it runs),
not estimated from data; the approximations (white e_t, process noise on the
unobserved coordinates entering only through the model) are documented in
docs/evaluation.md.

The filter's gains L_t do not depend on the measurements, so they are computed
once (``kalman_gains``, a jitted ``lax.scan``) and the running estimator is the
recursion of ``policy``: predict with (A_t, B_t), correct with L_{t+1}.
"""

from __future__ import annotations

import dataclasses
from typing import Optional

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from ..identify.identification import Experiment, data_based
from ..identify.info_state import info_dim
from ..identify.sysid import LinearModel
from ..ilqr.config import SolverConfig
from ..ilqr.plan import sysid_chunk
from ..ilqr.state import Nominal
from ..sim.rollout import on_device, open_loop_policy, rollout_batch
from ..task import tangent
from ..task.env import Env
from .policy import FeedbackPolicy

# Added to every covariance so that the innovation covariance is invertible
# when a noise is switched off (relative to 1, the scale of the states).
JITTER = 1e-12


@jax.jit
def kalman_gains(A, W, R, P0):
    """Gains L [T+1, nZ, nz] and posterior covariances P [T+1, nZ, nZ].

    A [T, nZ, nZ], W [T, nZ, nZ] the covariance of the information state's
    disturbance, R [nz, nz], P0 [nZ, nZ]. (B enters only through known
    inputs, so it does not change the gains.)
    """
    nz = R.shape[0]
    nZ = P0.shape[0]
    S = jnp.eye(nz, nZ, dtype=P0.dtype)
    eye = jnp.eye(nZ, dtype=P0.dtype)

    def correct(P_pred):
        innovation = S @ P_pred @ S.T + R
        L = jnp.linalg.solve(innovation, S @ P_pred).T  # P S' inv(innovation)
        I_LS = eye - L @ S
        P = I_LS @ P_pred @ I_LS.T + L @ R @ L.T  # Joseph form: stays symmetric PSD
        return L, 0.5 * (P + P.T)

    L0, P = correct(P0)

    def step(P, inp):
        A_t, W_t = inp
        P_pred = A_t @ P @ A_t.T + W_t
        L, P = correct(P_pred)
        return P, (L, P)

    _, (L, Ps) = jax.lax.scan(step, P, (A, W))
    return jnp.concatenate([L0[None], L]), jnp.concatenate([P[None], Ps])


@dataclasses.dataclass(frozen=True)
class EstimatorNoise:
    """The noise the filter is designed for (standard deviations)."""

    actuator: np.ndarray  # [nu]
    measurement: np.ndarray  # [nz]
    process: float = 0.0  # on qpos, qvel
    initial: float = 0.0  # start-state deviation
    model_error: float = 0.1  # isotropic share of the actuator term (see module docstring)


def identify_about_nominal(
    env: Env, policy: FeedbackPolicy, cfg: SolverConfig, *, n_s: Optional[int] = None, seed: int = 0
) -> LinearModel:
    """The ARMA model about the policy's nominal, identified from ``n_s``
    open-loop perturbation rollouts of ``env``'s simulator with its noise
    switched off (one identification of the ``nominal`` variant: the solve's
    ``sigma`` and least-squares fit). Default ``n_s``: 4 regressors' worth."""
    if policy.measures != "observations":
        raise ConfigError("The Kalman estimator is for data-based policies on the task's observations.")
    dims = env.dims
    q = policy.q
    n_s = n_s or max(cfg.resolved_n_s(env), 4 * info_dim(dims.nz, dims.nu, q) + 4 * dims.nu)
    ctrl = policy.controller
    # one open-loop identification, the noise off, sigma in absolute units, the plain least-squares fit
    settings = cfg.replace(
        n_s=n_s, n_avg=1, variant="plain", estimator="ols", cap_rank=False, adapt_sigma=False, sigma_scale="absolute"
    )
    data = on_device(env.data)
    identify = data_based(env, settings, q, data, False, sysid_chunk(settings, dims, data, False, n_s))
    zero = jnp.zeros_like(ctrl.u_bar)
    base = rollout_batch(dims, q, env.data, open_loop_policy(ctrl.u_bar, policy.info_dim), zero, zero)
    nominal = Nominal(ctrl.u_bar, base.z, None, jnp.zeros((dims.horizon + 1, policy.info_dim)), float("nan"))
    found = identify(jax.random.PRNGKey(seed), nominal, None, cfg.sigma, Experiment())
    if found.n_bad or found.problem == "nonfinite":
        raise ConfigError("The estimator's identification rollouts are not finite; lower the solve's sigma.")
    return found.model


def estimator_policy(
    env: Env, policy: FeedbackPolicy, model: LinearModel, noise: EstimatorNoise, name: str = "closed_loop_estimator"
) -> FeedbackPolicy:
    """``policy``'s nominal and gains, fed back on the Kalman-filtered
    information state of the ARMA ``model`` (see the module docstring)."""
    nz, nu, q = policy.nz, policy.nu, policy.q
    nZ = policy.info_dim
    C = np.asarray(env.data.C)
    # State noise is drawn in the tangent space (task.tangent): its covariance
    # in the observations is s^2 C J J' C', J the tangent basis at the start
    # state (the identity on hinges and slides; at every step, an
    # approximation on a free or ball joint).
    CJ = C @ np.asarray(tangent.basis(env.dims, env.data.x0))
    sa = np.broadcast_to(np.asarray(noise.actuator, float), (nu,))
    sv = np.broadcast_to(np.asarray(noise.measurement, float), (nz,))
    # The actuator noise a_t enters like the control: through B_t into the
    # newest observation and, for q > 1, into the information state's slot of
    # the last control (which holds the command, not what was applied).
    B = np.asarray(model.B)  # [T, nZ, nu]
    W = np.einsum("tij,j,tkj->tik", B, sa**2, B)
    spread = noise.model_error * np.trace(W[:, :nz, :nz], axis1=1, axis2=2) / nz
    W_z = spread[:, None, None] * np.eye(nz) + noise.process**2 * (CJ @ CJ.T) + JITTER * np.eye(nz)
    W[:, :nz, :nz] += W_z
    R = np.diag(sv**2) + JITTER * np.eye(nz)
    P0 = np.zeros((nZ, nZ))
    P0[: q * nz, : q * nz] = np.kron(np.ones((q, q)), noise.initial**2 * (CJ @ CJ.T) + JITTER * np.eye(nz))
    L, _ = kalman_gains(model.A, jnp.asarray(W), jnp.asarray(R), jnp.asarray(P0))
    ctrl = policy.controller._replace(F=jnp.asarray(model.A), G=jnp.asarray(model.B), L=L)
    return dataclasses.replace(policy, controller=ctrl, estimator="kalman", name=name)
