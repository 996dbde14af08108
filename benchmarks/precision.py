"""float64 vs float32: the same noiseless solve in both precisions.

    python benchmarks/precision.py [TASK]

Each precision runs in its own process (``PODILQR_X64`` is read at import).
The reference is the model-based optimum in float64.
"""

import json
import os
import subprocess
import sys

task = sys.argv[1] if len(sys.argv) > 1 else "pendulum-full"

if os.environ.get("PODILQR_PRECISION_CHILD"):
    import podilqr_jax as pj

    env = pj.make_task(task)
    out = {}
    for sigma in (1e-7, 1e-6, 1e-5, 1e-4, 1e-3):
        r = pj.solve(env, pj.default_config(env, sigma=sigma))
        out[sigma] = (r.final_cost, str(r.status), r.iterations)
    if os.environ.get("PODILQR_X64", "1") != "0":
        out["reference"] = pj.solve_model_based(env).final_cost
    print(json.dumps(out))
    sys.exit(0)

rows = {}
for x64 in ("1", "0"):
    env = dict(os.environ, PODILQR_X64=x64, PODILQR_PRECISION_CHILD="1")
    proc = subprocess.run([sys.executable, __file__, task], env=env, capture_output=True, text=True, check=True)
    rows[x64] = json.loads(proc.stdout.strip().splitlines()[-1])
ref = rows["1"]["reference"]
print(f"{task}: model-based optimum (float64) {ref:.6f}\n")
print(
    "| sigma | float64 cost / optimum | float64 status (iterations) "
    "| float32 cost / optimum | float32 status (iterations) |"
)
print("|---|---|---|---|---|")
for sigma in rows["1"]:
    if sigma == "reference":
        continue
    c64, s64, i64 = rows["1"][sigma]
    c32, s32, i32 = rows["0"][sigma]
    print(f"| {float(sigma):g} | {c64 / ref:.7f} | {s64} ({i64}) | {c32 / ref:.7f} | {s32} ({i32}) |")
