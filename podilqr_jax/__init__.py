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
from . import cache as _cache  # noqa: F401

# MJX prints a note to stdout when its optional `warp` backend is absent; keep
# stdout clean for the CLI's output.
with _contextlib.redirect_stdout(_io.StringIO()):
    from mujoco import mjx as _mjx  # noqa: F401

from .animate import Animation as Animation
from .animate import animate as animate
from .backward import BackwardResult as BackwardResult
from .backward import QuadraticCost as QuadraticCost
from .backward import backward_pass as backward_pass
from .cache import CacheInfo as CacheInfo
from .cache import cache_info as cache_info
from .config import PAPER_SETTINGS as PAPER_SETTINGS
from .config import VARIANTS as VARIANTS
from .config import SolverConfig as SolverConfig
from .env import Env as Env
from .env import EnvData as EnvData
from .env import EnvDims as EnvDims
from .episodes import EpisodeNoise as EpisodeNoise
from .episodes import Episodes as Episodes
from .episodes import run_episodes as run_episodes
from .errors import ConfigError as ConfigError
from .errors import ModelLoadError as ModelLoadError
from .errors import PodIlqrError as PodIlqrError
from .errors import TaskError as TaskError
from .estimators import ESTIMATORS as ESTIMATORS
from .estimators import fit_information_model_iv as fit_information_model_iv
from .evaluate import EvaluateSettings as EvaluateSettings
from .evaluate import evaluate as evaluate
from .info_state import companion as companion
from .info_state import info_states as info_states
from .kalman import EstimatorNoise as EstimatorNoise
from .kalman import estimator_policy as estimator_policy
from .kalman import identify_about_nominal as identify_about_nominal
from .model_based import linearise as linearise
from .noise import NoiseModel as NoiseModel
from .package_files import resolve_model_path as resolve_model_path
from .policy import FeedbackPolicy as FeedbackPolicy
from .policy import PolicyState as PolicyState
from .replan import replan_episodes as replan_episodes
from .result import IterationInfo as IterationInfo
from .result import Result as Result
from .result import Status as Status
from .result import load_result as load_result
from .solver import default_config as default_config
from .solver import solve as solve
from .solver import solve_model_based as solve_model_based
from .state import Record as Record
from .sysid import LinearModel as LinearModel
from .sysid import fit_information_model as fit_information_model
from .tasks import TASKS as TASKS
from .tasks import make_task as make_task

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
