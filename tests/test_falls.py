"""Fall figures of `podilqr evaluate` (control/falls.py) on models as they ship."""

from __future__ import annotations

import numpy as np
import pytest

import podilqr_jax as pj
from podilqr_jax.control.falls import FALL_RATIO, falls, root_body, root_heights
from podilqr_jax.studies.evaluate import EvaluateSettings, evaluate
from podilqr_jax.task.loading import load_env

pytest.importorskip("dm_control")


def _env(path, **kw):
    return pj.Env.from_xml(path, horizon=5, **kw)


def test_the_root_is_the_body_on_a_free_joint_or_a_vertical_slide():
    walker = _env("pkg://dm_control/suite/walker.xml")  # rootz, rootx slides, rooty hinge on the torso
    humanoid = _env("pkg://dm_control/suite/humanoid.xml")  # a free joint on the torso
    assert walker.mj_model.body(root_body(walker.mj_model)).name == "torso"
    assert humanoid.mj_model.body(root_body(humanoid.mj_model)).name == "torso"
    assert root_body(pj.make_task("cartpole-full").mj_model) is None  # a cart on a horizontal slide cannot fall
    assert root_body(_env("pkg://dm_control/suite/reacher.xml").mj_model) is None  # fixed base


def test_an_episode_falls_at_the_first_step_below_the_share_of_the_nominal_height():
    env = _env("pkg://dm_control/suite/walker.xml")
    m = env.mj_model
    body = root_body(m)
    x0 = np.asarray(env.data.x0)
    nominal = np.repeat(x0[None], 6, axis=0)
    h0 = root_heights(m, body, x0)
    assert h0 > 0
    up, down, nan = (nominal.copy() for _ in range(3))
    up[:, 0] -= 0.9 * (1 - FALL_RATIO) * h0  # rootz lowered, still above the line
    down[3:, 0] -= 1.1 * (1 - FALL_RATIO) * h0  # below it from step 3 on
    nan[2:] = np.nan  # a diverged episode has fallen where it diverged
    f = falls(root_heights(m, body, np.stack([up, down, nan])), root_heights(m, body, nominal))
    assert f.stayed_up.tolist() == [True, False, False]
    assert f.up_steps.tolist() == [5, 3, 2]  # 5 control steps: the whole episode


def test_evaluate_reports_fall_figures_only_where_the_robot_can_fall():
    env = pj.make_task("pendulum-full", horizon=10)
    result = pj.solve(env, pj.default_config(env, max_iterations=20))
    small = EvaluateSettings(levels=(0.0,), episodes=4, estimator=False, replan=False)
    report = evaluate(env, result, small)
    assert report["fall"] is None and all("stayed_up_rate" not in r for r in report["rows"])


def test_evaluate_on_a_walker_reports_that_the_noiseless_episodes_stay_up():
    env = load_env("examples/tasks/robots/dmc_walker_knee.toml").replace(horizon=5)
    result = pj.solve(env, pj.default_config(env, max_iterations=2, restarts=1))
    small = EvaluateSettings(levels=(0.0,), episodes=4, estimator=False, replan=False)
    report = evaluate(env, result, small)
    assert report["fall"] == {"root_body": "torso", "fall_ratio": FALL_RATIO, "episode_s": pytest.approx(0.05)}
    for row in report["rows"]:  # the nominal itself, and the reference's: both stand for the whole episode
        assert row["stayed_up_rate"] == 1.0 and row["mean_up_s"] == pytest.approx(0.05)
