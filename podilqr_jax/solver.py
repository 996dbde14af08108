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
import os
import time
from typing import Callable, NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from .backward import QuadraticCost, Regularisation, backward_pass
from .checkpoint import Nominal, SolverState, fingerprint, load_checkpoint, save_checkpoint
from .compile_watch import CompileWatch
from .config import SolverConfig, adapted_sigma, reidentify_scale
from .env import Env, mjx_model_of
from .errors import ConfigError
from .estimators import fit_information_model_iv
from .evaluation import true_costs
from .info_state import info_dim, n_regressors, observation_selector
from .interrupts import deferred_interrupts
from .line_search import line_search
from .model_based import linearise, nonfinite_hint
from .result import IterationInfo, Result, Status
from .rollout import (
    Policy,
    bytes_per_rollout,
    injected_perturbations,
    observations_of,
    perturbation_rollouts,
    replicated,
)
from .sysid import excited_rank, fit_information_model, fit_residual

Callback = Callable[[IterationInfo], None]

PHASES = ("rollouts", "fit", "backward", "line_search", "evaluation", "host")


def default_config(env: Env, **overrides) -> SolverConfig:
    """The task's recommended settings (``env`` defaults), with overrides."""
    settings = dict(env.solver_defaults)
    settings.update(overrides)
    return SolverConfig().replace(**settings)


class RunOptions(NamedTuple):
    """Checkpointing of a solve (validated by ``_run_options``)."""

    checkpoint: Optional[str]  # folder written every ``every`` iterations
    every: int
    resume: Optional[str]  # checkpoint folder (or file) to continue from


