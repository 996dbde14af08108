"""Serial reference: POD-iLQR in plain NumPy on native MuJoCo, one rollout at a time.

    python -m podilqr_jax.studies.bench.serial_reference --task pendulum-full --n-s 40 --iterations 80 [--compare]

The baseline for the speed benchmark: the same algorithm as ``podilqr_jax.solve``
(noiseless, variant ``plain``, least-squares fit), written the way the paper
authors' prototype works. Every rollout is a Python loop over the T control
steps, each holding u_t for ``substeps`` calls of ``mujoco.mj_step`` on one
``MjData``; the fit is a Python loop over t with one SVD per step; the backward
pass is a Python loop over t. The line search tries alpha = 1, 1/2, ... one
rollout at a time and stops at the first accepted step (the batched solver rolls
them all out at once; the accepted step is the same). The perturbations come
from ``np.random.default_rng(seed)``, not JAX's PRNG, so the iterates differ
slightly from the JAX solver's, but they converge to the same optimum.

Notation (shapes), as in ``podilqr_jax`` and docs/algorithm.md:
  x_t = [qpos, qvel] [nx]    z_t = C x_t [nz]    u_t [nu]    T control steps
  q      past observations in the information state
  Z_t    [nZ] = [z_t, ..., z_{t-q+1}, u_{t-1}, ..., u_{t-q+1}], newest first,
         nZ = q nz + (q-1) nu; rest history before t = 0: z_{-j} = z_0, u_{-j} = 0
  n_s    sysid rollouts per iteration, u_t = u_bar_t + du_t, du ~ N(0, sigma^2 I)
  A_t [nZ, nZ], B_t [nZ, nu]    dZ_{t+1} = A_t dZ_t + B_t du_t (Eq. c4tab)
  k_t [nu], K_t [nu, nZ]        u_t = u_bar_t + alpha k_t + K_t (Z_t - Z_bar_t)
  J = sum_{t<T} e_t' Q e_t + u_t' R u_t + e_T' QT e_T,  e_t = z_t - z*  (no 1/2)
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from typing import Callable, NamedTuple, Optional

import mujoco
import numpy as np
from scipy.linalg import cho_solve

import podilqr_jax as pj

PHASES = ("rollouts", "fit", "backward", "line_search")


# ----------------------------------------------------------------------- task
@dataclasses.dataclass
class Task:
    """The task as NumPy arrays, with one MuJoCo model and one ``MjData`` to step."""

    model: mujoco.MjModel
    data: mujoco.MjData
    substeps: int
    T: int
    nq: int
    nz: int
    nu: int
    q: int
    C: np.ndarray  # [nz, nx]
    x0: np.ndarray  # [nx]
    z_target: np.ndarray  # [nz]
    Q_t: np.ndarray  # [T, nz, nz] running weights (QT from the goal step on)
    QT: np.ndarray  # [nz, nz]
    R: np.ndarray  # [nu, nu]

    @property
    def nZ(self) -> int:
        return self.q * self.nz + (self.q - 1) * self.nu

    @property
    def S(self) -> np.ndarray:
        """S [nz, nZ]: z_t = S Z_t."""
        return np.eye(self.nz, self.nZ)


def make_serial_task(env: pj.Env, q: int) -> Task:
    """Read the MuJoCo model and the task arrays of ``env`` as NumPy."""
    d = env.data
    T = env.dims.horizon
    Q, QT = np.asarray(d.Q, float), np.asarray(d.QT, float)
    goal = int(d.goal_step)
    Q_t = np.stack([QT if t >= goal else Q for t in range(T)])
    return Task(
        model=env.mj_model,
        data=mujoco.MjData(env.mj_model),
        substeps=env.dims.substeps,
        T=T,
        nq=env.dims.nq,
        nz=env.dims.nz,
        nu=env.dims.nu,
        q=q,
        C=np.asarray(d.C, float),
        x0=np.asarray(d.x0, float),
        z_target=np.asarray(d.z_target, float),
        Q_t=Q_t,
        QT=QT,
        R=np.asarray(d.R, float),
    )


# ---------------------------------------------------------- information state
def initial_info_state(task: Task, z0: np.ndarray) -> np.ndarray:
    """Z_0 from the rest history: q copies of z_0, then q-1 zero controls."""
    return np.concatenate([np.tile(z0, task.q), np.zeros((task.q - 1) * task.nu)])


def shift(task: Task, Z: np.ndarray, z_next: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Z_{t+1} from Z_t, the new observation z_{t+1} and the applied control u_t."""
    q, nz, nu = task.q, task.nz, task.nu
    z_block = np.concatenate([z_next, Z[: (q - 1) * nz]])
    if q == 1:
        return z_block
    return np.concatenate([z_block, u, Z[q * nz : q * nz + (q - 2) * nu]])


