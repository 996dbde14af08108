"""Fully observed cart-pole under the paper's noise, `feedback` variant: how the
final true cost approaches the optimum as the sysid rollouts n_s grow.

    python benchmarks/noise_n_s.py                     # ~4 min on 2 CPU cores
    python benchmarks/noise_n_s.py --estimator iv      # the same with instrumental variables

Prints, per n_s, the final true cost / model-based optimum for seeds 0 and 1 and
the mean over the last 50 iterations (docs/noise.md, "Does Theorem 1 hold?").
"""

import argparse

import numpy as np

import podilqr_jax as pj

parser = argparse.ArgumentParser()
parser.add_argument("--estimator", default="ols", choices=pj.ESTIMATORS)
parser.add_argument("--n-s", default="40,160,640", help="comma-separated n_s values")
args = parser.parse_args()
optimum = pj.solve_model_based(pj.make_task("cartpole-full")).final_cost
env = pj.make_task("cartpole-full", noise="paper")
for n_s in (int(v) for v in args.n_s.split(",")):
    final, tail = [], []
    for seed in range(2):
        r = pj.solve(env, pj.default_config(env, n_s=n_s, seed=seed, estimator=args.estimator))
        history = np.asarray(r.true_cost_history) / optimum
        final.append(history[-1])
        tail.append(history[-50:].mean())
    print(f"{args.estimator} n_s={n_s:4d}  final {np.round(final, 5)}  mean of the last 50 {np.round(tail, 5)}")
