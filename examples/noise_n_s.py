"""Fully observed cart-pole under the paper's noise, `feedback` variant: how the
final true cost approaches the optimum as the sysid rollouts n_s grow.

    python examples/noise_n_s.py            # ~4 min on 2 CPU cores

Prints, per n_s, the final true cost / model-based optimum for seeds 0 and 1 and
the mean over the last 50 iterations (docs/noise.md, "Does Theorem 1 hold?").
"""

import numpy as np

import podilqr_jax as pj

optimum = pj.solve_model_based(pj.make_task("cartpole-full")).final_cost
env = pj.make_task("cartpole-full", noise="paper")
for n_s in (40, 160, 640):
    final, tail = [], []
    for seed in range(2):
        r = pj.solve(env, pj.default_config(env, n_s=n_s, seed=seed))
        history = np.asarray(r.true_cost_history) / optimum
        final.append(history[-1])
        tail.append(history[-50:].mean())
    print(f"n_s={n_s:4d}  final {np.round(final, 5)}  mean of the last 50 iterations {np.round(tail, 5)}")
