"""The noisy fit's own estimate of B's error, the sigma it adapts, and the paired line search (docs/noise.md)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax.identify.quality import b_error
from podilqr_jax.identify.sigma import noisy_sigma
from podilqr_jax.ilqr.driver import blind_fit
from podilqr_jax.ilqr.line_search import Candidates, Search, Step, line_search
from podilqr_jax.sim.rollout import open_loop_policy


def _linear_data(seed: int, n_s: int, sigma: float, noise: float, T: int = 6, nz: int = 3, nu: int = 2):
    """Rollouts of z_{t+1} = A z_t + B u_t + w_t about a zero nominal, and the true (A, B)."""
    rng = np.random.default_rng(seed)
    A = np.eye(nz) + 0.1 * rng.standard_normal((nz, nz))
    B = rng.standard_normal((nz, nu))
    u = sigma * rng.standard_normal((n_s, T, nu))
    z = np.zeros((n_s, T + 1, nz))
    z[:, 0] = 0.05 * rng.standard_normal((n_s, nz))
    for t in range(T):
        z[:, t + 1] = z[:, t] @ A.T + u[:, t] @ B.T + noise * rng.standard_normal((n_s, nz))
    return jnp.asarray(z), jnp.asarray(u), B


@pytest.mark.parametrize("sigma", [0.003, 0.03])
def test_the_estimate_tracks_the_measured_error_of_B(sigma):
    """Over 8 draws the estimated relative error of B is within 1.5x of the
    measured one (measured: 0.90x and 0.94x at the two scales, whose errors differ 10x)."""
    estimated, measured = [], []
    for seed in range(8):
        z, u, B = _linear_data(seed, n_s=60, sigma=sigma, noise=0.01)
        zero_z, zero_u = jnp.zeros(z.shape[1:]), jnp.zeros(u.shape[1:])
        model, report = pj.fit_information_model(z, u, zero_z, zero_u, 1, jnp.asarray(1e-12))
        estimated.append(b_error(model, report, np.full(2, sigma), 60, 1))
        measured.append(np.linalg.norm(np.asarray(model.B) - B) / (np.linalg.norm(B) * np.sqrt(6)))
    ratio = np.mean(estimated) / np.mean(measured)
    assert 1 / 1.5 < ratio < 1.5, (estimated, measured)


def test_no_signal_reads_as_an_infinite_error():
    z, u, _ = _linear_data(0, n_s=60, sigma=1e-7, noise=0.01)
    model, report = pj.fit_information_model(
        z, u, jnp.zeros(z.shape[1:]), jnp.zeros(u.shape[1:]), 1, jnp.asarray(1e-12)
    )
    assert b_error(model, report, np.full(2, 1e-7), 60, 1) > 1.0


def test_noisy_sigma_grows_above_the_target_and_keeps_below():
    cfg = pj.SolverConfig(sigma=1e-3, sigma_range=100.0, max_fit_error=0.1)
    assert noisy_sigma(1e-3, 0.4, cfg) == pytest.approx(8e-3)  # to half the target: x 0.4 / 0.05
    assert noisy_sigma(1e-3, 50.0, cfg) == pytest.approx(1e-2)  # by 10x at most
    assert noisy_sigma(1e-3, float("inf"), cfg) == pytest.approx(1e-2)
    assert noisy_sigma(1e-3, 0.06, cfg) == 1e-3  # below the target: kept
    assert noisy_sigma(1e-3, 1e-6, cfg) == 1e-3  # far below too: no estimate of curvature, no reason to shrink
    assert noisy_sigma(1e-3, float("nan"), cfg) == 1e-3
    assert noisy_sigma(0.09, 5.0, cfg) == pytest.approx(0.1)  # at most sigma x sigma_range


def test_a_blind_fit_warns_and_a_seeing_one_does_not():
    assert "could not see the controls" in blind_fit([3.0, 2.0, float("nan"), 0.5])
    assert blind_fit([0.3, 0.2, 4.0]) == ""
    assert blind_fit([float("nan")] * 3) == ""


@pytest.mark.parametrize("overrides, pattern", [({"max_fit_error": 0.0}, "max_fit_error"),
                                                ({"paired_line_search": 1}, "paired_line_search")])  # fmt: skip
def test_bad_settings(overrides, pattern):
    env = pj.make_task("pendulum-full", horizon=10)
    with pytest.raises(pj.ConfigError, match=pattern):
        pj.solve(env, pj.default_config(env, **overrides))


def test_a_noisy_solve_records_its_fit_error_and_adapts_sigma():
    """The general rule (not the bundled task's noisy defaults): sigma starts at
    1e-4 of the torque range, where the fit cannot see the controls (B err > 1),
    and grows; noiseless, nothing is recorded."""
    env = pj.make_task("pendulum-full", horizon=10, noise="paper")
    cfg = pj.default_config(env, sigma=1e-4, adapt_sigma=True, max_iterations=6)
    r = pj.solve(env, cfg)
    errors = np.asarray(r.fit_error_history)
    assert len(errors) == len(r.sigma_history) == r.iterations
    assert np.all(np.isfinite(errors[errors == errors]))
    assert errors[0] > 1.0
    assert r.sigma_history[-1] > 1e-4
    d = r.to_dict()
    assert len(d["fit_error_history"]) == r.iterations
    clean = pj.solve(pj.make_task("pendulum-full", horizon=10), pj.default_config(env, max_iterations=3))
    assert np.all(np.isnan(clean.fit_error_history))
    assert not any("could not see" in w for w in clean.warnings)


def _search(env, paired: bool, k, n_alphas: int = 4):
    dims, data = env.dims, env.data
    nZ = dims.nz
    alphas = jnp.asarray([1.0, 0.5, 0.25, 0.0][:n_alphas])
    zero = jnp.zeros(())
    step = Step(k, jnp.asarray(np.inf), zero, zero)
    policy = open_loop_policy(jnp.zeros((dims.horizon, dims.nu)), nZ)
    return line_search(
        Search(dims, 1, 1, True, None, paired), data, policy, step, Candidates(alphas, jnp.asarray(1e-4)),
        jax.random.PRNGKey(3),
    )  # fmt: skip


def test_paired_candidates_share_one_noise_draw():
    """With k = 0 every candidate is the same policy: paired, the same draw gives
    the same cost four times; unpaired, four draws give four costs."""
    env = pj.make_task("pendulum-full", horizon=10, noise="paper")
    k = jnp.zeros((env.dims.horizon, env.dims.nu))
    paired, unpaired = _search(env, True, k), _search(env, False, k)
    costs = np.asarray(paired.costs)
    assert np.all(costs == costs[0])
    assert len(set(np.asarray(unpaired.costs).tolist())) == 4
    assert not bool(paired.accepted)


def test_noise_fit_benchmark_smoke(tmp_path):
    """benchmarks/noise_fit.py on the bundled pendulum: one cell, its table and JSON."""
    import json
    import os
    import subprocess
    import sys

    script = os.path.join(os.path.dirname(__file__), os.pardir, "benchmarks", "noise_fit.py")
    out = tmp_path / "noise_fit.json"
    args = ["pendulum-full", "--sigmas", "1e-2", "--n-s", "40", "--seeds", "1", "--out", str(out)]
    proc = subprocess.run([sys.executable, script, *args], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "| 0.01 | 40 |" in proc.stdout
    rows = json.loads(out.read_text())["rows"]
    assert len(rows) == 1 and rows[0]["Bc"] > 0 and np.isfinite(rows[0]["quality"])


def test_the_line_search_averages_under_noise_by_default():
    """plain and feedback average NOISY_N_FORWARD rollouts per candidate on a
    noisy task, one without noise; averaged keeps n_s; nominal takes none."""
    from podilqr_jax.ilqr.config import NOISY_N_FORWARD

    cfg = pj.SolverConfig(n_s=40)
    assert cfg.resolved_n_forward(noisy=True) == NOISY_N_FORWARD == 8
    assert cfg.resolved_n_forward(noisy=False) == 1
    assert cfg.replace(variant="plain").resolved_n_forward(noisy=True) == NOISY_N_FORWARD
    assert cfg.replace(variant="averaged").resolved_n_forward(noisy=True) == 40
    assert cfg.replace(n_forward=3).resolved_n_forward(noisy=True) == 3
    pj.SolverConfig(variant="feedback", n_forward=4).noise.validate()
    with pytest.raises(pj.ConfigError, match="n_forward"):
        pj.SolverConfig(variant="nominal", n_forward=4).noise.validate()
    bundled = pj.make_task("pendulum-full", noise="paper").solver_defaults
    assert bundled["n_forward"] == 1 and bundled["adapt_sigma"] is False  # the measured noisy defaults stay
