"""Library use: swing up the partially observed cart-pole and compare with the
model-based optimum.

    python examples/swingup.py [TASK]
"""

import sys

import podilqr_jax as pj
from podilqr_jax.viz.plots import plot_convergence, plot_trajectory

task = sys.argv[1] if len(sys.argv) > 1 else "cartpole-partial"
env = pj.make_task(task)
cfg = pj.default_config(env)  # the task's sigma and n_s; override with keywords


def report(info: pj.IterationInfo) -> None:
    if info.iteration % 25 == 0:
        print(f"  iteration {info.iteration:3d}: cost {info.cost:.6g}, alpha {info.alpha:.3g}")


result = pj.solve(env, cfg, callback=report)
print(result.summary())
reference = pj.solve_model_based(env, cfg)
print(reference.summary())
print(f"cost ratio POD-iLQR / model-based: {result.final_cost / reference.final_cost:.6f}")
plot_convergence([result, reference], f"{task}_cost.png")
plot_trajectory(result, f"{task}_trajectory.png")
print(f"wrote {task}_cost.png and {task}_trajectory.png")
