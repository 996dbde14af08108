"""Are the learnt gains as good as the exact ones? Closed-loop cost under actuator noise.

    python benchmarks/feedback_gains.py [TASK] [HORIZON]     (default pendulum-partial 10)

Solves TASK with POD-iLQR at the task's sigma, with variant=feedback, and at
sigma/100, and the model-based reference; then runs 64 episodes per PRNG key
(1-5) at actuator noise 0.05, 0.1, 0.2 x max|u| of the model-based policy
(exact full-state gains), its nominal open loop, and each learnt policy
(information-state feedback). Prints |K_0|, |K_1| of each solve and one row
of mean costs per key. tests/test_evaluate.py quotes its output.
"""

import sys

import jax
import jax.numpy as jnp
import numpy as np

import podilqr_jax as pj
from podilqr_jax.control.episodes import EpisodeNoise, run_episodes


def main() -> None:
    task = sys.argv[1] if len(sys.argv) > 1 else "pendulum-partial"
    horizon = int(sys.argv[2]) if len(sys.argv) > 2 else 10
    env = pj.make_task(task, horizon=horizon)
    nx, nz, nu = env.dims.nx, env.dims.nz, env.dims.nu

    def actuator_noise(std):
        free = jnp.full(nu, np.inf)
        return EpisodeNoise(jnp.zeros(nx), jnp.zeros(nx), jnp.zeros(nz), jnp.full(nu, std), -free, free)

    reference = pj.solve_model_based(env)
    exact = pj.FeedbackPolicy.from_result(reference)
    sigma = pj.default_config(env).sigma
    settings = {"default": {}, "feedback": {"variant": "feedback"}, "sigma/100": {"sigma": sigma / 100}}
    learnt = {}
    for name, overrides in settings.items():
        r = pj.solve(env, pj.default_config(env, max_iterations=40, **overrides))
        learnt[name] = r.policy()
        print(
            f"{name:9s}: {r.status}, cost / optimum {r.final_cost / reference.final_cost:.12f}, "
            f"sigma {r.config['sigma']:g}, |K_0| {np.linalg.norm(r.K[0]):.3g}, |K_1| {np.linalg.norm(r.K[1]):.3g}",
            flush=True,
        )
    u_max = np.max(np.abs(reference.controls))
    print(f"optimum {reference.final_cost:.6g}; mean cost of 64 episodes")
    print("| noise | key | model-based | its open loop | " + " | ".join(f"learnt, {n}" for n in learnt) + " |")
    print("|---" * (4 + len(learnt)) + "|")
    for eps in (0.05, 0.1, 0.2):
        levels = actuator_noise(eps * u_max)
        for seed in range(1, 6):
            key = jax.random.PRNGKey(seed)
            policies = [exact, exact.open_loop(), *learnt.values()]
            costs = [float(np.mean(run_episodes(env.dims, env.data, p, key, levels, 64).cost)) for p in policies]
            print(f"| {eps} | {seed} | " + " | ".join(f"{c:.2f}" for c in costs) + " |", flush=True)


if __name__ == "__main__":
    main()
