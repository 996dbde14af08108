"""The outer iLQR loop in three parts: ``init``, ``step``, ``terminate``.

A solve fixes everything that does not change between iterations in a frozen
:class:`Context` (the task as the solver sees it, the settings, the cost, the
line search's step sizes, the identification strategy); the iteration's
mutable part is the :class:`~podilqr_jax.ilqr.state.SolverState`. Then

- :func:`init` measures the first nominal (or loads a checkpoint),
- :func:`step` runs one iteration: identify (unless the model is reused),
  backward pass, line search, and the bookkeeping of an accepted or rejected
  step, returning the :class:`~podilqr_jax.ilqr.stopping.Stop` of a rule that
  fired (``stopping``) or None,
- :func:`terminate` turns the state into a :class:`~podilqr_jax.ilqr.result.Result`,

and :func:`run` loops ``step`` with the progress callback, checkpoints and
Ctrl-C (``interrupts``). The driver only moves scalars to the host (cost,
acceptance, step size, mu), so each iteration can be reported live; every
array stays on the device. All jitted stages compile before or in the first
iteration and never again (``compilation.compile_watch``).

Regularisation schedule: after an accepted step mu <- max(mu / f, mu_min);
after the n-th consecutive rejected step mu <- max(mu f^n, mu_min) and the
backward pass is redone on the same identified model (noiseless rollouts are
deterministic, so re-identifying would give the same model). Past mu_max a
noiseless solve first identifies afresh at other sigmas (``cfg.reidentify``),
then with another experiment (``cfg.escalate``), before it stops. Under noise a
rejected step re-measures the nominal and identifies again.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable, NamedTuple, Optional

import jax
import numpy as np

from ..compilation import lockstep
from ..compilation.compile_watch import CompileWatch
from ..identify.identification import Experiment
from ..sim.rollout import Policy, observations_of, on_device
from ..task.env import Env, EnvData, EnvDims
from . import stopping
from .backward import QuadraticCost, Regularisation, backward_pass
from .checkpoint import load_checkpoint, save_checkpoint
from .config import SolverConfig, reidentify_scale
from .interrupts import deferred_interrupts
from .line_search import Candidates, Search, Step, line_search
from .plan import ExecutionPlan
from .result import IterationInfo, Result
from .state import Nominal, SolverState
from .stopping import Stop
from .true_cost import true_costs

Callback = Callable[[IterationInfo], None]

PHASES = ("rollouts", "fit", "backward", "line_search", "evaluation", "waiting", "race", "host")
"""Where a solve's seconds go. With several starts: ``waiting``, their stage calls waiting for each
other in lockstep (``compilation.lockstep.waited``); ``race``, waiting at a rung of their race (``race``)."""


class RunOptions(NamedTuple):
    """Checkpointing of a solve (validated by ``solver._run_options``)."""

    checkpoint: Optional[str]  # folder written every ``every`` iterations
    every: int
    resume: Optional[str]  # checkpoint folder (or file) to continue from


@dataclasses.dataclass(frozen=True)
class Context:
    """What a solve fixes before its first iteration (built by ``solver``)."""

    method: str  # "pod-ilqr" or "model-based"
    env: Env  # the task as the user gave it
    dims: EnvDims  # the task as the solver sees it (the full-state view for the reference)
    data: EnvData  # ... its arrays, on the device
    cfg: SolverConfig
    q: int
    identify: Callable  # the identification strategy (``identification``)
    noisy: bool
    nZ: int
    reidentify: int  # re-identifications at other sigmas before line_search_failed (0: none)
    escalate: bool  # then other experiments
    closed_loop: bool  # the identification runs through the current gains (variant != plain)
    cost_model: QuadraticCost
    reg: Regularisation
    steps: np.ndarray  # the candidate step sizes
    plan: ExecutionPlan  # how the solve runs: engine, batch sizes and chunks (``plan``)
    search: Search  # how its line searches run (static)
    candidates: Candidates  # ... the step sizes on the device, with alpha = 0 last under noise
    hold: Step  # the step that changes nothing (k = 0): a measurement of the policy as it is
    fingerprint: dict
    units: list  # sigma's unit per actuator (reported in the result)
    start: int = 0  # which start of a solve with restarts (``restarts``)

    @property
    def data_based(self) -> bool:
        return self.method == "pod-ilqr"


class Outcome(NamedTuple):
    """What one ``step`` did, for the progress line."""

    stop: Optional[Stop]
    note: str
    accepted: bool
    rollouts: int


class Timing:
    """Seconds per phase and compilations per iteration (not checkpointed)."""

    def __init__(self):
        self.phase_s = dict.fromkeys(PHASES, 0.0)
        self.compiles: list[int] = []
        self.first_compiles = 0

    def add(self, phase: str, t0: tuple[float, float]) -> None:
        """The seconds since ``t0`` (``clock()``) to ``phase``, less those its stage calls waited in lockstep."""
        t, w = clock()
        self.phase_s[phase] += (t - t0[0]) - (w - t0[1])
        self.phase_s["waiting"] += w - t0[1]


def clock() -> tuple[float, float]:
    """Now, and the seconds this thread's stage calls have waited in lockstep (``Timing.add``)."""
    return time.perf_counter(), lockstep.waited()


