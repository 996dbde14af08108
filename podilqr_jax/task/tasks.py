"""Bundled swing-up tasks: pendulum, cart-pole and a two-motor double pendulum,
fully and partially observed.

| task                    | observation                 | q | Q                   | QT     | R   |
|-------------------------|-----------------------------|---|---------------------|--------|-----|
| pendulum-full           | angle, angular rate         | 1 | diag(1, 0.1)        | 100 I  | 2   |
| pendulum-partial        | angle                       | 2 | 1                   | 100    | 2   |
| cartpole-full           | cart x, angle, both rates   | 1 | 0.1 I               | 5000 I | 1   |
| cartpole-partial        | cart x, pole angle          | 2 | 0.1 I               | 5000 I | 1   |
| doublependulum-full     | both angles, both rates     | 1 | diag(1, 1, .1, .1)  | 1000 I | 0.1 |
| doublependulum-partial  | both angles (jointpos       | 2 | I                   | 1000 I | 0.1 |
|                         | sensors, by name)           |   |                     |        |     |

Control steps of 0.1 s over a horizon of 30 (double pendulum: 20, see
docs/tasks.md); start hanging at rest (angle pi), target upright at rest
(angles 0, cart at 0). The double pendulum's motors are torque limited
(ctrlrange +-7 and +-1.8 N m), active on its optimal swing-up. Costs and
sysid settings of the pendulum and cart-pole follow the POD-iLQR authors'
reference settings (see docs/tasks.md).

``make_task(name, noise="paper")`` gives the paper's noisy system (Section VI):
initial-state deviation s0 = 0.01, process noise 10% of s0 and, under partial
observation, measurement noise 10% of s0; it also switches the task's solver
defaults to settings measured to work under that noise (docs/noise.md).
"""

from __future__ import annotations

import math
import os
from typing import Any

from ..errors import TaskError
from .env import Env
from .noise import NoiseModel

MODELS_DIR = os.path.join(os.path.dirname(__file__), "models")

_SYSTEMS: dict[str, dict[str, Any]] = {
    "pendulum": dict(
        xml="pendulum.xml",
        substeps=5,
        x0={"qpos": [math.pi], "qvel": [0.0]},
        R=2.0,
        observations={
            "full": dict(observation="full", target=[0.0, 0.0], Q=[1.0, 0.1], QT=100.0),
            "partial": dict(observation={"qpos": ["hinge"]}, target=[0.0], Q=1.0, QT=100.0),
        },
        solver=dict(sigma=1e-5, n_s=40),
        noisy_solver={
            "full": dict(sigma=1e-2, n_s=40, variant="feedback", max_iterations=100, adapt_sigma=False, n_forward=1),
            "partial": dict(sigma=1e-1, n_s=40, variant="averaged", max_iterations=100, adapt_sigma=False),
        },
    ),
    "cartpole": dict(
        xml="cartpole.xml",
        substeps=10,
        x0={"qpos": [0.0, math.pi], "qvel": [0.0, 0.0]},
        R=1.0,
        observations={
            "full": dict(observation="full", target=[0.0] * 4, Q=0.1, QT=5000.0),
            "partial": dict(observation={"qpos": ["slider", "hinge"]}, target=[0.0, 0.0], Q=0.1, QT=5000.0),
        },
        solver=dict(sigma=1e-2, n_s=40),
        noisy_solver={
            "full": dict(sigma=1e-1, n_s=40, variant="feedback", max_iterations=200, adapt_sigma=False, n_forward=1),
            "partial": dict(sigma=1.0, n_s=40, variant="averaged", max_iterations=200, adapt_sigma=False),
        },
    ),
    "doublependulum": dict(
        xml="double_pendulum.xml",
        substeps=10,
        horizon=20,  # at 30 the balancing tail needs sigma ~ 1e-11 (docs/tasks.md)
        x0={"qpos": [math.pi, 0.0], "qvel": [0.0, 0.0]},
        R=0.1,
        observations={
            "full": dict(observation="full", target=[0.0] * 4, Q=[1.0, 1.0, 0.1, 0.1], QT=1000.0),
            "partial": dict(
                observation={"sensors": ["shoulder_pos", "elbow_pos"]}, target=[0.0, 0.0], Q=1.0, QT=1000.0
            ),
        },
        solver=dict(sigma=1e-7, n_s=40),
    ),
}

TASKS = tuple(f"{system}-{obs}" for system, spec in _SYSTEMS.items() for obs in spec["observations"])


PAPER_S0 = 0.01


def make_task(name: str, *, horizon: int | None = None, noise: Any = None) -> Env:
    """A bundled task by name, e.g. ``"cartpole-partial"`` (see ``TASKS``), or
    the task file at a path ending in ``.toml`` or ``.json`` (docs/task_files.md).

    ``horizon``: control steps (default: the task's; 30 or 20 for the bundled ones).
    ``noise``: None (deterministic), ``"paper"`` (the paper's noise for this
    observation, see the module docstring), a :class:`NoiseModel` or a mapping
    of its fields. With noise the task's solver defaults are its noisy ones
    (the double pendulum has none measured: it keeps its noiseless ones).
    """
    if str(name).endswith((".toml", ".json")):  # a task file (docs/task_files.md)
        from .taskfile import load_task

        env = load_task(name)
        if horizon is not None:
            env = env.replace(horizon=horizon)
        return env if noise is None else env.replace(noise=_noise_model(noise, partial=not env.fully_observed))
    system, _, obs = name.partition("-")
    if system not in _SYSTEMS or obs not in _SYSTEMS[system]["observations"]:
        raise TaskError(
            f"Unknown task {name!r}. Bundled tasks: {', '.join(TASKS)}; or give the path "
            "of a task file (.toml or .json, see docs/task_files.md)."
        )
    spec = _SYSTEMS[system]
    noise = _noise_model(noise, partial=obs == "partial")
    return Env.from_xml(
        os.path.join(MODELS_DIR, spec["xml"]),
        substeps=spec["substeps"],
        horizon=spec.get("horizon", 30) if horizon is None else horizon,
        x0=spec["x0"],
        R=spec["R"],
        name=name,
        solver_defaults=spec["solver"] if noise.is_zero else spec.get("noisy_solver", {}).get(obs, spec["solver"]),
        noise=noise,
        **spec["observations"][obs],
    )


def _noise_model(noise: Any, partial: bool) -> NoiseModel:
    """``make_task``'s ``noise``: ``"paper"`` (measurement noise only where the
    task observes part of its state), a :class:`NoiseModel`, a mapping or None."""
    if isinstance(noise, str):
        if noise != "paper":
            raise TaskError(f"Unknown noise preset {noise!r}; use 'paper', a NoiseModel or a mapping.")
        return NoiseModel.paper(PAPER_S0, partial=partial)
    return NoiseModel.from_any(noise)
