"""Robots under the paper's noise: what each noise-aware default buys, one setting at a time.

    python benchmarks/noise_robots.py [--only cheetah,walker] [--iterations 150] [--out FILE]

Each task file is solved in its own process (`podilqr solve FILE --noise paper
--set restarts=1 --set max_iterations=N`, a cold start) under these settings:

- ``before``: what a task file got before the noise-aware defaults: sigma fixed
  at the noiseless default, one noisy rollout per line-search candidate
  (``adapt_sigma=false n_forward=1``);
- ``sigma``: sigma adapted to the fit's estimate of B's error (``n_forward=1``);
- ``defaults``: the defaults (sigma adapted, ``NOISY_N_FORWARD`` = 8 rollouts per candidate).

and, without noise, the model-based reference (``--compare``) for the
optimum. Per row: the policy's true cost (closed loop, noiseless) at the end,
its lowest and the median of the last 20 iterations, each over the
optimum; the last sigma, the median ``B err`` and the wall seconds. Writes
``benchmarks/results/noise/robots.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
TASKS = os.path.join(HERE, os.pardir, "examples", "tasks")
SUITE = {
    "cheetah": os.path.join(TASKS, "robots", "gym_half_cheetah_run.toml"),
    "walker": os.path.join(TASKS, "robots", "dmc_walker_knee.toml"),
    "hopper": os.path.join(TASKS, "third_party", "gym_hopper_balance.toml"),
    "pusher": os.path.join(TASKS, "robots", "gym_pusher_reach.toml"),
}
SETTINGS = {
    "before": ["adapt_sigma=false", "n_forward=1"],
    "sigma": ["n_forward=1"],
    "defaults": [],
}
OUT = os.path.join(HERE, "results", "noise", "robots.json")


def _solve(path: str, args: list[str], out: str) -> dict:
    cmd = [sys.executable, "-m", "podilqr_jax.cli", "solve", path, "--set", "restarts=1", *args]
    cmd += ["--no-plots", "--quiet", "--out", out]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0 or not os.path.exists(out):
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    with open(out) as f:
        return json.load(f) | {"command": " ".join(["podilqr", *cmd[3:-1], "FILE"])}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", default=",".join(SUITE))
    p.add_argument("--iterations", type=int, default=150)
    p.add_argument("--out", default=OUT)
    args = p.parse_args()
    rows = []
    print("| task | settings | final / optimum | lowest / optimum | last 20 / optimum | sigma | B err | wall s |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.only.split(","):
            path = SUITE[name]
            ref = _solve(path, ["--compare"], os.path.join(tmp, "clean.json"))
            optimum = min(float(ref["model_based_cost"]), float(ref["final_cost"]))
            rows.append(dict(task=name, settings="noiseless", pod_cost=ref["final_cost"],
                             model_based_cost=ref["model_based_cost"], optimum=optimum))  # fmt: skip
            for label, extra in SETTINGS.items():
                sets = [a for s in extra for a in ("--set", s)]
                noisy = ["--noise", "paper", "--set", f"max_iterations={args.iterations}", *sets]
                r = _solve(path, noisy, os.path.join(tmp, "noisy.json"))
                true = np.asarray(r["true_cost_history"], dtype=float)
                errors = np.asarray([np.nan if e is None else e for e in r["fit_error_history"]], dtype=float)
                row = dict(
                    task=name, settings=label, command=r["command"], optimum=optimum,
                    final=float(true[-1]) / optimum, lowest=float(true.min()) / optimum,
                    last20=float(np.median(true[-20:])) / optimum, sigma=float(r["sigma_history"][-1]),
                    b_err=float(np.nanmedian(errors)) if np.any(errors == errors) else float("nan"),
                    wall_s=float(r["wall_s"]), rejected=int(r["rejected_steps"]),
                )  # fmt: skip
                rows.append(row)
                print(f"| {name} | {label} | {row['final']:.3g} | {row['lowest']:.3g} | {row['last20']:.3g} "
                      f"| {row['sigma']:.2g} | {row['b_err']:.2g} | {row['wall_s']:.0f} |", flush=True)  # fmt: skip
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(dict(command=" ".join(["python", "benchmarks/noise_robots.py"] + sys.argv[1:]), rows=rows), f,
                  indent=1)  # fmt: skip
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
