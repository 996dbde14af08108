"""Identification under noise: Lemma 1 and Lemma 2 of the paper (Section V).

All systems are numpy-simulated linear-Gaussian LTV systems

    x_{t+1} = F_t x_t + G_t u_t + w_t,    z_t = C x_t + v_t,

identified with ``fit_information_model`` from rollouts about a nominal. The
nominal is the noiseless trajectory under u_bar, which for a linear system with
zero-mean noise (and feedback on the deviation from that nominal) is also the
mean trajectory, i.e. what the paper's averaged forward pass estimates. Using a
single noisy rollout as the nominal instead would shift every rollout's
deviation by the same noise realisation, an offset the intercept-free
regression cannot absorb.

* ``test_lemma1_full_observation_fit_is_consistent``: full observation (C = I),
  process noise only, q = 1, with feedback u = u_bar + K dx + du in the sysid
  rollouts (and, Lemma 1's simplest case, without feedback). The fitted
  (A_t, B_t) converge to the open-loop (F_t, G_t): the error falls like
  1/sqrt(n_s) (n_s = 100 -> 6400: ~8x), and it ends far below the closed-loop
  offset G K, so the fit returns the open-loop model, not A + B K.
* ``test_lemma1_injected_perturbation_form_matches_applied_control_fit``: the
  paper's two-step form of Lemma 1 (regress on [dx_t, du_inj_t] to get
  A + B K and B, then A = (A + B K) - B K) gives the library's numbers to
  round-off.
* ``test_lemma2_partial_observation_fit_stays_biased``: nx = 2, nz = 1, q = 2
  with measurement noise, process noise, or both plus feedback: the ARMA
  coefficients stay off the truth by a clear floor that does not shrink from
  n_s = 400 to 6400; the fit converges instead to the population least-squares
  value computed here in closed form (the noise-regressor correlation term of
  Eq. (partialsysid)). Without noise the same data give the truth exactly.
* ``test_lemma2_averaging_repeated_rollouts_removes_the_bias``: the remedy:
  each perturbation sequence is rolled out n_avg times and the trajectories
  are averaged before the fit; the bias falls with n_avg (1, 4, 16).

Comparison with the truth in information-state form: for q = 2, nz = nu = 1,
nx = 2 and an observable pair (C, F_{t-1}), the ARMA coefficients of

    z_{t+1} = a1 z_t + a2 z_{t-1} + b2 u_{t-1} + b1 u_t

are unique (the state x_{t-1} is a linear function of z_{t-1}, z_t, u_{t-1}),
so the fitted top row of [A_t | B_t] = [a1, a2, b2 | b1] is compared with them
directly. With a deterministic x_0 the rollout data span all four regressor
directions only from t = 3 on (x_{t-1} must be excited in both directions):
the noiseless check uses t = 3 .. T-1. The noisy comparisons use t = 5 .. T-1:
the response to the perturbations builds up over the first steps (std of dz_t
for t = 0 .. 6: 0, 0.005, 0.03, 0.07, 0.10, 0.15, 0.18, then ~0.15 .. 0.18),
so at t = 3, 4 the noise swamps the signal and those two steps alone set the
size and the (far from 1/n_avg) decay of the bias. Over 40 seeds, with t >= 3
the ratio err(n_avg = 16) / err(1) reached 0.59; with t >= 5 it is <= 0.23.

Shapes are reused so that ``fit_information_model`` compiles four times in all
(q = 1: n_s = 100, 6400; q = 2: n_s = 400, 6400).
"""

from __future__ import annotations

import linear_gaussian as lg
import numpy as np
import pytest

import podilqr_jax  # noqa: F401  (enables float64 in JAX)

# Exact-arithmetic identities (the same least-squares problem solved two ways,
# noiseless data): float64 round-off of small SVD solves is ~1e-13 relative.
FIT_RTOL = 1e-9

# Lemma 1 (full observation): nx = 3, nu = 2, T = 8; process noise std 0.05
# (half the perturbation std SIGMA_DU = 0.1), initial-state deviation std 0.1
# (the paper samples dx_0 at random; it also makes A_0 identifiable), feedback
# K_t = 0.3 N(0, 1).
L1_NX, L1_NU, L1_T = 3, 2, 8
L1_W_STD, L1_DX0_STD, L1_K_SCALE = 0.05, 0.1, 0.3
L1_N_SMALL, L1_N_LARGE = 100, 6400

