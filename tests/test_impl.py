"""MJX implementation choice (SolverConfig.impl, `--set impl=...`): validated before
anything is traced, a clear error when Warp is not installed, and where Warp is
installed, the same solve as MJX's JAX implementation."""

from __future__ import annotations

import numpy as np
import pytest
from mujoco.mjx import warp as mjx_warp

import podilqr_jax as pj
from podilqr_jax.cli import main

WARP = bool(getattr(mjx_warp, "WARP_INSTALLED", False))


def test_unknown_impl_is_refused():
    env = pj.make_task("pendulum-full", horizon=6)
    with pytest.raises(pj.ConfigError, match=r"Unknown `impl` 'cpp'; choose one of jax, warp"):
        pj.solve(env, pj.default_config(env, impl="cpp"))
    assert pj.default_config(env).impl == "jax"


@pytest.mark.skipif(WARP, reason="warp-lang is installed here: the missing-Warp message cannot be seen")
def test_warp_without_warp_lang_says_how_to_install_it(tmp_path, capsys):
    env = pj.make_task("pendulum-full", horizon=6)
    with pytest.raises(pj.ConfigError, match=r"needs the `warp-lang` package .*podilqr_jax\[cuda\]"):
        pj.solve(env, pj.default_config(env, impl="warp"))
    code = main(["solve", "pendulum-full", "--set", "impl=warp", "--out", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert code == 2 and "warp-lang" in err and "Traceback" not in err


def test_cli_refuses_an_unknown_impl(tmp_path, capsys):
    code = main(["solve", "pendulum-full", "--set", "impl=mjx-c", "--out", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert code == 2 and "Unknown `impl` 'mjx-c'" in err and "Traceback" not in err
    assert not (tmp_path / "r.json").exists()


@pytest.mark.skipif(not WARP, reason="warp-lang is not installed (pip install 'podilqr_jax[cuda]' or warp-lang)")
def test_warp_solve_matches_jax():
    env = pj.make_task("pendulum-full", horizon=8)
    cfg = pj.default_config(env, max_iterations=3, n_s=8)
    jax_run = pj.solve(env, cfg)
    warp_run = pj.solve(env, cfg.replace(impl="warp"))
    # Two implementations of the same physics: float round-off apart, which
    # the fit amplifies by 1 / sigma; the costs agree to far better than 1e-6.
    np.testing.assert_allclose(warp_run.cost_history, jax_run.cost_history, rtol=1e-6)
