"""The task: a MuJoCo model with its observation, cost, start, target and control box;
the bundled tasks and task files; the noise model and the one noise realisation
(``Disturbance``) every rollout takes."""

from .. import _runtime  # noqa: E402,F401  (JAX set up before anything here traces)
