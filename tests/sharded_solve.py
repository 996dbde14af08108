"""The averaged noisy solve that tests/test_scale.py (4 devices) and
tests/test_distributed.py (2 processes) shard, and its one-device result,
solved once per pytest process in the process itself (its compiled programs
are shared through the suite's compilation cache)."""

from __future__ import annotations

import functools
import os

import numpy as np

TASK = {"horizon": 8, "noise": "paper"}
SETTINGS = {"variant": "averaged", "n_s": 8, "n_avg": 2, "n_forward": 2, "n_alphas": 3, "max_iterations": 3}
BATCH = SETTINGS["n_s"] * SETTINGS["n_avg"]  # the sysid batch that is sharded

# The solve, for a child process and for ``one_device``: ``r``, the result (``pj`` the package).
SOLVE = f"""
env = pj.make_task("pendulum-full", **{TASK!r})
r = pj.solve(env, pj.default_config(env, **{SETTINGS!r}))
"""


def child_environment(env: dict) -> dict:
    """``env`` for a child process that imports this module (its folder on ``PYTHONPATH``)."""
    here = os.path.dirname(os.path.abspath(__file__))
    return env | {"PYTHONPATH": os.pathsep.join(filter(None, [here, env.get("PYTHONPATH")]))}


def summary(result) -> dict:
    """What the sharded runs are compared on."""
    return {
        "cost": list(result.cost_history),
        "true": list(result.true_cost_history),
        "K": np.asarray(result.K).tolist(),
        "controls": np.asarray(result.controls).tolist(),
    }


@functools.lru_cache(maxsize=1)
def one_device() -> dict:
    """The solve in this process, on its one device, unsharded."""
    import jax

    import podilqr_jax as pj
    from podilqr_jax.sim.rollout import batch_sharding

    assert jax.device_count() == 1 and batch_sharding(BATCH) is None, "the reference runs on one device"
    run = {"pj": pj}
    exec(SOLVE, run)  # the children's solve, as they run it
    return summary(run["r"])
