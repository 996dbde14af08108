"""Recover before giving up: re-identification when no step lowers the cost.

With sigma = 1 on the pendulum (a perturbation as large as the torques that
swing it up) the fit reads the response's curvature as slope, and at some
iteration no step size lowers the cost even at mu_max. Without
re-identification the solve stops there, ``line_search_failed``; with it the
solve draws fresh perturbations at sigma x 0.1 (then x 10) and goes on.
Until that iteration the two solves are the same computation (same keys, same
stages), so the comparison is exact, not a margin.
"""

import pytest

import podilqr_jax as pj
from podilqr_jax.ilqr.config import reidentify_scale


def test_reidentify_scales_alternate_smaller_then_larger():
    assert [reidentify_scale(a) for a in range(5)] == [1.0, 0.1, 10.0, 0.01, 100.0]


@pytest.fixture(scope="module")
def pendulum():
    return pj.make_task("pendulum-full", horizon=20)


def test_a_failed_line_search_reidentifies_before_it_stops(pendulum):
    # The paper's open-loop identification with every direction fitted: the defaults (closed loop, the
    # rank cap) converge at sigma = 1 on this task, and the check needs a line search that fails.
    settings = dict(sigma=1.0, n_s=8, max_iterations=200, variant="plain", cap_rank=False, adapt_sigma=False)
    gave_up = pj.solve(pendulum, pj.default_config(pendulum, reidentify=0, **settings))
    assert gave_up.status == pj.Status.LINE_SEARCH_FAILED
    assert gave_up.reidentifications == 0
    # the message names the diagnostic: what the model promised and what the system did
    assert "mu passed mu_max" in gave_up.message and "predicted a decrease of" in gave_up.message

    went_on = pj.solve(pendulum, pj.default_config(pendulum, reidentify=2, **settings))
    n = len(gave_up.cost_history)
    assert went_on.cost_history[:n] == gave_up.cost_history  # the same solve up to the failure
    assert went_on.reidentifications >= 1
    assert went_on.cost_history[-1] < gave_up.cost_history[-1]  # measured: 118.14 against 120.73
    assert any("identified afresh at another sigma" in w for w in went_on.warnings)


def test_model_based_solves_never_reidentify(pendulum):
    cfg = pj.default_config(pendulum, reidentify=2, max_iterations=3)
    assert pj.solve_model_based(pendulum, cfg).reidentifications == 0


def test_reidentify_must_be_a_count(pendulum):
    with pytest.raises(pj.ConfigError, match="reidentify"):
        pj.solve(pendulum, pj.default_config(pendulum, reidentify=-1))


def test_when_every_scale_fails_the_solve_changes_the_experiment(pendulum):
    # mu_max at mu_min: every rejected step ends in a re-identification, so the scales are soon spent.
    settings = dict(sigma=1.0, n_s=8, max_iterations=200, cap_rank=False, adapt_sigma=False, mu_max=1e-6, reidentify=1)
    gave_up = pj.solve(pendulum, pj.default_config(pendulum, escalate=False, **settings))
    assert gave_up.status == pj.Status.LINE_SEARCH_FAILED and not gave_up.mirrored
    notes = []
    went_on = pj.solve(pendulum, pj.default_config(pendulum, **settings), callback=lambda info: notes.append(info.note))
    n = len(gave_up.cost_history) - 1
    assert went_on.cost_history[:n] == gave_up.cost_history[:n]  # the same solve until the switch
    assert went_on.mirrored and any("mirrored +du/-du pairs from now on" in note for note in notes)
    assert any("or in another experiment" in w for w in went_on.warnings)
    # noiseless, an accepted step only lowers the cost: going on cannot end above where the other stopped
    assert went_on.final_cost <= gave_up.final_cost
    assert went_on.rollouts > gave_up.rollouts


def test_the_experiments_of_the_recovery_come_in_order():
    from podilqr_jax.ilqr.driver import next_experiment
    from podilqr_jax.ilqr.state import SolverState

    st = SolverState(nominal=None, gains=None, key=None, ls_key=None, mu=1.0)
    assert next_experiment(st, closed_loop=True) == "mirrored"
    st.mirrored = 1
    assert next_experiment(st, closed_loop=True) == "open_loop"
    assert next_experiment(st, closed_loop=False) is None  # already open loop: nothing left
    st.open_loop = 1
    assert next_experiment(st, closed_loop=True) is None
