"""Property-based tests over task configurations (hypothesis).

Any configuration, valid or not, either solves to a finite result or fails
with one of the documented errors (``pj.PodIlqrError``: TaskError,
ConfigError, ModelLoadError; docs/bad_input.md) before anything is traced;
never an uncaught exception, never NaN controls or gains. The values are drawn
from small sets so that the valid ones share array shapes and JAX compiles
each shape once across examples.
"""

import math
import os

import numpy as np
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import podilqr_jax as pj
from podilqr_jax.task.tasks import MODELS_DIR

PENDULUM = os.path.join(MODELS_DIR, "pendulum.xml")
CARTPOLE = os.path.join(MODELS_DIR, "cartpole.xml")

numbers = st.sampled_from([-1.0, 0.0, 1e-6, 1e-3, 0.1, 1.0, 100.0, math.nan, math.inf, "abc", None])
observations = st.sampled_from(
    [
        "full",
        "qpos",
        "velocity",
        {"qpos": ["hinge"]},
        {"qvel": [0]},
        {"qpos": []},
        {"qpos": ["elbow"]},
        {"qpos": [5]},
        {"sensors": ["tip"]},
        [[1.0, 0.0]],
        [[1.0, 0.0], [2.0, 0.0]],
        [[math.nan, 0.0]],
    ]
)

DOUBLE = os.path.join(MODELS_DIR, "double_pendulum.xml")

# Anything, mostly invalid: every field drawn from valid and invalid values.
any_task = st.fixed_dictionaries(
    {
        "model": st.sampled_from([PENDULUM, CARTPOLE]),
        "observation": observations,
        "horizon": st.sampled_from([-1, 0, 1, 4, 6, 2.5]),
        "substeps": st.sampled_from([0, 1, 5]),
        "Q": numbers,
        "R": numbers,
        "target": st.sampled_from([None, [0.0], [0.0, 0.0], [math.inf]]),
        "noise": st.sampled_from([None, {"initial": 0.01, "process": 0.001}, {"initial": -1.0}, {"bogus": 1.0}]),
    }
)
any_solver = st.fixed_dictionaries(
    {
        "q": st.sampled_from([None, -1, 0, 1, 2, 1.5]),
        "n_s": st.sampled_from([0, 2, 8, 24]),
        "sigma": numbers,
        "variant": st.sampled_from(["plain", "feedback", "averaged", "nominal", "magic"]),
        "estimator": st.sampled_from(["ols", "iv", "mle"]),
        "mu_factor": st.sampled_from([0.5, 1.0, 2.0]),
    }
)

# Valid values only (a few combinations are still refused, e.g. n_s too small
# for q = 2 or for the IV instruments): these mostly solve. Few distinct
# shapes, so that the examples share compilations.
valid_task = st.fixed_dictionaries(
    {
        "model": st.sampled_from([PENDULUM, CARTPOLE, DOUBLE]),
        "observation": st.sampled_from(["full", "qpos"]),
        "horizon": st.just(4),
        "substeps": st.sampled_from([1, 5]),
        "Q": st.sampled_from([0.0, 1.0, 100.0]),
        "R": st.sampled_from([1e-3, 1.0]),
        "noise": st.sampled_from([None, {"initial": 0.01, "process": 0.001, "measurement": 0.001}]),
    }
)
valid_solver = st.fixed_dictionaries(
    {
        "n_s": st.sampled_from([12, 24]),
        "sigma": st.sampled_from([1e-6, 1e-2, 1.0]),
        "variant": st.sampled_from(["plain", "feedback", "nominal"]),
        "estimator": st.sampled_from(["ols", "iv"]),
        # Both engines: the property is the solver's; MuJoCo's C engine compiles no physics,
        # so the examples drawn on it cost the suite a third of the MJX ones.
        "engine": st.sampled_from(["mjx", "native"]),
    }
)


def _solve_or_documented_error(task, solver):
    kwargs = {k: v for k, v in task.items() if k != "model" and v is not None}
    try:
        env = pj.Env.from_xml(task["model"], **kwargs)
        cfg = pj.SolverConfig(max_iterations=2).replace(**solver)
        result = pj.solve(env, cfg)
    except pj.PodIlqrError as exc:
        assert str(exc) and "Traceback" not in str(exc)
        event(f"refused: {type(exc).__name__}")
        return None
    event(f"solved: {result.status} on {result.engine}")
    assert result.status in set(pj.Status)
    assert np.all(np.isfinite(result.controls)) and np.all(np.isfinite(result.K))
    assert math.isfinite(result.cost_history[0])
    assert result.status == pj.Status.NONFINITE or math.isfinite(result.final_cost)
    if env.limited:
        assert np.all(result.controls >= np.asarray(env.data.u_low))
        assert np.all(result.controls <= np.asarray(env.data.u_high))
    return result


@settings(max_examples=60, deadline=None, derandomize=True)
@given(task=any_task, solver=any_solver)
def test_any_configuration_solves_or_fails_with_a_documented_error(task, solver):
    _solve_or_documented_error(task, solver)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
@given(task=valid_task, solver=valid_solver)
def test_valid_configurations_solve_to_finite_results(task, solver):
    _solve_or_documented_error(task, solver)