def companion(task: Task, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(A_t, B_t) of Eq. (c4tab) from the ARMA coefficients theta [nz, nZ + nu]."""
    q, nz, nu, nZ = task.q, task.nz, task.nu, task.nZ
    A = np.zeros((nZ, nZ))
    B = np.zeros((nZ, nu))
    A[:nz] = theta[:, :nZ]  # [alpha_1 .. alpha_q | beta_2 .. beta_q]
    B[:nz] = theta[:, nZ:]  # beta_1
    if q > 1:
        A[nz : q * nz, : (q - 1) * nz] = np.eye((q - 1) * nz)  # z_{t-i} moves down a slot
        B[q * nz : q * nz + nu] = np.eye(nu)  # u_t enters the first control slot
        if q > 2:
            A[q * nz + nu :, q * nz : q * nz + (q - 2) * nu] = np.eye((q - 2) * nu)  # older controls move down
    return A, B


# ------------------------------------------------------------ rollout and cost
class Trajectory(NamedTuple):
    z: np.ndarray  # [T+1, nz]
    u: np.ndarray  # [T, nu] applied controls
    Z: np.ndarray  # [T+1, nZ] information states built online


class Nominal(NamedTuple):
    traj: Trajectory
    cost: float


def rollout(task: Task, u_bar, offset=None, K=None, Z_bar=None) -> Trajectory:
    """One rollout of u_t = u_bar_t + offset_t + K_t (Z_t - Z_bar_t) from x0.

    ``offset`` is du (sysid) or alpha k (line search); without ``K`` it is open loop.
    """
    m, d = task.model, task.data
    mujoco.mj_resetData(m, d)
    d.qpos[:] = task.x0[: task.nq]
    d.qvel[:] = task.x0[task.nq :]
    z = np.empty((task.T + 1, task.nz))
    u = np.empty((task.T, task.nu))
    Z = np.empty((task.T + 1, task.nZ))
    z[0] = task.C @ task.x0
    Z[0] = initial_info_state(task, z[0])
    for t in range(task.T):
        u_t = u_bar[t] if offset is None else u_bar[t] + offset[t]
        if K is not None:
            u_t = u_t + K[t] @ (Z[t] - Z_bar[t])
        d.ctrl[:] = u_t
        mujoco.mj_step(m, d, nstep=task.substeps)  # hold u_t for one control step
        z[t + 1] = task.C @ np.concatenate([d.qpos, d.qvel])
        u[t] = u_t
        Z[t + 1] = shift(task, Z[t], z[t + 1], u_t)
    return Trajectory(z, u, Z)


def trajectory_cost(task: Task, traj: Trajectory) -> float:
    """J of one trajectory; inf when anything is not finite."""
    if not (np.all(np.isfinite(traj.z)) and np.all(np.isfinite(traj.u))):
        return np.inf
    J = 0.0
    for t in range(task.T):
        e = traj.z[t] - task.z_target
        J += e @ task.Q_t[t] @ e + traj.u[t] @ task.R @ traj.u[t]
    e = traj.z[task.T] - task.z_target
    J += e @ task.QT @ e
    return float(J) if np.isfinite(J) else np.inf


# ------------------------------------------------------------------------ fit
def least_squares(X: np.ndarray, Y: np.ndarray, rcond: float) -> np.ndarray:
    """Minimum-norm W of Y ~ X W (X [n, p], Y [n, m]): unit-RMS columns, SVD cut at rcond."""
    scale = np.sqrt(np.mean(X * X, axis=0))
    scale[scale <= 0] = 1.0  # all-zero columns (the rest history) stay zero
    U, s, Vt = np.linalg.svd(X / scale, full_matrices=False)
    keep = s > rcond * s[0]
    s_inv = np.zeros_like(s)
    s_inv[keep] = 1.0 / s[keep]
    W = Vt.T @ (s_inv[:, None] * (U.T @ Y))
    return W / scale[:, None]


def fit(task: Task, runs: list[Trajectory], nominal: Trajectory, rcond: float):
    """Per-step least squares of dz_{t+1} on [dZ_t, du_t] over the n_s rollouts.

    Returns A [T, nZ, nZ], B [T, nZ, nu] and the largest RMS of dz_{t+1}.
    """
    A = np.empty((task.T, task.nZ, task.nZ))
    B = np.empty((task.T, task.nZ, task.nu))
    target_rms = 0.0
    for t in range(task.T):
        X = np.stack([np.concatenate([r.Z[t] - nominal.Z[t], r.u[t] - nominal.u[t]]) for r in runs])
        Y = np.stack([r.z[t + 1] - nominal.z[t + 1] for r in runs])
        theta = least_squares(X, Y, rcond).T  # [nz, nZ + nu]
        A[t], B[t] = companion(task, theta)
        target_rms = max(target_rms, float(np.sqrt(np.mean(Y**2))))
    return A, B, target_rms


# -------------------------------------------------------------- backward pass
class Gains(NamedTuple):
    k: np.ndarray  # [T, nu]
    K: np.ndarray  # [T, nu, nZ]
    dV1: float
    dV2: float
    grad: np.ndarray  # [T, nu] dJ/du_t on the identified model
    mu: float
    ok: bool


def riccati(task: Task, A, B, nominal: Trajectory, mu: float) -> Optional[Gains]:
    """One backward sweep at regularisation mu; None when some Qr_uu is not positive definite."""
    S, zt, R = task.S, task.z_target, task.R
    Z_bar, u_bar = nominal.Z, nominal.u
    I = np.eye(task.nZ)
    e_T = S @ Z_bar[task.T] - zt
    v = 2.0 * S.T @ task.QT @ e_T  # v_T
    V = 2.0 * S.T @ task.QT @ S  # V_T
    lam = v.copy()  # costate lambda_T
    l_uu = 2.0 * R
    k = np.empty((task.T, task.nu))
    K = np.empty((task.T, task.nu, task.nZ))
    grad = np.empty((task.T, task.nu))
    dV1 = dV2 = 0.0
    for t in reversed(range(task.T)):
        A_t, B_t, Q = A[t], B[t], task.Q_t[t]
        l_Z = 2.0 * S.T @ Q @ (S @ Z_bar[t] - zt)
        l_ZZ = 2.0 * S.T @ Q @ S
        l_u = 2.0 * R @ u_bar[t]
        Q_Z = l_Z + A_t.T @ v
        Q_u = l_u + B_t.T @ v
        Q_ZZ = l_ZZ + A_t.T @ V @ A_t
        Q_uu = l_uu + B_t.T @ V @ B_t
        Q_uZ = B_t.T @ V @ A_t
        V_reg = V + mu * I  # Levenberg-Marquardt on V
        Qr_uu = l_uu + B_t.T @ V_reg @ B_t
        Qr_uZ = B_t.T @ V_reg @ A_t
        try:
            L = np.linalg.cholesky(0.5 * (Qr_uu + Qr_uu.T))
        except np.linalg.LinAlgError:
            return None
        k[t] = -cho_solve((L, True), Q_u)
        K[t] = -cho_solve((L, True), Qr_uZ)
        v = Q_Z + K[t].T @ Q_uu @ k[t] + K[t].T @ Q_u + Q_uZ.T @ k[t]
        V = Q_ZZ + K[t].T @ Q_uu @ K[t] + K[t].T @ Q_uZ + Q_uZ.T @ K[t]
        V = 0.5 * (V + V.T)
        grad[t] = l_u + B_t.T @ lam
        lam = l_Z + A_t.T @ lam
        dV1 += k[t] @ Q_u
        dV2 += 0.5 * k[t] @ Q_uu @ k[t]
    return Gains(k, K, float(dV1), float(dV2), grad, mu, True)


def backward_pass(task: Task, A, B, nominal: Trajectory, mu: float, cfg: pj.SolverConfig) -> Gains:
    """Sweep at mu, multiplying mu by mu_factor until every Qr_uu is positive definite."""
    mu = max(mu, cfg.mu_min)
    gains = riccati(task, A, B, nominal, mu)
    while gains is None and mu * cfg.mu_factor <= cfg.mu_max:
        mu *= cfg.mu_factor
        gains = riccati(task, A, B, nominal, mu)
    if gains is None:  # past mu_max: zero gains, never NaN
        zero_k, zero_K = np.zeros((task.T, task.nu)), np.zeros((task.T, task.nu, task.nZ))
        return Gains(zero_k, zero_K, 0.0, 0.0, np.zeros((task.T, task.nu)), mu, False)
    return gains


# ---------------------------------------------------------------- line search
def line_search(task: Task, nominal: Nominal, gains: Gains, cfg: pj.SolverConfig):
    """Try alpha = 1, 1/2, ... one rollout each; accept the first that lowers J by at
    least accept_ratio of the predicted decrease -(alpha dV1 + alpha^2 dV2).

    Returns (accepted, new nominal or None, predicted decrease at alpha = 1, rollouts).
    """
    predicted_1 = -(gains.dV1 + gains.dV2)
    for i in range(cfg.n_alphas):
        alpha = 0.5**i
        traj = rollout(task, nominal.traj.u, alpha * gains.k, gains.K, nominal.traj.Z)
        cost = trajectory_cost(task, traj)
        expected = -(alpha * gains.dV1 + alpha**2 * gains.dV2)
        ratio = (nominal.cost - cost) / expected if expected > 0 else 0.0
        if cost < nominal.cost and ratio > cfg.accept_ratio:
            return True, Nominal(traj, cost), predicted_1, i + 1
    return False, None, predicted_1, cfg.n_alphas


# --------------------------------------------------------------------- driver
PAPER_SETTINGS = pj.PAPER_SETTINGS
"""The settings that make ``podilqr_jax.solve`` the algorithm this reference
implements (``config.PAPER_SETTINGS``)."""


def serial_solve(
    env: pj.Env,
    cfg: Optional[pj.SolverConfig] = None,
    *,
    time_limit_s: Optional[float] = None,
    target_cost: Optional[float] = None,
    stop_at_target: bool = False,
    callback: Optional[Callable[[int, float, float], None]] = None,
) -> dict:
    """POD-iLQR from serial rollouts (noiseless, plain variant, least squares).

    Args:
      env: the task; only its MuJoCo model and arrays are read.
      cfg: solver settings; default ``podilqr_jax.default_config(env)``.
      time_limit_s: stop after the iteration that passes this wall time.
      target_cost: record the wall time at which the cost first goes <= it.
      stop_at_target: also stop there.
      callback: called as ``callback(iteration, cost, wall_s)`` after every iteration.

    Returns:
      A dict: cost_history (initial nominal first), iteration_s, phase_s, wall_s,
      iterations, rollouts, reached_target_s, controls [T][nu], status, message, q.
    """
    t_start = time.perf_counter()
    cfg = pj.default_config(env) if cfg is None else cfg
    q = cfg.validate(env, data_based=True)
    differs = {k: getattr(cfg, k) for k, v in PAPER_SETTINGS.items() if getattr(cfg, k) != v}
    if env.noisy or cfg.estimator != "ols" or cfg.mirrored or differs:
        raise ValueError(
            "serial_solve is the noiseless plain POD-iLQR with least squares on every direction above rcond, "
            f"at one fixed sigma; got noisy={env.noisy}, estimator={cfg.estimator!r}, mirrored={cfg.mirrored}, "
            f"{differs} (use PAPER_SETTINGS)."
        )
    task = make_serial_task(env, q)
    rng = np.random.default_rng(cfg.seed)
    phase_s = dict.fromkeys(PHASES, 0.0)

    # The first nominal: open-loop rollout of u = 0.
    t0 = time.perf_counter()
    first = rollout(task, np.zeros((task.T, task.nu)))
    nominal = Nominal(first, trajectory_cost(task, first))
    phase_s["line_search"] += time.perf_counter() - t0
    cost_history, iteration_s = [nominal.cost], []
    rollouts = 1
    reached = None
    if target_cost is not None and nominal.cost <= target_cost:
        reached = time.perf_counter() - t_start
    mu = max(cfg.mu_init, cfg.mu_min)
    failures = 0
    A = B = None  # the identified model about the current nominal
    status, message = "max_iterations", f"reached max_iterations={cfg.max_iterations}"
    iteration = 0
    if not np.isfinite(nominal.cost):
        status, message = "nonfinite", "the initial controls give a non-finite rollout"
    else:
        for iteration in range(1, cfg.max_iterations + 1):
            t_iter = time.perf_counter()
            stop = None
            # 1. Sysid: n_s rollouts of u = u_bar + du, du ~ N(0, sigma^2 I), then the fit.
            if A is None:
                t0 = time.perf_counter()
                du = cfg.sigma * rng.standard_normal((cfg.n_s, task.T, task.nu))
                runs = [rollout(task, nominal.traj.u, du[j]) for j in range(cfg.n_s)]
                rollouts += cfg.n_s
                t1 = time.perf_counter()
                # 2. Least-squares ARMA fit: A_t, B_t for t = 0 .. T-1.
                A, B, target_rms = fit(task, runs, nominal.traj, cfg.rcond)
                phase_s["rollouts"] += t1 - t0
                phase_s["fit"] += time.perf_counter() - t1
                if not all(np.all(np.isfinite(r.z)) and np.all(np.isfinite(r.u)) for r in runs) or not (
                    np.all(np.isfinite(A)) and np.all(np.isfinite(B))
                ):
                    stop = ("nonfinite", "a sysid rollout or the fitted model is not finite")
                elif target_rms == 0.0:
                    stop = ("no_response", f"the sysid perturbations (sigma={cfg.sigma:g}) changed no observation")
            # 3. Backward pass: k_t, K_t with Levenberg-Marquardt mu.
            if stop is None:
                t0 = time.perf_counter()
                gains = backward_pass(task, A, B, nominal.traj, mu, cfg)
                mu = gains.mu
                grad_norm = float(np.max(np.abs(gains.grad)))
                phase_s["backward"] += time.perf_counter() - t0
                if not gains.ok:
                    stop = ("line_search_failed", f"the backward pass needs regularisation above mu_max={cfg.mu_max:g}")
                elif grad_norm < cfg.gtol:
                    stop = ("converged", f"gradient norm {grad_norm:.3g} below gtol={cfg.gtol:g}")
            # 4. Forward pass and line search over alpha.
            if stop is None:
                t0 = time.perf_counter()
                accepted, new, predicted, n = line_search(task, nominal, gains, cfg)
                rollouts += n
                phase_s["line_search"] += time.perf_counter() - t0
                if accepted:
                    decrease = nominal.cost - new.cost
                    nominal, A, B = new, None, None  # identify again about the new nominal
                    failures = 0
                    mu = max(mu / cfg.mu_factor, cfg.mu_min)
                    if decrease < cfg.rtol * abs(new.cost):
                        stop = ("converged", f"relative cost decrease below rtol={cfg.rtol:g}")
                else:  # same model (noiseless: new rollouts would fit the same), larger mu
                    failures += 1
                    mu = max(mu * cfg.mu_factor**failures, cfg.mu_min)
                    if abs(predicted) < cfg.rtol * abs(nominal.cost):
                        stop = (
                            "converged",
                            f"no step lowers the cost and the predicted decrease {predicted:.3g} is small",
                        )
                    elif mu > cfg.mu_max:
                        stop = ("line_search_failed", f"no step lowered the cost; mu passed mu_max={cfg.mu_max:g}")
                cost_history.append(nominal.cost)
            now = time.perf_counter()
            iteration_s.append(now - t_iter)
            if reached is None and target_cost is not None and nominal.cost <= target_cost:
                reached = now - t_start
                if stop is None and stop_at_target:
                    stop = ("target_reached", f"cost {nominal.cost:.6g} <= target {target_cost:.6g}")
            if callback is not None:
                callback(iteration, nominal.cost, now - t_start)
            if stop is None and time_limit_s is not None and now - t_start > time_limit_s:
                stop = ("time_limit", f"wall time passed time_limit_s={time_limit_s:g}")
            if stop is not None:
                status, message = stop
                break
    return dict(
        cost_history=cost_history,
        iteration_s=iteration_s,
        phase_s=phase_s,
        wall_s=time.perf_counter() - t_start,
        iterations=iteration,
        rollouts=rollouts,
        reached_target_s=reached,
        controls=nominal.traj.u.tolist(),
        status=status,
        message=message,
        q=q,
    )


# ------------------------------------------------------------------------ CLI
def _phase_split(phase_s: dict, wall_s: float) -> str:
    return ", ".join(f"{k} {v:.3f} s ({100 * v / wall_s:.0f}%)" for k, v in phase_s.items())


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="pendulum-full", help=f"one of {', '.join(pj.TASKS)}")
    parser.add_argument("--n-s", type=int, default=None, help="sysid rollouts per iteration (task default)")
    parser.add_argument("--sigma", type=float, default=None, help="perturbation std (task default)")
    parser.add_argument("--iterations", type=int, default=None, help="max_iterations (default 300)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--time-limit", type=float, default=None, help="stop the serial solve after this many s")
    parser.add_argument("--target-cost", type=float, default=None, help="report when the cost first goes <= this")
    parser.add_argument("--compare", action="store_true", help="also run podilqr_jax.solve with the same settings")
    args = parser.parse_args(argv)

    env = pj.make_task(args.task)
    overrides = {"seed": args.seed, **PAPER_SETTINGS}
    for name, value in (("n_s", args.n_s), ("sigma", args.sigma), ("max_iterations", args.iterations)):
        if value is not None:
            overrides[name] = value
    cfg = pj.default_config(env, **overrides)
    print(f"{args.task}: n_s={cfg.n_s} sigma={cfg.sigma:g} max_iterations={cfg.max_iterations} seed={cfg.seed}")

    def report(iteration, cost, wall_s):
        if iteration % 10 == 0:
            print(f"  iter {iteration:4d}  cost {cost:.9g}  {wall_s:8.2f} s")

    out = serial_solve(env, cfg, time_limit_s=args.time_limit, target_cost=args.target_cost, callback=report)
    n = max(out["iterations"], 1)
    final = out["cost_history"][-1]
    print(
        f"serial: {out['iterations']} iterations, {out['status']}, final cost {final:.9g}, "
        f"wall {out['wall_s']:.2f} s, {out['wall_s'] / n:.4f} s/iteration, {out['rollouts']} rollouts"
    )
    print(f"  phases: {_phase_split(out['phase_s'], out['wall_s'])}")
    if out["reached_target_s"] is not None:
        print(f"  reached target {args.target_cost:g} after {out['reached_target_s']:.2f} s")

    if args.compare:
        res = pj.solve(env, cfg)
        m = max(res.iterations, 1)
        print(
            f"jax:    {res.iterations} iterations, {res.status}, final cost {res.final_cost:.9g}, "
            f"wall {res.wall_s:.2f} s (compile {res.compile_s:.2f} s), {res.run_s / m:.4f} s/iteration after compile"
        )
        print(f"final cost serial / jax = {final / res.final_cost:.9f}")


if __name__ == "__main__":
    main()
