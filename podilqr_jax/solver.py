"""The outer iLQR loop: a thin Python driver over jitted stages.

Each iteration of POD-iLQR:
  1. identification: ``n_s`` perturbation rollouts about the nominal (one MJX
     batch) and a per-step least-squares ARMA fit (``sysid``);
  2. backward pass with adaptive Levenberg-Marquardt regularisation;
  3. forward pass: every step size of the line search as one MJX batch.
The model-based reference replaces step 1 by exact Jacobians (``model_based``).

The driver only moves scalars to the host (cost, acceptance, step size, mu),
so each iteration can be reported live; every array stays on the device.
All jitted stages compile during the first iteration and never again (checked
by ``compile_watch`` and a test).

Regularisation schedule: after an accepted step mu <- max(mu / f, mu_min);
after the n-th consecutive rejected step mu <- max(mu f^n, mu_min) and the
backward pass is redone on the same identified model (noiseless rollouts are
deterministic, so re-identifying would give the same model).
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable, Optional

import jax
import jax.numpy as jnp
import numpy as np

from .backward import BackwardResult, QuadraticCost, Regularisation, backward_pass
from .compile_watch import CompileWatch
from .config import SolverConfig
from .env import Env
from .errors import ConfigError
from .estimators import fit_information_model_iv
from .evaluation import true_costs
from .info_state import info_dim, observation_selector
from .line_search import line_search
from .model_based import linearise
from .result import IterationInfo, Result, Status
from .rollout import Policy, bytes_per_rollout, injected_perturbations, perturbation_rollouts, replicated
from .sysid import LinearModel, fit_information_model

Callback = Callable[[IterationInfo], None]

PHASES = ("rollouts", "fit", "backward", "line_search", "evaluation", "host")


def default_config(env: Env, **overrides) -> SolverConfig:
    """The task's recommended settings (``env`` defaults), with overrides."""
    settings = dict(env.solver_defaults)
    settings.update(overrides)
    return SolverConfig().replace(**settings)


def solve(
    env: Env,
    cfg: Optional[SolverConfig] = None,
    *,
    u_init=None,
    callback: Optional[Callback] = None,
) -> Result:
    """POD-iLQR: optimise the controls of ``env`` from rollouts alone.

    Args:
      env: the task (see :class:`Env`, :func:`make_task`).
      cfg: solver settings; default :func:`default_config` of the task.
      u_init: initial nominal controls [T, nu]; default zeros.
      callback: called with an :class:`IterationInfo` after every iteration.

    Returns:
      A :class:`Result`; its ``status`` says why the solve stopped.
    """
    cfg = default_config(env) if cfg is None else cfg
    q = cfg.validate(env, data_based=True)
    dims, data = env.dims, _on_device(env.data)
    nZ = info_dim(dims.nz, dims.nu, q)
    sigma = _on_device(cfg.sigma)
    rcond = _on_device(cfg.rcond)
    noisy = env.noisy and cfg.variant != "nominal"
    feedback = cfg.variant != "plain"
    n_avg = cfg.resolved_n_avg()
    chunk = cfg.resolved_chunk(bytes_per_rollout(dims, data, noisy))
    no_gains = _on_device(np.zeros((dims.horizon, dims.nu, nZ)))

    def identify(key, nominal, gains):
        t0 = time.perf_counter()
        policy = nominal.policy(gains if feedback else no_gains)
        traj = perturbation_rollouts(dims, q, cfg.n_s, data, policy, key, sigma, n_avg=n_avg, noisy=noisy, chunk=chunk)
        traj.z.block_until_ready()
        t1 = time.perf_counter()
        if cfg.estimator == "iv":
            du = injected_perturbations(key, sigma, cfg.n_s, dims.horizon, dims.nu)
            model, report = fit_information_model_iv(traj.z, traj.u, du, nominal.z_bar, nominal.u_bar, q, rcond)
        else:
            model, report = fit_information_model(traj.z, traj.u, nominal.z_bar, nominal.u_bar, q, rcond)
        stop = None
        if not bool(report.all_finite):
            stop = (Status.NONFINITE, "a sysid rollout or the fitted model is not finite")
        elif float(jnp.max(report.target_rms)) == 0.0:
            stop = (
                Status.NO_RESPONSE,
                f"the sysid perturbations (sigma={cfg.sigma:g}) left every observation unchanged, "
                "so the fit sees no dynamics: raise sigma (or use float64, see docs/algorithm.md)",
            )
        t2 = time.perf_counter()
        return model, stop, cfg.n_s * n_avg, {"rollouts": t1 - t0, "fit": t2 - t1}

    return _iterate("pod-ilqr", env, dims, data, cfg, q, identify, u_init, callback, noisy, cfg.resolved_n_forward())


