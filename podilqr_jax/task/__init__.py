"""The task: a MuJoCo model with its observation, cost, start, target and control box;
the bundled tasks and task files; the noise model and the one noise realisation
(``Disturbance``) every rollout takes."""
