"""The rollout program the sysid batch and the line search share (sim/shared.py):
the same rollouts as the fused stages, one compile of the rollouts per solve."""

from __future__ import annotations

import logging
import os
import re
import warnings

import jax
import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax import environment
from podilqr_jax.identify.info_state import info_dim
from podilqr_jax.ilqr import line_search as ls
from podilqr_jax.ilqr import solver
from podilqr_jax.sim import contacts, rollout, shared, stages
from podilqr_jax.sim.rollout import Policy, on_device

COMPILED = re.compile(r"Finished XLA compilation of jit\((\S+)\)")
HORIZON = 17  # no other test uses it: the stages compile cold here


@pytest.mark.parametrize(
    ("setting", "n_s", "n_avg", "ls_rollouts", "sysid_chunk", "ls_chunk", "expected", "rows"),
    [
        (None, 40, 10, 440, 4000, 4000, 440, 0),  # the averaged variant: one call, 40 rows of padding
        ("auto", 8, 1, 10, None, None, 10, 0),  # one call, a quarter padded
        (None, 40, 1, 10, None, None, None, 0),  # the bundled defaults: 4 calls only when asked
        (None, 7, 1, 10, None, None, None, 0),  # more than a quarter padded
        ("1", 40, 1, 10, None, None, 10, 0),  # asked: 4 calls of 10
        ("on", 8 * 10, 1, 10, None, None, 10, 0),  # exactly MAX_GROUPS calls
        ("1", 400, 1, 10, None, None, None, 0),  # 40 calls: more than MAX_GROUPS
        ("1", 40, 1, 10, 20, None, None, 0),  # the sysid batch runs in chunks
        ("1", 40, 1, 10, None, 8, None, 0),  # the line search runs in chunks
        ("0", 40, 10, 440, 4000, 4000, None, 0),  # off
        ("off", 40, 1, 10, None, None, None, 0),
        (None, 40, 1, 10, None, None, 10, 38),  # a contact model (the hopper's rows): 4 calls by themselves
        ("auto", 40, 1, 10, None, None, None, 31),  # too few rows
        (None, 45, 1, 10, None, None, 10, 93),  # 5 calls, 5 rollouts of padding
        (None, 12, 1, 10, None, None, None, 93),  # 2 calls, 8 of padding: more than a quarter
        ("1", 12, 1, 10, None, None, 10, 0),  # asked: padded as needed
        (None, 400, 1, 10, None, None, None, 93),  # many rows, but more than MAX_GROUPS calls
        (None, 40, 1, 10, 20, None, None, 93),  # many rows, but the sysid batch runs in chunks
        ("0", 40, 1, 10, None, None, None, 93),  # off
    ],
)
def test_width_follows_the_batches_and_the_switch(
    monkeypatch, setting, n_s, n_avg, ls_rollouts, sysid_chunk, ls_chunk, expected, rows
):
    if setting is None:
        monkeypatch.delenv(shared.ENV_SWITCH, raising=False)
    else:
        monkeypatch.setenv(shared.ENV_SWITCH, setting)
    assert shared.MAX_GROUPS == 8 and contacts.MANY_ROWS == 32
    assert shared.width(n_s, n_avg, ls_rollouts, sysid_chunk, ls_chunk, rows) == expected


def test_a_contact_model_shares_by_default_and_a_small_one_does_not(monkeypatch):
    # No constraint: the bundled pendulum. Contacts: Gymnasium's hopper, as it
    # ships (its foot and leg against the floor, and its joint limits).
    monkeypatch.delenv(shared.ENV_SWITCH, raising=False)
    pendulum = pj.make_task("pendulum-full")
    assert contacts.constraint_rows(pendulum.data.model) == 0
    assert _default_width(pendulum) is None
    pytest.importorskip("gymnasium", reason="the `test` extra installs gymnasium")
    from podilqr_jax.task.taskfile import load_task

    gallery = os.path.join(os.path.dirname(os.path.dirname(__file__)), "examples", "tasks", "third_party")
    hopper = load_task(os.path.join(gallery, "gym_hopper_balance.toml"))
    rows = contacts.constraint_rows(hopper.data.model)
    assert rows >= contacts.MANY_ROWS
    d = jax.eval_shape(rollout.make_data, hopper.data.model)
    assert rows == d._impl.efc_D.shape[0]
    cfg = pj.default_config(hopper)
    assert cfg.n_s > cfg.n_alphas * cfg.resolved_n_forward()  # several calls
    assert _default_width(hopper) == cfg.n_alphas * cfg.resolved_n_forward()


def _default_width(env):
    cfg = pj.default_config(env)
    return solver._shared_width(env.dims, env.data, cfg, False, cfg.resolved_n_forward())


def test_an_unknown_setting_warns_once_and_means_auto(monkeypatch):
    monkeypatch.setattr(environment, "_warned", set())
    monkeypatch.setenv(shared.ENV_SWITCH, "sometimes")
    with pytest.warns(UserWarning, match="'sometimes' is not one of 1/on, 0/off, auto; using auto"):
        assert shared.width(40, 1, 10, None, None) is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # said once per process and value
        assert shared.width(40, 10, 440, None, None) == 440


