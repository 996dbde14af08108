"""The race between starts (``race_rung``): successive halving at the rungs, the same cuts whatever the timing."""

from __future__ import annotations

import random
import threading
import time

import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax.ilqr.race import Race, replay, rungs

ENV = pj.make_task("pendulum-partial").replace(horizon=10)
CFG = pj.default_config(ENV, max_iterations=8, restarts=4, race_rung=2, race_margin=1.0)


def test_the_rungs_double_below_max_iterations():
    assert rungs(8, 300) == [8, 16, 32, 64, 128, 256]
    assert rungs(2, 8) == [2, 4]
    assert rungs(0, 300) == [] and rungs(300, 300) == []


def test_replay_keeps_the_better_half_at_each_rung():
    histories = [
        [10, 9, 8, 7, 6, 5, 4, 3, 2],  # behind at rung 2, cut there
        [10, 5, 4, 3.5, 3.4, 3.3, 3.2, 3.1, 3.0],  # ahead at 2, behind start 2 at 4
        [10, 6, 3, 2, 1, 0.5, 0.4, 0.3, 0.2],  # the winner
        [10, 7, 7],  # converged at iteration 2: ranked by its final score, out at rung 2, not cut
    ]
    cut, final = replay(histories, 2, 9, 1.0)
    assert cut == {0: 2, 1: 4}
    assert final == [8, 3.4, 0.2, 7]
    assert replay(histories, 0, 9, 1.0) == ({}, [2, 3.0, 0.2, 7])
    # a margin keeps the starts of the worse half within it of the best: at rung 2 all are within 3.5 x 3,
    # at rung 4 start 0 (6) is not, and start 1 (3.4, 3.4 x the best's 1) races on to its end
    assert replay(histories, 2, 9, 3.5) == ({0: 4}, [6, 3.0, 0.2, 7])


def test_the_race_ranks_the_same_whatever_the_timing():
    """Four starts reporting in threads with random delays: the same cuts every
    time, and every start that stepped out of the group at a rung is back in it."""
    histories = [
        [9, 8, 7, 6, 5, 4, 3, 2, 1, 0.5],
        [9, 4, 3, 2.5, 2.4, 2.3, 2.2, 2.1, 2.0, 1.9],
        [9, 5, 2, 1, 0.8, 0.6, 0.4, 0.2, 0.1, 0.05],
        [9, 6, 5, 4.5],  # stops after iteration 3
    ]
    for trial in range(5):
        rng = random.Random(trial)
        live = {"n": 4, "out": 0}
        lock = threading.Lock()

        def step_out(live=live, lock=lock):
            with lock:
                live["n"] -= 1
                live["out"] += 1

        def step_in(n, live=live, lock=lock):
            with lock:
                live["n"] += n

        race = Race(4, 2, 1.0, 9, step_out, step_in)
        stops = {}

        def start(j, race=race, rng=rng, stops=stops):
            h = histories[j]
            for i in range(1, len(h)):
                time.sleep(rng.random() * 0.003)
                stop = race.after_iteration(j, h[: i + 1], lambda: False)
                if stop is not None:
                    stops[j] = (i, stop)
                    race.ended(j, h[: i + 1])
                    return
            race.ended(j, h)

        threads = [threading.Thread(target=start, args=(j,)) for j in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(10)
        assert not any(t.is_alive() for t in threads)
        assert race.cut == {0: 2, 3: 2, 1: 4}  # rung 2: 0 and 3 behind; rung 4: 1 behind 2
        assert {j: i for j, (i, _) in stops.items()} == race.cut
        assert str(stops[1][1].status) == "outraced" and "start 2" in stops[1][1].message
        assert live["n"] == 4 and live["out"] >= 1  # every start that stepped out came back


@pytest.fixture(scope="module")
def raced():
    return pj.solve(ENV, CFG), pj.solve(ENV, CFG.replace(race_rung=0))


def test_the_race_cuts_what_its_replay_cuts_and_keeps_the_best(raced):
    """The race's starts run what they run without it, up to where a rung cuts them:
    the same cuts and winner as the replay of the race over the run without one."""
    result, plain = raced
    histories = [s["cost_history"] for s in plain.starts]
    cut, final = replay(histories, CFG.race_rung, CFG.max_iterations, CFG.race_margin)
    assert cut  # the task has a race to run: some start falls behind
    assert {s["start"]: s["iterations"] for s in result.starts if s["status"] == "outraced"} == cut
    assert result.best_start == int(np.argmin(final))
    for s, p in zip(result.starts, plain.starts, strict=True):
        np.testing.assert_allclose(s["cost_history"], p["cost_history"][: len(s["cost_history"])], rtol=1e-9)
    np.testing.assert_allclose(result.final_cost, min(final), rtol=1e-9)
    assert sum(s["rollouts"] for s in result.starts) < sum(s["rollouts"] for s in plain.starts)
    assert f"{len(cut)} outraced at iteration" in result.message
    assert "race" in result.phase_s and all(s["status"] != "outraced" for s in plain.starts)


def test_the_phases_add_up_to_the_run_time(raced):
    """Every second of a solve with several starts is in a phase: its stages, their
    waits for each other (``waiting``, ``race``), and the other starts' run after it ended."""
    for r in raced:
        assert set(r.phase_s) >= {"rollouts", "fit", "backward", "line_search", "waiting", "race", "other_starts"}
        assert min(r.phase_s.values()) >= 0
        assert sum(r.phase_s.values()) == pytest.approx(r.wall_s, rel=1e-6)


def test_the_race_is_deterministic(raced):
    result, _ = raced
    again = pj.solve(ENV, CFG)
    assert again.starts == [dict(s, wall_s=t["wall_s"]) for s, t in zip(result.starts, again.starts, strict=True)]
    assert np.array_equal(again.controls, result.controls)


def test_a_resumed_race_cuts_the_same_starts(raced, tmp_path):
    """Stopped after the first rung and resumed: the cut starts stay cut (their
    checkpoints say so), the next rung is ranked as it was, the same result."""
    result, _ = raced
    first = pj.solve(ENV, CFG.replace(max_iterations=3), checkpoint=tmp_path)
    assert sum(s["status"] == "outraced" for s in first.starts) == 2
    resumed = pj.solve(ENV, CFG, resume=tmp_path)
    assert [(s["status"], s["iterations"]) for s in resumed.starts] == [
        (s["status"], s["iterations"]) for s in result.starts
    ]
    np.testing.assert_allclose([s["cost"] for s in resumed.starts], [s["cost"] for s in result.starts], rtol=1e-9)


@pytest.mark.parametrize(
    "setting, value",
    [("race_rung", -1), ("race_rung", 1.5), ("race_rung", True), ("race_margin", 0.9), ("race_margin", float("inf"))],
)
def test_bad_race_settings_are_refused(setting, value):
    with pytest.raises(pj.ConfigError, match=f"`{setting}`"):
        pj.solve(ENV, CFG.replace(**{setting: value}))
