"""How close are POD-iLQR's learnt gains to the true LQR law on a noisy linear system?

    python benchmarks/lq_gains.py [--n-s 100,400] [--seeds 0,1,2]

The system is the test suite's MuJoCo mass on a spring (tests/test_policy.py:
slide joint, Euler, exactly linear), with start deviation std 0.05 and
process noise std 1e-3, fully observed (q = 1), sysid sigma = 1, the
feedback variant. For least squares ("ols") and instrumental variables
("iv") it prints the largest gain error relative to the largest true LQR
gain, max_t |K_t - K_t^LQR| / max |K^LQR|, per n_s and seed.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

import podilqr_jax as pj

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))

from test_policy import HORIZON, lqr_gains, spring_env, true_linear_system  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n-s", default="100,400")
    parser.add_argument("--seeds", default="0,1,2")
    args = parser.parse_args()
    K_true = lqr_gains(*true_linear_system(), HORIZON)
    for estimator in ("ols", "iv"):
        for n_s in (int(v) for v in args.n_s.split(",")):
            errors = []
            for seed in (int(v) for v in args.seeds.split(",")):
                env = spring_env(noise={"initial": 0.05, "process": 1e-3})
                cfg = pj.default_config(
                    env, q=1, n_s=n_s, sigma=1.0, variant="feedback", estimator=estimator, max_iterations=4, seed=seed
                )
                K = pj.solve(env, cfg).K
                errors.append(np.max(np.abs(K - K_true)) / np.max(np.abs(K_true)))
            print(f"{estimator:3s} n_s={n_s:4d}: gain error " + ", ".join(f"{e:.4f}" for e in errors))


if __name__ == "__main__":
    main()
