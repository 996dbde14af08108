"""podilqr_jax: data-based iterative LQR (POD-iLQR) on batched MJX rollouts.

Precision: importing the package enables float64 in JAX (``jax_enable_x64``).
The least-squares fit differences rollouts that deviate from the nominal by
~sigma; in float32 a perturbation of 1e-4 on an angle of ~3 keeps about three
significant digits of dz, too few for the fit (docs/algorithm.md measures it).
Set ``PODILQR_X64=0`` before importing to keep JAX's float32 default.

Compilation: importing the package also turns on JAX's persistent compilation
cache in ``~/.cache/podilqr_jax/jax`` (``PODILQR_CACHE_DIR`` moves it,
``PODILQR_CACHE=0`` switches it off; see ``cache``).
"""

import contextlib as _contextlib
import io as _io
import os as _os

import jax as _jax

if _os.environ.get("PODILQR_X64", "1") != "0":
    _jax.config.update("jax_enable_x64", True)

# Sets up JAX's persistent compilation cache on import (before anything compiles).
from .sim import cache as _cache  # noqa: F401

# MJX prints a note to stdout when its optional `warp` backend is absent; keep
# stdout clean for the CLI's output.
with _contextlib.redirect_stdout(_io.StringIO()):
    from mujoco import mjx as _mjx  # noqa: F401

from .control.kalman import EstimatorNoise as EstimatorNoise
from .control.kalman import estimator_policy as estimator_policy
from .control.kalman import identify_about_nominal as identify_about_nominal
from .control.policy import FeedbackPolicy as FeedbackPolicy
from .control.policy import PolicyState as PolicyState
from .control.replan import replan_episodes as replan_episodes
from .errors import ConfigError as ConfigError
from .errors import ModelLoadError as ModelLoadError
from .errors import PodIlqrError as PodIlqrError
from .errors import TaskError as TaskError
from .identify.estimators import ESTIMATORS as ESTIMATORS
from .identify.estimators import fit_information_model_iv as fit_information_model_iv
from .identify.info_state import companion as companion
from .identify.info_state import info_states as info_states
from .identify.model_based import linearise as linearise
from .identify.sysid import LinearModel as LinearModel
from .identify.sysid import fit_information_model as fit_information_model
from .ilqr.backward import BackwardResult as BackwardResult
from .ilqr.backward import QuadraticCost as QuadraticCost
from .ilqr.backward import backward_pass as backward_pass
from .ilqr.config import PAPER_SETTINGS as PAPER_SETTINGS
from .ilqr.config import VARIANTS as VARIANTS
from .ilqr.config import SolverConfig as SolverConfig
from .ilqr.result import IterationInfo as IterationInfo
from .ilqr.result import Result as Result
from .ilqr.result import Status as Status
from .ilqr.result import load_result as load_result
from .ilqr.solver import default_config as default_config
from .ilqr.solver import solve as solve
from .ilqr.solver import solve_model_based as solve_model_based
from .ilqr.state import Record as Record
from .sim.cache import CacheInfo as CacheInfo
from .sim.cache import cache_info as cache_info
from .sim.episodes import EpisodeNoise as EpisodeNoise
from .sim.episodes import Episodes as Episodes
from .sim.episodes import run_episodes as run_episodes
from .studies.evaluate import EvaluateSettings as EvaluateSettings
from .studies.evaluate import evaluate as evaluate
from .task.env import Env as Env
from .task.env import EnvData as EnvData
from .task.env import EnvDims as EnvDims
from .task.noise import NoiseModel as NoiseModel
from .task.package_files import resolve_model_path as resolve_model_path
from .task.tasks import TASKS as TASKS
from .task.tasks import make_task as make_task
from .viz.animate import Animation as Animation
from .viz.animate import animate as animate

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
    "FeedbackPolicy",
    "IterationInfo",
    "LinearModel",
    "ModelLoadError",
    "NoiseModel",
    "PodIlqrError",
    "PolicyState",
    "QuadraticCost",
    "Record",
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
