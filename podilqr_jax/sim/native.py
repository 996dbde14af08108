"""The native engine: MuJoCo's own C step, batched on the host's cores, inside the one rollout scan.

MJX is the engine for accelerators. On a CPU, MuJoCo's C engine runs the
field's robots (floor contacts, RK4, 18-30 states) tens of times faster than
MJX compiled by XLA, and it needs no compilation. This module lets the one
rollout skeleton (``rollout.run``) keep its scan, its controllers and its
noise, with the physics step as the only switch: one control step of a whole
batch is one call of ``mujoco.rollout`` (``substeps`` physics steps per
rollout, a thread pool over the cores, the GIL released), reached from the
jitted program through ``jax.pure_callback``. Under ``vmap`` the callback
sees the whole batch at once (``vmap_method="broadcast_all"``), so the
feedback law, the information state and the noise stay in JAX while the
physics runs in C.

The carry of a native rollout is :class:`NativeData`: MuJoCo's full physical
state (``mjSTATE_FULLPHYSICS``: time, qpos, qvel, act, mocap, userdata,
plugin state) split into its time, qpos, qvel, act and the rest, so that
``rollout.state_of`` and ``rollout.with_state`` read and write x = [qpos,
qvel, act] as they do on MJX data. Sensors are recomputed at the state after the
step (and after the process noise) by ``mj_forward``, as MJX's observe does.

What differs from MJX, and by how much (tests/test_native.py, docs):

- every control step starts MuJoCo's constraint solver from a zero warm
  start (a control step's substeps carry it): the batch is split over
  threads, so a warm start left in a thread's ``MjData`` would belong to
  another rollout. Noiseless results are deterministic and the same for
  any thread count. Models without constraints agree with MJX to round-off;
  contact models to the solver's tolerance;
- the model is run as it was loaded (MuJoCo's PGS solver stays PGS; MJX's
  copy switches it to Newton, see ``env.mjx_model_of``);
- the callback has no derivative: the model-based reference differentiates
  it by central differences (``model_based``, ``jacobian="differences"``);
- one process runs its batches on its own cores: with several JAX devices
  or processes the native engine does not shard (MJX does).

Shapes: state vector [nstate] (``mj_stateSize(m, mjSTATE_FULLPHYSICS)``);
a batch [..., nstate] and controls [..., nu] with any leading dimensions.
"""

from __future__ import annotations

import dataclasses
import os
import threading
from typing import Optional

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS


