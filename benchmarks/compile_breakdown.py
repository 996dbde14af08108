"""Where a cold solve's compile time goes: tracing and XLA compilation per stage.

Runs a one-iteration solve with the persistent cache off and JAX's compile
log on, and prints the seconds of each tracing, lowering and XLA compilation
per jitted program, largest first. Run it in a fresh process per
measurement (``PODILQR_CACHE=0`` keeps every stage cold), and more than once:
one sample varies by 20-30 % on a shared machine. ``PYTHONPATH`` of another
checkout measures that one (as in benchmarks/journal.md):

    PODILQR_CACHE=0 python benchmarks/compile_breakdown.py doublependulum-partial --method model-based
    PODILQR_CACHE=0 PYTHONPATH=/tmp/before python benchmarks/compile_breakdown.py cartpole-partial
"""

from __future__ import annotations

import argparse
import collections
import logging
import os
import re
import time

import jax

# JAX's lines: "Finished tracing NAME for jit in S sec", "Finished jaxpr to MLIR module
# conversion jit(NAME) in S sec", "Finished XLA compilation of jit(NAME) in S sec".
TRACING = re.compile(r"Finished tracing (\S+) for \S+ in ([0-9.e-]+) sec")
OTHER = re.compile(r"Finished (jaxpr to MLIR module conversion|XLA compilation of) jit\((\S+)\) in ([0-9.e-]+) sec")
KIND = {"jaxpr to MLIR module conversion": "lowering", "XLA compilation of": "XLA compilation"}


class _Seconds(logging.Handler):
    """Adds up JAX's "Finished <what> for <program> in <s> sec" log lines."""

    def __init__(self) -> None:
        super().__init__()
        self.seconds: dict[tuple[str, str], float] = collections.defaultdict(float)

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if match := TRACING.search(message):
            self.seconds[("tracing", match.group(1))] += float(match.group(2))
        elif match := OTHER.search(message):
            self.seconds[(KIND[match.group(1)], match.group(2))] += float(match.group(3))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("task", help="a bundled task or a task file (.toml)")
    parser.add_argument("--method", choices=("pod-ilqr", "model-based"), default="pod-ilqr")
    parser.add_argument("--top", type=int, default=8, help="rows to print (default 8)")
    args = parser.parse_args()
    if os.environ.get("PODILQR_CACHE") != "0":
        print("note: PODILQR_CACHE is not 0, so stages may load from the cache instead of compiling")
    jax.config.update("jax_log_compiles", True)
    handler = _Seconds()
    logger = logging.getLogger("jax")
    logger.addHandler(handler)
    logger.setLevel(logging.WARNING)
    logger.propagate = False  # the counts, not JAX's log lines, on the terminal

    import podilqr_jax as pj

    try:
        from podilqr_jax.task.taskfile import load_task
    except ImportError:  # a checkout from before the subpackages
        from podilqr_jax.taskfile import load_task

    env = load_task(args.task) if args.task.endswith(".toml") else pj.make_task(args.task)
    solve = pj.solve if args.method == "pod-ilqr" else pj.solve_model_based
    t0 = time.perf_counter()
    result = solve(env, pj.default_config(env, max_iterations=1))
    print(f"{args.task} {args.method}: compile_s {result.compile_s:.2f}, wall {time.perf_counter() - t0:.2f} s")
    rows = sorted(handler.seconds.items(), key=lambda kv: -kv[1])[: args.top]
    print("| program | what | s |\n|---|---|---|")
    for (what, program), seconds in rows:
        print(f"| {program} | {what} | {seconds:.2f} |")


if __name__ == "__main__":
    main()
