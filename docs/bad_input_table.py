"""Every bad input we tried on `podilqr solve`, and what the user sees.

    python docs/bad_input_table.py                 # print the table
    python docs/bad_input_table.py --write docs/bad_input.md

Each case writes its files into a fresh temporary folder, puts a result file
there that must survive untouched, runs the CLI in-process (the same
``podilqr_jax.cli.main`` as the ``podilqr`` command) and records the exit
status and the message on stderr. ``tests/test_bad_input.py`` runs the same
cases and asserts: non-zero exit, one message without a traceback, and the
existing result file unchanged.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import os
import sys
import tempfile
import textwrap
from typing import Callable

MODEL = """<mujoco model="arm">
  <option timestep="0.02" integrator="{integrator}"><flag contact="disable"/></option>
  {asset}
  <worldbody>
    <body name="link">
      <joint name="hinge" type="hinge" axis="0 1 0" damping="0.01"/>
      <geom type="{geom}" {geom_args} mass="0.5"/>
      <site name="tip" pos="0 0 0.5"/>
    </body>
  </worldbody>
  <actuator><motor name="torque" joint="hinge"/></actuator>
  <sensor><framepos name="tip_pos" objtype="site" objname="tip"/></sensor>
</mujoco>
"""
GOOD_GEOM = dict(geom="capsule", geom_args='fromto="0 0 0 0 0 0.5" size="0.02"', asset="", integrator="Euler")

TASK = """name = "arm"
model = "arm.xml"
substeps = 5
horizon = {horizon}
target = {target}

[observation]
{observation}

[start]
qpos = {qpos}

[cost]
Q = {Q}
R = 1.0

