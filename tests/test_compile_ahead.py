"""The compile ahead (compilation/ahead.py): the first iteration's stages compile in
the dry run's threads, never again in the solve, and the solve's numbers are
those of a solve without it."""

from __future__ import annotations

import logging
import re

import jax
import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax.compilation import ahead

# The stages' programs as JAX's compile log names them: the jitted stage, or
# ``call`` for a stage run from its exported program (the package's cache on).
STAGE_PROGRAMS = {
    "perturbation_rollouts", "fit_information_model", "backward_pass", "line_search", "call",
}  # fmt: skip
COMPILED = re.compile(r"Finished XLA compilation of jit\((\S+)\)")


class _Compiles(logging.Handler):
    """(thread name, program) of every XLA compilation JAX logs."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[tuple[str, str]] = []

    def emit(self, record: logging.LogRecord) -> None:
        if match := COMPILED.search(record.getMessage()):
            self.seen.append((record.threadName, match.group(1)))


@pytest.fixture
def compile_log():
    handler = _Compiles()
    logger = logging.getLogger("jax")
    level, propagate = logger.level, logger.propagate
    jax.config.update("jax_log_compiles", True)
    logger.addHandler(handler)
    logger.setLevel(logging.WARNING)
    logger.propagate = False
    try:
        yield handler
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
        logger.propagate = propagate
        jax.config.update("jax_log_compiles", False)


def _solve(horizon: int, method=pj.solve):
    env = pj.make_task("pendulum-partial", horizon=horizon)  # a horizon no other test uses: a cold compile
    return method(env, pj.default_config(env, max_iterations=3, rtol=0.0, gtol=0.0))


def test_the_stages_compile_in_the_dry_run_threads_only(monkeypatch, compile_log):
    monkeypatch.setenv(ahead.ENV_SWITCH, "2")  # on, also where this machine has one core
    result = _solve(horizon=11)
    assert ahead.last_error is None
    in_threads = [program for thread, program in compile_log.seen if thread.startswith("podilqr-compile")]
    in_main = [program for thread, program in compile_log.seen if not thread.startswith("podilqr-compile")]
    # identification (rollouts, fit), backward pass, line search
    assert len(in_threads) >= 4 and set(in_threads) <= STAGE_PROGRAMS, compile_log.seen
    assert not STAGE_PROGRAMS & set(in_main), compile_log.seen
    assert result.phase_s["compile"] > 0
    assert result.compiles_per_iteration[1:] == [0] * (result.iterations - 1)


def test_the_model_based_stages_compile_in_the_dry_run_threads_only(monkeypatch, compile_log):
    monkeypatch.setenv(ahead.ENV_SWITCH, "2")
    _solve(horizon=12, method=pj.solve_model_based)
    assert ahead.last_error is None
    in_threads = {program for thread, program in compile_log.seen if thread.startswith("podilqr-compile")}
    in_main = {program for thread, program in compile_log.seen if not thread.startswith("podilqr-compile")}
    assert in_threads and not (STAGE_PROGRAMS | {"linearise"}) & in_main, compile_log.seen


def test_a_solve_gives_the_same_numbers_with_and_without_it(monkeypatch):
    monkeypatch.setenv(ahead.ENV_SWITCH, "2")
    on = _solve(horizon=13)
    jax.clear_caches()  # the second solve compiles (or loads) afresh, without the dry run
    monkeypatch.setenv(ahead.ENV_SWITCH, "0")
    off = _solve(horizon=13)
    assert off.phase_s["compile"] == 0.0 and on.phase_s["compile"] > 0
    np.testing.assert_array_equal(on.cost_history, off.cost_history)
    np.testing.assert_array_equal(on.K, off.K)
    np.testing.assert_array_equal(on.controls, off.controls)


def test_an_error_in_the_dry_run_leaves_the_solve_to_compile_as_it_goes(monkeypatch):
    monkeypatch.setenv(ahead.ENV_SWITCH, "2")

    def refuse(self, name, target, args, kwargs):
        raise RuntimeError(f"no lowering of {name} today")

    monkeypatch.setattr(ahead.DryRun, "submit", refuse)
    result = _solve(horizon=14)
    assert "RuntimeError: no lowering of" in ahead.last_error
    assert result.iterations == 3 and np.isfinite(result.cost_history[-1])
    assert result.compiles_per_iteration[1:] == [0, 0]


@pytest.mark.parametrize(
    ("setting", "cores", "expected"),
    [(None, 2, 2), ("1", 8, ahead.MAX_WORKERS), (None, 1, 0), ("off", 2, 0), ("0", 2, 0), ("3", 1, 3)],
)
def test_workers_follow_the_cores_and_the_switch(monkeypatch, setting, cores, expected):
    if setting is None:
        monkeypatch.delenv(ahead.ENV_SWITCH, raising=False)
    else:
        monkeypatch.setenv(ahead.ENV_SWITCH, setting)
    monkeypatch.setattr(ahead.os, "sched_getaffinity", lambda pid: set(range(cores)), raising=False)
    assert ahead.workers() == expected
