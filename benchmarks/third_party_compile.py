"""Where the compile time of a third-party model goes: integrator x constraint solver.

Compiles one control step (substeps = 5, ``rollout.physics_step``, which
takes RK4 steps through ``rk4.step``; the last row steps through ``mjx.step``
as before that change) of
dm_control's cartpole.xml and its ``jax.jacfwd`` (what the model-based
reference compiles) for variants of the model, one option changed at a time,
and prints a Markdown table (benchmarks/journal.md). Run it with the persistent
compilation cache off, so every compile is cold:

    PODILQR_CACHE=0 python benchmarks/third_party_compile.py
"""

import copy
import time

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

import podilqr_jax as pj
from podilqr_jax.sim.rollout import physics_step, with_state
from podilqr_jax.task.package_files import resolve_model_path

EULER = int(mujoco.mjtIntegrator.mjINT_EULER)


def variant(base, integrator=None, iterations=None, ls_iterations=None, no_limit=False):
    m = copy.deepcopy(base)
    if integrator is not None:
        m.opt.integrator = integrator
    if iterations is not None:
        m.opt.iterations, m.opt.ls_iterations = iterations, ls_iterations
    if no_limit:
        m.jnt_limited[:] = 0
    return m


def compile_seconds(model, mj_step=None) -> tuple[float, float]:
    env = pj.Env.from_model(model, substeps=5, horizon=2, name="cartpole")
    dims, data = env.dims, env.data

    def step(x, u):
        return physics_step(dims, data.model, with_state(dims, mjx.make_data(data.model), x), u, mj_step).qpos

    x, u = data.x0, jnp.zeros(dims.nu)
    t0 = time.perf_counter()
    jax.jit(step).lower(x, u).compile()
    t1 = time.perf_counter()
    jax.jit(jax.jacfwd(step, argnums=(0, 1))).lower(x, u).compile()
    return t1 - t0, time.perf_counter() - t1


def main() -> None:
    base = mujoco.MjModel.from_xml_path(resolve_model_path("pkg://dm_control/suite/cartpole.xml"))
    cases = [
        ("Euler, slider limit removed", variant(base, integrator=EULER, no_limit=True)),
        ("Euler, slider limit as shipped", variant(base, integrator=EULER)),
        ("RK4, slider limit removed", variant(base, no_limit=True)),
        ("RK4, limit, solver at 1 iteration / 1 line-search iteration", variant(base, iterations=1, ls_iterations=1)),
        ("RK4, limit, 100 / 50 iterations (as shipped)", variant(base)),
        ("RK4 as shipped, through `mjx.step` (before `rk4.step`)", variant(base), mjx.step),
    ]
    print("| cartpole.xml variant | step compile s | jacfwd compile s |\n|---|---|---|")
    for label, model, *mj_step in cases:
        step_s, jac_s = compile_seconds(model, *mj_step)
        print(f"| {label} | {step_s:.1f} | {jac_s:.1f} |", flush=True)


if __name__ == "__main__":
    main()
