"""The `podilqr` command line: outputs, task files and one-paragraph errors."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from podilqr_jax.cli import main

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TASK_FILE = os.path.join(REPO, "examples", "tasks", "my_pendulum.toml")
REQUIRED_KEYS = {"final_cost", "cost_history", "controls", "iterations", "status", "rollouts", "wall_s", "compile_s"}


def test_solve_writes_json_and_plots(tmp_path, capsys):
    out = tmp_path / "sub" / "result.json"
    code = main(["solve", "pendulum-full", "--set", "max_iterations=4", "--set", "horizon=10", "--out", str(out)])
    assert code == 0
    payload = json.loads(out.read_text())
    assert REQUIRED_KEYS <= set(payload)
    assert len(payload["controls"]) == 10
    umask = os.umask(0)
    os.umask(umask)
    assert os.stat(out).st_mode & 0o777 == 0o666 & ~umask  # as open() would make it, not mkstemp's 0600
    assert payload["iterations"] == 4 and payload["cost_history"][-1] < payload["cost_history"][0]
    assert (tmp_path / "sub" / "result_cost.png").stat().st_size > 0
    assert (tmp_path / "sub" / "result_trajectory.png").stat().st_size > 0
    assert "pod-ilqr on pendulum-full" in capsys.readouterr().err


def test_solve_task_file_with_compare(tmp_path):
    out = tmp_path / "r.json"
    code = main(["solve", TASK_FILE, "--compare", "--set", "max_iterations=3", "--out", str(out), "--no-plots"])
    assert code == 0
    payload = json.loads(out.read_text())
    assert payload["task"] == "my-pendulum" and payload["q"] == 2
    assert payload["model_based_cost"] > 0 and payload["ratio_to_model_based"] > 0
    assert not (tmp_path / "r_cost.png").exists()


def test_compare_says_where_two_solves_part_when_their_costs_differ(tmp_path, capsys):
    """Noiseless costs more than 1% apart: --compare prints where the two
    nominal trajectories are farthest apart and writes it to the JSON. Here a
    huge fixed sigma (1 rad) makes the identified model poor for two iterations."""
    from podilqr_jax.cli import _apart

    out = tmp_path / "r.json"
    sets = ["max_iterations=2", "sigma=1", "adapt_sigma=false"]
    argv = ["solve", "pendulum-full", "--compare", "--quiet", "--no-plots", "--out", str(out)]
    assert main(argv + [a for s in sets for a in ("--set", s)]) == 0
    payload = json.loads(out.read_text())
    assert abs(payload["ratio_to_model_based"] - 1) > 0.01
    gap = payload["largest_state_gap"]
    pod, ref = np.asarray(payload["states"]), np.asarray(payload["model_based"]["states"])
    assert gap["gap"] == np.max(np.abs(pod - ref)) == abs(gap["this"] - gap["other"])
    assert gap["this"] == pod[gap["step"], payload["state_labels"].index(gap["state"])]
    err = capsys.readouterr().err
    assert f"farthest apart in {gap['state']} at step {gap['step']}" in err
    assert "two local minima" not in err and "--set seed=N" not in err  # neither converged in two iterations
    both = _apart(1.343, {**gap, "state": "qpos:shoulder"}, both_converged=True)
    assert both.startswith("POD-iLQR ends 34.3% above the model-based solve, both converged: two local minima")
    assert both.endswith("other starts may end in other basins, lower ones too: try `--set seed=N` (other sysid draws)")


def test_task_file_on_a_model_that_is_not_bundled(tmp_path, capsys):
    """examples/tasks/reacher.toml: two limited motors, a fingertip sensor; from
    the CLI alone. --compare is refused before any solve (sensor observation)."""
    reacher = os.path.join(REPO, "examples", "tasks", "reacher.toml")
    assert main(["solve", reacher, "--compare", "--out", str(tmp_path / "c.json")]) == 2
    assert "model-based reference needs a cost on the state" in capsys.readouterr().err.replace("\n", " ")
    out = tmp_path / "r.json"
    assert main(["solve", reacher, "--set", "max_iterations=4", "--out", str(out), "--no-plots", "--quiet"]) == 0
    d = json.loads(out.read_text())
    assert d["observation_labels"][:3] == [
        "sensor:fingertip_pos[0]",
        "sensor:fingertip_pos[1]",
        "sensor:fingertip_pos[2]",
    ]
    assert d["control_limits"] == [[-0.5, 0.5], [-0.5, 0.5]]
    assert max(abs(u) for row in d["controls"] for u in row) <= 0.5
    assert d["cost_history"][-1] < d["cost_history"][0]


@pytest.mark.parametrize(
    "argv, pattern",
    [
        (["solve", "rocket-full"], "Unknown task 'rocket-full'"),
        (["solve", "pendulum-full", "--set", "sigmaa=1"], "Unknown solver setting"),
        (["solve", "pendulum-full", "--set", "sigma"], "--set expects KEY=VALUE"),
        (["solve", "pendulum-full", "--set", "n_s=1"], "below the 3 regressors"),
        (["solve", "missing/task.toml"], "does not exist"),
    ],
)
def test_input_errors_print_one_paragraph(tmp_path, capsys, argv, pattern):
    code = main(argv + ["--out", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("error: ") and pattern in err.replace("\n", " ")
    assert "Traceback" not in err
    assert not (tmp_path / "r.json").exists()


def test_bad_task_file_values(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(
        open(TASK_FILE)
        .read()
        .replace("QT = 100.0", "QT = nan")
        .replace('"my_pendulum.xml"', '"%s"' % os.path.join(os.path.dirname(TASK_FILE), "my_pendulum.xml"))
    )
    assert main(["solve", str(bad), "--out", str(tmp_path / "r.json")]) == 2
    assert "non-finite number at `cost.QT`" in capsys.readouterr().err


def test_unwritable_output_keeps_existing_file(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    existing = locked / "result.json"
    existing.write_text("{}")
    os.chmod(locked, 0o500)
    try:
        if os.access(locked, os.W_OK):  # running as root: permissions do not bind
            pytest.skip("permissions are not enforced for this user")
        assert main(["solve", "pendulum-full", "--out", str(existing)]) == 2
        assert "not writable" in capsys.readouterr().err
        assert existing.read_text() == "{}"
    finally:
        os.chmod(locked, 0o700)


def test_output_path_is_a_folder(tmp_path, capsys):
    assert main(["solve", "pendulum-full", "--out", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err


def test_console_script_exit_code_and_no_traceback(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "podilqr_jax.cli", "solve", "pendulum-full", "--bogus-option"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert proc.returncode == 2
    assert "unrecognized arguments: --bogus-option" in proc.stderr
    assert "Traceback" not in proc.stderr and proc.stdout == ""


def test_tasks_lists_the_bundled_tasks(capsys):
    import podilqr_jax as pj

    assert main(["tasks"]) == 0
    header, *rows = [re.split(r"\s{2,}", line.strip()) for line in capsys.readouterr().out.splitlines()]
    assert header == ["task", "observation", "nx", "nz", "nu", "horizon", "control dt", "controls"]
    assert [row[0] for row in rows] == list(pj.TASKS)
    for name, row in zip(pj.TASKS, rows, strict=True):
        env = pj.make_task(name)
        d = env.dims
        assert row[1] == ", ".join(env.observation_labels)
        assert row[2:6] == [str(d.nx), str(d.nz), str(d.nu), str(d.horizon)], row


@pytest.mark.slow
def test_bench_tiny_runs_every_section_from_the_installed_package(tmp_path):
    """`podilqr bench --tiny` (the smoke test of the command): every section at
    the smallest size, run from outside the source tree, so it needs only the
    installed package (child processes included)."""
    out = tmp_path / "bench"
    proc = subprocess.run(
        [sys.executable, "-m", "podilqr_jax.cli", "bench", "--tiny", "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
    report = json.loads((out / "bench.json").read_text())
    sections = {"grids", "baselines", "tasks", "memory", "devices", "cache", "ls_memory", "engines"}
    assert {"machine", "settings"} | sections <= set(report)
    cells = report["grids"]["pendulum-full"]
    assert [(c["n_s"], c["n_avg"]) for c in cells] == [(8, 1), (8, 2)]
    assert all(c["iteration_s_median"] > 0 and c["recompiles_after_first"] == 0 for c in cells)
    summary = report["tasks"]["pendulum-full"]
    assert summary["rollout_throughput_vs_native"] > 0 and summary["speedup_vs_serial"] > 0
    assert report["memory"][0]["finite"] and "error" not in report["memory"][0]
    assert report["devices"][0]["devices"] == 2
    cache = {row["mode"]: row for row in report["cache"]["runs"]}
    assert set(cache) == {"off", "cold", "warm"} and not any("error" in row for row in cache.values())
    assert cache["off"]["cache_entries"] == 0 < cache["cold"]["cache_entries"] <= cache["warm"]["cache_entries"]
    assert report["cache"]["same_cost_warm_as_cold"]
    rows = report["ls_memory"]["rows"]
    assert [row["chunk"] for row in rows] == [None, 44] and rows[1]["max_rel_cost_diff_vs_first"] < 1e-9
    speeds = report["engines"]["speeds"]
    assert [row["task"] for row in speeds] == ["pendulum-full"]  # run outside a checkout: no task files found
    assert speeds[0]["native"]["steps_per_s"] > 0 and speeds[0]["mjx"]["steps_per_s"] > 0
    assert set(report["engines"]["time_to_cost"][0]) >= {"mjx_s", "native_s", "target_cost"}
    assert "native steps/s" in proc.stdout
    for name in ("time_per_iteration.png", "phases.png", "throughput.png"):
        assert (out / name).stat().st_size > 0
    assert "| pendulum-full |" in proc.stdout


def test_bench_bad_input_exits_2(tmp_path, capsys):
    assert main(["bench", "--tasks", "rocket-full", "--out", str(tmp_path)]) == 2
    assert "--tasks takes a comma-separated subset" in capsys.readouterr().err
    assert main(["bench", "--sections", "grid,nope", "--out", str(tmp_path)]) == 2
    assert "--sections takes a comma-separated subset" in capsys.readouterr().err
    assert not (tmp_path / "bench.json").exists()


def test_help_and_the_parsers_load_neither_jax_nor_mujoco():
    """`podilqr --help` (and every command's help) answers without importing JAX or
    MuJoCo: the package's names load on first use (podilqr_jax/__init__.py)."""
    code = (
        "import sys, contextlib, io\n"
        "from podilqr_jax import cli\n"
        "for argv in (['--help'], ['solve', '--help'], ['evaluate', '--help'], ['bench', '--help']):\n"
        "    with contextlib.redirect_stdout(io.StringIO()):\n"
        "        try:\n"
        "            cli.main(argv)\n"
        "        except SystemExit:\n"
        "            pass\n"
        "print(sorted(m for m in ('jax', 'mujoco') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"


def test_xla_log_lines_are_kept_out_unless_verbose(monkeypatch):
    """XLA's C++ log lines (its slow-compile alarms, ERROR-level lines, among
    them) are hidden by every command unless --verbose or PODILQR_VERBOSE=1:
    quiet_backends raises TF_CPP_MIN_LOG_LEVEL to 3 before JAX loads, and a
    level the user set is kept. That level 3 silences XLA's lines is shown on
    its informational lines (TF_CPP_MAX_VLOG_LEVEL), which level 0 lets through."""
    import logging

    from podilqr_jax import cli

    monkeypatch.setattr(logging.getLogger("jax"), "level", logging.getLogger("jax").level)  # restored afterwards
    for verbose, variable, expected in ((False, None, "3"), (True, None, None), (False, "1", None)):
        monkeypatch.delenv("TF_CPP_MIN_LOG_LEVEL", raising=False)
        if variable is None:
            monkeypatch.delenv("PODILQR_VERBOSE", raising=False)
        else:
            monkeypatch.setenv("PODILQR_VERBOSE", variable)
        cli.quiet_backends(verbose=verbose)
        assert os.environ.get("TF_CPP_MIN_LOG_LEVEL") == expected, (verbose, variable)
    monkeypatch.setenv("TF_CPP_MIN_LOG_LEVEL", "0")
    monkeypatch.delenv("PODILQR_VERBOSE", raising=False)
    cli.quiet_backends(verbose=False)
    assert os.environ["TF_CPP_MIN_LOG_LEVEL"] == "0"  # the user's own level is kept
    assert logging.getLogger("jax").level == logging.ERROR

    code = "import jax.numpy as jnp\nprint(float(jnp.ones(3).sum()))\n"
    env = {k: v for k, v in os.environ.items() if k != "PODILQR_VERBOSE"}
    env["TF_CPP_MAX_VLOG_LEVEL"] = "1"
    runs = {
        level: subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            env={**env, "TF_CPP_MIN_LOG_LEVEL": level},
            timeout=120,
        )
        for level in ("3", "0")
    }
    assert all(r.returncode == 0 and r.stdout.strip() == "3.0" for r in runs.values())
    assert runs["3"].stderr.strip() == ""
    assert len(runs["0"].stderr.splitlines()) > 10  # the lines level 3 kept out


def test_a_gradient_past_float_range_prints_as_overflow():
    from podilqr_jax.cli import _figure

    assert _figure(float("inf")).strip() == "overflow" and _figure(float("nan")).strip() == "-"
    assert _figure(0.0015).strip() == "0.0015" and len(_figure(float("inf"))) == len(_figure(1.0))