def policy_of(nominal: Nominal, K) -> Policy:
    """u_t = u_bar_t + K_t (Z_t - Z_bar_t) about ``nominal``."""
    return Policy(nominal.u_bar, nominal.Z_bar[:-1], K)


def measure(ctx: Context, st: SolverState, timing: Timing, policy: Policy, step: Optional[Step], cost0: float):
    """The batched line search of ``policy`` with ``step`` (None: ``ctx.hold``, a
    measurement) about a nominal of cost ``cost0``; returns (its result, accepted)."""
    t0 = clock()
    st.ls_key, sub = jax.random.split(st.ls_key)
    step = (ctx.hold if step is None else step)._replace(cost0=on_device(cost0))
    ls = line_search(ctx.search, ctx.data, policy, step, ctx.candidates, sub)
    accepted = bool(ls.accepted)
    st.record.diverged_candidates += int(ls.n_diverged)
    timing.add("line_search", t0)
    return ls, accepted


def ground_truth(ctx: Context, st: SolverState, timing: Timing) -> tuple[float, float]:
    """True (closed-loop, noiseless) and open-loop replay cost of the current policy."""
    if not ctx.noisy:
        return st.nominal.cost, st.nominal.cost
    t0 = clock()
    tc = true_costs(ctx.dims, ctx.q, ctx.data, policy_of(st.nominal, st.gains))
    out = float(tc.closed_loop), float(tc.open_loop)
    timing.add("evaluation", t0)
    return out


def init(ctx: Context, timing: Timing, u_init, resume: Optional[str]) -> SolverState:
    """The state before the first iteration: the first nominal measured (the
    line search with k = 0, K = 0 rolls out ``u_init`` open loop), or a
    checkpoint."""
    if resume is not None:
        return load_checkpoint(resume, ctx.fingerprint, on_device)
    cfg, dims = ctx.cfg, ctx.dims
    key = jax.random.PRNGKey(cfg.seed)
    st = SolverState(
        nominal=None,
        gains=on_device(np.zeros((dims.horizon, dims.nu, ctx.nZ))),
        key=key,
        ls_key=jax.random.fold_in(key, 1),  # the forward passes' own noise stream
        mu=max(cfg.mu_init, cfg.mu_min),
        sigma=float(cfg.sigma),
        mirrored=int(cfg.mirrored),
    )
    with CompileWatch() as watch:
        first = Policy(u_init, on_device(np.zeros((dims.horizon, ctx.nZ))), st.gains)
        ls, _ = measure(ctx, st, timing, first, None, np.inf)
        st.nominal = Nominal.measured(ls)
        true_cost, open_cost = ground_truth(ctx, st, timing)
    record = st.record
    record.diverged_candidates = 0  # the first measurement is not a candidate step
    record.cost_history, record.true_cost_history, record.open_loop_cost_history = (
        [st.nominal.cost], [true_cost], [open_cost],
    )  # fmt: skip
    record.rollouts = ctx.plan.ls_rollouts
    timing.first_compiles = watch.compiles
    return st