def _setup(noise=None):
    env = pj.make_task("pendulum-partial", horizon=HORIZON, noise=noise)
    dims, data, q = env.dims, on_device(env.data), 2
    nZ, T = info_dim(dims.nz, dims.nu, q), dims.horizon
    rng = np.random.default_rng(5)
    policy = Policy(
        on_device(rng.normal(size=(T, dims.nu))),
        on_device(0.1 * rng.normal(size=(T, nZ))),
        on_device(0.05 * rng.normal(size=(T, dims.nu, nZ))),
    )
    return dims, data, q, policy


@pytest.mark.parametrize(
    ("noise", "n_avg", "mirrored"), [(None, 1, False), (None, 1, True), ("paper", 1, False), ("paper", 3, True)]
)
def test_the_sysid_batch_is_the_fused_stages(noise, n_avg, mirrored):
    dims, data, q, policy = _setup(noise)
    key, sigma, n_s, width = jax.random.PRNGKey(11), on_device(np.full(dims.nu, 0.05)), 12, 7  # 2-6 calls, padded
    fused = rollout.perturbation_rollouts(
        dims, q, n_s, data, policy, key, sigma, n_avg=n_avg, noisy=noise is not None, mirrored=mirrored
    )
    zero = on_device(np.zeros((width, dims.horizon, dims.nu)))
    grouped = shared.perturbation_rollouts(
        dims, q, n_s, data, policy, key, sigma, zero, width=width, n_avg=n_avg, noisy=noise is not None,
        mirrored=mirrored,
    )  # fmt: skip
    assert grouped.z.shape == fused.z.shape and grouped.u.shape == fused.u.shape and grouped.x is None
    # The same draws and operations in another program: equal here (noiseless) or to
    # 3e-18 in z (noisy, this machine); XLA elsewhere may round an operation otherwise.
    scale = float(np.max(np.abs(fused.z)))
    np.testing.assert_allclose(grouped.z, fused.z, rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(grouped.u, fused.u, rtol=0, atol=1e-13 * float(np.max(np.abs(fused.u))))


@pytest.mark.parametrize(("noise", "n_fwd"), [(None, 1), ("paper", 2)])
def test_the_line_search_is_the_fused_stage(noise, n_fwd):
    dims, data, q, policy = _setup(noise)
    noisy = noise is not None
    steps = 0.5 ** np.arange(5)
    alphas = on_device(np.append(steps, 0.0) if noisy else steps)
    k = on_device(np.random.default_rng(2).normal(size=(dims.horizon, dims.nu)))
    args = (dims, q, data, policy, k, alphas, on_device(1e9), on_device(-1.0), on_device(0.1), on_device(0.0))
    key = jax.random.PRNGKey(4)
    fused = ls.line_search(*args, key, n_fwd, noisy, None)
    zero = on_device(np.zeros((int(alphas.shape[0]) * n_fwd, dims.horizon, dims.nu)))
    grouped = ls.line_search_grouped(*args, key, zero, n_fwd, noisy)
    assert bool(fused.accepted) == bool(grouped.accepted) and float(fused.alpha) == float(grouped.alpha)
    np.testing.assert_allclose(grouped.costs, fused.costs, rtol=1e-12)
    np.testing.assert_allclose(grouped.Z, fused.Z, rtol=0, atol=1e-12 * float(np.max(np.abs(fused.Z))))


def test_a_solve_compiles_the_rollouts_once_and_matches_the_fused_stages(monkeypatch):
    monkeypatch.setattr(stages, "folder", lambda: None)  # plain jits: the compile log names the stages
    monkeypatch.setenv(shared.ENV_SWITCH, "1")  # the sysid batch in several calls (auto: in one only)
    seen: list[str] = []

    class Log(logging.Handler):
        def emit(self, record):
            if match := COMPILED.search(record.getMessage()):
                seen.append(match.group(1))

    env = pj.make_task("cartpole-partial", horizon=HORIZON)
    cfg = pj.default_config(env, max_iterations=3, rtol=0.0, gtol=0.0)  # n_s = 40, 10 candidates: 4 calls
    handler, logger = Log(), logging.getLogger("jax")
    level, propagate = logger.level, logger.propagate
    jax.config.update("jax_log_compiles", True)
    logger.addHandler(handler)
    logger.setLevel(logging.WARNING)
    logger.propagate = False
    try:
        on = pj.solve(env, cfg)
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
        logger.propagate = propagate
        jax.config.update("jax_log_compiles", False)
    assert seen.count("rollout_group") == 1, seen
    assert not {"perturbation_rollouts", "line_search"} & set(seen), seen
    monkeypatch.setenv(shared.ENV_SWITCH, "0")
    off = pj.solve(env, cfg)
    assert on.iterations == off.iterations == 3
    # noiseless: the same numbers (bit for bit on this machine)
    np.testing.assert_allclose(on.cost_history, off.cost_history, rtol=1e-12)
    np.testing.assert_allclose(on.K, off.K, rtol=1e-9, atol=1e-12 * float(np.max(np.abs(off.K))))
