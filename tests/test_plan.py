"""The execution plan (podilqr_jax/ilqr/plan.py): decided once per solve from the
model, the settings and the machine, recorded in the result and its JSON."""

from __future__ import annotations

import jax

import podilqr_jax as pj
from podilqr_jax.ilqr import solver
from podilqr_jax.sim.rollout import on_device


def test_the_result_records_how_the_solve_ran(tmp_path):
    env = pj.make_task("pendulum-full", horizon=8)
    result = pj.solve(env, pj.default_config(env, n_s=8, max_iterations=2))
    plan = result.plan
    assert plan["engine"] == result.engine == "mjx" and plan["impl"] == "jax"
    assert (plan["backend"], plan["devices"], plan["processes"]) == (jax.default_backend(), 1, 1)
    # 8 sysid rollouts and 10 line-search candidates, each one batch under the default budget
    assert (plan["sysid_rollouts"], plan["sysid_chunk"], plan["ls_rollouts"], plan["ls_chunk"]) == (8, None, 10, None)
    assert plan["jacobian"] == "" and plan["starts"] == 1
    assert plan["xla_options"] == {"xla_cpu_use_fusion_emitters": False} and plan["x64"] is True
    assert plan["cache"] in ("on", "read", "off", "jax")
    result.save_json(tmp_path / "r.json")
    assert pj.load_result(tmp_path / "r.json").plan == plan


def test_the_reference_records_its_jacobian_and_no_sysid_batch():
    env = pj.make_task("pendulum-full", horizon=8)
    plan = pj.solve_model_based(env, pj.default_config(env, max_iterations=2)).plan
    assert plan["jacobian"] == "exact" and plan["sysid_rollouts"] == 0 and plan["sysid_chunk"] is None


def test_a_small_memory_budget_chunks_both_batches(monkeypatch):
    """The averaged variant's 400 sysid and 440 line-search rollouts under a
    budget of a few rollouts (nothing compiles: the plan alone)."""
    env = pj.make_task("pendulum-partial", noise="paper")
    cfg = pj.default_config(env, variant="averaged", memory_budget_mb=0.05)
    cfg = cfg.replace(restarts=cfg.resolved_restarts(env))  # as the solve resolves it
    dims, data = env.dims, on_device(env.data)
    n_fwd = cfg.resolved_n_forward()
    plan = solver._plan(dims, data, cfg, True, n_fwd, sysid_rollouts=cfg.n_s * cfg.resolved_n_avg())
    assert plan.sysid_rollouts == 400 and plan.ls_rollouts == (cfg.n_alphas + 1) * n_fwd == 440
    assert 1 <= plan.sysid_chunk < 400 and 1 <= plan.ls_chunk < 440
