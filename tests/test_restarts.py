"""Several starts in one batch (``restarts``): the best start, every start's cost, lockstep batches."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import time

import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax import cli
from podilqr_jax.cli import main
from podilqr_jax.compilation import lockstep
from podilqr_jax.ilqr.restarts import START_FIELDS, first_guesses
from podilqr_jax.ilqr.result import BASIN_RATIO

ENV = pj.make_task("pendulum-partial").replace(horizon=10)
CFG = pj.default_config(ENV, max_iterations=4)
K = 3


@pytest.fixture(scope="module")
def restarted():
    """A solve with K restarts, and the lockstep group it ran in."""
    groups = []

    class Recording(lockstep.Group):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            groups.append(self)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(lockstep, "Group", Recording)
        result = pj.solve(ENV, CFG.replace(restarts=K))
    return result, groups[0]


def test_restarts_return_the_lowest_start_and_every_starts_cost(restarted):
    result, group = restarted
    assert all(tuple(s) == START_FIELDS for s in result.starts)
    assert [s["start"] for s in result.starts] == list(range(K))
    assert [s["seed"] for s in result.starts] == list(range(K))
    costs = [s["cost"] for s in result.starts]
    assert len(set(costs)) == K  # other first guesses, other runs
    assert result.best_start == int(np.argmin(costs)) and result.final_cost == min(costs)
    assert result.plan["starts"] == K
    assert group.batches.get(K, 0) >= 4 * CFG.max_iterations  # the stages of all starts ran as batches of K
    assert f"{K} starts, the best is start {result.best_start}" in result.summary()
    again = pj.Result.from_dict(json.loads(json.dumps(result.to_dict())))
    assert again.starts == result.starts and again.best_start == result.best_start


def test_a_start_is_the_solve_from_its_first_guess_and_seed(restarted):
    """Start j of the batch runs what a solve of its own from the same first
    guess and seed runs: the same iterations, the costs to round-off (a batched
    program adds in another order)."""
    result, _ = restarted
    j = result.best_start
    guess = first_guesses(CFG, ENV.data.u_low, ENV.data.u_high, np.zeros((ENV.dims.horizon, ENV.dims.nu)), K)[j]
    alone = pj.solve(ENV, CFG.replace(seed=j), u_init=np.asarray(guess))
    assert alone.iterations == result.iterations and str(alone.status) == str(result.status)
    np.testing.assert_allclose(result.cost_history, alone.cost_history, rtol=1e-9)
    np.testing.assert_allclose(result.controls, alone.controls, rtol=1e-7, atol=1e-9)


def test_restarts_are_deterministic(restarted):
    result, _ = restarted
    again = pj.solve(ENV, CFG.replace(restarts=K))
    assert again.starts == [dict(s, wall_s=t["wall_s"]) for s, t in zip(result.starts, again.starts, strict=True)]
    assert np.array_equal(again.controls, result.controls)


@pytest.mark.parametrize("setting, value", [("restarts", 0), ("restarts", 1.5), ("restart_scale", -0.1)])
def test_bad_restart_settings_are_refused(setting, value):
    with pytest.raises(pj.ConfigError, match=f"`{setting}`"):
        pj.solve(ENV, CFG.replace(**{setting: value}))


def test_cli_restarts_checkpoint_per_start_and_resume(tmp_path, capsys, restarted):
    """``--restarts``: every start in the JSON, a checkpoint folder per start, and a
    resumed solve that ends where the uninterrupted one did."""
    result, _ = restarted
    out, ckpt = tmp_path / "r.json", tmp_path / "ckpt"
    common = ["solve", "pendulum-partial", "--restarts", str(K), "--set", "horizon=10", "--no-plots"]
    assert main(common + ["--set", "max_iterations=2", "--checkpoint", str(ckpt), "--out", str(out)]) == 0
    assert sorted(p.name for p in ckpt.iterdir()) == [f"start{j}" for j in range(K)]
    assert all((ckpt / f"start{j}" / "checkpoint.npz").is_file() for j in range(K))
    assert f"{K} starts" in capsys.readouterr().err
    assert main(common + ["--set", "max_iterations=4", "--resume", str(ckpt), "--out", str(out)]) == 0
    payload = json.loads(out.read_text())
    assert [s["iterations"] for s in payload["starts"]] == [s["iterations"] for s in result.starts]
    np.testing.assert_allclose([s["cost"] for s in payload["starts"]], [s["cost"] for s in result.starts], rtol=1e-9)
    capsys.readouterr()
    assert main(common + ["--restarts", str(K + 1), "--resume", str(ckpt), "--out", str(out)]) == 2
    assert f"holds no 'start{K}'" in capsys.readouterr().err


def test_the_summary_says_when_the_first_guess_ended_in_a_worse_basin(restarted):
    result, _ = restarted
    starts = [dict(s) for s in result.starts]
    starts[0]["cost"], starts[1]["cost"] = 2.0 * starts[1]["cost"], starts[1]["cost"]
    worse = dataclasses.replace(result, starts=starts, best_start=1)
    assert "the first guess given (start 0) ended in a worse local minimum, 2x the best" in worse.summary()
    starts[0]["cost"] = starts[1]["cost"] * (1 + BASIN_RATIO / 2)  # within BASIN_RATIO: one basin
    assert "worse local minimum" not in dataclasses.replace(result, starts=starts, best_start=1).summary()
    assert cli.BASIN_RATIO == BASIN_RATIO  # --compare's threshold is the same


def test_the_callers_own_first_guesses_are_the_starts(restarted):
    """``u_init`` [K, T, nu]: K starts from those guesses; the K guesses of the
    default restarts give the default restarts' result, bit for bit."""
    result, _ = restarted
    zero = np.zeros((ENV.dims.horizon, ENV.dims.nu))
    guesses = np.stack([np.asarray(g) for g in first_guesses(CFG, ENV.data.u_low, ENV.data.u_high, zero, K)])
    given = pj.solve(ENV, CFG, u_init=guesses)
    assert given.starts == [dict(s, wall_s=t["wall_s"]) for s, t in zip(result.starts, given.starts, strict=True)]
    assert np.array_equal(given.controls, result.controls)
    with pytest.raises(pj.ConfigError, match="holds 3 first guesses"):
        pj.solve(ENV, CFG.replace(restarts=2), u_init=guesses)
    with pytest.raises(pj.ConfigError, match="K first guesses"):
        pj.solve(ENV, CFG, u_init=guesses[:, :-1])