def solve(
    env: Env,
    cfg: Optional[SolverConfig] = None,
    *,
    u_init=None,
    callback: Optional[Callback] = None,
    checkpoint: Optional[str | os.PathLike] = None,
    checkpoint_every: int = 10,
    resume: Optional[str | os.PathLike] = None,
) -> Result:
    """POD-iLQR: optimise the controls of ``env`` from rollouts alone.

    Args:
      env: the task (see :class:`Env`, :func:`make_task`).
      cfg: solver settings; default :func:`default_config` of the task.
      u_init: initial nominal controls [T, nu]; default zeros.
      callback: called with an :class:`IterationInfo` after every iteration.
      checkpoint: a folder; the solver state is saved there (atomically, as
        ``checkpoint.npz``) every ``checkpoint_every`` iterations and when
        the solve stops (see ``checkpoint``).
      resume: a checkpoint folder to continue from: the same task and
        settings (``max_iterations`` may be raised) give the same result, bit
        for bit, as a run that was never stopped. ``u_init`` is then unused.

    Returns:
      A :class:`Result`; its ``status`` says why the solve stopped. Ctrl-C
      (SIGINT, from the main thread) stops the solve after the iteration it
      lands in (a second Ctrl-C at once) and returns the result of the last
      completed iteration with status ``interrupted`` (see ``interrupts``).
    """
    cfg = default_config(env) if cfg is None else cfg
    q = cfg.validate(env, data_based=True)
    run = _run_options(checkpoint, checkpoint_every, resume)
    dims, data = env.dims, _on_device(_in_impl(env, cfg.impl))
    nZ = info_dim(dims.nz, dims.nu, q)
    rcond = _on_device(cfg.rcond)
    noisy = env.noisy and cfg.variant != "nominal"
    units = actuator_units(env, cfg)
    adapt = cfg.adapt_sigma and not noisy
    feedback = cfg.variant != "plain"
    n_avg = cfg.resolved_n_avg()
    chunk = cfg.resolved_chunk(bytes_per_rollout(dims, data, noisy))
    no_gains = _on_device(np.zeros((dims.horizon, dims.nu, nZ)))
    # noiseless sysid from a fixed start: fit only the directions the perturbations excite (sysid.excited_rank)
    max_rank = jax.device_put(excited_rank(dims, q), replicated()) if cfg.cap_rank and not noisy else None
    zero_z = _on_device(np.zeros((dims.horizon + 1, dims.nz)))
    zero_u = _on_device(np.zeros((dims.horizon, dims.nu)))

    def identify(key, nominal, gains, sigma, mirrored, open_loop):
        """One identification at scale ``sigma`` (times ``units``), with
        mirrored pairs or open loop where the recovery switched to them;
        returns (model, stop, rollouts, n_bad, phase times, the next sigma or None)."""
        t0 = time.perf_counter()
        mirrored = mirrored and not open_loop
        closed = feedback and not open_loop
        if closed and cfg.saturated_open_loop and env.limited:
            gains = _unsaturated_gains(gains, nominal.u_bar, data.u_low, data.u_high)
        policy = _policy(nominal, gains if closed else no_gains)
        sigma_t = _on_device(sigma * units)
        traj = perturbation_rollouts(
            dims, q, cfg.n_s, data, policy, key, sigma_t, n_avg=n_avg, noisy=noisy, chunk=chunk, mirrored=mirrored
        )
        traj.z.block_until_ready()
        t1 = time.perf_counter()
        # mirrored rollouts come back as half-differences: deviations about a zero nominal
        z_bar, u_bar = (zero_z, zero_u) if mirrored else (nominal.z_bar, nominal.u_bar)
        if cfg.estimator == "iv":
            du = injected_perturbations(key, sigma_t, cfg.n_s, dims.horizon, dims.nu)
            model, report = fit_information_model_iv(traj.z, traj.u, du, z_bar, u_bar, q, rcond)
        else:
            model, report = fit_information_model(traj.z, traj.u, z_bar, u_bar, q, rcond, max_rank)
        stop = None
        n_bad = int(report.n_bad)
        n_good = cfg.n_s - n_bad
        if n_good < needed:
            stop = (
                Status.NONFINITE,
                f"{n_bad} of {cfg.n_s} sysid rollouts diverged (non-finite states); the {n_good} left are "
                f"too few for the fit ({needed} needed): lower sigma, or look at the model's stability",
            )
        elif not bool(jnp.all(jnp.isfinite(model.A)) & jnp.all(jnp.isfinite(model.B))):
            stop = (Status.NONFINITE, "the fitted model is not finite")
        elif float(jnp.max(report.target_rms)) == 0.0:
            stop = (
                Status.NO_RESPONSE,
                f"the sysid perturbations (sigma={sigma:g}) left every observation unchanged, "
                "so the fit sees no dynamics: raise sigma (or use float64, see docs/algorithm.md)",
            )
        following = None
        if adapt and stop is None:
            rho, floor = fit_residual(report, nominal.z_bar)
            if np.isfinite(rho):
                following = adapted_sigma(sigma, rho, floor, 2 if mirrored else 1, cfg)
        t2 = time.perf_counter()
        rollouts = cfg.n_s * n_avg * (2 if mirrored else 1)
        return model, stop, rollouts, n_bad, {"rollouts": t1 - t0, "fit": t2 - t1}, following

    needed = n_regressors(dims.nz, dims.nu, q)
    return _iterate(
        "pod-ilqr", env, dims, data, cfg, q, identify, u_init, callback, noisy, cfg.resolved_n_forward(), run
    )


