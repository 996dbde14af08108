"""A task named on a command line: a bundled task by name or a task file by
path, with the ``--noise`` text of the ``podilqr`` commands applied to it."""

from __future__ import annotations

import os
from typing import Any, Optional

from ..errors import TaskError
from .noise import NoiseModel
from .taskfile import load_task
from .tasks import PAPER_S0, make_task


def load_env(task: str, noise: Optional[str] = None):
    """A bundled task by name, or a task file by path; ``noise`` as --noise."""
    is_file = task.endswith((".toml", ".json")) or os.path.sep in task
    env = load_task(task) if is_file else make_task(task)
    if noise is None:
        return env
    spec = noise_model(noise, env)
    if not is_file:  # a bundled task: its noisy solver defaults come with the noise
        return make_task(task, noise=spec)
    return env.replace(noise=spec)


def noise_model(text: str, env) -> NoiseModel:
    """The noise of a --noise text for ``env``: ``paper`` (the paper's levels,
    measurement noise only where ``env`` observes part of its state), ``none``
    or initial=S0,process=SW,measurement=SV."""
    spec = _parse_noise(text)
    return NoiseModel.paper(PAPER_S0, partial=not env.fully_observed) if spec == "paper" else spec


def _parse_noise(text: str):
    text = text.strip()
    if text in ("paper", "none"):
        return "paper" if text == "paper" else NoiseModel()
    fields: dict[str, Any] = {}
    for item in text.split(","):
        key, _, raw = item.partition("=")
        try:
            fields[key.strip()] = float(raw)
        except ValueError:  # also a missing `=`: float("") fails
            raise TaskError(
                f"--noise expects `paper`, `none` or initial=S0,process=SW,measurement=SV (numbers); got {text!r}."
            ) from None
    return NoiseModel.from_any(fields)
