"""What the race between starts keeps and saves: ``race_rung`` on the tasks that run several starts.

For each task, in a fresh process each, one at a time:

- ``podilqr solve FILE --set race_rung=0``: every start to its own end (no race);
- ``podilqr solve FILE``: the default race (``race_rung`` = ``RACE_RUNG``);

and from the first run's score histories, the race it would have run under other
rules, first rungs and margins (``ilqr.race.replay``: the starts a race keeps run what
they ran).
The table gives, per task, the starts, the best cost without the race, the race's
best over it, the start-iterations and rollouts it ran against the starts' own
ends, the wall seconds of both runs, and the default rule replayed; then every rule
replayed, over all the tasks.

    python benchmarks/race.py                        # the robots' and the basins' tasks (about 40 min on 2 cores)
    python benchmarks/race.py --only gym_ant_rise    # one task
    python benchmarks/race.py --replay-only          # the table from the runs saved
    python benchmarks/race.py --race-only            # the race again, the runs without it as saved

Runs go to runs/race/NAME-{off,race}.json; the tables are printed and written to
runs/race/race.json. The one measured for ``docs/robustness.md`` ("Racing the starts")
is benchmarks/results/race/race.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from podilqr_jax.ilqr.config import RACE_MARGIN, RACE_RUNG  # noqa: E402
from podilqr_jax.ilqr.race import replay  # noqa: E402

ROBOTS = os.path.join(ROOT, "examples", "tasks", "robots")
BASINS = os.path.join(ROOT, "examples", "tasks", "basins")
THIRD = os.path.join(ROOT, "examples", "tasks", "third_party")
# (task file, extra arguments): the contact-rich robots run CONTACT_RESTARTS starts by default;
# the basins' tasks have no contacts (one start by default) and run 8 here.
TASKS = [
    (os.path.join(ROBOTS, "dmc_manipulator_reach.toml"), []),
    (os.path.join(ROBOTS, "dmc_walker_knee.toml"), []),
    (os.path.join(ROBOTS, "gym_ant_rise.toml"), []),
    (os.path.join(ROBOTS, "gym_half_cheetah_run.toml"), []),
    (os.path.join(ROBOTS, "dmc_quadruped_stand.toml"), []),
    (os.path.join(THIRD, "gym_hopper_balance.toml"), []),
    (os.path.join(THIRD, "dmc_finger_turn.toml"), []),
    (os.path.join(BASINS, "cartpole_angles_short.toml"), ["--restarts", "8"]),
    (os.path.join(BASINS, "dmc_cartpole_angles_long.toml"), ["--restarts", "8"]),
    (os.path.join(BASINS, "acrobot_angles_short.toml"), ["--restarts", "8"]),
    (os.path.join(BASINS, "gym_inverted_double_pendulum_tilted.toml"), ["--restarts", "8"]),
    (os.path.join(BASINS, "gym_inverted_pendulum_tilted.toml"), ["--restarts", "8"]),
    (os.path.join(ROBOTS, "gym_walker2d_stand.toml"), []),
]
RUNGS = (8, 16, 32, 64)  # the first rungs and margins replayed
MARGINS = (1.0, 1.25, 1.5, 2.0, 3.0)


def name_of(path: str) -> str:
    return os.path.splitext(os.path.basename(path))[0]


def solve(path: str, extra: list, out: str, timeout: float) -> dict:
    cmd = [sys.executable, "-m", "podilqr_jax.cli", "solve", path, "--no-plots", "--quiet", "--out", out, *extra]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"timed_out": True, "command_wall_s": timeout}
    if not os.path.exists(out):
        return {"error": (proc.stderr or "")[-2000:], "command_wall_s": time.perf_counter() - t0}
    with open(out) as f:
        r = json.load(f)
    r["command_wall_s"] = time.perf_counter() - t0
    return r


def _score(r: dict) -> float:
    return r["final_true_cost"] if r.get("noisy") else r["final_cost"]


def _spent(r: dict) -> tuple[int, int]:
    starts = r.get("starts") or [{"iterations": r["iterations"], "rollouts": r["rollouts"]}]
    return sum(s["iterations"] for s in starts), sum(s["rollouts"] for s in starts)


def row_of(name: str, off: dict, on: dict) -> dict:
    row = {"task": name}
    if "final_cost" not in off:
        return row | {"off": {k: off.get(k) for k in ("timed_out", "error")}}
    histories = [s["cost_history"] for s in off["starts"]]
    iters_off, rollouts_off = _spent(off)
    row.update(
        starts=len(off["starts"]),
        best_off=_score(off),
        start_iterations_off=iters_off,
        rollouts_off=rollouts_off,
        wall_off=off["wall_s"],
        max_iterations=off["config"]["max_iterations"],
    )
    if off.get("noisy"):  # the race ranks the true costs; the starts record only the last
        histories = None
    replays = {}
    for b in RUNGS if histories else ():
        for m in MARGINS:
            cut, final = replay(histories, b, off["config"]["max_iterations"], m)
            iters = sum(cut.get(j, len(h) - 1) for j, h in enumerate(histories))
            replays[f"{b} x {m:g}"] = {"best_over_off": min(final) / row["best_off"], "start_iterations": iters}
    row["replayed"] = replays
    if "final_cost" in on:
        iters_on, rollouts_on = _spent(on)
        row.update(
            best_race=_score(on),
            ratio=_score(on) / row["best_off"],
            start_iterations_race=iters_on,
            rollouts_race=rollouts_on,
            wall_race=on["wall_s"],
            statuses_race=[s["status"] for s in on["starts"]],
        )
    else:
        row["race"] = {k: on.get(k) for k in ("timed_out", "error")}
    return row


DEFAULT = f"{RACE_RUNG} x {RACE_MARGIN:g}"


def table(rows: list) -> str:
    lines = [
        "| task | starts | best, no race | race / no race | start-iterations | rollouts | wall s "
        "| replayed: best / no race (start-iterations) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "best_off" not in r:
            lines.append(f"| {r['task']} | | {r.get('off')} | | | | | |")
            continue
        race = (
            (
                f"{r['ratio']:.4f} | {r['start_iterations_race']} / {r['start_iterations_off']} | "
                f"{r['rollouts_race']} / {r['rollouts_off']} | {r['wall_race']:.0f} / {r['wall_off']:.0f}"
            )
            if "ratio" in r
            else f"{r.get('race')} | | | "
        )
        v = r["replayed"].get(DEFAULT)
        rep = f"{v['best_over_off']:.4f} ({v['start_iterations']})" if v else ""
        lines.append(f"| {r['task']} | {r['starts']} | {r['best_off']:.6g} | {race} | {rep} |")
    return "\n".join(lines)


def rules(rows: list) -> str:
    """Every replayed rule over the tasks: how many it left more than 1% above the solve
    without the race, the worst ratio, and the start-iterations it ran over those."""
    rows = [r for r in rows if r.get("replayed")]
    off = sum(r["start_iterations_off"] for r in rows)
    lines = [
        f"| first rung x margin | tasks > 1% above (of {len(rows)}) | worst | start-iterations (of {off}) |",
        "|---|---|---|---|",
    ]
    for b in RUNGS:
        for m in MARGINS:
            key = f"{b} x {m:g}"
            ratios = [r["replayed"][key]["best_over_off"] for r in rows]
            iters = sum(r["replayed"][key]["start_iterations"] for r in rows)
            mark = " (default)" if key == DEFAULT else ""
            worse = sum(x > 1.01 for x in ratios)
            lines.append(f"| {key}{mark} | {worse} | {max(ratios):.3f} | {iters} ({iters / off:.2f}) |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=os.path.join(ROOT, "runs", "race"))
    ap.add_argument("--only", default="", help="comma-separated task names (file names without .toml)")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per solve")
    ap.add_argument("--replay-only", action="store_true", help="no solves: the table from the runs in --out")
    ap.add_argument("--race-only", action="store_true", help="solve with the race only; the runs without it as saved")
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    only = {n for n in args.only.split(",") if n}
    rows = []
    for path, extra in TASKS:
        name = name_of(path)
        if only and name not in only:
            continue
        runs = {}
        for tag, more in (("off", ["--set", "race_rung=0"]), ("race", [])):
            out = os.path.join(args.out, f"{name}-{tag}.json")
            if args.replay_only or (args.race_only and tag == "off" and os.path.exists(out)):
                runs[tag] = json.load(open(out)) if os.path.exists(out) else {"error": "not run"}
            else:
                runs[tag] = solve(path, extra + more, out, args.timeout)
            print(f"{name} {tag}: {runs[tag].get('status', runs[tag])} {runs[tag].get('wall_s', '')}", flush=True)
        rows.append(row_of(name, runs["off"], runs["race"]))
    text = table(rows)
    print(f"\nrace_rung = {RACE_RUNG}, race_margin = {RACE_MARGIN:g} (the defaults) against every start to its end:\n")
    print(text)
    print("\nThe race's rules replayed on the solves without it:\n")
    print(rules(rows))
    with open(os.path.join(args.out, "race.json"), "w") as f:
        json.dump({"race_rung": RACE_RUNG, "race_margin": RACE_MARGIN, "rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