def solve_model_based(
    env: Env,
    cfg: Optional[SolverConfig] = None,
    *,
    u_init=None,
    callback: Optional[Callback] = None,
    checkpoint: Optional[str | os.PathLike] = None,
    checkpoint_every: int = 10,
    resume: Optional[str | os.PathLike] = None,
) -> Result:
    """The model-based reference: iLQR with exact MJX Jacobians on the full state.

    Same task, cost, backward pass, line search and stopping rules as
    :func:`solve`; the identification is replaced by forward-mode derivatives through
    ``mjx.step``. The data-based settings (``q``, ``n_s``, ``sigma``) are unused.
    """
    cfg = default_config(env) if cfg is None else cfg
    cfg.validate(env, data_based=False)
    run = _run_options(checkpoint, checkpoint_every, resume)
    view = env.full_state_view()
    dims, data = view.dims, _on_device(view.data)

    def identify(key, nominal, gains, sigma, mirrored, open_loop):
        t0 = time.perf_counter()
        model = linearise(dims, data, nominal.x_bar, nominal.u_bar)
        finite = bool(jnp.all(jnp.isfinite(model.A)) & jnp.all(jnp.isfinite(model.B)))
        why = "the exact linearisation is not finite" + nonfinite_hint(env.mj_model)
        stop = None if finite else (Status.NONFINITE, why)
        return model, stop, 0, 0, {"rollouts": 0.0, "fit": time.perf_counter() - t0}, None

    return _iterate("model-based", env, dims, data, cfg, 1, identify, u_init, callback, False, 1, run)


@jax.jit
def _unsaturated_gains(K, u_bar, u_low, u_high):
    """``K`` [T, nu, nZ] with the rows of controls that sit on their ctrlrange
    bound in the nominal set to zero, for the closed-loop sysid rollouts
    (``SolverConfig.saturated_open_loop``).

    Feedback on a saturated control cannot act past the bound, and it can
    keep the perturbations from acting at all: a clipped perturbation is
    one-sided, so the deviations after it have a mean of the order of sigma,
    which the gains turn into a push against the bound. On dm_control's
    cart-pole the applied control moved in 0-20% of the rollouts at the last
    saturated steps, the fit lost the control's column there (rank 4 of 5)
    and the step it proposed raised the cost (``examples/saturated_sysid.py``).
    With those rows at zero each perturbation acts on one side, as open loop.
    """
    at_bound = (u_bar <= u_low) | (u_bar >= u_high)
    return jnp.where(at_bound[:, :, None], 0.0, K)


def actuator_units(env: Env, cfg: SolverConfig) -> np.ndarray:
    """[nu] the unit of each actuator's sysid perturbation (``cfg.sigma_scale``):
    half its ctrlrange where it is limited, else 1; all 1 for ``absolute``."""
    low, high = np.asarray(env.data.u_low, dtype=float), np.asarray(env.data.u_high, dtype=float)
    half = (high - low) / 2
    limited = np.isfinite(half) & (half > 0)
    if cfg.sigma_scale == "absolute":
        return np.ones(env.dims.nu)
    return np.where(limited, half, 1.0)


def _in_impl(env: Env, impl: str):
    """The task's data with its MJX model in implementation ``impl`` (``SolverConfig.impl``)."""
    if impl == "jax":
        return env.data
    model, _ = mjx_model_of(env.mj_model, env.name, impl=impl)
    return env.data._replace(model=model)


def _policy(nominal: Nominal, K) -> Policy:
    """u_t = u_bar_t + K_t (Z_t - Z_bar_t) about ``nominal``."""
    return Policy(nominal.u_bar, nominal.Z_bar[:-1], K)


