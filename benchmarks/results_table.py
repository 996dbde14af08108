"""The table of docs/results.md: every bundled task, POD-iLQR vs model-based.

python benchmarks/results_table.py > table.md
"""

import podilqr_jax as pj

print(
    "| task | POD-iLQR cost | model-based cost | ratio | POD status | POD iterations | MB iterations "
    "| POD rollouts | POD wall s (compile s) | MB wall s (compile s) |"
)
print("|---|---|---|---|---|---|---|---|---|---|")
for task in pj.TASKS:
    env = pj.make_task(task)
    cfg = pj.default_config(env)
    pod = pj.solve(env, cfg)
    ref = pj.solve_model_based(env, cfg)
    print(
        f"| {task} | {pod.final_cost:.6f} | {ref.final_cost:.6f} | {pod.final_cost / ref.final_cost:.7f} "
        f"| {pod.status} | {pod.iterations} | {ref.iterations} | {pod.rollouts} "
        f"| {pod.wall_s:.1f} ({pod.compile_s:.1f}) | {ref.wall_s:.1f} ({ref.compile_s:.1f}) |",
        flush=True,
    )