def _identification_stop(ctx: Context, found, sigma: float) -> Optional[Stop]:
    """What the driver makes of an identification's problem (``identify.Identified.problem``)."""
    if found.problem is None:
        return None
    if ctx.data_based:
        return stopping.identification_stop(found, ctx.cfg.n_s, sigma)
    return stopping.exact_model_stop(found, ctx.identify.hint, ctx.identify.jacobian)


def step(ctx: Context, st: SolverState, timing: Timing) -> Outcome:
    """One iteration: identify (unless the model is reused), backward pass, line search."""
    cfg, record = ctx.cfg, st.record
    note, iter_rollouts = "", 0
    nominal = st.nominal
    if st.model is None:
        st.key, sub = jax.random.split(st.key)
        sigma = st.sigma * reidentify_scale(st.reidentified)
        found = ctx.identify(sub, nominal, st.gains, sigma, Experiment(bool(st.mirrored), bool(st.open_loop)))
        st.model, iter_rollouts = found.model, found.rollouts
        if ctx.data_based:  # the model-based reference has no scale
            record.sigma_history.append(sigma)
            record.fit_error_history.append(found.fit_error)
        if found.next_sigma is not None and st.reidentified == 0:  # adapt from the base scale only
            st.sigma = found.next_sigma
        record.rollouts += iter_rollouts
        for name, secs in found.seconds.items():
            timing.phase_s[name] += secs
        stop = _identification_stop(ctx, found, sigma)
        if stop is not None:
            st.model = None
            return Outcome(stop, note, False, iter_rollouts)
        if found.n_bad:
            record.diverged_rollouts += found.n_bad
            note = f"{found.n_bad} sysid rollouts diverged, left out of the fit"
        elif found.fit_error > 1.0 and not any(e > 1.0 for e in record.fit_error_history[:-1]):
            note = (
                f"B err {found.fit_error:.3g}: the controls' effect is below the noise at sigma {sigma:.3g}, "
                "the model's gains are noise" + ("; sigma grows" if cfg.adapt_sigma else "; raise sigma or n_s")
            )
    elif ctx.data_based:  # the model of the last identification, reused with a larger mu
        record.sigma_history.append(record.sigma_history[-1])
        # (a checkpoint written before fit errors were recorded has none to repeat)
        record.fit_error_history.append(record.fit_error_history[-1] if record.fit_error_history else float("nan"))

    t0 = clock()
    back = backward_pass(st.model, nominal.Z_bar, nominal.u_bar, ctx.cost_model, on_device(st.mu), ctx.reg)
    back_ok = bool(back.ok)
    st.mu = float(back.mu)
    grad_norm = float(np.max(np.abs(np.asarray(back.grad))))
    if grad_norm != grad_norm:  # the costate overflowed float (a long horizon, an unstable nominal): inf - inf
        grad_norm = float("inf")
    timing.add("backward", t0)
    record.grad_norm_history.append(grad_norm)
    record.mu_history.append(st.mu)
    stop = stopping.backward_stop(back_ok, grad_norm, ctx.noisy, cfg)
    if stop is not None and not back_ok and ctx.reidentify:
        # A fit that no mu up to mu_max regularises is a poor identification, as a
        # step that no mu makes lower the cost is: the same recoveries before the stop.
        recovery = _recover(ctx, st)
        if recovery is not None:
            record.alpha_history.append(0.0)
            _record_costs(ctx, st, timing)
            why = "at every sigma" if recovery[0] else f"mu above mu_max={cfg.mu_max:g}"
            return Outcome(None, f"the backward pass needs {why}: {recovery[1]}", False, iter_rollouts)
    if stop is not None:
        if back_ok:  # converged: the gains of this pass go with the nominal
            st.back_k, st.gains = back.k, back.K
        return Outcome(stop, note, False, iter_rollouts)
    if back_ok:
        st.back_k = back.k
        proposed = Step(back.k, None, back.dV1, back.dV2)
        ls, accepted = measure(ctx, st, timing, policy_of(nominal, back.K), proposed, nominal.cost)
    else:  # noisy and no usable model: re-measure the current policy
        ls, accepted = measure(ctx, st, timing, policy_of(nominal, st.gains), None, nominal.cost)
    iter_rollouts += ctx.plan.ls_rollouts
    record.rollouts += ctx.plan.ls_rollouts
    if accepted:
        stop = _accept(ctx, st, ls, back)
    else:
        stop, note = _reject(ctx, st, ls, note)
    _record_costs(ctx, st, timing)
    return Outcome(stop, note, accepted, iter_rollouts)