def _iterate(method, env, dims, data, cfg, q, identify, u_init, callback, noisy, n_fwd, run) -> Result:
    """The outer loop; ``dims, data`` are the task as the solver sees it (its
    data committed to the device), ``env`` the task as the user gave it,
    ``run`` the checkpoint/resume options."""
    t_start = time.perf_counter()
    nZ = info_dim(dims.nz, dims.nu, q)
    # Only a data-based fit has something to re-draw; under noise a rejected step never stops the solve.
    reidentify = cfg.reidentify if method == "pod-ilqr" and not noisy else 0
    escalate = reidentify > 0 and cfg.escalate
    closed_loop = cfg.variant != "plain"
    selector = observation_selector(dims.nz, dims.nu, q)
    box = (data.u_low, data.u_high) if env.limited else (None, None)
    cost_model = QuadraticCost(selector, data.z_target, data.Q, data.QT, data.R, data.goal_step, *box)
    reg = Regularisation(_on_device(cfg.mu_min), _on_device(cfg.mu_max), _on_device(cfg.mu_factor))
    steps = 0.5 ** np.arange(cfg.n_alphas)
    # Under noise alpha = 0 is the last candidate: when nothing is accepted it
    # is a fresh measurement of the current policy (see line_search).
    alphas = _on_device(np.append(steps, 0.0) if noisy else steps)
    ls_rollouts = int(alphas.shape[0]) * n_fwd
    ls_chunk = cfg.resolved_chunk(bytes_per_rollout(dims, data, noisy, record_state=True), group=1)
    ls_chunk = None if ls_chunk >= ls_rollouts else ls_chunk  # one compile for every budget that fits
    accept_ratio = _on_device(cfg.accept_ratio)
    zero_k = _on_device(np.zeros((dims.horizon, dims.nu)))
    no_change = _on_device(0.0)
    phase_s = dict.fromkeys(PHASES, 0.0)
    compiles: list[int] = []
    total_watch = CompileWatch()
    print_ = fingerprint(method, env, dims, cfg)

    def measure(st, policy, k, cost0, dV1, dV2):
        t0 = time.perf_counter()
        st.ls_key, sub = jax.random.split(st.ls_key)
        ls = line_search(
            dims, q, data, policy, k, alphas, _on_device(cost0), dV1, dV2, accept_ratio, sub, n_fwd, noisy, ls_chunk
        )
        accepted = bool(ls.accepted)
        st.diverged_candidates += int(ls.n_diverged)
        phase_s["line_search"] += time.perf_counter() - t0
        return ls, accepted

    def ground_truth(st: SolverState):
        """True (closed-loop, noiseless) and open-loop replay cost of the current policy."""
        if not noisy:
            return st.nominal.cost, st.nominal.cost
        t0 = time.perf_counter()
        tc = true_costs(dims, q, data, _policy(st.nominal, st.gains))
        out = float(tc.closed_loop), float(tc.open_loop)
        phase_s["evaluation"] += time.perf_counter() - t0
        return out

    def one_iteration(st: SolverState):
        """Identify (unless the model is reused), backward pass, line search.
        Returns (stop or None, note for the progress line, accepted, rollouts)."""
        stop, note, iter_rollouts, accepted = None, "", 0, False
        nominal = st.nominal
        if st.model is None:
            st.key, sub = jax.random.split(st.key)
            sigma = st.sigma * reidentify_scale(st.reidentified)
            st.model, stop, iter_rollouts, n_bad, times, following = identify(
                sub, nominal, st.gains, sigma, bool(st.mirrored), bool(st.open_loop)
            )
            if method == "pod-ilqr":  # the model-based reference has no scale
                st.sigma_history.append(sigma)
            if following is not None and st.reidentified == 0:  # adapt from the base scale only
                st.sigma = following
            st.rollouts += iter_rollouts
            for name, secs in times.items():
                phase_s[name] += secs
            if n_bad and stop is None:
                st.diverged_rollouts += n_bad
                note = f"{n_bad} sysid rollouts diverged, left out of the fit"
        elif method == "pod-ilqr":  # the model of the last identification, reused with a larger mu
            st.sigma_history.append(st.sigma_history[-1])
        if stop is not None:
            st.model = None
            return stop, note, accepted, iter_rollouts
        t0 = time.perf_counter()
        back = backward_pass(st.model, nominal.Z_bar, nominal.u_bar, cost_model, _on_device(st.mu), reg)
        back_ok = bool(back.ok)
        st.mu = float(back.mu)
        grad_norm = float(jnp.max(jnp.abs(back.grad)))
        phase_s["backward"] += time.perf_counter() - t0
        st.grad_history.append(grad_norm)
        st.mu_history.append(st.mu)
        if not back_ok and not noisy:
            return (
                (Status.LINE_SEARCH_FAILED, f"the backward pass needs regularisation above mu_max={cfg.mu_max:g}"),
                note,
                accepted,
                iter_rollouts,
            )
        if back_ok:
            st.back_k = back.k
            if grad_norm < cfg.gtol:
                st.gains = back.K
                return (
                    (Status.CONVERGED, f"gradient norm {grad_norm:.3g} below gtol={cfg.gtol:g}"),
                    note,
                    False,
                    iter_rollouts,
                )
            ls, accepted = measure(st, _policy(nominal, back.K), back.k, nominal.cost, back.dV1, back.dV2)
        else:  # noisy and no usable model: re-measure the current policy
            ls, accepted = measure(st, _policy(nominal, st.gains), zero_k, nominal.cost, no_change, no_change)
        iter_rollouts += ls_rollouts
        st.rollouts += ls_rollouts
        if accepted:
            new_cost = float(ls.cost)
            st.alpha_history.append(float(ls.alpha))
            decrease = nominal.cost - new_cost
            st.nominal = Nominal.measured(ls)
            st.gains = back.K
            st.model = None
            st.failures = st.streak = st.reidentified = 0
            st.mu = max(st.mu / cfg.mu_factor, cfg.mu_min)
            if not noisy and decrease < cfg.rtol * abs(new_cost):
                stop = (Status.CONVERGED, f"relative cost decrease below rtol={cfg.rtol:g}")
        else:
            st.alpha_history.append(0.0)
            st.failures += 1
            st.rejected += 1
            st.streak += 1
            st.longest_streak = max(st.longest_streak, st.streak)
            st.mu = max(st.mu * cfg.mu_factor**st.failures, cfg.mu_min)
            if noisy:
                # The nominal's cost may be a lucky draw that no step can beat:
                # take the fresh measurement of the same policy (the alpha = 0
                # candidate) and identify again about it, with mu capped. A
                # divergent measurement is not taken: the nominal stays.
                st.mu = min(st.mu, cfg.mu_cap)
                st.model = None
                if np.isfinite(float(ls.cost)):
                    st.nominal = Nominal.measured(ls)
                    st.remeasured += 1  # routine under noise: no progress note
                else:
                    note = "no step accepted; the re-measurement diverged, nominal kept"
            else:
                # indexed on the host: an eager jnp index would compile a kernel
                predicted = float(np.asarray(ls.expected)[0])
                if abs(predicted) < cfg.rtol * abs(nominal.cost):
                    stop = (
                        Status.CONVERGED,
                        f"no step lowers the cost and the predicted decrease {predicted:.3g} is below rtol x cost",
                    )
                elif st.mu > cfg.mu_max and st.reidentified < reidentify:
                    # Before giving up: fresh perturbations at another scale, mu afresh.
                    st.reidentified += 1
                    st.reidentifications += 1
                    st.model, st.failures = None, 0
                    st.mu = max(cfg.mu_init, cfg.mu_min)
                    note = (
                        f"no step lowered the cost up to mu_max: re-identifying with fresh perturbations at "
                        f"sigma = {st.sigma * reidentify_scale(st.reidentified):.3g}"
                    )
                elif st.mu > cfg.mu_max and escalate and (change := _next_experiment(st, closed_loop)) is not None:
                    # The scales are spent: another experiment for the rest of the solve, the scales afresh.
                    setattr(st, change, 1)
                    st.reidentified = 0
                    st.reidentifications += 1
                    st.model, st.failures = None, 0
                    st.mu = max(cfg.mu_init, cfg.mu_min)
                    note = "no step lowered the cost at any sigma: " + (
                        f"identifying with mirrored +du/-du pairs from now on (2 x {cfg.n_s * cfg.resolved_n_avg()} "
                        "rollouts)"
                        if change == "mirrored"
                        else "identifying open loop, without pairs, from now on (the paper's experiment)"
                    )
                elif st.mu > cfg.mu_max:
                    stop = (
                        Status.LINE_SEARCH_FAILED,
                        _failure_message(cfg, st, ls, steps, nominal.cost, reidentify, escalate),
                    )
                else:
                    st.mu_retries += 1
                    note = f"no step lowered the cost: mu raised to {st.mu:.3g}, retrying"
        st.cost_history.append(st.nominal.cost)
        true_cost, open_cost = ground_truth(st)
        st.true_history.append(true_cost)
        st.open_history.append(open_cost)
        return stop, note, accepted, iter_rollouts

    status, message = Status.MAX_ITERATIONS, f"reached max_iterations={cfg.max_iterations}"
    if noisy:
        message += " (under noise a solve runs to max_iterations; see true_cost_history)"
    first_compiles = 0
    interrupted = "Ctrl-C; the result is the nominal and gains of the last completed iteration"
    with total_watch, deferred_interrupts as interrupts:
        if run.resume is not None:
            st = load_checkpoint(run.resume, print_, _on_device)
        else:
            # The first nominal: the line search with k = 0, K = 0 rolls out u0 open loop.
            key = jax.random.PRNGKey(cfg.seed)
            st = SolverState(
                iteration=0,
                nominal=None,
                gains=_on_device(np.zeros((dims.horizon, dims.nu, nZ))),
                model=None,
                back_k=None,
                key=key,
                ls_key=jax.random.fold_in(key, 1),  # the forward passes' own noise stream
                mu=max(cfg.mu_init, cfg.mu_min),
                sigma=float(cfg.sigma),
                mirrored=int(cfg.mirrored),
            )
            with CompileWatch() as watch0:
                first = Policy(_initial_controls(u_init, dims), _on_device(np.zeros((dims.horizon, nZ))), st.gains)
                ls, _ = measure(st, first, zero_k, np.inf, no_change, no_change)
                st.nominal = Nominal.measured(ls)
                true_cost, open_cost = ground_truth(st)
            st.diverged_candidates = 0  # the first measurement is not a candidate step
            st.cost_history, st.true_history, st.open_history = [st.nominal.cost], [true_cost], [open_cost]
            st.rollouts = ls_rollouts
            first_compiles = watch0.compiles
        safe = st.snapshot()
        if not np.isfinite(st.nominal.cost):
            status, message = Status.NONFINITE, "the initial controls give a non-finite rollout"
        elif st.stopped is not None:  # resumed from the checkpoint of a finished solve: nothing to do
            status, message = Status(st.stopped[0]), st.stopped[1] + " (before the checkpoint)"
        else:
            try:
                for iteration in range(st.iteration + 1, cfg.max_iterations + 1):
                    if interrupts.requested:  # Ctrl-C during the last iteration (or before the first)
                        if run.checkpoint is not None:
                            save_checkpoint(run.checkpoint, st, print_)
                        status, message = Status.INTERRUPTED, interrupted
                        break
                    t_iter = time.perf_counter()
                    with CompileWatch() as watch:
                        stop, note, accepted, iter_rollouts = one_iteration(st)
                        st.iteration = iteration
                    compiles.append(watch.compiles + (first_compiles if not compiles else 0))
                    safe = st.snapshot()
                    if stop is not None:
                        st.stopped = [str(stop[0]), stop[1]]
                    final = stop is not None or iteration == cfg.max_iterations
                    if run.checkpoint is not None and (iteration % run.every == 0 or final):
                        save_checkpoint(run.checkpoint, st, print_)
                    if callback is not None:
                        callback(_info(st, iteration, accepted, iter_rollouts, time.perf_counter() - t_iter, note))
                    if stop is not None:
                        status, message = stop
                        break
            except KeyboardInterrupt:
                st = safe.restored()
                if run.checkpoint is not None:  # the last completed iteration: resumable as is
                    save_checkpoint(run.checkpoint, st, print_)
                status, message = Status.INTERRUPTED, interrupted

    wall = time.perf_counter() - t_start
    # Everything outside the jitted stages. Stage times include their own
    # compilation in the first iteration; compile_s reports it separately.
    phase_s["host"] = max(0.0, wall - sum(v for k, v in phase_s.items() if k != "host"))
    return _result(method, env, dims, cfg, q, st, status, message, noisy, phase_s, compiles, total_watch, wall)


