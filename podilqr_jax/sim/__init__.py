"""Simulation and compilation: the one rollout engine (``rollout.run``), batched and
sharded through MJX or run on MuJoCo's C engine; MuJoCo's RK4; traced stages on disk, XLA
options and the compilation cache."""

from .. import _runtime  # noqa: E402,F401  (JAX set up before anything here traces)
