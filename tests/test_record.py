"""The solve's counters and histories live in one ``Record``: every field of it
reaches the result, its JSON and a checkpoint without further edits."""

from __future__ import annotations

import dataclasses
import json

import numpy as np

import podilqr_jax as pj
from podilqr_jax.ilqr.checkpoint import fingerprint, load_checkpoint, save_checkpoint
from podilqr_jax.ilqr.state import Nominal, Record, SolverState
from podilqr_jax.sim.rollout import on_device


def _distinct_record() -> Record:
    """Every counter and history set to a value of its own."""
    values = {}
    for i, f in enumerate(dataclasses.fields(Record)):
        values[f.name] = 10 + i if f.name in Record.counters() else [float(i), float(i) + 0.5]
    return Record(**values)


def test_every_record_field_reaches_the_result_and_its_json(tmp_path):
    env = pj.make_task("pendulum-full", horizon=6)
    result = pj.solve(env, pj.default_config(env, max_iterations=2))
    assert result.record.iterations == result.iterations == 2
    result.record = _distinct_record()
    for name in Record.names():
        assert getattr(result, name) == getattr(result.record, name), name
    path = tmp_path / "result.json"
    result.save_json(path)
    saved = json.loads(path.read_text())
    assert {name: saved[name] for name in Record.names()} == result.record.as_dict()
    assert pj.load_result(path).record == result.record


def test_every_record_field_and_state_scalar_survives_a_checkpoint(tmp_path):
    env = pj.make_task("pendulum-full", horizon=6)
    cfg = pj.default_config(env)
    dims, T = env.dims, env.dims.horizon
    nominal = Nominal(
        on_device(np.zeros((T, dims.nu))),
        on_device(np.zeros((T + 1, dims.nz))),
        on_device(np.zeros((T + 1, dims.nx))),
        on_device(np.zeros((T + 1, dims.nz))),
        1.5,
    )
    key = np.asarray([0, 7], dtype=np.uint32)
    state = SolverState(nominal=nominal, gains=on_device(np.ones((T, dims.nu, dims.nz))), key=key, ls_key=key, mu=0.25)
    state.record = _distinct_record()
    for i, name in enumerate(SolverState.SCALARS):
        if name not in ("mu", "stopped"):
            setattr(state, name, type(getattr(state, name))(i + 2))
    state.stopped = ["converged", "because"]
    print_ = fingerprint("pod-ilqr", env, dims, cfg)
    save_checkpoint(tmp_path, state, print_)
    loaded = load_checkpoint(tmp_path, print_, on_device)
    assert loaded.record == state.record
    for name in SolverState.SCALARS:
        assert getattr(loaded, name) == getattr(state, name), name
    assert loaded.nominal.cost == 1.5