def _failure_message(cfg, st, ls, steps, cost0: float, reidentify: int, escalated: bool) -> str:
    """Why the last (noiseless) line search failed, in the numbers it measured;
    ``steps`` are its candidate step sizes; ``escalated``: the recovery also
    changed the experiment (``_next_experiment``)."""
    expected = np.asarray(ls.expected)
    costs = np.where(np.isfinite(np.asarray(ls.costs)), np.asarray(ls.costs), np.inf)
    i = int(np.argmin(costs))
    tried = ", ".join(f"x {reidentify_scale(a):g}" for a in range(1, reidentify + 1))
    again = f" and {reidentify} re-identifications (sigma {tried})" if reidentify else ""
    if escalated and _experiments_tried(st, cfg):
        again += ", then the same with " + ", then ".join(_experiments_tried(st, cfg))
    change = f"changed the cost by {costs[i] - cost0:+.3g}" if np.isfinite(costs[i]) else "diverged"
    return (
        f"no step size lowered the cost after {st.streak} retries with growing regularisation{again}; "
        f"mu passed mu_max={cfg.mu_max:g}. The last model predicted a decrease of {expected[0]:.3g} for the full "
        f"step; the best candidate (alpha = {steps[i]:.3g}, predicted {expected[i]:.3g}) {change}"
    )