[solver]
n_s = 20
"""
GOOD_TASK = dict(horizon=20, target="[0.0]", observation='qpos = ["hinge"]', qpos="[3.14159]", Q="1.0")

SENTINEL = '{"kept": "a result written earlier"}\n'


@dataclasses.dataclass(frozen=True)
class Case:
    what: str
    args: tuple[str, ...]  # CLI arguments; {dir} is the case's folder
    model: dict = dataclasses.field(default_factory=dict)  # overrides of GOOD_GEOM
    task: dict = dataclasses.field(default_factory=dict)  # overrides of GOOD_TASK
    raw_model: str | None = None  # the model file's whole text
    raw_task: str | None = None
    setup: Callable[[str], None] | None = None


SOLVE = ("solve", "{dir}/arm.toml", "--out", "{dir}/result.json", "--no-plots", "--quiet")


def _read_only_folder(root: str) -> None:
    open(os.path.join(root, "not_a_folder"), "w").close()


def _task_in_latin1(root: str) -> None:
    with open(os.path.join(root, "arm.toml"), "wb") as f:
        f.write(TASK.format(**GOOD_TASK).replace('name = "arm"', 'name = "bras articul\xe9"').encode("latin-1"))


def _checkpoint(content: bytes) -> Callable[[str], None]:
    def write(root: str) -> None:
        os.makedirs(os.path.join(root, "ckpt"))
        with open(os.path.join(root, "ckpt", "checkpoint.npz"), "wb") as f:
            f.write(content)

    return write


CASES = (
    Case("Malformed XML (an unclosed element)", SOLVE, raw_model="<mujoco><worldbody><body></worldbody></mujoco>"),
    Case(
        "A mesh file that does not exist",
        SOLVE,
        model=dict(geom="mesh", geom_args='mesh="m"', asset='<asset><mesh name="m" file="missing.stl"/></asset>'),
    ),
    Case(
        "A model MJX cannot load (implicit integrator), asked to run on MJX",
        SOLVE + ("--set", "engine=mjx"),
        model=dict(integrator="implicit"),
    ),
    Case("The model file does not exist", SOLVE, raw_task=TASK.format(**GOOD_TASK).replace("arm.xml", "nope.xml")),
    Case("An unknown joint name", SOLVE, task=dict(observation='qpos = ["elbow"]')),
    Case(
        "An unknown sensor name",
        SOLVE,
        task=dict(observation='sensors = ["tip_vel"]', target="[0.0, 0.0, 0.5]"),
    ),
    Case("An observation of size 0", SOLVE, task=dict(observation="qpos = []")),
    Case("`horizon` 0", SOLVE, task=dict(horizon=0)),
    Case("`horizon` negative", SOLVE, task=dict(horizon=-5)),
    Case("`q` 0", SOLVE + ("--set", "q=0")),
    Case("A non-finite number in the task file", SOLVE, task=dict(Q="nan")),
    Case("An infinite start state", SOLVE, task=dict(qpos="[inf]")),
    Case("A target of the wrong length", SOLVE, task=dict(target="[0.0, 0.0]")),
    Case("A cost matrix of the wrong shape", SOLVE, task=dict(Q="[[1.0, 0.0], [0.0, 1.0]]")),
    Case("A start state of the wrong length", SOLVE, task=dict(qpos="[3.1, 0.0]")),
    Case("`n_s` below the number of regressors", SOLVE + ("--set", "n_s=3")),
    Case("An unknown solver setting", SOLVE + ("--set", "sigmaa=1e-3")),
    Case(
        "An unknown setting in a task file's [solver] table",
        SOLVE,
        raw_task=TASK.format(**GOOD_TASK).replace("n_s = 20", "sigmaa = 1e-3"),
    ),
    Case("A solver setting of the wrong type", SOLVE + ("--set", "sigma=abc")),
    Case("An unknown engine", SOLVE + ("--set", "engine=gpu")),
    Case("`--restarts` 0", SOLVE + ("--restarts", "0")),
    Case("`--restarts` resuming a folder written without restarts", SOLVE + ("--restarts", "2", "--resume", "{dir}")),
    Case(
        "Exact Jacobians asked of the native engine",
        SOLVE + ("--method", "model-based", "--set", "engine=native", "--set", "jacobian=exact"),
    ),
    Case("A task file that is not valid TOML", SOLVE, raw_task='name = "arm"\nmodel = arm.xml\n'),
    Case("A task file without a model", SOLVE, raw_task='name = "arm"\nhorizon = 20\n'),
    Case("A task file that is not UTF-8 (Latin-1)", SOLVE, setup=_task_in_latin1),
    Case("An unknown bundled task", ("solve", "pendulum-ful", "--out", "{dir}/result.json")),
    Case("An unknown command-line option", SOLVE + ("--frobnicate",)),
    Case(
        "An output path that cannot be written",
        ("solve", "{dir}/arm.toml", "--out", "{dir}/not_a_folder/result.json"),
        setup=_read_only_folder,
    ),
    Case("`--out` names a folder", ("solve", "{dir}/arm.toml", "--out", "{dir}")),
    Case("`--resume` from a folder without a checkpoint", SOLVE + ("--resume", "{dir}/nowhere")),
    Case("`--resume` from an empty checkpoint.npz", SOLVE + ("--resume", "{dir}/ckpt"), setup=_checkpoint(b"")),
    Case(
        "`--resume` from a checkpoint.npz cut short",
        SOLVE + ("--resume", "{dir}/ckpt"),
        setup=_checkpoint(b"PK\x03\x04\x14\x00\x00\x00\x08\x00"),
    ),
    Case(
        "`--resume` from a checkpoint.npz of other content",
        SOLVE + ("--resume", "{dir}/ckpt"),
        setup=_checkpoint(b"\x93NUMPY\x01\x00garbage" * 4),
    ),
    Case("`--every` 0", SOLVE + ("--checkpoint", "{dir}/ckpt", "--every", "0")),
    Case(
        "A checkpoint folder that cannot be created",
        SOLVE + ("--checkpoint", "{dir}/not_a_folder/ckpt"),
        setup=_read_only_folder,
    ),
)


@dataclasses.dataclass
class Outcome:
    case: Case
    status: int
    stderr: str
    result_kept: bool


def run_case(case: Case) -> Outcome:
    from podilqr_jax import cli

    with tempfile.TemporaryDirectory() as root:
        with open(os.path.join(root, "arm.xml"), "w") as f:
            f.write(case.raw_model if case.raw_model is not None else MODEL.format(**{**GOOD_GEOM, **case.model}))
        with open(os.path.join(root, "arm.toml"), "w") as f:
            f.write(case.raw_task if case.raw_task is not None else TASK.format(**{**GOOD_TASK, **case.task}))
        with open(os.path.join(root, "result.json"), "w") as f:
            f.write(SENTINEL)
        if case.setup is not None:
            case.setup(root)
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                status = cli.main([a.format(dir=root) for a in case.args])
            except SystemExit as exc:  # argparse's usage errors
                status = exc.code
        with open(os.path.join(root, "result.json")) as f:
            kept = f.read() == SENTINEL
        return Outcome(case, int(status), err.getvalue().replace(root, "DIR"), kept)


def table(outcomes: list[Outcome]) -> str:
    lines = [
        "| bad input | exit | what the user sees (stderr) |",
        "|---|---|---|",
    ]
    for o in outcomes:
        message = " ".join(o.stderr.split()).replace("|", "\\|")
        lines.append(f"| {o.case.what} | {o.status} | {message} |")
    return "\n".join(lines)


HEADER = """# Bad input: what the user sees

Every case below was run by `python docs/bad_input_table.py --write docs/bad_input.md`,
which wrote this page: the command `podilqr solve` with a task file (or options)
broken in one way, in a folder that already held a `result.json`. Every case
exits with a non-zero status (2 for input errors, as argparse does for its usage
errors), prints one paragraph to stderr and no traceback, and leaves the earlier
`result.json` untouched (outputs are checked before any work and written
atomically). `tests/test_bad_input.py` asserts all of that for each row, and
`tests/test_properties.py` draws random task configurations with hypothesis:
each either solves to a finite result or fails with one of these errors.

The task file of the cases (each changes one thing):

```toml
{task}```

and its model `arm.xml`, a one-link arm with a `tip_pos` sensor.

"""


def page(outcomes: list[Outcome]) -> str:
    """docs/bad_input.md: the header, the task file of the cases and the table."""
    return HEADER.format(task=TASK.format(**GOOD_TASK)) + table(outcomes) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", default=None, help="write the markdown page here")
    args = parser.parse_args(argv)
    outcomes = [run_case(c) for c in CASES]
    text = page(outcomes)
    if args.write:
        with open(args.write, "w", encoding="utf-8") as f:
            f.write(text)
        print(f"wrote {args.write} ({len(outcomes)} cases)", file=sys.stderr)
    else:
        print(text)
    bad = [o.case.what for o in outcomes if o.status == 0 or "Traceback" in o.stderr or not o.result_kept]
    if bad:
        print(textwrap.fill("NOT handled: " + "; ".join(bad)), file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
