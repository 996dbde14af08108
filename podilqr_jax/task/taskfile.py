"""Task files: a task described in TOML or JSON, solvable without Python.

Schema (every key optional unless marked; the model path is relative to the
task file; see docs/task_files.md for a worked example)::

    name = "my-pendulum"
    model = "pendulum.xml"        # required: an MJCF file, or a file inside an
                                  # installed package: "pkg://dm_control/suite/pendulum.xml"
    substeps = 5                  # physics steps per control step
    horizon = 30                  # control steps T
    target = [0.0]                # z*, length nz (before the first [table]!)

    [observation]                 # or observation = "full" / "qpos"
    qpos = ["hinge"]              # joint names or indices
    qvel = []
    # C = [[1.0, 0.0]]            # or an explicit matrix [nz, nq + nv]

    [start]                       # x0; default: the model's qpos0 at rest (act 0)
    qpos = [3.14159]
    qvel = [0.0]

    [cost]
    Q = 1.0                       # scalar, diagonal list or matrix
    QT = 100.0
    R = 2.0

    [noise]                       # optional: standard deviations (default none)
    initial = 0.01                # start-state deviation s0
    process = 0.001               # w_t, added to qpos/qvel after each control step
    measurement = 0.001           # v_t, added to each observation

    [solver]                      # any solver setting by its name (or [solver.<group>] tables)
    sigma = 1e-5
    n_s = 40
    # variant = "feedback"        # plain | feedback | averaged | nominal
"""

from __future__ import annotations

import json
import math
import os
from typing import Any

import tomllib

from ..errors import TaskError
from .env import Env
from .package_files import resolve_model_path

_TOP_KEYS = {"name", "model", "substeps", "horizon", "observation", "start", "target", "cost", "solver", "noise"}
_COST_KEYS = {"Q", "QT", "R"}


def load_task(path: str | os.PathLike) -> Env:
    """Read a .toml or .json task file into an :class:`Env`."""
    path = os.fspath(path)
    spec = read_task_spec(path)
    return task_from_spec(spec, base_dir=os.path.dirname(os.path.abspath(path)), default_name=path)


def read_task_spec(path: str) -> dict[str, Any]:
    if not os.path.isfile(path):
        raise TaskError(f"The task file {path!r} does not exist.")
    ext = os.path.splitext(path)[1].lower()
    try:
        if ext == ".toml":
            with open(path, "rb") as f:
                spec = tomllib.load(f)
        elif ext == ".json":
            with open(path) as f:
                spec = json.load(f, parse_constant=_reject_constant)
        else:
            raise TaskError(f"Task files must end in .toml or .json; got {path!r}.")
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise TaskError(f"The task file {path!r} is not valid {ext[1:].upper()}: {exc}.") from None
    except UnicodeDecodeError as exc:
        raise TaskError(
            f"The task file {path!r} is not UTF-8 text (byte {exc.object[exc.start]:#04x} at offset {exc.start}); "
            "save it as UTF-8."
        ) from None
    if not isinstance(spec, dict):
        raise TaskError(f"The task file {path!r} must hold a table/object at the top level.")
    _check_finite(spec, "")
    return spec


def task_from_spec(spec: dict[str, Any], base_dir: str, default_name: str = "task") -> Env:
    unknown = set(spec) - _TOP_KEYS
    if unknown:
        raise TaskError(f"Unknown key(s) {sorted(unknown)} in the task file; known keys: {sorted(_TOP_KEYS)}.")
    if "model" not in spec:
        raise TaskError(
            'The task file needs `model = "path/to/model.xml"` (relative to the task file) '
            'or `model = "pkg://PACKAGE/PATH.xml"` (a file inside an installed package).'
        )
    cost = spec.get("cost", {})
    if not isinstance(cost, dict) or set(cost) - _COST_KEYS:
        raise TaskError(f"[cost] must be a table with keys among {sorted(_COST_KEYS)}; got {cost!r}.")
    kwargs: dict[str, Any] = {}
    for key in ("substeps", "horizon"):
        if key in spec:
            kwargs[key] = spec[key]
    if "observation" in spec:
        obs = spec["observation"]
        kwargs["observation"] = obs["C"] if isinstance(obs, dict) and set(obs) == {"C"} else obs
    if "start" in spec:
        start = spec["start"]
        if isinstance(start, dict) and set(start) - {"qpos", "qvel", "act"}:
            raise TaskError(
                f"[start] has unknown key(s) {sorted(set(start) - {'qpos', 'qvel', 'act'})}; it takes `qpos`, "
                "`qvel` and (on a model whose actuators have activation dynamics) `act`. "
                "In TOML, keys written after a [table] header belong to that table: put top-level keys "
                "such as `target` before the first [table]."
            )
        kwargs["x0"] = start
    if "target" in spec:
        kwargs["target"] = spec["target"]
    kwargs.update(cost)
    name = str(spec.get("name") or os.path.splitext(os.path.basename(default_name))[0])
    solver = spec.get("solver", {})
    if not isinstance(solver, dict):
        raise TaskError(f"[solver] must be a table of solver settings; got {solver!r}.")
    # The settings are checked where they are built (``default_config``), which names this table.
    model_path = resolve_model_path(str(spec["model"]), base_dir)  # or pkg://PACKAGE/PATH
    noise = spec.get("noise")
    if noise is not None and not isinstance(noise, dict):
        raise TaskError(f"[noise] must be a table with keys initial, process, measurement; got {noise!r}.")
    return Env.from_xml(model_path, name=name, solver_defaults=solver, noise=noise, **kwargs)


def _reject_constant(name: str) -> float:
    raise TaskError(f"The task file holds the non-finite number {name}; use finite numbers.")


def _check_finite(obj: Any, where: str) -> None:
    if isinstance(obj, float) and not math.isfinite(obj):
        raise TaskError(f"The task file holds a non-finite number at `{where or 'top level'}`; use finite numbers.")
    if isinstance(obj, dict):
        for k, v in obj.items():
            _check_finite(v, f"{where}.{k}" if where else str(k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            _check_finite(v, f"{where}[{i}]")