def _next_experiment(st, closed_loop: bool):
    """The state flag of the next experiment the recovery switches to, or None
    when both are spent: mirrored pairs, then the open-loop (``plain``) identification
    (where the solve identifies closed loop; pairs are dropped for it)."""
    if not st.mirrored:
        return "mirrored"
    if closed_loop and not st.open_loop:
        return "open_loop"
    return None


def _experiments_tried(st, cfg) -> list[str]:
    """The experiments the recovery switched to in this solve (``_next_experiment``)."""
    tried = [(st.mirrored and not cfg.mirrored, "mirrored +du/-du pairs"), (st.open_loop, "open-loop identification")]
    return [name for flag, name in tried if flag]


def _info(st: SolverState, iteration: int, accepted: bool, rollouts: int, wall: float, note: str) -> IterationInfo:
    return IterationInfo(
        iteration=iteration,
        cost=st.nominal.cost,
        alpha=st.alpha_history[-1] if st.alpha_history else 0.0,
        mu=st.mu,
        grad_norm=st.grad_history[-1] if st.grad_history else float("nan"),
        accepted=accepted,
        rollouts=rollouts,
        rollouts_per_s=rollouts / wall if wall > 0 else float("nan"),
        wall_s=wall,
        true_cost=st.true_history[-1],
        note=note,
        sigma=st.sigma_history[-1] if st.sigma_history else float("nan"),
    )