# Lemma 2 (partial observation): lightly damped, time-varying oscillator,
# nx = 2, nz = nu = 1, q = 2, T = 12, deterministic x_0.
L2_T, L2_Q = 12, 2
L2_T_IDENT = 3  # first step whose coefficients the (noiseless) data identify
L2_T_CMP = 5  # first step compared under noise (see the module docstring)
L2_N_SMALL, L2_N_LARGE = 400, 6400


# ---------------------------------------------------------------------------
# helpers (numpy, independent of the library; the systems, rollouts and fit
# wrapper are shared with test_estimators.py through linear_gaussian.py)
# ---------------------------------------------------------------------------


def arma_regressors(dz, du, t):
    """q = 2 regression at step t >= 1: X = [dz_t, dz_{t-1}, du_{t-1}, du_t], Y = dz_{t+1} (nz = nu = 1)."""
    return np.concatenate([dz[:, t], dz[:, t - 1], du[:, t - 1], du[:, t]], axis=1), dz[:, t + 1, 0]


def population_fit(F, G, C, k, w_std, v_std):
    """Limit n_s -> infinity of the least-squares ARMA fit, [T, 4] (rows t < L2_T_IDENT unused).

    The regressors and targets are linear in the independent standard normals
    xi = (du, w, v) / std, so E[X'X] and E[X'Y] follow from simulating the
    deviations for each unit vector of xi: Theta = E[X'X]^{-1} E[X'Y]. This is
    the truth plus Lemma 2's correlation term of Eq. (partialsysid).
    """
    T, nx, nu = G.shape
    nz = C.shape[0]
    sizes = [T * nu, T * nx, (T + 1) * nz]
    E = np.split(np.eye(sum(sizes)), np.cumsum(sizes)[:-1], axis=1)
    p = sum(sizes)
    dz, du_app = lg.deviations(
        F,
        G,
        C,
        k,
        lg.SIGMA_DU * E[0].reshape(p, T, nu),
        w_std * E[1].reshape(p, T, nx),
        v_std * E[2].reshape(p, T + 1, nz),
    )
    theta = np.zeros((T, 4))
    for t in range(L2_T_IDENT, T):
        X, Y = arma_regressors(dz, du_app, t)
        theta[t] = np.linalg.solve(X.T @ X, X.T @ Y)
    return theta


def coeff_err(theta, ref, t_first=L2_T_CMP):
    """Relative Frobenius error of ARMA coefficients [T, 4] over the steps t >= t_first."""
    return lg.rel_fro(theta[t_first:], ref[t_first:])


# ---------------------------------------------------------------------------
# Lemma 1: full observation, process noise, feedback in the sysid rollouts
# ---------------------------------------------------------------------------


def fit_q1(x, u, du, x_bar, u_bar):
    """Least-squares fit with q = 1 (full observation); it has no use for the injected du."""
    return lg.fit_ols(x, u, x_bar, u_bar, 1)


def lemma1_problem(seed, feedback=True):
    rng = np.random.default_rng(seed)
    F, G = lg.random_ltv(rng, L1_NX, L1_NU, L1_T)
    K = L1_K_SCALE * rng.standard_normal((L1_T, L1_NU, L1_NX))
    if not feedback:
        K = np.zeros_like(K)
    x0 = rng.standard_normal(L1_NX)
    u_bar = rng.standard_normal((L1_T, L1_NU))
    return rng, F, G, K, lg.nominal(F, G, x0, u_bar), u_bar


def lemma1_errors(seed, feedback=True):
    """Relative errors of [A_t | B_t] vs [F_t | G_t] at n_s = L1_N_SMALL, L1_N_LARGE, and ||G K|| (relative)."""
    rng, F, G, K, x_bar, u_bar = lemma1_problem(seed, feedback)
    return lg.full_obs_fit_errors(fit_q1, rng, F, G, K, x_bar, u_bar, (L1_N_SMALL, L1_N_LARGE), L1_W_STD, L1_DX0_STD)


