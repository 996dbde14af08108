"""Mirrored perturbations (+du, -du, fit on half-differences) against the plain fit.

Two questions (docs/robustness.md, "Mirrored perturbations"):

1. Under the paper's noise (``make_task(name, noise="paper")``, the settings of
   ``podilqr reproduce``), does the mirrored fit lower the final true cost of
   each variant? Rows at the same n_s (twice the rollouts) and at n_s / 2 pairs
   (the same rollouts per iteration).
2. Noiseless, with no per-task settings: the task files given on the command
   line (default: the partially observed acrobot), solved with the defaults and
   with ``mirrored=True``, against the model-based reference.

    python benchmarks/mirrored_study.py --out runs/mirrored            # both parts
    python benchmarks/mirrored_study.py --out runs/mirrored --part noisy --seeds 2

Prints a Markdown table per part and writes ``<out>/rows.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import podilqr_jax as pj
from podilqr_jax.studies.reproduce import ROW_SETTINGS
from podilqr_jax.task.noise import NoiseModel
from podilqr_jax.task.taskfile import load_task
from podilqr_jax.task.tasks import PAPER_S0

HORIZON = 30
ITERATIONS = {"pendulum": 100, "cartpole": 200}
VARIANTS = ("nominal", "feedback", "averaged", "iv")


def noisy_rows(seeds: int, systems) -> list[dict]:
    rows = []
    for system in systems:
        name = f"{system}-partial"
        clean = pj.make_task(name, horizon=HORIZON)
        optimum = pj.solve_model_based(clean, pj.default_config(clean, max_iterations=500)).final_cost
        env = pj.make_task(name, horizon=HORIZON, noise=NoiseModel.paper(PAPER_S0, partial=True))
        # the study's noiseless row at the same sigma as the noisy ones (as `podilqr reproduce`)
        base = pj.default_config(env, max_iterations=ITERATIONS[system], adapt_sigma=False, escalate=False)
        for variant in VARIANTS:
            for label, extra in (
                ("least squares", {}),
                ("mirrored", {"mirrored": True}),
                ("mirrored, n_s/2", {"mirrored": True, "n_s": base.n_s // 2}),
            ):
                for seed in range(seeds):
                    cfg = base.replace(seed=seed, **ROW_SETTINGS.get(variant, dict(variant=variant)), **extra)
                    r = pj.solve(env, cfg)
                    row = dict(
                        part="noisy",
                        task=name,
                        variant=variant,
                        fit=label,
                        seed=seed,
                        n_s=cfg.n_s,
                        rollouts=r.rollouts,
                        ratio=r.final_true_cost / optimum,
                        status=r.status.value,
                        wall_s=r.wall_s,
                    )
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    return rows


def noiseless_rows(task_files) -> list[dict]:
    rows = []
    for path in task_files:
        env = load_task(path)
        ref = pj.solve_model_based(env)
        for label, extra in (("least squares", {}), ("mirrored", {"mirrored": True})):
            r = pj.solve(env, pj.default_config(env, **extra))
            row = dict(
                part="noiseless",
                task=env.name,
                fit=label,
                ratio=r.final_cost / ref.final_cost,
                cost=r.final_cost,
                reference=ref.final_cost,
                status=r.status.value,
                iterations=r.iterations,
                rollouts=r.rollouts,
                wall_s=r.wall_s,
            )
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def tables(rows) -> str:
    out = []
    noisy = [r for r in rows if r["part"] == "noisy"]
    if noisy:
        out += [
            "| task | variant | fit | n_s | rollouts (mean) | true cost / optimum (mean) | per seed |",
            "|---|---|---|---|---|---|---|",
        ]
        keys = sorted(
            {(r["task"], r["variant"], r["fit"]) for r in noisy}, key=lambda k: (k[0], VARIANTS.index(k[1]), k[2])
        )
        for task, variant, fit in keys:
            g = [r for r in noisy if (r["task"], r["variant"], r["fit"]) == (task, variant, fit)]
            mean = sum(r["ratio"] for r in g) / len(g)
            roll = sum(r["rollouts"] for r in g) / len(g)
            seeds = ", ".join(f"{r['ratio']:.4f}" for r in g)
            out.append(f"| {task} | {variant} | {fit} | {g[0]['n_s']} | {roll:.0f} | {mean:.4f} | {seeds} |")
    clean = [r for r in rows if r["part"] == "noiseless"]
    if clean:
        out += [
            "",
            "| task | fit | POD-iLQR / model-based | status | iterations | rollouts |",
            "|---|---|---|---|---|---|",
        ]
        for r in clean:
            out.append(
                f"| {r['task']} | {r['fit']} | {r['ratio']:.6g} | {r['status']} | {r['iterations']} | {r['rollouts']} |"
            )
    return "\n".join(out)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="runs/mirrored")
    p.add_argument("--part", choices=("noisy", "noiseless", "both"), default="both")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--systems", default="cartpole,pendulum")
    p.add_argument("tasks", nargs="*", default=["examples/tasks/held_out/acrobot_partial.toml"])
    a = p.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    t0 = time.perf_counter()
    rows = []
    if a.part in ("noisy", "both"):
        rows += noisy_rows(a.seeds, a.systems.split(","))
    if a.part in ("noiseless", "both"):
        rows += noiseless_rows(a.tasks)
    with open(os.path.join(a.out, "rows.json"), "w") as f:
        json.dump({"rows": rows, "wall_s": time.perf_counter() - t0}, f, indent=1)
    print(tables(rows))


if __name__ == "__main__":
    main()