def _result(method, env, dims, cfg, q, st: SolverState, status, message, noisy, phase_s, compiles, watch, wall):
    warnings = []
    if st.diverged_rollouts:
        warnings.append(f"{st.diverged_rollouts} sysid rollouts diverged (non-finite) and were left out of the fit")
    if st.diverged_candidates:
        warnings.append(f"{st.diverged_candidates} line-search candidates diverged and were rejected")
    if warnings:  # divergences belong in the message; retries are routine
        message += "; " + "; ".join(warnings)
    if st.reidentifications:
        warnings.append(
            f"{st.reidentifications} times no step lowered the cost up to mu_max and the model was identified "
            "afresh at another sigma" + (" or in another experiment" if _experiments_tried(st, cfg) else "")
        )
    if st.mu_retries:
        warnings.append(
            f"{st.mu_retries} times no step lowered the cost and the backward pass was redone with a larger mu"
        )
    nominal = st.nominal
    k = np.asarray(st.back_k) if st.back_k is not None else np.zeros((dims.horizon, dims.nu))
    x_bar = np.asarray(nominal.x_bar)
    return Result(
        method=method,
        task=env.name,
        status=status,
        message=message,
        controls=np.asarray(nominal.u_bar),
        observations=np.asarray(observations_of(env.dims, env.data, x_bar))
        if env.dims.sensors
        else x_bar @ np.asarray(env.data.C).T,
        states=x_bar,
        info_states=np.asarray(nominal.Z_bar),
        K=np.asarray(st.gains),
        k=k,
        q=q,
        cost_history=st.cost_history,
        alpha_history=st.alpha_history,
        mu_history=st.mu_history,
        grad_norm_history=st.grad_history,
        iterations=st.iteration,
        rollouts=st.rollouts,
        wall_s=wall,
        compile_s=watch.seconds,
        run_s=max(0.0, wall - watch.seconds),
        compiles_per_iteration=compiles,
        phase_s=phase_s,
        config=dataclasses.asdict(cfg) | {"q": q},
        control_dt=env.control_dt,
        observation_labels=env.observation_labels,
        state_labels=env.state_labels,
        variant=cfg.variant if method == "pod-ilqr" else "model-based",
        noisy=noisy,
        noise=env.noise.as_dict() if noisy else {},
        true_cost_history=st.true_history,
        open_loop_cost_history=st.open_history,
        rejected_steps=st.rejected,
        remeasured=st.remeasured,
        longest_rejection_streak=st.longest_streak,
        diverged_rollouts=st.diverged_rollouts,
        diverged_candidates=st.diverged_candidates,
        mu_retries=st.mu_retries,
        reidentifications=st.reidentifications,
        warnings=list(env.model_notes) + warnings,  # options switched off for MJX (env.mjx_model_of)
        control_limits=np.stack([env.data.u_low, env.data.u_high], axis=1).tolist() if env.limited else [],
        sigma_history=st.sigma_history,
        sigma_units=actuator_units(env, cfg).tolist() if method == "pod-ilqr" else [],
        mirrored=bool(st.mirrored and not st.open_loop) and method == "pod-ilqr",
        open_loop=bool(st.open_loop) or (method == "pod-ilqr" and cfg.variant == "plain"),
    )


