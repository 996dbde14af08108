"""The code blocks of README.md and docs/task_files.md, as written.

- README.md's Python blocks run in order, in one namespace, from the
  repository's folder (in this process, so that programs other tests compiled
  are reused), and each shows the library doing its job.
- Every ``podilqr`` command of a shell block is taken by the CLI's own parser
  and the files it reads exist, and README.md's shell lines run as written, in
  order, from a scratch folder (each writes what its comment promises), except
  the three that run for minutes (their comments say how long: ``reproduce
  --quick``, ``evaluate``, ``bench``), which run at their smallest size in the
  smoke tests named in ``LONG_RUNS``. The install commands at the top of the
  README: the test command is what CI (``.ci/run``) runs; the main command's
  solve is the README's first Python block (both solvers, default settings).
- docs/task_files.md: each complete TOML block is the task file its command
  names, byte for byte, and the command runs as written (from a scratch folder
  whose ``examples`` is the repository's), printing the summary shown below it.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import json
import os
import re
import shlex

import numpy as np
import pytest
import test_swingup

from podilqr_jax import cli

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
INSTALL = ("python3 -m venv .venv",)  # the README's install commands: CI's own job
# README.md's shell commands that run for minutes, and the smoke test that runs each at its smallest size.
LONG_RUNS = {
    "reproduce": ("test_reproduce.py", "test_reproduce_writes_summary_figures_and_table"),
    "evaluate": ("test_evaluate.py", "test_cli_evaluate_runs_and_loads_the_saved_result"),
    "bench": ("test_cli.py", "test_bench_tiny_runs_every_section_from_the_installed_package"),
}


def blocks(doc: str) -> list[tuple[str, str, int]]:
    """The fenced code blocks of ``doc``: (language, text, first line)."""
    text = open(os.path.join(ROOT, doc), encoding="utf-8").read()
    found = []
    for m in re.finditer(r"^```(\w*)\n(.*?)^```", text, re.S | re.M):
        found.append((m.group(1), m.group(2), text[: m.start()].count("\n") + 2))
    return found


def commands(doc: str) -> list[list[str]]:
    """The ``podilqr`` command lines of ``doc``'s shell blocks, split as a shell would."""
    found = []
    for lang, text, _ in blocks(doc):
        if lang != "bash":
            continue
        for line in text.splitlines():
            if line.startswith(INSTALL):
                continue
            words = shlex.split(line, comments=True)
            assert words and words[0] == "podilqr", f"{doc}: a shell line that is not a podilqr command: {line!r}"
            found.append(words[1:])
    return found


def _settings(toml: str) -> list[str]:
    """A TOML text's lines without comments and padding."""
    lines = (line.split("#")[0].strip() for line in toml.splitlines())
    return [line for line in lines if line]


@pytest.mark.slow
def test_the_readme_python_blocks_run_as_written(monkeypatch):
    python = [(text, line) for lang, text, line in blocks("README.md") if lang == "python"]
    assert len(python) == 4, "a Python block was added to README.md: say here what it must show"
    ns: dict = {}
    after = []
    monkeypatch.chdir(ROOT)
    with contextlib.redirect_stdout(io.StringIO()):
        for text, line in python:
            exec(compile(text, f"README.md:{line}", "exec"), ns)
            after.append(dict(ns))
    # The partially observed cart-pole: the model-based optimum (both solvers run
    # their 300 iterations down to a relative decrease of ~1e-9 per step).
    # The same checks as every bundled task's swing-up (tests/test_swingup.py leaves this one to this test).
    assert after[0]["env"].name == test_swingup.README_TASK
    test_swingup.check_swing_up(after[0]["env"], after[0]["result"], after[0]["reference"])
    # The reacher loaded from its MJCF file: the fingertip reaches (0, 0.4, 0) at rest.
    reach = after[1]["result"]
    assert reach.status.value == "converged" and reach.final_cost < 0.1 * reach.cost_history[0]
    np.testing.assert_allclose(reach.observations[-1][:3], [0.0, 0.4, 0.0], atol=5e-3)
    # The noisy pendulum: the learnt policy's true cost falls.
    noisy = after[2]["result"]
    assert np.isfinite(noisy.final_true_cost) and noisy.final_true_cost < 0.5 * noisy.true_cost_history[0]
    # The policy stepped by hand: on the nominal's measurements it plays the nominal's controls.
    np.testing.assert_allclose(np.asarray(after[3]["u"]), noisy.controls[0], atol=1e-9)


def test_every_readme_command_is_taken_by_the_cli():
    from podilqr_jax.studies.bench.suite import parser as bench_parser

    seen = set()
    for argv in commands("README.md") + commands("docs/task_files.md"):
        parser = bench_parser() if argv[0] == "bench" else cli._parser()
        args = parser.parse_args(argv[1:] if argv[0] == "bench" else argv)
        seen.add(argv[0])
        for name in ("task", "result"):
            value = getattr(args, name, None)
            if value and value.endswith((".toml", ".json")) and not value.startswith("runs/"):
                assert os.path.isfile(os.path.join(ROOT, value)), f"podilqr {' '.join(argv)}: no {value}"
    assert {"tasks", "solve", "animate", "reproduce", "evaluate", "bench"} <= seen
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert cli.main(["tasks"]) == 0
    assert "cartpole-partial" in out.getvalue()


