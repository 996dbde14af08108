"""The learnt controller, measured: closed-loop cost of POD-iLQR's policy over the model-based one.

    python benchmarks/controller_quality.py [--tasks pendulum-full,...] [--set mirrored=true ...]

For each task: solve with POD-iLQR (defaults, plus any ``--set``) and with the
model-based reference, then run the same 128 episodes (PRNG key 1) of both
policies under small noise:

- fully observed tasks: actuator noise of 5% of the reference's max |u|;
- partially observed tasks: process noise 2e-3 on every state coordinate with
  exact measurements (the information state is then exact).

Prints the mean cost of each policy and their ratio (docs/results.md's
controller column), the nominal costs' ratio, and max_t ||K_t|| / ||K_t^exact||
over the first steps. The model-based policy feeds back the full state; the
learnt one its information state.
"""

from __future__ import annotations

import argparse
import json

import jax
import jax.numpy as jnp
import numpy as np

import podilqr_jax as pj
from podilqr_jax.control.episodes import EpisodeNoise, run_episodes

TASKS = ("pendulum-full", "pendulum-partial", "cartpole-full", "cartpole-partial")
EPISODES = 128


def small_noise(env, reference) -> EpisodeNoise:
    nx, nz, nu = env.dims.nx, env.dims.nz, env.dims.nu
    zeros = jnp.zeros
    low, high = env.data.u_low, env.data.u_high
    if env.fully_observed:
        a = 0.05 * float(np.max(np.abs(reference.controls)))
        return EpisodeNoise(zeros(nx), zeros(nx), zeros(nz), jnp.full(nu, a), low, high)
    return EpisodeNoise(zeros(nx), jnp.full(nx, 2e-3), zeros(nz), zeros(nu), low, high)


def measure(env, cfg) -> dict:
    reference = pj.solve_model_based(env)
    learnt = pj.solve(env, cfg)
    levels = small_noise(env, reference)
    key = jax.random.PRNGKey(1)
    exact_policy = pj.FeedbackPolicy.from_result(reference)
    costs = []
    for policy in (exact_policy, learnt.policy()):
        measured = env.dims.nx if policy.measures == "state" else env.dims.nz
        costs.append(
            float(
                np.mean(
                    run_episodes(env.dims, env.data, policy, key, levels._replace(v=jnp.zeros(measured)), EPISODES).cost
                )
            )
        )
    return dict(
        task=env.name,
        nominal_ratio=learnt.final_cost / reference.final_cost,
        closed_loop_exact=costs[0],
        closed_loop_learnt=costs[1],
        controller_ratio=costs[1] / costs[0],
        status=learnt.status.value,
        K_norms=[float(np.linalg.norm(k)) for k in np.asarray(learnt.K)[:4]],
        K_exact=[float(np.linalg.norm(k)) for k in np.asarray(reference.K)[:4]],
    )


def _value(raw: str):
    try:
        return json.loads(raw)
    except json.JSONDecodeError:
        return raw  # a word such as variant=feedback


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", default=",".join(TASKS))
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    a = p.parse_args(argv)
    overrides = {k: _value(v) for k, _, v in (item.partition("=") for item in a.set)}
    print(
        "| task | settings | nominal / model-based | closed loop: learnt / model-based | learnt | model-based "
        "| ||K_0..3|| learnt | exact |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name in a.tasks.split(","):
        env = pj.make_task(name)
        r = measure(env, pj.default_config(env, **overrides))
        ks = ", ".join(f"{k:.3g}" for k in r["K_norms"])
        ke = ", ".join(f"{k:.3g}" for k in r["K_exact"])
        print(
            f"| {name} | {' '.join(a.set) or 'defaults'} | {r['nominal_ratio']:.7f} | {r['controller_ratio']:.4f} | "
            f"{r['closed_loop_learnt']:.4g} | {r['closed_loop_exact']:.4g} | {ks} | {ke} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