def test_every_starts_cost_history_is_kept_and_drawn(restarted, tmp_path):
    from podilqr_jax.viz.plots import plot_convergence

    result, _ = restarted
    assert all(len(s["cost_history"]) == s["iterations"] + 1 for s in result.starts)
    assert result.starts[result.best_start]["cost_history"] == list(result.cost_history)
    path = plot_convergence([result], tmp_path / "cost.png")
    assert os.path.getsize(path) > 10_000


def test_an_error_in_one_start_is_raised_and_the_others_stop(restarted):
    """A start that raises (here its progress callback) ends the solve with that error, at once: no start waits
    for it forever in the lockstep group."""
    seen = []

    def callback(info):
        seen.append((info.start, info.iteration))
        if info.start == 1 and info.iteration == 2:
            raise ValueError("boom in start 1")

    with pytest.raises(ValueError, match="boom in start 1"):
        pj.solve(ENV, CFG.replace(restarts=K), callback=callback)
    assert max(i for _, i in seen) <= 3  # the other starts stopped within an iteration


@pytest.mark.parametrize("signals", [1, 2])
def test_ctrl_c_stops_every_start(restarted, signals, python_sigint):
    """Ctrl-C (here from a start's callback, in-process) stops every start at an iteration boundary and returns
    the best one so far, status `interrupted`; a second one stops them at once (the lockstep group is aborted)."""
    from podilqr_jax.ilqr.interrupts import deferred_interrupts

    def callback(info):
        if info.start == 1 and info.iteration == 2:
            os.kill(os.getpid(), signal.SIGINT)
            if signals == 2:  # the second once the first was handled (two pending signals would be one)
                deadline = time.time() + 30
                while not deferred_interrupts.requested and time.time() < deadline:
                    time.sleep(0.001)
                os.kill(os.getpid(), signal.SIGINT)

    result = pj.solve(ENV, CFG.replace(restarts=K, max_iterations=50), callback=callback)
    assert result.status == pj.Status.INTERRUPTED
    assert all(s["status"] == "interrupted" and s["iterations"] <= 3 for s in result.starts)


def test_restarts_default_to_several_starts_on_contact_rich_models_only():
    from podilqr_jax.ilqr.config import CONTACT_RESTARTS
    from podilqr_jax.task.taskfile import load_task

    hopper = load_task("examples/tasks/third_party/gym_hopper_balance.toml")  # floor contacts: 38 constraint rows
    assert pj.default_config(hopper).restarts is None
    assert pj.default_config(hopper).resolved_restarts(hopper) == CONTACT_RESTARTS > 1
    assert pj.default_config(ENV).resolved_restarts(ENV) == 1  # no contacts
    assert pj.default_config(hopper, restarts=2).resolved_restarts(hopper) == 2  # a setting wins
    # K first guesses set the number where restarts is left unset
    guesses = np.zeros((2, ENV.dims.horizon, ENV.dims.nu))
    assert pj.solve(ENV, CFG.replace(max_iterations=1), u_init=guesses).config["restarts"] == 2
