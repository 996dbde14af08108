"""Bad input fails in Python, before tracing, with a clear message."""

from __future__ import annotations

import math
import os

import pytest

import podilqr_jax as pj
from podilqr_jax.sim import engines
from podilqr_jax.task.tasks import MODELS_DIR

PENDULUM = os.path.join(MODELS_DIR, "pendulum.xml")


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return str(p)


def test_missing_model_file(tmp_path):
    with pytest.raises(pj.ModelLoadError, match="does not exist"):
        pj.Env.from_xml(tmp_path / "nope.xml")


def test_malformed_xml_reports_mujoco_message(tmp_path):
    path = _write(tmp_path, "bad.xml", "<mujoco><worldbody><body></mujoco>")
    with pytest.raises(pj.ModelLoadError, match="XML parse error"):
        pj.Env.from_xml(path)


def test_model_mjx_cannot_load_names_the_feature(tmp_path):
    xml = (
        '<mujoco><option><flag override="enable"/></option><worldbody><body>'
        '<joint name="j" type="hinge"/><geom size=".1"/></body></worldbody>'
        '<actuator><motor joint="j"/></actuator></mujoco>'
    )
    # `override` changes the contacts' parameters, so MJX refuses it where it
    # would run (the reporting-only `energy` flag is switched off instead:
    # test_third_party.py); MuJoCo's C engine runs the model as it is.
    env = pj.Env.from_xml(_write(tmp_path, "override.xml", xml))
    with pytest.raises(pj.ModelLoadError, match="MJX cannot load.*OVERRIDE.*'native'"):
        engines.on_engine(env, "mjx")
    assert engines.on_engine(env, "auto").dims.engine == "native"


def test_model_without_actuators(tmp_path):
    xml = '<mujoco><worldbody><body><joint type="hinge"/><geom size=".1"/></body></worldbody></mujoco>'
    with pytest.raises(pj.TaskError, match="no actuators"):
        pj.Env.from_xml(_write(tmp_path, "noact.xml", xml))


def test_unknown_task():
    with pytest.raises(pj.TaskError, match="Unknown task 'rocket-full'.*pendulum-full"):
        pj.make_task("rocket-full")


@pytest.mark.parametrize(
    "kwargs, pattern",
    [
        (dict(Q=[1.0, 2.0, 3.0]), "`Q` must be a scalar, a diagonal of length 2"),
        (dict(QT=[[1.0, 2.0], [0.0, 1.0]]), "`QT` must be symmetric"),
        (dict(Q=[1.0, -1.0]), "`Q` must be positive semi-definite"),
        (dict(R=0.0), "`R` must be positive definite"),
        (dict(R=[[1.0, 0.0], [0.0, 1.0]]), "`R` must be a scalar"),
        (dict(x0=[0.0, 0.0, 0.0]), "`x0` must have length 2"),
        (dict(x0=[math.nan, 0.0]), "non-finite"),
        (dict(target=[0.0]), "`target` must have length 2"),
        (dict(observation=[[1.0, 0.0, 0.0]]), r"shape \[nz, nq \+ nv\] = \[nz, 2\]"),
        (dict(observation=[[1.0, 0.0], [2.0, 0.0]]), "rank deficient"),
        (dict(observation={"qpos": ["elbow"]}), "Unknown joint 'elbow'.*hinge"),
        (dict(observation={"qpos": []}), "size 0"),
        (dict(observation="everything"), "Unknown observation"),
        (dict(horizon=0), "`horizon` must be an integer >= 1"),
        (dict(substeps=-2), "`substeps` must be an integer >= 1"),
    ],
)
def test_bad_task_settings(kwargs, pattern):
    with pytest.raises(pj.TaskError, match=pattern):
        pj.Env.from_xml(PENDULUM, **kwargs)


@pytest.fixture(scope="module")
def pendulum_partial():
    return pj.make_task("pendulum-partial")


@pytest.mark.parametrize(
    "overrides, pattern",
    [
        (dict(n_s=3), "`n_s`=3 is below the 4 regressors of the ARMA fit at q=2"),
        (dict(sigma=0.0), "`sigma` must be > 0"),
        (dict(sigma=-1e-3), "`sigma` must be > 0"),
        (dict(q=0), "`q` must be an integer >= 1"),
        (dict(q=30), "horizon T=30 must exceed q=30"),
        (dict(max_iterations=0), "`max_iterations` must be an integer >= 1"),
        (dict(rtol=math.inf), "`rtol` must be a finite number"),
        (dict(mu_factor=1.0), "`mu_factor` must be > 1"),
    ],
)
def test_bad_solver_settings(pendulum_partial, overrides, pattern):
    cfg = pj.default_config(pendulum_partial, **overrides)
    with pytest.raises(pj.ConfigError, match=pattern):
        pj.solve(pendulum_partial, cfg)


def test_unknown_solver_setting(pendulum_partial):
    with pytest.raises(pj.ConfigError, match="Unknown solver setting.*'sigmaa'.*known settings"):
        pj.default_config(pendulum_partial, sigmaa=1.0)


def test_unknown_solver_setting_of_the_task(pendulum_partial):
    """A task's own [solver] table is checked where the settings are built, and the message says where it came from."""
    env = pendulum_partial.replace(solver_defaults={"sigmaa": 1.0})
    with pytest.raises(pj.ConfigError, match=r"recommends unknown solver setting.*'sigmaa'.*\[solver\] table"):
        pj.default_config(env)


def test_horizon_not_above_q():
    env = pj.make_task("cartpole-partial", horizon=2)
    with pytest.raises(pj.ConfigError, match="horizon T=2 must exceed q=2"):
        pj.solve(env)


def test_bad_initial_controls(pendulum_partial):
    with pytest.raises(pj.ConfigError, match=r"`u_init` must have shape \[horizon, nu\] = \[30, 1\]"):
        pj.solve(pendulum_partial, u_init=[[0.0]] * 29)


def test_perturbations_below_resolution_are_reported_not_converged():
    """A sigma so small that x + du rounds back to x leaves every dz exactly zero."""
    env = pj.make_task("pendulum-partial", horizon=8)
    result = pj.solve(env, pj.default_config(env, sigma=1e-300))
    assert result.status == pj.Status.NO_RESPONSE, result.summary()
    assert "raise sigma" in result.message


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_a_task_file_that_is_not_utf8_is_one_paragraph_and_exit_2(tmp_path, capsys, suffix):
    from podilqr_jax.cli import main

    path = tmp_path / f"latin1{suffix}"
    path.write_bytes('name = "caf\u00e9"\n'.encode("latin-1"))  # 0xe9 alone is not UTF-8
    with pytest.raises(pj.TaskError, match=r"not UTF-8 text \(byte 0xe9 at offset 11\); save it as UTF-8"):
        from podilqr_jax.task.taskfile import load_task

        load_task(path)
    assert main(["solve", str(path), "--out", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "not UTF-8" in err and str(path) in err