def _run_options(checkpoint, every, resume) -> RunOptions:
    if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or every < 1:
        raise ConfigError(f"`checkpoint_every` (--every) must be an integer >= 1; got {every!r}.")
    if checkpoint is not None:
        checkpoint = os.fspath(checkpoint)
        try:
            os.makedirs(checkpoint, exist_ok=True)
        except OSError as exc:
            raise ConfigError(
                f"Cannot create the checkpoint folder {checkpoint!r}: {exc.strerror}. Choose another folder."
            ) from None
        if not os.access(checkpoint, os.W_OK):
            raise ConfigError(f"The checkpoint folder {checkpoint!r} is not writable. Choose another folder.")
    return RunOptions(checkpoint, int(every), None if resume is None else os.fspath(resume))


def _on_device(x):
    """``x`` committed to the default device (replicated over all devices when
    there are several, see ``rollout.replicated``): a number or NumPy array becomes a
    float64 (or float32) array, a pytree of arrays (``EnvData``) keeps its types.

    Driver-made arrays must be committed like the jitted stages' outputs they
    alternate with: JAX keys its compilation cache on whether an argument is
    committed, and mixing the two compiles every stage twice.

    With several processes (``jax.distributed``) every process holds the same
    values (the same task, settings and seed, or a replicated stage output):
    each places its own host copy on its devices, and nothing crosses hosts.
    """
    if isinstance(x, (int, float, np.ndarray, np.generic)):
        x = jnp.asarray(x, dtype=jnp.result_type(float))
    if jax.process_count() > 1:
        x = jax.tree_util.tree_map(lambda a: np.asarray(a) if isinstance(a, jax.Array) else a, x)
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
