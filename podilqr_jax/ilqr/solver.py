"""``solve`` and ``solve_model_based``: a solve's settings checked, its context built, the driver run.

Each iteration of POD-iLQR:
  1. identification: ``n_s`` perturbation rollouts about the nominal (one MJX
     batch) and a per-step least-squares ARMA fit (``identification``, ``sysid``);
  2. backward pass with adaptive Levenberg-Marquardt regularisation (``backward``);
  3. forward pass: every step size of the line search as one MJX batch (``line_search``).
The model-based reference replaces step 1 by exact Jacobians (``model_based``).
This module validates the inputs, places the task's arrays on the device and
fixes everything that does not change between iterations in the driver's
frozen :class:`~podilqr_jax.ilqr.driver.Context`; ``driver`` runs the loop
(init / step / terminate) and ``stopping`` holds every rule that ends it.
"""

from __future__ import annotations

import os
from typing import Optional

import jax.numpy as jnp
import numpy as np

from ..errors import ConfigError
from ..identify.identification import Exact, actuator_units, data_based
from ..identify.info_state import info_dim, observation_selector
from ..identify.model_based import nonfinite_hint
from ..sim import contacts, engines
from ..sim.rollout import on_device
from ..task.env import Env
from . import restarts
from .backward import QuadraticCost, Regularisation
from .checkpoint import fingerprint
from .config import GROUPS, SETTINGS, SolverConfig
from .driver import Callback, Context, RunOptions, run
from .line_search import Candidates, Search, Step
from .plan import ExecutionPlan, build_plan, line_search_chunk, sysid_chunk
from .result import Result

__all__ = ["Callback", "RunOptions", "default_config", "solve", "solve_model_based"]


def default_config(env: Env, **overrides) -> SolverConfig:
    """The task's recommended settings (``env`` defaults), with overrides."""
    known = set(SETTINGS) | set(GROUPS)
    unknown = sorted(set(env.solver_defaults) - known)
    if unknown:
        raise ConfigError(
            f"The task {env.name!r} recommends unknown solver setting(s) {unknown} (the [solver] table of a task "
            f"file, or Env.solver_defaults); known settings: {sorted(known)}."
        )
    # The overrides after the task's defaults: a group given here replaces the task's settings of that group.
    cfg = SolverConfig().replace(**env.solver_defaults).replace(**overrides)
    return cfg if cfg.n_s is not None else cfg.replace(n_s=cfg.resolved_n_s(env))


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
      u_init: initial nominal controls [T, nu]; default zeros. Or K first
        guesses [K, T, nu]: K starts from them (``restarts``, which is then
        K, 1 or unset).
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
    cfg = _starts_of(u_init, default_config(env) if cfg is None else cfg)
    q = cfg.validate(env, data_based=True)
    cfg = cfg.replace(n_s=cfg.resolved_n_s(env), restarts=cfg.resolved_restarts(env))
    run_options = _run_options(checkpoint, checkpoint_every, resume)
    env = engines.on_engine(env, cfg.engine)
    dims, data = env.dims, on_device(_in_impl(env, cfg.impl))
    noisy = env.noisy and cfg.variant != "nominal"
    n_fwd = cfg.resolved_n_forward(noisy)
    plan = _plan(dims, data, cfg, noisy, n_fwd, sysid_rollouts=cfg.n_s * cfg.resolved_n_avg())
    identify = data_based(env, cfg, q, data, noisy, plan.sysid_chunk)
    ctx = _context("pod-ilqr", env, dims, data, cfg, q, identify, noisy, n_fwd, plan)
    return _run(ctx, _first_controls(u_init, dims, run_options), callback, run_options)


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
    """The model-based reference: iLQR with MJX's Jacobians on the full state.

    Same task, cost, backward pass, line search and stopping rules as
    :func:`solve`; the identification is replaced by the linearisation of
    ``mjx.step``: forward-mode derivatives, or central differences of the step
    on a contact-rich model (``cfg.jacobian``). On the native engine
    (``cfg.engine``) it takes central differences of MuJoCo's C step, all
    2 T (nx + nu) of them one batch over the cores; ``jacobian="exact"``
    keeps ``engine="auto"`` on MJX. The data-based settings (``q``, ``n_s``,
    ``sigma``) are unused.
    """
    cfg = _starts_of(u_init, default_config(env) if cfg is None else cfg)
    cfg.validate(env, data_based=False)
    cfg = cfg.replace(n_s=cfg.resolved_n_s(env), restarts=cfg.resolved_restarts(env))
    run_options = _run_options(checkpoint, checkpoint_every, resume)
    env = engines.on_engine(env, "mjx" if cfg.engine == "auto" and cfg.jacobian == "exact" else cfg.engine)
    view = env.full_state_view()
    dims, data = view.dims, on_device(view.data)
    native = dims.native is not None  # no derivative through MuJoCo's C engine: central differences, batched
    floating = bool(dims.quats)  # a free or ball joint: forward mode is blind at zero angular rate
    jacobian = (
        "differences" if native and cfg.jacobian == "auto" else contacts.jacobian(cfg.jacobian, env.mj_model, floating)
    )
    plan = _plan(dims, data, cfg, False, 1, jacobian=jacobian)
    identify = Exact(dims, data, nonfinite_hint(env.mj_model), plan.jacobian)
    ctx = _context("model-based", env, dims, data, cfg, 1, identify, False, 1, plan)
    return _run(ctx, _first_controls(u_init, dims, run_options), callback, run_options)


def _run(ctx: Context, u_init, callback, run_options: RunOptions) -> Result:
    """One solve, or with ``restarts`` > 1 several in lockstep (``restarts``)."""
    return (restarts.run if ctx.cfg.restarts > 1 else run)(ctx, u_init, callback, run_options)