def _record_costs(ctx: Context, st: SolverState, timing: Timing) -> None:
    """The end of an iteration's record: the nominal's cost, and the policy's true and open-loop costs."""
    record = st.record
    record.cost_history.append(st.nominal.cost)
    true_cost, open_cost = ground_truth(ctx, st, timing)
    record.true_cost_history.append(true_cost)
    record.open_loop_cost_history.append(open_cost)


def _accept(ctx: Context, st: SolverState, ls, back) -> Optional[Stop]:
    """An accepted step: the chosen candidate is the new nominal, its gains the policy's."""
    cfg = ctx.cfg
    new_cost = float(ls.cost)
    st.record.alpha_history.append(float(ls.alpha))
    decrease = st.nominal.cost - new_cost
    st.nominal = Nominal.measured(ls)
    st.gains = back.K
    st.model = None
    st.failures = st.streak = st.reidentified = 0
    st.mu = max(st.mu / cfg.mu_factor, cfg.mu_min)
    return stopping.accepted_stop(decrease, new_cost, ctx.noisy, cfg)


def _reject(ctx: Context, st: SolverState, ls, note: str) -> tuple[Optional[Stop], str]:
    """A rejected step: mu grows; under noise the nominal is re-measured, noiseless
    the recoveries run (another sigma, another experiment) before the solve stops."""
    cfg, record = ctx.cfg, st.record
    record.alpha_history.append(0.0)
    st.failures += 1
    st.streak += 1
    record.rejected_steps += 1
    record.longest_rejection_streak = max(record.longest_rejection_streak, st.streak)
    st.mu = max(st.mu * cfg.mu_factor**st.failures, cfg.mu_min)
    if ctx.noisy:
        # The nominal's cost may be a lucky draw that no step can beat: take the
        # fresh measurement of the same policy (the alpha = 0 candidate) and
        # identify again about it, with mu capped. A divergent measurement is
        # not taken: the nominal stays.
        st.mu = min(st.mu, cfg.mu_cap)
        st.model = None
        if np.isfinite(float(ls.cost)):
            st.nominal = Nominal.measured(ls)
            record.remeasured += 1  # routine under noise: no progress note
        else:
            note = "no step accepted; the re-measurement diverged, nominal kept"
        return None, note
    predicted = float(np.asarray(ls.expected)[0])  # indexed on the host: an eager jnp index would compile a kernel
    stop = stopping.small_prediction_stop(predicted, st.nominal.cost, cfg)
    if stop is not None:
        return stop, note
    if st.mu <= cfg.mu_max:
        record.mu_retries += 1
        return None, f"no step lowered the cost: mu raised to {st.mu:.3g}, retrying"
    recovery = _recover(ctx, st)
    if recovery is not None:
        changed, how = recovery
        return None, (
            "no step lowered the cost at any sigma: " if changed else "no step lowered the cost up to mu_max: "
        ) + how
    tried = experiments_tried(st, cfg) if ctx.escalate else []
    return stopping.line_search_failed(cfg, st.streak, tried, ls, ctx.steps, st.nominal.cost, ctx.reidentify), note


