"""What the paper's noise does to the fit on a robot: the identified (A_t, B_t) against the exact linearisation.

    python benchmarks/noise_fit.py [TASK FILE] [--sigmas 1e-4,1e-3,1e-2,1e-1] [--n-s 48,192,768] [--seeds 3]

About the noiseless solve's policy (``pj.solve`` of the task, one start, its
nominal controls and gains), under the task's noise (default: the paper's),
each cell runs the solver's own sysid batch (``perturbation_rollouts``, with
the policy's feedback as the ``feedback`` variant does) and fits it by least
squares (``fit_information_model``) in two ways:

- ``nominal``: deviations from one noisy rollout of the policy, as the solver
  measures its nominal (``plain`` and ``feedback`` on a noisy task);
- ``centred``: deviations from the batch's own mean, i.e. the same fit with an
  intercept, which takes up the nominal's noise;

Per cell (medians over the seeds) it prints what the noise does to B: the
relative error (Frobenius, all steps) of each noisy fit against the fit of
the same perturbations without noise; the fit's own estimate of that error
(``quality.b_error``, what the solver reports as ``B err``); the signal-to-noise
of the excitation, the RMS one-step response of the state to the
perturbations (exact B times sigma) over the RMS one-step process noise; and
the centred fit's errors against the exact linearisation of the engine's step
(central differences), which on a contact model also hold the curvature that
a sigma-sized perturbation averages over. Writes
``benchmarks/results/noise/noise_fit.json`` (the figures, with the command).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import podilqr_jax as pj
from podilqr_jax.identify.identification import actuator_units
from podilqr_jax.identify.model_based import linearise
from podilqr_jax.identify.quality import b_error
from podilqr_jax.sim import engines
from podilqr_jax.sim.rollout import Policy, perturbation_rollouts, rollout_batch

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT = os.path.join(HERE, os.pardir, "examples", "tasks", "robots", "dmc_walker_knee.toml")
OUT = os.path.join(HERE, "results", "noise", "noise_fit.json")


def _rel(err, ref) -> float:
    return float(np.linalg.norm(np.asarray(err)) / np.linalg.norm(np.asarray(ref)))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("task", nargs="?", default=DEFAULT)
    p.add_argument("--sigmas", default="1e-4,1e-3,1e-2,1e-1")
    p.add_argument("--n-s", default="48,192,768")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--out", default=OUT)
    args = p.parse_args()
    t_start = time.perf_counter()
    clean = pj.make_task(args.task)
    noisy = pj.make_task(args.task, noise="paper")
    if not clean.fully_observed:
        sys.exit("noise_fit.py compares with the state's linearisation: give a fully observed task.")
    result = pj.solve(clean, pj.default_config(clean, restarts=1))
    env = engines.on_engine(noisy, engines.resolve("auto", noisy))
    dims, data, q = env.dims, env.data, 1
    u_bar, K = jnp.asarray(result.controls), jnp.asarray(result.K)
    zero = jnp.zeros_like(u_bar)
    clean_data = engines.on_engine(clean, engines.resolve("auto", clean)).data
    x_clean = rollout_batch(dims, q, clean_data,
                            Policy(u_bar, jnp.zeros((dims.horizon, dims.nz)), jnp.zeros_like(K)),
                            zero, zero, record_state=True)  # fmt: skip
    exact = linearise(dims, data, x_clean.x, u_bar, "differences")
    units = jnp.asarray(actuator_units(noisy, pj.default_config(noisy)))
    sw = float(noisy.noise.process)
    rows = []
    print(f"{noisy.name}: noiseless cost {result.final_cost:.4g}; noise {noisy.noise}")
    print("| sigma | n_s | signal/noise | B err, nominal | B err, centred | B err estimate | B vs exact | A vs exact |")
    print("|---|---|---|---|---|---|---|---|")
    policy = Policy(u_bar, x_clean.z[:-1], K)
    for sigma in (float(s) for s in args.sigmas.split(",")):
        sigma_t = sigma * units
        response = np.sqrt(np.mean(np.sum((np.asarray(exact.B) * np.asarray(sigma_t)) ** 2, axis=(1, 2))))
        snr = response / (sw * np.sqrt(dims.ndx)) if sw > 0 else np.inf
        for n_s in (int(v) for v in args.n_s.split(",")):
            cells = {k: [] for k in ("Bn", "Bc", "quality", "B_exact", "A_exact")}
            for seed in range(args.seeds):
                key = jax.random.PRNGKey(seed)
                # the solver's nominal under noise: one noisy rollout of the policy
                measured = perturbation_rollouts(dims, q, 1, data, policy, jax.random.fold_in(key, 7), 0.0 * sigma_t,
                                                 noisy=True)  # fmt: skip
                traj = perturbation_rollouts(dims, q, n_s, data, policy, key, sigma_t, noisy=True)
                # the same perturbations without noise: what the fit would read at this sigma and n_s
                ref = perturbation_rollouts(dims, q, n_s, clean_data, policy, key, sigma_t)
                B_ref = pj.fit_information_model(ref.z, ref.u, x_clean.z, u_bar, q, jnp.asarray(1e-10))[0].B
                for tag, (zb, ub) in {"n": (measured.z[0], measured.u[0]),
                                      "c": (traj.z.mean(axis=0), traj.u.mean(axis=0))}.items():  # fmt: skip
                    model, report = pj.fit_information_model(traj.z, traj.u, zb, ub, q, jnp.asarray(1e-10))
                    cells["B" + tag].append(_rel(model.B - B_ref, B_ref))
                    if tag == "c":
                        cells["quality"].append(b_error(model, report, np.asarray(sigma_t), n_s, q))
                        cells["B_exact"].append(_rel(model.B - exact.B, exact.B))
                        cells["A_exact"].append(_rel(model.A - exact.A, exact.A))
            med = {k: float(np.median(v)) for k, v in cells.items()}
            rows.append(dict(sigma=sigma, n_s=n_s, snr=float(snr), **med))
            print(f"| {sigma:g} | {n_s} | {snr:.3g} | {med['Bn']:.3g} | {med['Bc']:.3g} | {med['quality']:.3g} "
                  f"| {med['B_exact']:.3g} | {med['A_exact']:.3g} |")  # fmt: skip
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(dict(command=" ".join(["python", "benchmarks/noise_fit.py"] + sys.argv[1:]), task=noisy.name,
                       noise=str(noisy.noise), seeds=args.seeds, rows=rows,
                       seconds=time.perf_counter() - t_start), f, indent=1)  # fmt: skip
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