def default_threads() -> int:
    """The threads of the native batches: every core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


class NativeModel:
    """A MuJoCo model with the thread pool and the per-thread ``MjData`` that
    run its batches (one per model and process, see :func:`native_model`).

    Hashable by identity: it is a static field of ``EnvDims`` (``native``),
    so a jitted stage compiles once per model, as with MJX's static fields.
    """

    def __init__(self, mj_model: mujoco.MjModel, threads: Optional[int] = None):
        self.model = mj_model
        self.threads = default_threads() if threads is None else int(threads)
        self.nstate = int(mujoco.mj_stateSize(mj_model, FULL))
        self.nq, self.nv, self.nu, self.na = int(mj_model.nq), int(mj_model.nv), int(mj_model.nu), int(mj_model.na)
        self.nsensordata = int(mj_model.nsensordata)
        self._datas = [mujoco.MjData(mj_model) for _ in range(max(1, self.threads))]
        self._pool = mj_rollout.Rollout(nthread=self.threads if self.threads > 1 else 0)
        self._lock = threading.Lock()  # one batch at a time through the pool and its MjData
        d = mujoco.MjData(mj_model)
        template = np.empty(self.nstate)
        mujoco.mj_getState(mj_model, d, template, FULL)
        self.template = template  # the state of a fresh MjData (time 0, qpos0, at rest, default mocap)

    def __repr__(self) -> str:  # no address: the repr appears in stage names and messages
        return f"NativeModel(nq={self.nq}, nv={self.nv}, nu={self.nu}, threads={self.threads})"

    # ---------------------------------------------------------------- host side
    def step(self, state: np.ndarray, ctrl: np.ndarray, substeps: int) -> np.ndarray:
        """Hold ``ctrl`` [..., nu] for ``substeps`` MuJoCo steps from every
        ``state`` [..., nstate]; returns the states after, [..., nstate]."""
        lead = state.shape[:-1]
        s = np.ascontiguousarray(state, dtype=np.float64).reshape(-1, self.nstate)
        batch = s.shape[0]
        u = np.ascontiguousarray(
            np.broadcast_to(np.asarray(ctrl, dtype=np.float64).reshape(batch, 1, self.nu), (batch, substeps, self.nu))
        )
        out = np.empty((batch, substeps, self.nstate))
        sens = np.empty((batch, substeps, self.nsensordata))
        warm = np.zeros((batch, self.nv))
        with self._lock:
            self._pool.rollout(
                [self.model] * batch,
                self._datas,
                s,
                u,
                nstep=substeps,
                initial_warmstart=warm,
                state=out,
                sensordata=sens,
                skip_checks=True,
            )
        return out[:, -1].reshape(lead + (self.nstate,))

    def sensors(self, state: np.ndarray) -> np.ndarray:
        """``sensordata`` [..., nsensordata] at every ``state`` [..., nstate] (``mj_forward``)."""
        lead = state.shape[:-1]
        s = np.asarray(state, dtype=np.float64).reshape(-1, self.nstate)
        out = np.empty((s.shape[0], self.nsensordata))
        with self._lock:
            d = self._datas[0]
            for i, s_i in enumerate(s):
                mujoco.mj_setState(self.model, d, s_i, FULL)
                mujoco.mj_forward(self.model, d)
                out[i] = d.sensordata
        return out.reshape(lead + (self.nsensordata,))


_models: dict[int, tuple[mujoco.MjModel, NativeModel]] = {}
_models_lock = threading.Lock()


def native_model(mj_model: mujoco.MjModel) -> NativeModel:
    """The one :class:`NativeModel` of ``mj_model`` in this process (kept, with
    the model, for the process's life: a second solve of the same task reuses
    its compiled stages)."""
    with _models_lock:
        entry = _models.get(id(mj_model))
        if entry is None or entry[0] is not mj_model:
            entry = _models[id(mj_model)] = (mj_model, NativeModel(mj_model))
        return entry[1]


@dataclasses.dataclass(frozen=True)
class NativeData:
    """A native rollout's carry: MuJoCo's full physical state in five parts
    (time [1], qpos [nq], qvel [nv], act [na], the rest), with ``replace`` as MJX data has it."""

    time: jnp.ndarray
    qpos: jnp.ndarray
    qvel: jnp.ndarray
    act: jnp.ndarray
    rest: jnp.ndarray

    def replace(self, **changes) -> "NativeData":
        return dataclasses.replace(self, **changes)

    def vector(self) -> jnp.ndarray:
        return jnp.concatenate([self.time, self.qpos, self.qvel, self.act, self.rest], axis=-1)

    @staticmethod
    def of_vector(s: jnp.ndarray, native: "NativeModel") -> "NativeData":
        q, v = 1 + native.nq, 1 + native.nq + native.nv
        a = v + native.na
        return NativeData(s[..., :1], s[..., 1:q], s[..., q:v], s[..., v:a], s[..., a:])


jax.tree_util.register_dataclass(NativeData, data_fields=["time", "qpos", "qvel", "act", "rest"], meta_fields=[])


def start_data(native: NativeModel, dtype) -> NativeData:
    """The carry of a fresh ``MjData`` (the rollout writes its start state into it)."""
    return NativeData.of_vector(jnp.asarray(native.template, dtype=dtype), native)


def step(native: NativeModel, substeps: int, d: NativeData, u: jnp.ndarray) -> NativeData:
    """One control step of MuJoCo's C engine from ``d`` under ``u`` (traceable;
    under ``vmap`` one host call for the whole batch)."""
    s = d.vector()
    out = jax.ShapeDtypeStruct(s.shape, s.dtype)

    def host(s_np, u_np):
        return native.step(np.asarray(s_np), np.asarray(u_np), substeps).astype(s_np.dtype)

    s_next = jax.pure_callback(host, out, s, u.astype(s.dtype), vmap_method="broadcast_all")
    return NativeData.of_vector(s_next, native)


def sensordata(native: NativeModel, d: NativeData) -> jnp.ndarray:
    """MuJoCo's ``sensordata`` at the state of ``d`` (traceable)."""
    s = d.vector()
    out = jax.ShapeDtypeStruct(s.shape[:-1] + (native.nsensordata,), s.dtype)

    def host(s_np):
        return native.sensors(np.asarray(s_np)).astype(s_np.dtype)

    return jax.pure_callback(host, out, s, vmap_method="broadcast_all")