@pytest.mark.parametrize("feedback", [True, False], ids=["feedback", "open_loop"])
def test_lemma1_full_observation_fit_is_consistent(feedback):
    # w_t is independent of the regressors [dx_t, du_t] (they depend on w_{<t}
    # only), so least squares is unbiased and its error is pure Monte Carlo:
    # ~ w_std / (regressor std sqrt(n_s)). From n_s = 100 to 6400 it should
    # drop by sqrt(64) = 8; over seeds 0..39 (both cases) the ratio was
    # 6.5 .. 10.4, the error at 6400 was 0.0048 .. 0.0103 and at 100
    # 0.044 .. 0.085. A biased fit would level off (ratio -> 1), a fit that
    # returned the closed-loop A + B K would sit at ||G K|| = 0.32 .. 0.55
    # relative (the error at 6400 was <= 0.03 of that).
    err_small, err_large, gk = lemma1_errors(seed=0, feedback=feedback)
    assert err_small > 0.02  # the noise is visible at n_s = 100 ...
    assert 4.0 < err_small / err_large < 16.0  # ... and averages out like 1/sqrt(n_s)
    assert err_large < 0.02
    if feedback:
        assert gk > 0.2
        assert err_large < 0.1 * gk  # open-loop (F, G), not the closed loop


def test_lemma1_injected_perturbation_form_matches_applied_control_fit():
    # Lemma 1's proof regresses dx_{t+1} on [dx_t, du_inj_t], getting
    # [F + G K | G] (+ noise), and recovers F = (F + G K) - G K. The library
    # regresses on the applied deviation K dx + du_inj instead; the two
    # regressor sets are an invertible linear map of each other, so on the
    # same (noisy) data both give the same numbers, to round-off.
    rng, F, G, K, x_bar, u_bar = lemma1_problem(seed=1)
    x, u, du_inj = lg.full_obs_rollouts(rng, F, G, x_bar, u_bar, K, L1_N_SMALL, L1_W_STD, L1_DX0_STD)
    A, B, _ = fit_q1(x, u, du_inj, x_bar, u_bar)
    dx = x - x_bar
    for t in range(L1_T):
        X = np.concatenate([dx[:, t], du_inj[:, t]], axis=1)
        W = np.linalg.lstsq(X, dx[:, t + 1], rcond=None)[0]
        closed, B_inj = W[:L1_NX].T, W[L1_NX:].T
        A_inj = closed - B_inj @ K[t]
        assert lg.rel_err(A[t], A_inj) < FIT_RTOL
        assert lg.rel_err(B[t], B_inj) < FIT_RTOL
        # and the plain applied-control regression, in numpy
        W_app = np.linalg.lstsq(np.concatenate([dx[:, t], u[:, t] - u_bar[t]], axis=1), dx[:, t + 1], rcond=None)[0]
        assert lg.rel_err(A[t], W_app[:L1_NX].T) < FIT_RTOL
        assert lg.rel_err(B[t], W_app[L1_NX:].T) < FIT_RTOL
        # the closed-loop matrix itself is far from F: the subtraction matters
        assert lg.rel_err(closed, F[t]) > 0.05


# ---------------------------------------------------------------------------
# Lemma 2: partial observation, noise -> biased fit; averaging removes it
# ---------------------------------------------------------------------------

# (process noise std, measurement noise std, feedback gain scale on dz_t),
# with SIGMA_DU = 0.1 on the perturbations; the observation deviations they
# cause have std ~0.15 .. 0.18 at the compared steps, so the measurement noise
# is ~0.3 of the signal in amplitude.
L2_CASES = {
    "measurement": (0.0, 0.05, 0.0),
    "process": (0.05, 0.0, 0.0),  # the same process noise is harmless with full observation (Lemma 1)
    "both_feedback": (0.02, 0.05, 0.3),  # the paper's setting: feedback does not remove the bias
}


def lemma2_problem(seed, k_scale):
    return lg.oscillator_problem(seed, L2_T, k_scale, t_first=L2_T_IDENT)


def lemma2_fit(rng, F, G, C, k, z_bar, u_bar, n, w_std, v_std, n_avg=1):
    """Fitted ARMA coefficients [T, 4] from n perturbation sequences, each averaged over n_avg noisy runs."""
    du = lg.SIGMA_DU * rng.standard_normal((n, L2_T, 1))
    dz, du_app = 0.0, 0.0
    for _ in range(n_avg):
        w = w_std * rng.standard_normal((n, L2_T, 2))
        v = v_std * rng.standard_normal((n, L2_T + 1, 1))
        dz_r, du_r = lg.deviations(F, G, C, k, du, w, v)
        dz, du_app = dz + dz_r / n_avg, du_app + du_r / n_avg
    A, B, rank = lg.fit_ols(z_bar + dz, u_bar + du_app, z_bar, u_bar, L2_Q)
    return lg.arma_coefficients(A, B), rank


