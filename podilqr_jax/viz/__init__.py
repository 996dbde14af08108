"""Plots and animations of a solve."""

from .. import _runtime  # noqa: E402,F401  (JAX set up before anything here traces)
