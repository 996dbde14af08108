"""Errors raised before anything is traced.

Every message says what was expected, what was given and how to fix it; the
CLI prints the message as one paragraph and exits non-zero.
"""

from __future__ import annotations


class PodIlqrError(ValueError):
    """Base class of every input error of podilqr_jax."""


class TaskError(PodIlqrError):
    """A task (model, observation, cost, start or target) is malformed."""


class ModelLoadError(TaskError):
    """MuJoCo or MJX could not load the model."""


class ConfigError(PodIlqrError):
    """A solver setting is out of range or inconsistent with the task."""
