"""iLQR: cost, backward pass, line search, settings, the driver (init / step / terminate)
and its stopping rules, state, result and checkpoints."""

from .. import _runtime  # noqa: E402,F401  (JAX set up before anything here traces)
