"""Smoke test of the benchmark of what the robust defaults cost (``podilqr_jax.studies.bench.defaults_cost``)."""

import json

import pytest

from podilqr_jax.studies.bench import defaults_cost


def test_the_defaults_cost_benchmark_reports_both_settings(tmp_path, capsys):
    out = tmp_path / "cost.json"
    assert (
        defaults_cost.main(["--tasks", "pendulum-full", "--horizon", "10", "--max-iterations", "3", "--out", str(out)])
        == 0
    )
    report = json.loads(out.read_text())
    row = report["tasks"]["pendulum-full"]
    assert row["before"]["settings"]["variant"] == "plain" and row["after"]["settings"] == {"max_iterations": 3}
    for which in ("before", "after"):
        r = row[which]
        assert r["iterations"] <= 3 and r["rollouts_per_iteration"] > 0 and r["ratio"] > 0
        assert r["to_target"] is None or r["to_target"]["iterations"] <= r["iterations"]
    assert "| pendulum-full | after |" in capsys.readouterr().err


def test_the_defaults_cost_benchmark_refuses_unknown_tasks():
    with pytest.raises(SystemExit):
        defaults_cost.main(["--tasks", "rocket-full"])
