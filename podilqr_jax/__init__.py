"""podilqr_jax: data-based iterative LQR (POD-iLQR) on batched MJX rollouts.

Precision: importing the package enables float64 in JAX (``jax_enable_x64``).
The least-squares fit differences rollouts that deviate from the nominal by
~sigma; in float32 a perturbation of 1e-4 on an angle of ~3 keeps about three
significant digits of dz, too few for the fit (docs/algorithm.md measures it).
Set ``PODILQR_X64=0`` before importing to keep JAX's float32 default.

Compilation: the package also turns on JAX's persistent compilation cache in
``~/.cache/podilqr_jax/jax`` (``PODILQR_CACHE_DIR`` moves it, ``PODILQR_CACHE=0``
switches it off, ``PODILQR_CACHE=read`` reads it without writing; see ``cache``).

The public names below are imported on first use: ``import podilqr_jax`` itself
loads neither JAX nor MuJoCo (``_runtime`` sets JAX up when they are).
"""

import os as _os
import sys as _sys

from . import environment as _environment

# float64 unless PODILQR_X64=0 (``_runtime`` says why). JAX is not imported
# here: asking through its variable makes JAX start in float64 wherever it is
# imported first; ``_runtime`` then sets it in JAX's config and restores the
# variable.
_X64_ASKED = _environment.switch(_environment.X64, True)
_X64_VARIABLE_BEFORE = _os.environ.get("JAX_ENABLE_X64")
if _X64_ASKED and "jax" not in _sys.modules:
    _os.environ["JAX_ENABLE_X64"] = "1"
if "jax" in _sys.modules:  # JAX is loaded already: set it up now (float64, the cache), at little cost
    from . import _runtime  # noqa: E402,F401

_PUBLIC = {  # name -> the module that defines it, imported on first use
    "EstimatorNoise": ".control.kalman",
    "estimator_policy": ".control.kalman",
    "identify_about_nominal": ".control.kalman",
    "FeedbackPolicy": ".control.policy",
    "PolicyState": ".control.policy",
    "replan_episodes": ".control.replan",
    "ConfigError": ".errors",
    "ModelLoadError": ".errors",
    "PodIlqrError": ".errors",
    "TaskError": ".errors",
    "ESTIMATORS": ".identify.estimators",
    "fit_information_model_iv": ".identify.estimators",
    "companion": ".identify.info_state",
    "info_states": ".identify.info_state",
    "linearise": ".identify.model_based",
    "LinearModel": ".identify.sysid",
    "fit_information_model": ".identify.sysid",
    "BackwardResult": ".ilqr.backward",
    "QuadraticCost": ".ilqr.backward",
    "backward_pass": ".ilqr.backward",
    "PAPER_SETTINGS": ".ilqr.config",
    "VARIANTS": ".ilqr.config",
    "SolverConfig": ".ilqr.config",
    "ILQRSettings": ".ilqr.config",
    "IdentificationSettings": ".ilqr.config",
    "NoiseSettings": ".ilqr.config",
    "RecoverySettings": ".ilqr.config",
    "ExecutionSettings": ".ilqr.config",
    "ReferenceSettings": ".ilqr.config",
    "ExecutionPlan": ".ilqr.plan",
    "IterationInfo": ".ilqr.result",
    "Result": ".ilqr.result",
    "Status": ".ilqr.result",
    "load_result": ".ilqr.result",
    "default_config": ".ilqr.solver",
    "solve": ".ilqr.solver",
    "solve_model_based": ".ilqr.solver",
    "Record": ".ilqr.state",
    "CacheInfo": ".compilation.cache",
    "cache_info": ".compilation.cache",
    "EpisodeNoise": ".control.episodes",
    "Episodes": ".control.episodes",
    "run_episodes": ".control.episodes",
    "EvaluateSettings": ".studies.evaluate",
    "evaluate": ".studies.evaluate",
    "Env": ".task.env",
    "EnvData": ".task.env",
    "EnvDims": ".task.env",
    "NoiseModel": ".task.noise",
    "resolve_model_path": ".task.package_files",
    "TASKS": ".task.tasks",
    "make_task": ".task.tasks",
    "Animation": ".viz.animate",
    "animate": ".viz.animate",
}


def __getattr__(name: str):
    """The public names, imported on first use (``import podilqr_jax`` stays light)."""
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'podilqr_jax' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list:
    return sorted(set(globals()) | set(_PUBLIC))


__version__ = "0.1.0"

__all__ = [
    "Animation",
    "BackwardResult",
    "CacheInfo",
    "ConfigError",
    "Env",
    "EnvData",
    "EnvDims",
    "ESTIMATORS",
    "EpisodeNoise",
    "Episodes",
    "EstimatorNoise",
    "EvaluateSettings",
    "ExecutionPlan",
    "ExecutionSettings",
    "FeedbackPolicy",
    "ILQRSettings",
    "IdentificationSettings",
    "IterationInfo",
    "LinearModel",
    "ModelLoadError",
    "NoiseModel",
    "NoiseSettings",
    "PodIlqrError",
    "PolicyState",
    "QuadraticCost",
    "Record",
    "RecoverySettings",
    "ReferenceSettings",
    "Result",
    "SolverConfig",
    "Status",
    "PAPER_SETTINGS",
    "TASKS",
    "TaskError",
    "VARIANTS",
    "animate",
    "backward_pass",
    "cache_info",
    "companion",
    "default_config",
    "estimator_policy",
    "evaluate",
    "fit_information_model",
    "fit_information_model_iv",
    "identify_about_nominal",
    "info_states",
    "linearise",
    "load_result",
    "make_task",
    "replan_episodes",
    "resolve_model_path",
    "run_episodes",
    "solve",
    "solve_model_based",
]
