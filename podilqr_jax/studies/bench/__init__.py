"""``podilqr bench``: the benchmarks, installed with the package.

``suite`` is the benchmark behind ``podilqr bench`` (the n_s x n_avg grid, the
baselines, memory, devices); ``native_rollout`` and ``serial_reference`` are its
baselines (MuJoCo's native ``mujoco.rollout`` and POD-iLQR in plain NumPy), and
``rollout_throughput`` the MJX-vs-native physics throughput table of
docs/tasks.md. Each also runs on its own::

    python -m podilqr_jax.studies.bench --quick --out runs/bench
    python -m podilqr_jax.studies.bench.native_rollout --task cartpole-full --batch 256,1024
    python -m podilqr_jax.studies.bench.serial_reference --task pendulum-full --compare
    python -m podilqr_jax.studies.bench.rollout_throughput --batch 1024

Results and their discussion live in the repository's benchmarks/ and
benchmarks/journal.md.
"""

from .suite import BenchSettings, main, run

__all__ = ["BenchSettings", "main", "run"]
