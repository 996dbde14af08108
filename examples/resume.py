"""Checkpoint, stop, resume: the resumed solve equals the uninterrupted one.

    python examples/resume.py [--task cartpole-full] [--noise paper] [--stop 20] [--iterations 40]

Runs the task for --iterations straight; then for --stop iterations with a
checkpoint every 5 (and at the end) into a temporary folder; then resumes from
that folder to --iterations. Prints whether controls, gains and every history
agree bit for bit, the checkpoint's size and the time to write it.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

import podilqr_jax as pj
from podilqr_jax.ilqr.checkpoint import FILE


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="cartpole-full")
    parser.add_argument("--noise", default=None, help="`paper` for the paper's noise")
    parser.add_argument("--stop", type=int, default=20)
    parser.add_argument("--iterations", type=int, default=40)
    args = parser.parse_args()
    env = pj.make_task(args.task, noise=args.noise)
    cfg = pj.default_config(env, max_iterations=args.iterations)
    straight = pj.solve(env, cfg)
    with tempfile.TemporaryDirectory() as folder:
        first = pj.solve(env, cfg.replace(max_iterations=args.stop), checkpoint=folder, checkpoint_every=5)
        size = os.path.getsize(os.path.join(folder, FILE))
        t0 = time.perf_counter()
        resumed = pj.solve(env, cfg, resume=folder)
        resume_s = time.perf_counter() - t0
    same = all(
        np.array_equal(getattr(straight, n), getattr(resumed, n)) for n in ("controls", "K", "k", "states")
    ) and all(
        getattr(straight, n) == getattr(resumed, n)
        for n in ("cost_history", "true_cost_history", "mu_history", "alpha_history", "grad_norm_history")
    )
    print(
        f"{args.task} (noise {args.noise}): straight {straight.iterations} iterations, cost {straight.final_cost:.9g}"
    )
    print(
        f"stopped after {first.iterations}, resumed to {resumed.iterations} in {resume_s:.1f} s: cost "
        f"{resumed.final_cost:.9g}; identical bit for bit: {same}; checkpoint {size / 1024:.0f} KiB"
    )


if __name__ == "__main__":
    main()
