"""Every bad input of docs/bad_input.md: a non-zero exit, one message, no
traceback, and an earlier result file left as it was."""

import importlib.util
import os
import sys

import pytest

_PATH = os.path.join(os.path.dirname(__file__), os.pardir, "docs", "bad_input_table.py")
_spec = importlib.util.spec_from_file_location("bad_input_table", _PATH)
bad_inputs = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = bad_inputs  # dataclasses look their module up there
_spec.loader.exec_module(bad_inputs)


_OUTCOMES: dict = {}  # case -> its outcome, for the page's staleness test at the end


@pytest.mark.parametrize("case", bad_inputs.CASES, ids=lambda c: c.what)
def test_bad_input_is_refused_cleanly(case):
    outcome = _OUTCOMES[case.what] = bad_inputs.run_case(case)
    assert outcome.status != 0
    assert "Traceback" not in outcome.stderr
    assert "error:" in outcome.stderr
    assert outcome.result_kept


def test_the_good_task_of_the_table_solves(tmp_path):
    """The cases' base task is valid: each case breaks exactly one thing."""
    import podilqr_jax as pj
    from podilqr_jax.task.taskfile import load_task

    (tmp_path / "arm.xml").write_text(bad_inputs.MODEL.format(**bad_inputs.GOOD_GEOM))
    (tmp_path / "arm.toml").write_text(bad_inputs.TASK.format(**bad_inputs.GOOD_TASK))
    env = load_task(tmp_path / "arm.toml")
    r = pj.solve(env, pj.default_config(env, max_iterations=2))
    assert r.iterations == 2 and r.final_cost < r.cost_history[0]


def test_the_page_says_what_the_cases_print_today():
    """docs/bad_input.md is what ``python docs/bad_input_table.py --write
    docs/bad_input.md`` writes now: a new case, a changed message or a new
    option in the usage line fails here until the page is regenerated."""
    outcomes = [_OUTCOMES.get(c.what) or bad_inputs.run_case(c) for c in bad_inputs.CASES]
    page = os.path.join(os.path.dirname(__file__), os.pardir, "docs", "bad_input.md")
    with open(page, encoding="utf-8") as f:
        assert f.read() == bad_inputs.page(outcomes), (
            "docs/bad_input.md is stale: run python docs/bad_input_table.py --write docs/bad_input.md"
        )