def _recover(ctx: Context, st: SolverState) -> Optional[tuple[bool, str]]:
    """The recoveries of a noiseless data-based solve whose identified model gave
    no usable step up to mu_max, before it stops: fresh perturbations at another
    scale (``cfg.reidentify``), then another experiment (``cfg.escalate``).
    Returns (whether the experiment changed, what was done), or None when they are spent."""
    cfg = ctx.cfg
    if st.reidentified < ctx.reidentify:  # before giving up: fresh perturbations at another scale, mu afresh
        st.reidentified += 1
        _identify_afresh(ctx, st)
        sigma = st.sigma * reidentify_scale(st.reidentified)
        return False, f"re-identifying with fresh perturbations at sigma = {sigma:.3g}"
    change = next_experiment(st, ctx.closed_loop) if ctx.escalate else None
    if change is not None:  # the scales are spent: another experiment for the rest of the solve, the scales afresh
        setattr(st, change, 1)
        st.reidentified = 0
        _identify_afresh(ctx, st)
        if change == "mirrored":
            how = f"identifying with mirrored +du/-du pairs from now on (2 x {cfg.n_s * cfg.resolved_n_avg()} rollouts)"
        else:
            how = "identifying open loop, without pairs, from now on (the paper's experiment)"
        return True, how
    return None


def _identify_afresh(ctx: Context, st: SolverState) -> None:
    st.record.reidentifications += 1
    st.model, st.failures = None, 0
    st.mu = max(ctx.cfg.mu_init, ctx.cfg.mu_min)


def next_experiment(st: SolverState, closed_loop: bool) -> Optional[str]:
    """The state flag of the next experiment the recovery switches to, or None
    when both are spent: mirrored pairs, then the open-loop (``plain``) identification
    (where the solve identifies closed loop; pairs are dropped for it)."""
    if not st.mirrored:
        return "mirrored"
    if closed_loop and not st.open_loop:
        return "open_loop"
    return None


def experiments_tried(st: SolverState, cfg: SolverConfig) -> list[str]:
    """The experiments the recovery switched to in this solve (``next_experiment``)."""
    tried = [(st.mirrored and not cfg.mirrored, "mirrored +du/-du pairs"), (st.open_loop, "open-loop identification")]
    return [name for flag, name in tried if flag]


def run(ctx: Context, u_init, callback: Optional[Callback], options: RunOptions) -> Result:
    """``init``, then ``step`` until a rule stops the solve, then ``terminate``."""
    with deferred_interrupts as interrupts:
        return run_within(ctx, u_init, callback, options, interrupts)


def run_within(
    ctx: Context, u_init, callback: Optional[Callback], options: RunOptions, interrupts, race=None
) -> Result:
    """:func:`run` inside an entered ``deferred_interrupts`` (``interrupts``), in
    any thread: the restarts run one per thread (``restarts``), each reporting
    its iterations to their ``race`` (``race.Race``) where one is run."""
    t_start = time.perf_counter()
    timing = Timing()
    total_watch = CompileWatch()
    with total_watch:
        st = init(ctx, timing, u_init, options.resume)
        stop = stopping.initial_stop(st.nominal.cost) or stopping.resumed_stop(st.stopped)
        if stop is None:
            st, stop = _loop(ctx, st, timing, callback, options, interrupts, race)
    wall = time.perf_counter() - t_start
    # Everything outside the jitted stages. Stage times include their own
    # compilation in the first iteration; compile_s reports it separately.
    timing.phase_s["host"] = max(0.0, wall - sum(v for k, v in timing.phase_s.items() if k != "host"))
    return terminate(ctx, st, stop, timing, total_watch, wall)


