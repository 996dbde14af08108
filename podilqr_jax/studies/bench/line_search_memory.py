"""Peak memory of the line search's batch against its chunk size: one noisy
line search of (n_alphas + 1) x n_forward cart-pole rollouts per fresh process.

    python -m podilqr_jax.studies.bench.line_search_memory [--n-forward 10000] [--chunks none,55000,22000,10000,5000]

``none`` is the batch in one piece. Every row has the wall time (compile
included), the peak RSS (``VmHWM``; the process's start-up peak is
``import_peak_host_mb``, the peak after compiling ``after_compile_peak_host_mb``:
the compiler's heap stays with the process), XLA's planned temporary memory
of the compiled program (``xla_temp_mb``, what the chunk bounds) and the
largest relative difference of the candidates' costs from the first row's,
which should be round-off: the chunked batch runs the same rollouts with the
same noise (``line_search``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from typing import Any, Optional, Sequence

from .report import emit


def _peak_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0
    return float("nan")


def one_line_search(task: str, n_forward: int, chunk: Optional[int], n_alphas: int = 10) -> dict[str, Any]:
    """In this process: one noisy line search (the paper's noise, open-loop
    nominal u = 0 with a random step k) of ``(n_alphas + 1) x n_forward``
    rollouts in chunks of ``chunk`` (None: one batch)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import podilqr_jax as pj
    from podilqr_jax.identify.info_state import info_dim
    from podilqr_jax.ilqr.line_search import Candidates, Search, Step, line_search
    from podilqr_jax.sim.rollout import open_loop_policy

    base = _peak_mb()
    env = pj.make_task(task, noise="paper")
    dims = env.dims
    q = pj.SolverConfig().resolved_q(env)
    policy = open_loop_policy(jnp.zeros((dims.horizon, dims.nu)), info_dim(dims.nz, dims.nu, q))
    k = jnp.asarray(np.random.default_rng(0).normal(size=(dims.horizon, dims.nu)))
    alphas = jnp.asarray(np.append(0.5 ** np.arange(n_alphas), 0.0))
    step, candidates = Step(k, jnp.asarray(np.inf), -1.0, 0.0), Candidates(alphas, 1e-4)
    dynamic = (env.data, policy, step, candidates, jax.random.PRNGKey(0))
    t0 = time.perf_counter()
    compiled = line_search.lower(Search(dims, q, n_forward, True, chunk), *dynamic).compile()
    after_compile = _peak_mb()
    memory = compiled.memory_analysis()
    ls = compiled(*dynamic)
    costs = np.asarray(ls.costs)
    wall = time.perf_counter() - t0
    return {
        "task": task,
        "n_forward": n_forward,
        "rollouts": int(alphas.shape[0]) * n_forward,
        "chunk": chunk,
        "wall_s_with_compile": wall,
        "peak_host_mb": _peak_mb(),
        "import_peak_host_mb": base,
        "after_compile_peak_host_mb": after_compile,
        # XLA's buffer plan of the compiled line search: its temporaries follow the chunk
        "xla_temp_mb": None if memory is None else memory.temp_size_in_bytes / 2**20,
        "costs": costs.tolist(),
    }


def peak_memory_vs_chunk(
    task: str = "cartpole-partial",
    n_forward: int = 10_000,
    chunks: Sequence[Optional[int]] = (None, 22_000, 10_000, 5_000),
) -> dict[str, Any]:
    """One fresh process per chunk size (``None``: unchunked); the rows and
    the ratios of each row's peak RSS and wall time to the first row's."""
    rows = []
    for chunk in chunks:
        cmd = [sys.executable, "-m", "podilqr_jax.studies.bench.line_search_memory", "--child", task, str(n_forward)]
        cmd.append("none" if chunk is None else str(chunk))
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=3600, env=dict(os.environ))
        if out.returncode != 0:
            tail = out.stderr.strip().splitlines()[-1:] or [f"exit {out.returncode}"]
            rows.append({"chunk": chunk, "error": tail[0]})
            continue
        rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    ok = [r for r in rows if "error" not in r]
    if ok:
        import numpy as np

        ref = np.asarray(ok[0]["costs"])
        for r in ok:
            r["max_rel_cost_diff_vs_first"] = float(np.max(np.abs(np.asarray(r["costs"]) - ref) / np.abs(ref)))
            r["peak_over_first"] = r["peak_host_mb"] / ok[0]["peak_host_mb"]
            r["wall_over_first"] = r["wall_s_with_compile"] / ok[0]["wall_s_with_compile"]
    return {"task": task, "n_forward": n_forward, "rows": rows}


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m podilqr_jax.studies.bench.line_search_memory", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--task", default="cartpole-partial")
    parser.add_argument("--n-forward", type=int, default=10_000)
    parser.add_argument("--chunks", default="none,22000,10000,5000", help="chunk sizes; none = one batch")
    parser.add_argument("--out", default=None, help="write the report as JSON here")
    parser.add_argument("--child", nargs=3, metavar=("TASK", "N_FORWARD", "CHUNK"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        task, n_fwd, chunk = args.child
        print(json.dumps(one_line_search(task, int(n_fwd), None if chunk == "none" else int(chunk))))
        return 0
    chunks = [None if c.strip() == "none" else int(c) for c in args.chunks.split(",") if c.strip()]
    report = peak_memory_vs_chunk(args.task, args.n_forward, chunks)
    emit(report, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
