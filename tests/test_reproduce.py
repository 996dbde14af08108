"""`podilqr reproduce` and the noise options of `podilqr solve` (tiny settings).

The study itself (5 seeds, hundreds of iterations) is in docs/noise.md; here a
two-iteration version checks the schema of summary.json, the figures, the
table and the command-line errors.
"""

from __future__ import annotations

import json

import pytest

from podilqr_jax.cli import main
from podilqr_jax.studies.reproduce import format_table

ROW_KEYS = {
    "system",
    "observation",
    "variant",
    "seed",
    "final_true_cost",
    "nominal_true_cost",
    "model_based_cost",
    "rollouts_per_iteration",
    "iterations",
    "wall_s",
    "sigma",
    "total_rollouts",
    "true_cost_history",
}


@pytest.mark.slow
def test_reproduce_writes_summary_figures_and_table(tmp_path, capsys):
    """`podilqr reproduce --tiny` (the CLI's smoke test): every panel and the sweep."""
    assert main(["reproduce", "--tiny", "--systems", "pendulum", "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    rows = summary["rows"]
    assert format_table(rows) in capsys.readouterr().out
    assert summary["machine"]["backend"] == "cpu" and summary["machine"]["x64"]  # the same description as bench
    for row in summary["rows"]:
        assert ROW_KEYS <= set(row)
        assert row["final_true_cost"] > 0 and row["model_based_cost"] > 0
    main_rows = [r for r in rows if r["study"] == "main"]
    seen = {(r["observation"], r["variant"]) for r in main_rows}
    assert seen == {
        ("full", "nominal"),
        ("full", "plain"),
        ("full", "feedback"),
        ("partial", "nominal"),
        ("partial", "plain"),
        ("partial", "feedback"),
        ("partial", "averaged"),
        ("partial", "iv"),
    }
    iv = [r for r in main_rows if r["variant"] == "iv"][0]
    assert iv["estimator"] == "iv" and iv["n_avg"] == 1
    # every row of a panel compares with the nominal run of the same seed and sigma
    for r in main_rows:
        nominal = [n for n in main_rows if n["observation"] == r["observation"] and n["variant"] == "nominal"]
        assert r["nominal_true_cost"] == nominal[0]["final_true_cost"]
    averaged = [r for r in main_rows if r["variant"] == "averaged"][0]
    plain = [r for r in main_rows if r["variant"] == "plain" and r["observation"] == "partial"][0]
    assert averaged["n_avg"] == 10 and averaged["rollouts_per_iteration"] > 10 * plain["rollouts_per_iteration"]
    sweep = {r["sigma"] for r in rows if r["study"] == "sigma_sweep"}
    assert len(sweep) == 2  # 3 x the default sigma of each observation
    for name in ("fig2_true_cost.png", "sigma_sweep.png"):
        assert (tmp_path / name).stat().st_size > 10_000
    table = (tmp_path / "table.md").read_text()
    assert table == format_table(rows) + "\n"
    assert "| pendulum | partial | averaged |" in table and "Sigma sweep" in table


def test_solve_with_paper_noise_reports_true_cost_ratio(tmp_path, capsys):
    out = tmp_path / "r.json"
    argv = ["solve", "pendulum-full", "--noise", "paper", "--compare", "--no-plots", "--out", str(out)]
    code = main(argv + ["--set", "max_iterations=2", "--set", "horizon=8"])
    assert code == 0
    payload = json.loads(out.read_text())
    assert payload["noisy"] and payload["variant"] == "feedback"  # the task's noisy default
    assert payload["noise"] == {"initial": 0.01, "process": 0.001, "measurement": 0.0}
    assert payload["ratio_to_model_based"] == pytest.approx(payload["final_true_cost"] / payload["model_based_cost"])
    assert "true cost (noiseless, closed loop) / model-based" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "pattern"),
    [
        (["solve", "pendulum-full", "--noise", "process=-1"], "must be >= 0"),
        (["solve", "pendulum-full", "--noise", "loud"], "--noise expects"),
        (["solve", "pendulum-full", "--noise", "paper", "--set", "variant=avg"], "Unknown variant 'avg'"),
        (["reproduce", "--systems", "rocket"], "--systems takes"),
        (["reproduce", "--seeds", "0"], "`seeds` must be an integer >= 1"),
    ],
)
def test_noise_input_errors(tmp_path, capsys, argv, pattern):
    code = main(argv + ["--out", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: ") and pattern in err.replace("\n", " ")
    assert "Traceback" not in err
