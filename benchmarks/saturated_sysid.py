"""Why closed-loop identification needs no feedback on saturated controls.

Solves dm_control's cart-pole swing-up (examples/tasks/third_party/
dmc_cartpole_swingup.toml) with the closed-loop identification keeping its
gains on controls that sit on their +-1 bound (``saturated_open_loop=False``,
no recovery), until no step lowers the cost; then, about that stuck nominal,
identifies twice, with the gains as they are and with the rows of saturated
controls zeroed (the default), and prints per step: where the nominal is
saturated, the rank the fit kept, the share of rollouts whose applied control
moved at all, and what a short step of each model's backward pass does to the
true cost against what the model predicted.

    python benchmarks/saturated_sysid.py          # about 1 min on 2 cores
"""

import os
import tempfile

import jax.numpy as jnp
import numpy as np

import podilqr_jax as pj
from podilqr_jax.identify.identification import _unsaturated_gains
from podilqr_jax.identify.info_state import observation_selector
from podilqr_jax.identify.sysid import excited_rank, fit_information_model
from podilqr_jax.ilqr.backward import QuadraticCost, Regularisation, backward_pass
from podilqr_jax.ilqr.checkpoint import fingerprint, load_checkpoint
from podilqr_jax.ilqr.line_search import Candidates, Search, Step, line_search
from podilqr_jax.sim.rollout import Policy, perturbation_rollouts
from podilqr_jax.task.taskfile import load_task

HERE = os.path.dirname(os.path.abspath(__file__))
TASK = os.path.join(HERE, os.pardir, "examples", "tasks", "third_party", "dmc_cartpole_swingup.toml")


def main() -> None:
    env = load_task(TASK)
    # MJX: the rollouts below are MJX batches of the same model (auto would take the native engine for RK4)
    cfg = pj.default_config(
        env, engine="mjx", saturated_open_loop=False, escalate=False, reidentify=0, adapt_sigma=False
    )
    with tempfile.TemporaryDirectory() as ck:
        stuck = pj.solve(env, cfg, checkpoint=ck, checkpoint_every=1000)
        print(f"with feedback on saturated controls: {stuck.status} at cost {stuck.final_cost:.4f}")
        q = cfg.validate(env)
        st = load_checkpoint(ck, fingerprint("pod-ilqr", env, env.dims, cfg), jnp.asarray)
    dims, data, nom = env.dims, env.data, st.nominal
    u = np.asarray(nom.u_bar)[:, 0]
    print("t (tens)          " + "".join(str(t // 10) for t in range(dims.horizon)))
    print("saturated         " + "".join("S" if abs(x) >= 1.0 else "." for x in u))
    cost = QuadraticCost(
        observation_selector(dims.nz, dims.nu, q),
        data.z_target,
        data.Q,
        data.QT,
        data.R,
        data.goal_step,
        data.u_low,
        data.u_high,
    )
    reg = Regularisation(jnp.asarray(cfg.mu_min), jnp.asarray(cfg.mu_max), jnp.asarray(cfg.mu_factor))
    alphas = jnp.asarray(0.5 ** np.arange(cfg.n_alphas))
    for label, gains in (
        ("gains as they are", st.gains),
        ("saturated rows 0 ", _unsaturated_gains(st.gains, nom.u_bar, data.u_low, data.u_high)),
    ):
        policy = Policy(nom.u_bar, nom.Z_bar[:-1], gains)
        traj = perturbation_rollouts(dims, q, cfg.n_s, data, policy, st.key, jnp.asarray(cfg.sigma))
        model, report = fit_information_model(
            traj.z, traj.u, nom.z_bar, nom.u_bar, q, jnp.asarray(cfg.rcond), jnp.asarray(excited_rank(dims, q))
        )
        moved = (np.abs(np.asarray(traj.u)[:, :, 0] - u[None]) > 0).mean(axis=0)
        print(f"{label}: rank  " + "".join(str(int(r)) for r in np.asarray(report.rank)))
        print(f"{label}: moved " + "".join(str(min(9, int(10 * m))) for m in moved) + "   (tenths of the rollouts)")
        back = backward_pass(model, nom.Z_bar, nom.u_bar, cost, jnp.asarray(cfg.mu_min), reg)
        ls = line_search(
            Search(dims, q),
            data,
            Policy(nom.u_bar, nom.Z_bar[:-1], back.K),
            Step(back.k, jnp.asarray(nom.cost), back.dV1, back.dV2),
            Candidates(alphas, jnp.asarray(cfg.accept_ratio)),
            st.ls_key,
        )
        i = cfg.n_alphas - 1
        change = float(np.asarray(ls.costs)[i]) - nom.cost
        print(
            f"{label}: alpha = {float(alphas[i]):.3g}: predicted decrease {float(np.asarray(ls.expected)[i]):.3g}, "
            f"measured change {change:+.3g}"
        )


if __name__ == "__main__":
    main()