def _plan(dims, data, cfg: SolverConfig, noisy: bool, n_fwd: int, sysid_rollouts: int = 0, jacobian: str = ""):
    """How the solve runs (``plan``): its engine, batches and chunks under the
    memory budget (shared by the starts of ``restarts``), and the machine's part; ``sysid_rollouts`` 0 and a
    ``jacobian`` for the model-based reference."""
    ls_rollouts = len(_step_candidates(cfg, noisy)) * n_fwd
    if cfg.restarts > 1:  # the starts' batches run side by side (``restarts``, resolved): the budget is shared
        cfg = cfg.replace(memory_budget_mb=cfg.memory_budget_mb / cfg.restarts)
    return build_plan(
        engine=dims.engine,
        impl=cfg.impl,
        sysid_rollouts=sysid_rollouts,
        sysid_chunk=sysid_chunk(cfg, dims, data, noisy, sysid_rollouts) if sysid_rollouts else None,
        ls_rollouts=ls_rollouts,
        ls_chunk=line_search_chunk(cfg, dims, data, noisy, ls_rollouts),
        jacobian=jacobian,
    )


def _step_candidates(cfg: SolverConfig, noisy: bool) -> np.ndarray:
    """The line search's step sizes 1, 1/2, ..., 2^-(n_alphas - 1); under noise
    alpha = 0 last: when nothing is accepted it is a fresh measurement of the
    current policy (see line_search)."""
    steps = 0.5 ** np.arange(cfg.n_alphas)
    return np.append(steps, 0.0) if noisy else steps


def _context(method, env, dims, data, cfg, q, identify, noisy: bool, n_fwd: int, plan: ExecutionPlan) -> Context:
    """Everything the driver keeps fixed; ``dims, data`` are the task as the
    solver sees it (its data committed to the device), ``env`` as the user gave
    it; ``plan`` how it runs."""
    # Only a data-based fit has something to re-draw; under noise a rejected step never stops the solve.
    reidentify = cfg.reidentify if method == "pod-ilqr" and not noisy else 0
    box = (data.u_low, data.u_high) if env.limited else (None, None)
    selector = observation_selector(dims.nz, dims.nu, q)
    steps = _step_candidates(cfg, noisy=False)
    alphas = on_device(_step_candidates(cfg, noisy))
    no_change = on_device(0.0)
    return Context(
        method=method,
        env=env,
        dims=dims,
        data=data,
        cfg=cfg,
        q=q,
        identify=identify,
        noisy=noisy,
        nZ=info_dim(dims.nz, dims.nu, q),
        reidentify=reidentify,
        escalate=reidentify > 0 and cfg.escalate,
        closed_loop=cfg.variant != "plain",
        cost_model=QuadraticCost(selector, data.z_target, data.Q, data.QT, data.R, data.goal_step, *box),
        reg=Regularisation(on_device(cfg.mu_min), on_device(cfg.mu_max), on_device(cfg.mu_factor)),
        steps=steps,
        plan=plan,
        search=Search(dims, q, n_fwd, noisy, plan.ls_chunk, noisy and cfg.paired_line_search),
        candidates=Candidates(alphas, on_device(cfg.accept_ratio)),
        hold=Step(on_device(np.zeros((dims.horizon, dims.nu))), on_device(np.inf), no_change, no_change),
        fingerprint=fingerprint(method, env, dims, cfg),
        units=actuator_units(env, cfg).tolist() if method == "pod-ilqr" else [],
    )


def _in_impl(env: Env, impl: str):
    """The task's data with its MJX model in implementation ``impl`` (``SolverConfig.impl``)."""
    if impl == "jax" or env.dims.native is not None:
        return env.data
    return env.data._replace(model=env.mjx_model(impl))


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


def _first_controls(u_init, dims, run_options: RunOptions):
    """The controls of the first nominal on the device (unused when resuming)."""
    return None if run_options.resume is not None else _initial_controls(u_init, dims)


def _starts_of(u_init, cfg: SolverConfig) -> SolverConfig:
    """``cfg`` with ``restarts`` = K where ``u_init`` holds K first guesses [K, T, nu]."""
    shape = np.shape(u_init) if u_init is not None else ()
    if len(shape) != 3:
        return cfg
    if shape[0] < 1:
        raise ConfigError(f"`u_init` holds no first guess (shape {list(shape)}); give [K, horizon, nu] with K >= 1.")
    if cfg.restarts not in (None, 1, shape[0]):
        raise ConfigError(
            f"`u_init` holds {shape[0]} first guesses ([K, horizon, nu] = {list(shape)}) but `restarts` is "
            f"{cfg.restarts}; give {cfg.restarts} guesses, or leave restarts unset (it then takes their number)."
        )
    return cfg.replace(restarts=shape[0])


def _initial_controls(u_init, dims) -> jnp.ndarray:
    """The first nominal's controls [T, nu] on the device, or the K first guesses [K, T, nu] (``_starts_of``)."""
    if u_init is None:
        return on_device(np.zeros((dims.horizon, dims.nu)))
    u = np.asarray(u_init, dtype=float)
    if u.shape[-2:] != (dims.horizon, dims.nu) or u.ndim not in (2, 3):  # K >= 1: ``_starts_of`` checked
        raise ConfigError(
            f"`u_init` must have shape [horizon, nu] = [{dims.horizon}, {dims.nu}] (or [K, {dims.horizon}, "
            f"{dims.nu}]: K first guesses); got {u.shape}."
        )
    if u.ndim == 3 and u.shape[0] == 1:  # one first guess: one solve
        u = u[0]
    if not np.all(np.isfinite(u)):
        raise ConfigError("`u_init` holds non-finite numbers; use finite initial controls.")
    return on_device(u)
