"""Several starts of one solve, in one batch: ``restarts = k``.

An iLQR solve ends in the local minimum whose basin its first iterations
lead to; on a multi-modal task (a swing-up that can go either way, a balance
with several ways to catch the fall) another first guess may end far lower
(docs/robustness.md, "Basins on multi-modal tasks"). With
``SolverConfig.restarts = k`` the solver runs k solves of the task:

- start 0 from the controls given (zero by default) with ``seed``;
- start j from those controls plus Gaussian noise of ``restart_scale`` times
  each actuator's half ctrlrange (1 where it is unlimited), drawn with
  ``numpy.random.default_rng((seed, j))`` and clipped to the range, with
  ``seed + j`` for its perturbations and noise (or, where the caller gives K
  first guesses, ``u_init`` [K, T, nu], start j from the j-th of them),

and returns the result of the one that ends lowest (the noiseless
closed-loop cost under noise), with every start's outcome in
``Result.starts`` and a warning when the first guess given ended more than
``BASIN_RATIO`` above the best: a worse local minimum.

The starts race (``race``): at iterations ``race_rung``, twice that, four
times that, ... the starts of the worse half of those still racing that are
more than ``race_margin`` times the best's cost stop, status ``outraced``, so
that the physics goes to the starts that can still win; ``race_rung = 0``
runs every start to its own end.

The k solves are not run one after another. Each runs the one driver
(``driver.run_within``) in a thread of its own, and their stage calls meet in
a lockstep group (``compilation.lockstep``): each identification, backward
pass and line search of the k solves is one batched call with a leading
problem axis, so that on an accelerator k starts should cost about one batch, and on a
CPU one call per stage (the cores shared by the whole batch) instead of k.

Checkpoints: start j writes to and resumes from the subfolder ``startJ`` of
the folder given. A resumed solve equals the uninterrupted one to round-off
(bit for bit where the starts ran in lockstep: which calls share a batch after
the resume can differ where they had drifted apart). Ctrl-C (or a scheduler's
stop) stops every start after its iteration in flight, as it stops one solve.
"""

from __future__ import annotations

import dataclasses
import math
import os
import threading
import time
from typing import Optional

import numpy as np

from ..compilation import lockstep
from ..errors import ConfigError
from ..sim.rollout import on_device
from .checkpoint import fingerprint
from .driver import Callback, Context, RunOptions, run_within
from .interrupts import deferred_interrupts
from .race import Race
from .result import BASIN_RATIO, Result, Status

START_FIELDS = ("start", "seed", "cost", "true_cost", "status", "iterations", "rollouts", "wall_s", "cost_history")
"""What ``Result.starts`` holds for each start."""


def first_guesses(cfg, u_low, u_high, u_init, k: int) -> list:
    """The k first guesses of ``cfg`` (module docstring) about ``u_init`` [T, nu]
    in the box [``u_low``, ``u_high``], on the device; the rows of ``u_init``
    where it holds k guesses [k, T, nu] (the user's own); None each when resuming."""
    if u_init is None:
        return [None] * k
    if u_init.ndim == 3:
        return [on_device(row) for row in np.asarray(u_init)]  # rows on the host: no eager index to compile
    low, high = np.asarray(u_low, dtype=float), np.asarray(u_high, dtype=float)
    span = high - low
    half = np.where(np.isfinite(span) & (span > 0), span / 2, 1.0)
    base = np.asarray(u_init, dtype=float)
    guesses = [u_init]
    for j in range(1, k):
        noise = np.random.default_rng((cfg.seed, j)).standard_normal(base.shape) * cfg.restart_scale * half
        guesses.append(on_device(np.clip(base + noise, low, high)))
    return guesses


def _start_context(ctx: Context, j: int, plan) -> Context:
    cfg = ctx.cfg.replace(seed=ctx.cfg.seed + j)
    return dataclasses.replace(
        ctx, cfg=cfg, plan=plan, start=j, fingerprint=fingerprint(ctx.method, ctx.env, ctx.dims, cfg)
    )


def _start_options(options: RunOptions, j: int) -> RunOptions:
    """Start j's checkpoint and resume folders: ``startJ`` inside the ones given."""
    checkpoint = resume = None
    if options.checkpoint is not None:
        checkpoint = os.path.join(options.checkpoint, f"start{j}")
        os.makedirs(checkpoint, exist_ok=True)
    if options.resume is not None:
        resume = os.path.join(options.resume, f"start{j}")
        if not os.path.isdir(resume):
            raise ConfigError(
                f"The checkpoint folder {options.resume!r} holds no {f'start{j}'!r}: a solve with restarts resumes "
                "from the folder its own checkpoints went to (one subfolder per start). Resume with the restarts "
                "it was written with, or resume a checkpoint of one solve without restarts."
            )
    return RunOptions(checkpoint, options.every, resume)


