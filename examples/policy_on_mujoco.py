"""Run a learnt policy step by step on plain MuJoCo (no MJX), with noisy sensors.

    python examples/policy_on_mujoco.py [--task pendulum-partial] [--noise 0.1] [--episodes 20]

Solves the task with POD-iLQR, then drives ``mujoco.MjData`` (the C
simulator) from Python: at every control step the policy gets the noisy
measurement z = C x + v, returns u = u_bar + K (Z - Z_bar), and the actuator
adds noise. Prints the mean cost of the closed loop and of the nominal
controls replayed open loop over the same noise, and the compilations seen
after the first episode (none: the step functions compile once).
"""

from __future__ import annotations

import argparse

import mujoco
import numpy as np

import podilqr_jax as pj
from podilqr_jax.compilation.compile_watch import CompileWatch


def episode(env, policy, rng, actuator_std, measurement_std, feedback=True):
    model = env.mj_model
    data = mujoco.MjData(model)
    nq = env.dims.nq
    x0 = np.asarray(env.data.x0)
    data.qpos[:], data.qvel[:] = x0[:nq], x0[nq:]
    C = np.asarray(env.data.C)
    substeps = env.dims.substeps

    def measure():
        x = np.concatenate([data.qpos, data.qvel])
        return x, C @ x + measurement_std * rng.standard_normal(C.shape[0])

    x, z = measure()
    state = policy.reset(z)
    u_bar = np.asarray(policy.controller.u_bar)
    zs, us = [C @ x], []
    for t in range(policy.horizon):
        u = np.asarray(policy.act(state)) if feedback else u_bar[t]
        data.ctrl[:] = u + actuator_std * rng.standard_normal(u.shape)
        for _ in range(substeps):
            mujoco.mj_step(model, data)
        x, z = measure()
        if t + 1 < policy.horizon:
            state = policy.update(state, u, z)
        zs.append(C @ x)
        us.append(u)
    e, u = np.stack(zs) - np.asarray(env.data.z_target), np.stack(us)
    Q, QT, R = (np.asarray(m) for m in (env.data.Q, env.data.QT, env.data.R))
    return float(np.einsum("ti,ij,tj->", e[:-1], Q, e[:-1]) + np.einsum("ti,ij,tj->", u, R, u) + e[-1] @ QT @ e[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="pendulum-partial")
    parser.add_argument("--noise", type=float, default=0.1, help="actuator noise std / max control")
    parser.add_argument("--episodes", type=int, default=20)
    args = parser.parse_args()

    env = pj.make_task(args.task)
    result = pj.solve(env)
    print(result.summary())
    policy = result.policy()
    print(policy)
    u_max = float(np.max(np.abs(result.controls)))
    obs_range = np.ptp(result.observations, axis=0)
    actuator_std, measurement_std = args.noise * u_max, 0.1 * args.noise * obs_range
    costs = {"closed_loop": [], "open_loop": []}
    watch = CompileWatch()
    for name, feedback in (("closed_loop", True), ("open_loop", False)):
        rng = np.random.default_rng(0)  # the same noise for both
        for i in range(args.episodes):
            if i == 1 and feedback:
                watch.__enter__()  # count from the second closed-loop episode on
            costs[name].append(episode(env, policy, rng, actuator_std, measurement_std, feedback))
    watch.__exit__()
    for name, c in costs.items():
        print(f"{name:12s} mean cost {np.mean(c):10.4g}  (nominal {result.final_cost:.4g}, {args.episodes} episodes)")
    print(f"{watch.compiles} compilations after the first episode ({policy.horizon * (2 * args.episodes - 1)} steps)")


if __name__ == "__main__":
    main()