def _raced(ctx: Context, st: SolverState, timing: Timing, race, interrupts) -> Optional[Stop]:
    """This start's iterations so far reported to the race; its stop where a rung cuts it."""
    t0 = clock()
    scores = st.record.true_cost_history if ctx.noisy else st.record.cost_history
    stop = race.after_iteration(ctx.start, scores, lambda: interrupts.requested)
    timing.add("race", t0)
    return stop


def _loop(ctx: Context, st: SolverState, timing: Timing, callback, options: RunOptions, interrupts, race=None):
    """Iterations until a stop: (the state, the stop); after a Ctrl-C inside an
    iteration the state is the last completed iteration's."""
    cfg = ctx.cfg
    safe = st.snapshot()
    if race is not None and st.record.iterations:  # resumed: at a rung, it waits there as it would have
        stop = _raced(ctx, st, timing, race, interrupts)
        if stop is not None:
            st.stopped = [str(stop.status), stop.message]
            if options.checkpoint is not None:
                save_checkpoint(options.checkpoint, st, ctx.fingerprint)
            return st, stop
    try:
        for iteration in range(st.record.iterations + 1, cfg.max_iterations + 1):
            if interrupts.requested:  # Ctrl-C during the last iteration (or before the first)
                if options.checkpoint is not None:
                    save_checkpoint(options.checkpoint, st, ctx.fingerprint)
                return st, stopping.interrupted(interrupts.signal)
            t_iter = time.perf_counter()
            with CompileWatch() as watch:
                outcome = step(ctx, st, timing)
                st.record.iterations = iteration
            timing.compiles.append(watch.compiles + (timing.first_compiles if not timing.compiles else 0))
            safe = st.snapshot()
            if outcome.stop is None and race is not None and iteration < cfg.max_iterations:
                stop = _raced(ctx, st, timing, race, interrupts)
                if stop is not None:
                    outcome = outcome._replace(stop=stop, note=f"outraced at iteration {iteration}")
            if outcome.stop is not None:
                st.stopped = [str(outcome.stop.status), outcome.stop.message]
            final = outcome.stop is not None or iteration == cfg.max_iterations
            if options.checkpoint is not None and (iteration % options.every == 0 or final):
                save_checkpoint(options.checkpoint, st, ctx.fingerprint)
            if callback is not None:
                callback(_info(st, iteration, outcome, time.perf_counter() - t_iter, ctx))
            if outcome.stop is not None:
                return st, outcome.stop
    except KeyboardInterrupt:
        st = safe.restored()
        if options.checkpoint is not None:  # the last completed iteration: resumable as is
            save_checkpoint(options.checkpoint, st, ctx.fingerprint)
        return st, stopping.interrupted(interrupts.signal)
    return st, stopping.iterations_stop(cfg, ctx.noisy)


def _info(st: SolverState, iteration: int, outcome: Outcome, wall: float, ctx: Context) -> IterationInfo:
    record = st.record
    return IterationInfo(
        iteration=iteration,
        cost=st.nominal.cost,
        alpha=record.alpha_history[-1] if record.alpha_history else 0.0,
        mu=st.mu,
        grad_norm=record.grad_norm_history[-1] if record.grad_norm_history else float("nan"),
        accepted=outcome.accepted,
        rollouts=outcome.rollouts,
        rollouts_per_s=outcome.rollouts / wall if wall > 0 else float("nan"),
        wall_s=wall,
        true_cost=record.true_cost_history[-1],
        note=outcome.note,
        sigma=record.sigma_history[-1] if record.sigma_history else float("nan"),
        fit_error=record.fit_error_history[-1] if record.fit_error_history else float("nan"),
        engine=ctx.dims.engine,
        start=ctx.start,
    )