def run(ctx: Context, u_init, callback: Optional[Callback], options: RunOptions) -> Result:
    """``ctx.cfg.restarts`` solves in lockstep (module docstring); the best one's result."""
    k = ctx.cfg.restarts
    plan = dataclasses.replace(ctx.plan, starts=k)
    ctxs = [_start_context(ctx, j, plan) for j in range(k)]
    opts = [_start_options(options, j) for j in range(k)]
    guesses = first_guesses(ctx.cfg, ctx.data.u_low, ctx.data.u_high, u_init, k)
    group = lockstep.Group(k)
    race = Race(k, ctx.cfg.race_rung, ctx.cfg.race_margin, ctx.cfg.max_iterations, group.step_out, group.step_in)
    results: list[Optional[Result]] = [None] * k
    errors: list[Optional[BaseException]] = [None] * k
    t0 = time.perf_counter()
    with deferred_interrupts as interrupts:

        def solve_start(j: int) -> None:
            try:
                with group.member(j):
                    r = results[j] = run_within(ctxs[j], guesses[j], callback, opts[j], interrupts, race)
                    if r.status == Status.INTERRUPTED:
                        race.gone()
                    else:
                        race.ended(j, r.true_cost_history if r.noisy else r.cost_history)
            except BaseException as exc:  # noqa: BLE001 - raised in the caller's thread below
                race.gone()
                errors[j] = exc
                if not isinstance(exc, KeyboardInterrupt):
                    group.abort()  # the others stop at their next stage call; this error is raised

        threads = [threading.Thread(target=solve_start, args=(j,), name=f"podilqr-start-{j}") for j in range(k)]
        for t in threads:
            t.start()
        for t in threads:
            while t.is_alive():
                try:
                    t.join(0.2)
                except KeyboardInterrupt:  # a second Ctrl-C: every start stops at once
                    group.abort()
    wall = time.perf_counter() - t0
    failed = [e for e in errors if e is not None and not isinstance(e, KeyboardInterrupt)]
    if failed:
        raise failed[0]
    if all(r is None for r in results):
        raise KeyboardInterrupt
    return best_of(ctx, ctxs, results, wall, group, race)


def _score(r: Result) -> float:
    c = r.final_true_cost if r.noisy else r.final_cost
    return c if math.isfinite(c) else math.inf


def best_of(ctx: Context, ctxs: list[Context], results: list, wall: float, group, race: Race) -> Result:
    """The result of the start that ended lowest, with every start's outcome."""
    done = [j for j, r in enumerate(results) if r is not None]
    best = min(done, key=lambda j: (_score(results[j]), j))
    starts = [
        {
            "start": j,
            "seed": ctxs[j].cfg.seed,
            "cost": r.final_cost,
            "true_cost": r.final_true_cost,
            "status": str(r.status),
            "iterations": r.iterations,
            "rollouts": r.rollouts,
            "wall_s": r.wall_s,
            "cost_history": list(r.cost_history),
        }
        for j, r in enumerate(results)
        if r is not None
    ]
    r = results[best]
    floor = _score(r)
    worse = [j for j in done if _score(results[j]) > floor * (1 + BASIN_RATIO) + 1e-300]
    warnings = list(r.warnings)
    if 0 in race.cut and best != 0:
        first = results[0]
        warnings.insert(
            0,
            f"the first guess given (start 0) fell behind: it was outraced at iteration {race.cut[0]} at "
            f"{_score(first):.6g}; the best start (start {best}) ended at {floor:.6g}",
        )
    elif 0 in worse:
        first = results[0]
        ratio = f"{_score(first) / floor:.3g}x " if floor > 0 else ""
        warnings.insert(
            0,
            f"the first guess given (start 0) ended at {_score(first):.6g} ({first.status}), "
            f"{ratio}the best start's {floor:.6g} (start {best}): a worse local minimum",
        )
    elif [j for j in worse if j not in race.cut]:  # an outraced start did not end in its minimum
        n = sum(j not in race.cut for j in worse)
        warnings.insert(0, f"{n} of {len(results)} starts ended more than {BASIN_RATIO:.0%} above the best")
    total = sum(s["rollouts"] for s in starts)
    batches = ", ".join(f"{n} of width {w}" for w, n in sorted(group.batches.items()))
    raced = ""
    if race.cut:
        rungs = sorted(set(race.cut.values()))
        raced = f"; {len(race.cut)} outraced at iteration{'s' if len(rungs) > 1 else ''} {', '.join(map(str, rungs))}"
    message = (
        f"start {best} of {len(results)} (the lowest{raced}; {total} rollouts over all starts; "
        f"batched calls: {batches}): "
    )
    phase_s = dict(r.phase_s)
    phase_s["other_starts"] = max(0.0, wall - r.wall_s)  # after this start ended, while the others ran on
    return dataclasses.replace(
        r,
        phase_s=phase_s,
        message=message + r.message,
        warnings=warnings,
        starts=starts,
        best_start=best,
        wall_s=wall,
        run_s=max(0.0, wall - r.compile_s),
        config=ctx.cfg.flat() | {"q": ctx.q},
    )
