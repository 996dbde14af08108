"""No iteration after the first compiles anything (acceptance 4 of the core issue)."""

from __future__ import annotations

import podilqr_jax as pj


def test_second_iteration_compiles_nothing():
    env = pj.make_task("pendulum-partial", horizon=8)
    cfg = pj.default_config(env, max_iterations=6, rtol=0.0, gtol=0.0)
    result = pj.solve(env, cfg)
    assert result.iterations >= 3, result.summary()
    assert result.compiles_per_iteration[1:] == [0] * (result.iterations - 1), result.compiles_per_iteration


def test_changing_traced_settings_does_not_recompile():
    env = pj.make_task("pendulum-partial", horizon=8)
    pj.solve(env, pj.default_config(env, max_iterations=2))
    again = pj.solve(env, pj.default_config(env, max_iterations=3, sigma=3e-5, rtol=0.0, mu_min=1e-5, seed=7))
    assert sum(again.compiles_per_iteration) == 0, again.compiles_per_iteration


def test_compile_watch_sees_a_new_compilation():
    """The watch itself can fail: a fresh shape must be counted."""
    env = pj.make_task("pendulum-partial", horizon=9)
    result = pj.solve(env, pj.default_config(env, max_iterations=2))
    assert result.compiles_per_iteration[0] > 0
    assert result.compile_s > 0