@pytest.mark.slow
def test_the_readme_shell_lines_run_as_written(tmp_path, monkeypatch, capsys):
    os.symlink(os.path.join(ROOT, "examples"), tmp_path / "examples")
    monkeypatch.chdir(tmp_path)
    ran = []
    for argv in commands("README.md"):
        if argv[0] in LONG_RUNS:
            module, name = LONG_RUNS[argv[0]]
            smoke = getattr(importlib.import_module(module.removesuffix(".py")), name, None)
            assert callable(smoke), f"podilqr {argv[0]}: no smoke test {module}::{name}"
            continue
        assert cli.main(argv) == 0, argv
        ran.append(argv[0])
    assert ran.count("solve") == 4 and {"tasks", "animate"} <= set(ran)
    assert "cartpole-partial" in capsys.readouterr().out  # podilqr tasks
    # podilqr solve pendulum-full --out runs/p/result.json: JSON, cost and trajectory PNGs, motion GIF
    swing = json.loads((tmp_path / "runs/p/result.json").read_text())
    assert swing["status"] == "converged" and swing["final_cost"] < 0.1 * swing["cost_history"][0]
    for name in ("result_cost.png", "result_trajectory.png", "result_motion.gif"):
        assert (tmp_path / "runs/p" / name).stat().st_size > 0, name
    assert (tmp_path / "swingup.gif").stat().st_size > 0  # podilqr animate runs/p/result.json --out swingup.gif
    reference = json.loads((tmp_path / "r.json").read_text())  # the model-based reference
    assert reference["method"] == "model-based" and reference["status"] in ("converged", "max_iterations")
    noisy = json.loads((tmp_path / "runs/noisy/result.json").read_text())  # learnt under noise, compared
    assert noisy["true_cost_history"][-1] < noisy["true_cost_history"][0] and noisy["ratio_to_model_based"] > 0


def test_the_task_file_guide_runs_as_written(tmp_path, monkeypatch):
    import importlib.util

    from podilqr_jax.ilqr.result import load_result
    from podilqr_jax.task.package_files import resolve_model_path

    docs = blocks("docs/task_files.md")
    files = {"reacher": "examples/tasks/reacher.toml", "my-pendulum": "examples/tasks/my_pendulum.toml"}
    for lang, text, line in docs:
        if lang != "toml":
            continue
        name = re.search(r'^name = "(.+)"', text, re.M)
        if name:  # a whole task file: the one on disk
            path = files[name.group(1)]
            on_disk = open(os.path.join(ROOT, path), encoding="utf-8").read()
            assert _settings(text) == _settings(on_disk), f"docs/task_files.md:{line} is not {path} as it is"
        else:  # alternatives for one setting: each model path resolves
            for model in re.findall(r'^model = "(pkg://([^/]+)/.+)"', text, re.M):
                if importlib.util.find_spec(model[1]) is not None:
                    assert os.path.isfile(resolve_model_path(model[0]))
    os.symlink(os.path.join(ROOT, "examples"), tmp_path / "examples")
    shown = [text for lang, text, _ in docs if lang == "" and " on reacher: " in text]
    monkeypatch.chdir(tmp_path)
    for argv in commands("docs/task_files.md"):
        assert cli.main(argv) == 0, argv
    reacher = load_result(tmp_path / "runs/reacher/result.json")
    status, final = re.search(r"on reacher: (\w+) after .*?cost \S+ -> (\S+);", " ".join(shown[0].split())).groups()
    assert reacher.status.value == status and abs(reacher.final_cost - float(final)) < 1e-4 * float(final)
    pendulum = json.loads((tmp_path / "runs/my_pendulum/result.json").read_text())
    assert pendulum["status"] == "converged" and pendulum["ratio_to_model_based"] < 1.001


def test_every_environment_variable_of_the_package_is_in_the_table():
    """docs/environment.md lists every PODILQR_* variable the package reads,
    and nothing the package does not read."""
    package = os.path.join(ROOT, "podilqr_jax")
    read = set()
    for folder, _, names in os.walk(package):
        for name in names:
            if name.endswith(".py"):
                with open(os.path.join(folder, name), encoding="utf-8") as f:
                    read |= set(re.findall(r"PODILQR_[A-Z0-9_]+", f.read()))
    with open(os.path.join(ROOT, "docs", "environment.md"), encoding="utf-8") as f:
        listed = set(re.findall(r"^\| `(PODILQR_[A-Z0-9_]+)`", f.read(), re.M))
    assert read == listed, f"read but not listed: {sorted(read - listed)}; listed but not read: {sorted(listed - read)}"