def lemma2_errors(seed, case):
    """(noiseless error, error at L2_N_SMALL, error at L2_N_LARGE, distance to the population fit at
    L2_N_LARGE, population bias), all relative to the true coefficients."""
    w_std, v_std, k_scale = L2_CASES[case]
    rng, F, G, C, k, z_bar, u_bar, truth = lemma2_problem(seed, k_scale)
    clean, rank = lemma2_fit(rng, F, G, C, k, z_bar, u_bar, L2_N_SMALL, 0.0, 0.0)
    assert np.all(rank[L2_T_IDENT:] == 4)
    small, _ = lemma2_fit(rng, F, G, C, k, z_bar, u_bar, L2_N_SMALL, w_std, v_std)
    large, _ = lemma2_fit(rng, F, G, C, k, z_bar, u_bar, L2_N_LARGE, w_std, v_std)
    pop = population_fit(F, G, C, k, w_std, v_std)
    return (
        coeff_err(clean, truth, L2_T_IDENT),
        coeff_err(small, truth),
        coeff_err(large, truth),
        coeff_err(large, pop),
        coeff_err(pop, truth),
    )


@pytest.mark.parametrize("case", list(L2_CASES))
def test_lemma2_partial_observation_fit_stays_biased(case):
    # Over seeds 0..39 per case: the noiseless fit matched the truth to
    # <= 7e-15; the error at n_s = 6400 was 0.36 .. 0.59 (measurement),
    # 0.11 .. 0.27 (process), 0.35 .. 0.61 (both + feedback); the ratio
    # err(6400) / err(400) was 0.88 .. 1.17 (1/sqrt(16) = 0.25 for an unbiased
    # fit); the distance from the fit at 6400 to the population value (the
    # Monte Carlo part) was <= 0.028, at most 0.081 of the error. An unbiased
    # fit would be at that Monte Carlo level, below the 0.05 floor.
    clean, err_small, err_large, to_pop, pop_bias = lemma2_errors(seed=0, case=case)
    # the truth is right and identifiable: noiseless data reproduce it
    assert clean < FIT_RTOL
    # biased: a clear floor at large n_s, not falling like 1/sqrt(n_s)
    assert err_large > 0.05
    assert err_large > 0.5 * err_small
    # ... because it converges to the biased population value (the
    # correlation term of Eq. (partialsysid)), not to the truth
    assert pop_bias > 0.05
    assert to_pop < 0.05
    assert to_pop < 0.25 * err_large


def lemma2_averaging_errors(seed, n_avgs=(1, 4, 16)):
    """Errors vs the truth and vs the population fit (noise std / sqrt(n_avg)) at n_s = L2_N_LARGE."""
    w_std, v_std, k_scale = L2_CASES["both_feedback"]
    rng, F, G, C, k, z_bar, u_bar, truth = lemma2_problem(seed, k_scale)
    errs, to_pop = [], []
    for n_avg in n_avgs:
        theta, _ = lemma2_fit(rng, F, G, C, k, z_bar, u_bar, L2_N_LARGE, w_std, v_std, n_avg)
        pop = population_fit(F, G, C, k, w_std / np.sqrt(n_avg), v_std / np.sqrt(n_avg))
        errs.append(coeff_err(theta, truth))
        to_pop.append(coeff_err(theta, pop))
    return errs, to_pop


def test_lemma2_averaging_repeated_rollouts_removes_the_bias():
    # Averaging n_avg runs of the same perturbation sequence divides the noise
    # variance by n_avg while the perturbation response is unchanged, so the
    # bias (noise variance / regressor variance, for small noise) falls
    # roughly like 1/n_avg once it is small. Process noise 0.02, measurement
    # noise 0.05, feedback on; over seeds 0..39 the error was 0.36 .. 0.61
    # (n_avg = 1), 0.14 .. 0.35 (4), 0.042 .. 0.13 (16); ratios
    # err(4) / err(1) 0.39 .. 0.58, err(16) / err(4) 0.29 .. 0.40,
    # err(16) / err(1) 0.12 .. 0.23; the Monte Carlo part (distance to the
    # population value at the reduced noise) was <= 0.027, far below those
    # steps.
    errs, to_pop = lemma2_averaging_errors(seed=0)
    e1, e4, e16 = errs
    assert e1 > 0.2
    assert e4 < 0.75 * e1
    assert e16 < 0.6 * e4
    assert e16 < 0.4 * e1
    assert max(to_pop) < 0.05