def solve_model_based(
    env: Env,
    cfg: Optional[SolverConfig] = None,
    *,
    u_init=None,
    callback: Optional[Callback] = None,
) -> Result:
    """The model-based reference: iLQR with exact MJX Jacobians on the full state.

    Same task, cost, backward pass, line search and stopping rules as
    :func:`solve`; the identification is replaced by ``jax.jacfwd`` through
    ``mjx.step``. The data-based settings (``q``, ``n_s``, ``sigma``) are unused.
    """
    cfg = default_config(env) if cfg is None else cfg
    cfg.validate(env, data_based=False)
    view = env.full_state_view()
    dims, data = view.dims, _on_device(view.data)

    def identify(key, nominal, gains):
        t0 = time.perf_counter()
        model = linearise(dims, data, nominal.x_bar, nominal.u_bar)
        finite = bool(jnp.all(jnp.isfinite(model.A)) & jnp.all(jnp.isfinite(model.B)))
        stop = None if finite else (Status.NONFINITE, "the exact linearisation is not finite")
        return model, stop, 0, {"rollouts": 0.0, "fit": time.perf_counter() - t0}

    return _iterate("model-based", env, dims, data, cfg, 1, identify, u_init, callback, False, 1)


@dataclasses.dataclass
class _Nominal:
    u_bar: jnp.ndarray
    z_bar: jnp.ndarray
    x_bar: jnp.ndarray
    Z_bar: jnp.ndarray
    cost: float

    @classmethod
    def measured(cls, ls) -> "_Nominal":
        """The line search's chosen rollout as the new nominal."""
        return cls(ls.trajectory.u, ls.trajectory.z, ls.trajectory.x, ls.Z, float(ls.cost))

    def policy(self, K) -> Policy:
        """u_t = u_bar_t + K_t (Z_t - Z_bar_t) about this nominal."""
        return Policy(self.u_bar, self.Z_bar[:-1], K)


