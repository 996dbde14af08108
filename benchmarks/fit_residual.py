"""The fit's relative residual against sigma, and the round-off floor the solver estimates.

About a swinging nominal (u = 0.3 sin(0.3 t)) of a task, 40 sysid rollouts
at each sigma, least squares with the rank cap; prints rho (RMS of the fit
residual over the RMS of the response, all steps) and the round-off estimate
that ``adapt_sigma`` compares it with (``sysid.fit_residual``, the numbers
the solver reads; ``identify.sigma.adapted_sigma``). Curvature makes rho grow like
sigma (like sigma^2 with ``--mirrored``), round-off like 1 / sigma.

    python benchmarks/fit_residual.py [TASK or task file] [--mirrored]   # default: dm_control's cart-pole
"""

import argparse
import os

import jax
import jax.numpy as jnp
import numpy as np

import podilqr_jax as pj
from podilqr_jax.identify.info_state import info_dim
from podilqr_jax.identify.sysid import excited_rank, fit_residual
from podilqr_jax.sim.rollout import open_loop_policy, perturbation_rollouts, rollout_batch
from podilqr_jax.task.taskfile import load_task

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT = os.path.join(HERE, os.pardir, "examples", "tasks", "third_party", "dmc_cartpole_swingup.toml")
SIGMAS = (1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("task", nargs="?", default=DEFAULT)
    p.add_argument("--mirrored", action="store_true")
    args = p.parse_args()
    env = load_task(args.task) if args.task.endswith((".toml", ".json")) else pj.make_task(args.task)
    q = pj.default_config(env).validate(env)
    dims, data = env.dims, env.data
    nZ = info_dim(dims.nz, dims.nu, q)
    u_bar = jnp.asarray(0.3 * np.sin(0.3 * np.arange(dims.horizon)))[:, None] * jnp.ones((1, dims.nu))
    zero = jnp.zeros((dims.horizon, dims.nu))
    nominal = rollout_batch(dims, q, data, open_loop_policy(u_bar, nZ), zero, zero, record_state=True)
    z_bar, u_nom = (jnp.zeros_like(nominal.z), jnp.zeros_like(nominal.u)) if args.mirrored else (nominal.z, nominal.u)
    print("| sigma | rho | round-off estimate | rho / estimate |\n|---|---|---|---|")
    for sigma in SIGMAS:
        traj = perturbation_rollouts(
            dims, q, 40, data, open_loop_policy(nominal.u, nZ), jax.random.PRNGKey(0), jnp.asarray(sigma),
            mirrored=args.mirrored,
        )  # fmt: skip
        _, report = pj.fit_information_model(
            traj.z, traj.u, z_bar, u_nom, q, jnp.asarray(1e-10), jnp.asarray(excited_rank(dims, q))
        )
        rho, floor = fit_residual(report, nominal.z)
        print(f"| {sigma:g} | {rho:.2g} | {floor:.2g} | {rho / floor:.3g} |")


if __name__ == "__main__":
    main()