def blind_fit(fit_errors) -> str:
    """The warning of a noisy solve whose fits could not see the controls through
    the noise (``identify.quality``: B's estimated relative error above 1 over
    most of the run), or ""."""
    errors = np.asarray([e for e in fit_errors if e == e], dtype=float)
    if errors.size == 0 or not np.median(errors) > 1.0:
        return ""
    return (
        f"the fit could not see the controls through the noise: B's estimated relative error was above 1 in "
        f"{int(np.sum(errors > 1.0))} of {errors.size} identifications (median {np.median(errors):.3g}), so the "
        "gradients and gains are mostly noise; raise sigma (adapt_sigma grows it up to sigma x sigma_range), "
        "n_s, or with variant='averaged' n_avg (docs/noise.md)"
    )


def terminate(ctx: Context, st: SolverState, stop: Stop, timing: Timing, watch: CompileWatch, wall: float) -> Result:
    """The result of a solve that stopped with ``stop``."""
    cfg, dims, env, record = ctx.cfg, ctx.dims, ctx.env, st.record
    message = stop.message
    warnings = []
    if record.diverged_rollouts:
        warnings.append(f"{record.diverged_rollouts} sysid rollouts diverged (non-finite) and were left out of the fit")
    if record.diverged_candidates:
        warnings.append(f"{record.diverged_candidates} line-search candidates diverged and were rejected")
    if warnings:  # divergences belong in the message; retries are routine
        message += "; " + "; ".join(warnings)
    if record.reidentifications:
        warnings.append(
            f"{record.reidentifications} times no step lowered the cost up to mu_max and the model was identified "
            "afresh at another sigma" + (" or in another experiment" if experiments_tried(st, cfg) else "")
        )
    if record.mu_retries:
        warnings.append(
            f"{record.mu_retries} times no step lowered the cost and the backward pass was redone with a larger mu"
        )
    blind = blind_fit(record.fit_error_history)
    if blind:
        warnings.append(blind)
    if dims.quats and not ctx.data_based and ctx.identify.jacobian == "exact":
        warnings.append(
            "jacobian='exact' on a model with a free or ball joint: MJX's forward-mode derivative of a quaternion's "
            "rotation is zero at zero angular rate, so a body at rest may never be turned; jacobian='differences' "
            "(what auto takes on such a model) has no such blind spot"
        )
    nominal = st.nominal
    compile_s = watch.seconds
    k = np.asarray(st.back_k) if st.back_k is not None else np.zeros((dims.horizon, dims.nu))
    x_bar = np.asarray(nominal.x_bar)
    pod = ctx.data_based
    return Result(
        method=ctx.method,
        task=env.name,
        status=stop.status,
        message=message,
        controls=np.asarray(nominal.u_bar),
        observations=np.asarray(observations_of(env.dims, env.data, x_bar))
        if env.dims.sensors
        else x_bar @ np.asarray(env.data.C).T,
        states=x_bar,
        info_states=np.asarray(nominal.Z_bar),
        K=np.asarray(st.gains),
        k=k,
        q=ctx.q,
        record=dataclasses.replace(record),
        wall_s=wall,
        compile_s=compile_s,
        run_s=max(0.0, wall - compile_s),
        compiles_per_iteration=timing.compiles,
        phase_s=timing.phase_s,
        config=cfg.flat() | {"q": ctx.q},
        control_dt=env.control_dt,
        observation_labels=env.observation_labels,
        state_labels=env.state_labels,
        variant=cfg.variant if pod else "model-based",
        noisy=ctx.noisy,
        noise=env.noise.as_dict() if ctx.noisy else {},
        warnings=list(env.model_notes) + warnings,  # options switched off for MJX (env.mjx_model_of)
        control_limits=np.stack([env.data.u_low, env.data.u_high], axis=1).tolist() if env.limited else [],
        sigma_units=list(ctx.units) if pod else [],
        mirrored=bool(st.mirrored and not st.open_loop) and pod,
        open_loop=bool(st.open_loop) or (pod and cfg.variant == "plain"),
        engine=dims.engine,
        plan=ctx.plan.as_dict(),
    )
