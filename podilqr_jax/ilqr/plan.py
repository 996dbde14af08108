"""How a solve runs, decided once before its first iteration: the execution plan.

The solver's settings say *what* is computed (the paper's iLQR and
identification, the noise variant, the recovery); the plan says *how* this
solve runs it on this machine:

- ``engine``, ``impl``: the rollouts' engine (``sim.engines``: MJX or
  MuJoCo's C engine, as ``engine = "auto"`` resolved it for the model) and
  MJX's implementation;
- ``backend``, ``devices``, ``processes``: where JAX runs (a batch is sharded
  over several devices);
- ``sysid_rollouts``, ``sysid_chunk``: the rollouts of one identification
  (n_s x n_avg; the mirrored experiment runs twice that) and the most that
  run in one call under the memory budget (``SolverConfig.resolved_chunk``),
  a larger batch running in chunks of it (None: the batch fits, mirrored
  too);
- ``ls_rollouts``, ``ls_chunk``: the line search's batch and its chunk
  (None: one batch);
- ``jacobian``: the model-based reference's linearisation (``exact`` or
  ``differences``; empty for POD-iLQR);
- ``xla_options``, ``cache``, ``x64``: what the package compiles with
  (``compilation.xla_options``), the persistent compilation cache's state
  (``compilation.cache``: on, read, off, or the user's own JAX cache) and the float
  width;
- ``starts``: the solves of a solve with restarts that run in lockstep, each
  stage one batched call (``restarts``, ``compilation.lockstep``).

``solver`` builds it from the model, the settings and the machine (and the
environment switches of docs/environment.md, read there once); the
identification and the line search take their sizes from
it, and the result records it (``Result.plan``, and ``plan`` in its JSON),
so a result says how it was computed as well as what.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Optional

import jax

from ..compilation import cache, xla_options
from ..sim.rollout import bytes_per_rollout
from ..task.env import EnvData, EnvDims
from .config import SolverConfig


@dataclasses.dataclass(frozen=True)
class ExecutionPlan:
    """How one solve runs (module docstring)."""

    engine: str
    impl: str
    backend: str
    devices: int
    processes: int
    sysid_rollouts: int
    sysid_chunk: Optional[int]
    ls_rollouts: int
    ls_chunk: Optional[int]
    jacobian: str
    xla_options: tuple[tuple[str, Any], ...]
    cache: str
    x64: bool
    starts: int = 1  # solves run in lockstep, each stage one batched call (``restarts``; 1: none)

    def as_dict(self) -> dict[str, Any]:
        """The plan as JSON values (``Result.plan``)."""
        return dataclasses.asdict(self) | {"xla_options": dict(self.xla_options)}


def sysid_chunk(cfg: SolverConfig, dims: EnvDims, data: EnvData, noisy: bool, rollouts: int) -> Optional[int]:
    """The most sysid rollouts of one call under ``cfg``'s memory budget, or
    None where a batch of ``rollouts`` fits, mirrored (twice that) too: one
    program for every budget that fits."""
    chunk = cfg.resolved_chunk(bytes_per_rollout(dims, data, noisy))
    return None if chunk >= 2 * rollouts else chunk


def line_search_chunk(cfg: SolverConfig, dims: EnvDims, data: EnvData, noisy: bool, rollouts: int) -> Optional[int]:
    """The most line-search rollouts (with their states) of one call under
    ``cfg``'s memory budget, or None where the ``rollouts`` fit."""
    chunk = cfg.resolved_chunk(bytes_per_rollout(dims, data, noisy, record_state=True), group=1)
    return None if chunk >= rollouts else chunk


def build_plan(
    *,
    engine: str,
    impl: str,
    sysid_rollouts: int,
    sysid_chunk: Optional[int],
    ls_rollouts: int,
    ls_chunk: Optional[int],
    jacobian: str = "",
) -> ExecutionPlan:
    """The plan of a solve whose sizes the solver has worked out; the machine's
    part (devices, XLA's options, the cache, x64) read here."""
    return ExecutionPlan(
        engine=engine,
        impl=impl if engine == "mjx" else "",
        backend=jax.default_backend(),
        devices=jax.device_count(),
        processes=jax.process_count(),
        sysid_rollouts=sysid_rollouts,
        sysid_chunk=sysid_chunk,
        ls_rollouts=ls_rollouts,
        ls_chunk=ls_chunk,
        jacobian=jacobian,
        xla_options=tuple(sorted(xla_options.options().items())),
        cache=cache.mode(),
        x64=bool(jax.config.jax_enable_x64),
    )
