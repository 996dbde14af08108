"""benchmarks/gpu_check.py, the prepared GPU check, runs end to end (here on the CPU, --quick)."""

from __future__ import annotations

import importlib.util
import json
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_the_gpu_check_runs_and_writes_its_table(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("gpu_check", ROOT / "benchmarks" / "gpu_check.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main(["--quick", "--out", str(tmp_path)]) == 0
    out = json.loads((tmp_path / "gpu_check.json").read_text())
    by_engine = {r["engine"]: r for r in out["steps"]}
    assert set(by_engine) == {"native", "jax", "warp"}
    assert by_engine["native"]["steps_per_s"] > 0 and by_engine["jax"]["steps_per_s"] > 0
    assert "steps_per_s" in by_engine["warp"] or "warp" in by_engine["warp"]["error"].lower()
    (solve,) = out["solves"]
    assert solve["starts"] == 1 and solve["iterations"] == 2 and solve["cost"] > 0
    assert "| cartpole | 8 | native |" in capsys.readouterr().out