def _iterate(method, env, dims, data, cfg, q, identify, u_init, callback, noisy, n_fwd) -> Result:
    """The outer loop; ``dims, data`` are the task as the solver sees it (its
    data committed to the device), ``env`` the task as the user gave it."""
    t_start = time.perf_counter()
    nZ = info_dim(dims.nz, dims.nu, q)
    u0 = _initial_controls(u_init, dims)
    selector = observation_selector(dims.nz, dims.nu, q)
    cost_model = QuadraticCost(selector, data.z_target, data.Q, data.QT, data.R, data.goal_step)
    reg = Regularisation(_on_device(cfg.mu_min), _on_device(cfg.mu_max), _on_device(cfg.mu_factor))
    steps = 0.5 ** np.arange(cfg.n_alphas)
    # Under noise alpha = 0 is the last candidate: when nothing is accepted it
    # is a fresh measurement of the current policy (see line_search).
    alphas = _on_device(np.append(steps, 0.0) if noisy else steps)
    ls_rollouts = int(alphas.shape[0]) * n_fwd
    accept_ratio = _on_device(cfg.accept_ratio)
    zero_k = _on_device(np.zeros((dims.horizon, dims.nu)))
    no_change = _on_device(0.0)
    gains = _on_device(np.zeros((dims.horizon, dims.nu, nZ)))  # K of the current policy
    phase_s = dict.fromkeys(PHASES, 0.0)
    compiles: list[int] = []
    total_watch = CompileWatch()
    key = jax.random.PRNGKey(cfg.seed)
    ls_key = jax.random.fold_in(key, 1)  # the forward passes' own noise stream

    def measure(policy, k, cost0, dV1, dV2):
        nonlocal ls_key
        t0 = time.perf_counter()
        ls_key, sub = jax.random.split(ls_key)
        cost0 = _on_device(cost0)
        ls = line_search(dims, q, data, policy, k, alphas, cost0, dV1, dV2, accept_ratio, sub, n_fwd=n_fwd, noisy=noisy)
        accepted = bool(ls.accepted)
        phase_s["line_search"] += time.perf_counter() - t0
        return ls, accepted

    def ground_truth(nominal):
        """True (closed-loop, noiseless) and open-loop replay cost of the current policy."""
        if not noisy:
            return nominal.cost, nominal.cost
        t0 = time.perf_counter()
        tc = true_costs(dims, q, data, nominal.policy(gains))
        out = float(tc.closed_loop), float(tc.open_loop)
        phase_s["evaluation"] += time.perf_counter() - t0
        return out

    with total_watch:
        # The first nominal: the line search with k = 0, K = 0 rolls out u0 open loop.
        with CompileWatch() as watch0:
            first = Policy(u0, _on_device(np.zeros((dims.horizon, nZ))), gains)
            ls, _ = measure(first, zero_k, np.inf, no_change, no_change)
            nominal = _Nominal.measured(ls)
            true_cost, open_cost = ground_truth(nominal)
        cost_history = [nominal.cost]
        true_history, open_history = [true_cost], [open_cost]
        alpha_history: list[float] = []
        mu_history: list[float] = []
        grad_history: list[float] = []
        rollouts = ls_rollouts
        mu = max(cfg.mu_init, cfg.mu_min)
        failures = rejected = remeasured = streak = longest_streak = 0
        model: Optional[LinearModel] = None
        back: Optional[BackwardResult] = None
        status, message = Status.MAX_ITERATIONS, f"reached max_iterations={cfg.max_iterations}"
        if noisy:
            message += " (under noise a solve runs to max_iterations; see true_cost_history)"
        iteration = 0
        first_compiles = watch0.compiles

        if not np.isfinite(nominal.cost):
            status, message = Status.NONFINITE, "the initial controls give a non-finite rollout"
        else:
            for iteration in range(1, cfg.max_iterations + 1):
                t_iter = time.perf_counter()
                with CompileWatch() as watch:
                    stop, iter_rollouts, accepted = None, 0, False
                    if model is None:
                        key, sub = jax.random.split(key)
                        model, stop, iter_rollouts, times = identify(sub, nominal, gains)
                        for name, secs in times.items():
                            phase_s[name] += secs
                    if stop is None:
                        t0 = time.perf_counter()
                        back = backward_pass(model, nominal.Z_bar, nominal.u_bar, cost_model, _on_device(mu), reg)
                        back_ok = bool(back.ok)
                        mu = float(back.mu)
                        grad_norm = float(jnp.max(jnp.abs(back.grad)))
                        phase_s["backward"] += time.perf_counter() - t0
                        grad_history.append(grad_norm)
                        mu_history.append(mu)
                        if not back_ok and not noisy:
                            stop = (
                                Status.LINE_SEARCH_FAILED,
                                f"the backward pass needs regularisation above mu_max={cfg.mu_max:g}",
                            )
                        elif back_ok and grad_norm < cfg.gtol:
                            stop = (Status.CONVERGED, f"gradient norm {grad_norm:.3g} below gtol={cfg.gtol:g}")
                            gains = back.K
                    if stop is None:
                        if back_ok:
                            ls, accepted = measure(nominal.policy(back.K), back.k, nominal.cost, back.dV1, back.dV2)
                        else:  # noisy and no usable model: re-measure the current policy
                            ls, accepted = measure(nominal.policy(gains), zero_k, nominal.cost, no_change, no_change)
                        iter_rollouts += ls_rollouts
                        if accepted:
                            new_cost = float(ls.cost)
                            alpha_history.append(float(ls.alpha))
                            decrease = nominal.cost - new_cost
                            nominal = _Nominal.measured(ls)
                            gains = back.K
                            model = None
                            failures = streak = 0
                            mu = max(mu / cfg.mu_factor, cfg.mu_min)
                            if not noisy and decrease < cfg.rtol * abs(new_cost):
                                stop = (Status.CONVERGED, f"relative cost decrease below rtol={cfg.rtol:g}")
                        else:
                            alpha_history.append(0.0)
                            failures += 1
                            rejected += 1
                            streak += 1
                            longest_streak = max(longest_streak, streak)
                            mu = max(mu * cfg.mu_factor**failures, cfg.mu_min)
                            if noisy:
                                # The nominal's cost may be a lucky draw that no
                                # step can beat: take the fresh measurement of the
                                # same policy (the alpha = 0 candidate) and
                                # identify again about it, with mu capped.
                                mu = min(mu, cfg.mu_cap)
                                nominal = _Nominal.measured(ls)
                                model = None
                                remeasured += 1
                                if not np.isfinite(nominal.cost):
                                    stop = (Status.NONFINITE, "a re-measured nominal rollout is not finite")
                            else:
                                # indexed on the host: an eager jnp index would compile a kernel
                                predicted = float(np.asarray(ls.expected)[0])
                                if abs(predicted) < cfg.rtol * abs(nominal.cost):
                                    stop = (
                                        Status.CONVERGED,
                                        f"no step lowers the cost and the predicted decrease {predicted:.3g} "
                                        f"is below rtol x cost",
                                    )
                                elif mu > cfg.mu_max:
                                    stop = (
                                        Status.LINE_SEARCH_FAILED,
                                        f"no step size lowered the cost; regularisation passed mu_max={cfg.mu_max:g}",
                                    )
                        cost_history.append(nominal.cost)
                        true_cost, open_cost = ground_truth(nominal)
                        true_history.append(true_cost)
                        open_history.append(open_cost)
                    rollouts += iter_rollouts
                compiles.append(watch.compiles + (first_compiles if iteration == 1 else 0))
                if callback is not None:
                    wall = time.perf_counter() - t_iter
                    callback(
                        IterationInfo(
                            iteration=iteration,
                            cost=nominal.cost,
                            alpha=alpha_history[-1] if alpha_history else 0.0,
                            mu=mu,
                            grad_norm=grad_history[-1] if grad_history else float("nan"),
                            accepted=accepted,
                            rollouts=iter_rollouts,
                            rollouts_per_s=iter_rollouts / wall if wall > 0 else float("nan"),
                            wall_s=wall,
                            true_cost=true_history[-1],
                        )
                    )
                if stop is not None:
                    status, message = stop
                    break

    wall = time.perf_counter() - t_start
    # Everything outside the jitted stages. Stage times include their own
    # compilation in the first iteration; compile_s reports it separately.
    phase_s["host"] = max(0.0, wall - sum(v for k, v in phase_s.items() if k != "host"))
    k = np.asarray(back.k) if back is not None else np.zeros((dims.horizon, dims.nu))
    x_bar = np.asarray(nominal.x_bar)
    return Result(
        method=method,
        task=env.name,
        status=status,
        message=message,
        controls=np.asarray(nominal.u_bar),
        observations=x_bar @ np.asarray(env.data.C).T,
        states=x_bar,
        info_states=np.asarray(nominal.Z_bar),
        K=np.asarray(gains),
        k=k,
        q=q,
        cost_history=cost_history,
        alpha_history=alpha_history,
        mu_history=mu_history,
        grad_norm_history=grad_history,
        iterations=iteration,
        rollouts=rollouts,
        wall_s=wall,
        compile_s=total_watch.seconds,
        run_s=max(0.0, wall - total_watch.seconds),
        compiles_per_iteration=compiles,
        phase_s=phase_s,
        config=dataclasses.asdict(cfg) | {"q": q},
        control_dt=env.control_dt,
        observation_labels=env.observation_labels,
        state_labels=env.state_labels,
        variant=cfg.variant if method == "pod-ilqr" else "model-based",
        noisy=noisy,
        noise=env.noise.as_dict() if noisy else {},
        true_cost_history=true_history,
        open_loop_cost_history=open_history,
        rejected_steps=rejected,
        remeasured=remeasured,
        longest_rejection_streak=longest_streak,
    )


def _on_device(x):
    """``x`` committed to the default device (replicated over all devices when
    there are several, see ``rollout.replicated``): a number or NumPy array becomes a
    float64 (or float32) array, a pytree of arrays (``EnvData``) keeps its types.

    Driver-made arrays must be committed like the jitted stages' outputs they
    alternate with: JAX keys its compilation cache on whether an argument is
    committed, and mixing the two compiles every stage twice.
    """
    if isinstance(x, (int, float, np.ndarray, np.generic)):
        x = jnp.asarray(x, dtype=jnp.result_type(float))
    return jax.device_put(x, replicated())


def _initial_controls(u_init, dims) -> jnp.ndarray:
    if u_init is None:
        return _on_device(np.zeros((dims.horizon, dims.nu)))
    u = np.asarray(u_init, dtype=float)
    if u.shape != (dims.horizon, dims.nu):
        raise ConfigError(f"`u_init` must have shape [horizon, nu] = [{dims.horizon}, {dims.nu}]; got {u.shape}.")
    if not np.all(np.isfinite(u)):
        raise ConfigError("`u_init` holds non-finite numbers; use finite initial controls.")
    return _on_device(u)
