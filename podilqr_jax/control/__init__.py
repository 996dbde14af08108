"""Control: a finished solve as a controller, its Monte Carlo episodes, the Kalman estimator,
receding-horizon replanning."""

from .. import _runtime  # noqa: E402,F401  (JAX set up before anything here traces)
