"""A control task on a MuJoCo model: dynamics, observation, cost, start, target.

Notation (shapes):
  x = [qpos, qvel, act]       state, [nx] with nx = nq + nv + na (act: the activations of
                              actuators with dynamics, MuJoCo's ``act``; na = 0 on most models)
  z = C x + D s(x)            observation, [nz]: joint coordinates (rows of C)
                              and named MuJoCo sensors s = ``sensordata`` (rows
                              of D; only when ``EnvDims.sensors``)
  u                           control (MuJoCo ``ctrl``), [nu], clamped to the
                              model's ``ctrlrange`` where ``ctrllimited``
  T                           horizon in control steps; one control step is
                              ``substeps`` physics steps of the model's timestep
  cost  J = sum_{t<T} (z_t - z*)' Q (z_t - z*) + u_t' R u_t
            + (z_T - z*)' QT (z_T - z*)

An :class:`Env` splits into hashable static dimensions (:class:`EnvDims`, used
as a static jit argument: changing them recompiles) and a pytree of arrays
(:class:`EnvData`, traced: changing the values never recompiles).

A task needs only what MuJoCo compiles. MJX's copy of the model is built the
first time the task's data is read on the MJX engine (``Env.data``), and kept;
a model MJX cannot convert (a geom pair without an MJX collision function, the
implicit integrator, a sensor MJX does not compute, ...) loads all the same and
runs on MuJoCo's C engine (``sim.engines``). Where MJX is asked for such a model
it refuses with MJX's reason (:class:`MJXUnavailable`).
"""

from __future__ import annotations

import copy
import dataclasses
import os
import threading
from typing import Any, Mapping, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from ..errors import ModelLoadError, TaskError
from .noise import NoiseLevels, NoiseModel, noise_levels
from .package_files import is_package_path, resolve_model_path
from .tangent import quaternions


@dataclasses.dataclass(frozen=True)
class EnvDims:
    """Static sizes of a task (hashable; a static jit argument)."""

    nq: int
    nv: int
    nu: int
    nz: int
    substeps: int
    horizon: int
    sensors: bool = False  # some observation reads ``sensordata`` (needs mjx.forward)
    # (qpos address, dof address) of each free or ball joint's quaternion: where
    # a state deviation is formed in the tangent space (``task.tangent``).
    quats: tuple[tuple[int, int], ...] = ()
    # The engine of the rollouts: None for MJX, or the ``sim.native.NativeModel``
    # that runs them in MuJoCo's C engine (hashed by identity; ``Env.on_engine``).
    native: Any = dataclasses.field(default=None, repr=False)
    # Activations in the state: actuators with dynamics (filter, integrator, muscle) carry MuJoCo's ``act``.
    na: int = 0

    @property
    def nx(self) -> int:
        return self.nq + self.nv + self.na

    @property
    def ndx(self) -> int:
        """The size of a state deviation, 2 nv + na (``task.tangent``; nx where nq == nv)."""
        return 2 * self.nv + self.na

    @property
    def engine(self) -> str:
        """``mjx`` or ``native``: the engine the rollouts of these dimensions run on."""
        return "mjx" if self.native is None else "native"

    def as_dict(self) -> dict:
        """The sizes (and the engine where it is not MJX), as plain values."""
        sizes = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "native"}
        if not self.quats:
            del sizes["quats"]  # a hinge-and-slide checkpoint keeps the fingerprint it was written with
        if not self.na:
            del sizes["na"]  # so does one of a model without activations
        return sizes if self.native is None else sizes | {"engine": self.engine}


class EnvData(NamedTuple):
    """Traced arrays of a task."""

    model: Any  # mjx.Model on the MJX engine (``Env.data``); None on the native one; MJXUnavailable where MJX cannot
    C: jnp.ndarray  # [nz, nx] observation matrix (zero rows for sensor channels)
    x0: jnp.ndarray  # [nx] start state (qpos, qvel, act)
    z_target: jnp.ndarray  # [nz]
    Q: jnp.ndarray  # [nz, nz] running cost on the observation error
    QT: jnp.ndarray  # [nz, nz] terminal cost
    R: jnp.ndarray  # [nu, nu] control cost
    noise: NoiseLevels  # standard deviations of dx0, w_t, v_t
    goal_step: jnp.ndarray  # int: running steps t >= goal_step cost with QT (default horizon: none do)
    D: jnp.ndarray  # [nz, nsensordata] sensor selection (used only when dims.sensors)
    u_low: jnp.ndarray  # [nu] lower control limits (-inf where the actuator is not limited)
    u_high: jnp.ndarray  # [nu] upper control limits (+inf where not limited)


@dataclasses.dataclass(frozen=True, eq=False)
class Env:
    """A task: a MuJoCo model with observation, cost, start and target.

    Build one with :meth:`Env.from_xml` (any MJCF file) or
    :func:`podilqr_jax.make_task` (bundled tasks).
    """

    name: str
    mj_model: mujoco.MjModel
    dims: EnvDims
    arrays: EnvData  # the task's arrays without MJX's model (None): read ``data``, which adds it where MJX runs
    observation_labels: tuple[str, ...]
    control_dt: float
    solver_defaults: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    noise: NoiseModel = NoiseModel()
    observation: Any = None  # the observation as given (kept by ``replace``)
    # One line per choice made for the engine the rollouts run on: the options switched off on MJX's copy
    # (``mjx_notes``), or why ``engine = "auto"`` runs the C engine (``sim.engines.on_engine``).
    model_notes: tuple[str, ...] = ()
    # MJX's copy of ``mj_model`` per implementation, built once and shared by the copies of this task.
    mjx_models: "MJXModels" = dataclasses.field(default=None, repr=False)

    def __post_init__(self):
        if self.mjx_models is None:
            object.__setattr__(self, "mjx_models", MJXModels(self.mj_model, self.name))

    # ----------------------------------------------------------------- building
    @classmethod
    def from_xml(
        cls,
        path: str | os.PathLike,
        *,
        observation: Any = "full",
        substeps: int = 1,
        horizon: int = 30,
        x0: Any = None,
        target: Any = None,
        Q: Any = 1.0,
        QT: Any = 100.0,
        R: Any = 1.0,
        name: str | None = None,
        solver_defaults: Mapping[str, Any] | None = None,
        noise: Any = None,
    ) -> "Env":
        """Load an MJCF file and describe the task on it.

        Args:
          path: the MJCF file, or ``pkg://PACKAGE/PATH`` for a file inside an
            installed package (``pkg://dm_control/suite/cartpole.xml``; see
            ``package_files``).
          observation: ``"full"`` (all of qpos and qvel), ``"qpos"`` (all
            positions), a mapping ``{"qpos": [...], "qvel": [...],
            "sensors": [...]}`` whose qpos/qvel entries are indices or joint
            names and whose sensors are names of the model's ``<sensor>``
            elements (position or velocity stage: ``jointpos``, ``framepos``,
            ``framequat``, ``jointvel``, ``velocimeter``, ...), or a matrix
            ``C`` of shape ``[nz, nx]`` with full row rank (nx = nq + nv + na,
            the activations ``act`` last where some actuator has dynamics).
          substeps: physics steps per control step (control dt = substeps x
            the model's timestep).
          horizon: number of control steps T.
          x0: start state: a mapping ``{"qpos": [...], "qvel": [...], "act": [...]}``
            or a vector of length nx. Default: the model's ``qpos0`` at rest (and act 0).
          target: target observation z*, length nz. Default: the start's.
          Q, QT: running and terminal cost on the observation error: a scalar
            (times identity), a diagonal (length nz) or a matrix [nz, nz];
            symmetric positive semi-definite.
          R: control cost: scalar, diagonal or matrix [nu, nu]; positive
            definite.
          solver_defaults: the task's recommended solver settings (any
            ``SolverConfig`` field), used by :func:`default_config`.
          noise: the system's noise, a :class:`NoiseModel` or a mapping
            ``{"initial": s0, "process": sw, "measurement": sv}`` of standard
            deviations. Default: none (a deterministic system).
        """
        path = os.fspath(path)
        if is_package_path(path):  # pkg://PACKAGE/PATH: a file inside an installed package
            path = resolve_model_path(path)
        if not os.path.exists(path):
            raise ModelLoadError(
                f"The model file {path!r} does not exist. Give the path of an "
                "MJCF (.xml) file; in a task file it is relative to the task file."
            )
        try:
            mj_model = mujoco.MjModel.from_xml_path(path)
        except Exception as exc:  # mujoco raises ValueError with its parser message
            raise ModelLoadError(
                f"MuJoCo could not load {path!r}: {exc}. Fix the MJCF file "
                "(MuJoCo's message names the element and line)."
            ) from None
        return cls.from_model(
            mj_model,
            observation=observation,
            substeps=substeps,
            horizon=horizon,
            x0=x0,
            target=target,
            Q=Q,
            QT=QT,
            R=R,
            name=name or os.path.splitext(os.path.basename(path))[0],
            solver_defaults=solver_defaults,
            noise=noise,
        )

    @classmethod
    def from_model(
        cls,
        mj_model: mujoco.MjModel,
        *,
        observation: Any = "full",
        substeps: int = 1,
        horizon: int = 30,
        x0: Any = None,
        target: Any = None,
        Q: Any = 1.0,
        QT: Any = 100.0,
        R: Any = 1.0,
        name: str = "model",
        solver_defaults: Mapping[str, Any] | None = None,
        noise: Any = None,
    ) -> "Env":
        """Like :meth:`from_xml`, from an already loaded ``mujoco.MjModel``."""
        nq, nv, nu = mj_model.nq, mj_model.nv, mj_model.nu
        if nu < 1:
            raise TaskError(
                f"The model {name!r} has no actuators (nu = 0); POD-iLQR needs at "
                "least one control. Add an <actuator> to the MJCF file."
            )
        _check_int("substeps", substeps, minimum=1)
        _check_int("horizon", horizon, minimum=1)

        obs = _observation_matrix(mj_model, observation)
        C, labels = obs.C, obs.labels
        nz = C.shape[0]
        u_low, u_high = control_limits(mj_model)
        x0_vec = _start_state(mj_model, x0)
        if target is None:
            target_vec = C @ x0_vec
        else:
            target_vec = _vector("target", target, nz, "the observation size nz")
        Qm = _cost_matrix("Q", Q, nz, "nz (observation size)", definite=False)
        QTm = _cost_matrix("QT", QT, nz, "nz (observation size)", definite=False)
        Rm = _cost_matrix("R", R, nu, "nu (number of controls)", definite=True)
        noise_model = NoiseModel.from_any(noise).validate()

        dims = EnvDims(
            nq=nq,
            nv=nv,
            nu=nu,
            nz=nz,
            substeps=int(substeps),
            horizon=int(horizon),
            sensors=obs.sensors,
            quats=quaternions(mj_model),
            na=int(mj_model.na),
        )
        arrays = EnvData(
            model=None,  # MJX's copy is built when MJX runs (``data``)
            C=jnp.asarray(C),
            x0=jnp.asarray(x0_vec),
            z_target=jnp.asarray(target_vec),
            Q=jnp.asarray(Qm),
            QT=jnp.asarray(QTm),
            R=jnp.asarray(Rm),
            noise=noise_levels(noise_model, dims.ndx, nz),
            goal_step=jnp.asarray(int(horizon)),
            D=jnp.asarray(obs.D),
            u_low=jnp.asarray(u_low),
            u_high=jnp.asarray(u_high),
        )
        return cls(
            name=name,
            mj_model=mj_model,
            dims=dims,
            arrays=arrays,
            observation_labels=labels,
            control_dt=float(mj_model.opt.timestep) * int(substeps),
            solver_defaults=dict(solver_defaults or {}),
            noise=noise_model,
            observation=observation,
            model_notes=mjx_notes(mj_model),
        )

    # ------------------------------------------------------------------ the data
    @property
    def data(self) -> EnvData:
        """The task's arrays as its engine's rollouts take them: on MJX with
        MJX's copy of the model (built on the first read, then kept), on the
        native engine with none. Where MJX cannot convert the model the model
        field is an :class:`MJXUnavailable`, which refuses to run with MJX's reason."""
        if self.dims.native is not None:
            return self.arrays
        return self.arrays._replace(model=self.mjx_models.get("jax", sensors=self.dims.sensors))

    def mjx_model(self, impl: str = "jax"):
        """MJX's copy of the model in implementation ``impl`` (``SolverConfig.impl``);
        a :class:`ModelLoadError` with MJX's reason where MJX cannot convert it."""
        model = self.mjx_models.get(impl, sensors=self.dims.sensors)
        if isinstance(model, MJXUnavailable):
            raise ModelLoadError(model.message)
        return model

    @property
    def mjx_problem(self) -> str:
        """Why MJX cannot run this task ("" where it can; builds MJX's copy to find out)."""
        model = self.mjx_models.get("jax", sensors=self.dims.sensors)
        return model.reason if isinstance(model, MJXUnavailable) else ""

    # --------------------------------------------------------------- variations
    def replace(self, **changes: Any) -> "Env":
        """A copy with some of ``horizon``, ``x0``, ``target``, ``Q``, ``QT``,
        ``R``, ``noise``, ``solver_defaults`` changed (validated as in
        :meth:`from_model`)."""
        allowed = {"horizon", "x0", "target", "Q", "QT", "R", "name", "noise", "solver_defaults"}
        unknown = set(changes) - allowed
        if unknown:
            raise TaskError(f"Env.replace got unknown field(s) {sorted(unknown)}; allowed: {sorted(allowed)}.")
        d = self.arrays
        kwargs = dict(
            observation=np.asarray(d.C) if self.observation is None else self.observation,
            substeps=self.dims.substeps,
            horizon=self.dims.horizon,
            x0=np.asarray(d.x0),
            target=np.asarray(d.z_target),
            Q=np.asarray(d.Q),
            QT=np.asarray(d.QT),
            R=np.asarray(d.R),
            name=self.name,
            solver_defaults=self.solver_defaults,
            noise=self.noise,
        )
        kwargs.update(changes)
        env = Env.from_model(self.mj_model, **kwargs)
        env = dataclasses.replace(env, observation_labels=self.observation_labels, mjx_models=self.mjx_models)
        env = env.on_engine(self.dims.native, self.model_notes)
        goal = int(self.arrays.goal_step)
        return env if goal == self.dims.horizon or "horizon" in changes else env.with_goal_step(goal)

    def on_engine(self, native, notes: tuple[str, ...] | None = None) -> "Env":
        """A copy whose rollouts run on ``native`` (a ``sim.native.NativeModel``
        of this task's model), or on MJX with None (``SolverConfig.engine``);
        ``notes`` replace ``model_notes`` (default: MJX's where MJX runs, none on the C engine)."""
        if notes is None:
            notes = mjx_notes(self.mj_model) if native is None else ()
        dims = dataclasses.replace(self.dims, native=native)
        return dataclasses.replace(self, dims=dims, model_notes=tuple(notes))

    def with_start_state(self, x0) -> "Env":
        """A copy starting from the state ``x0`` = [qpos, qvel, act] (the same MJX
        model and cost; traced, so solving from it never recompiles)."""
        x = np.asarray(x0, dtype=float)
        if x.shape != (self.dims.nx,) or not np.all(np.isfinite(x)):
            raise TaskError(f"`x0` must be {self.dims.nx} finite numbers (qpos, qvel, act); got {x0!r}.")
        return dataclasses.replace(self, arrays=self.arrays._replace(x0=jnp.asarray(x, self.arrays.x0.dtype)))

    def with_goal_step(self, step: int) -> "Env":
        """A copy whose running cost uses QT from step ``step`` on: the target
        is to be reached by ``step`` and held to the horizon. ``step = horizon``
        (the default) is the ordinary cost. Traced: changing it never
        recompiles (receding-horizon replanning uses it, see ``replan``)."""
        T = self.dims.horizon
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or not 0 <= step <= T:
            raise TaskError(f"`goal_step` must be an integer in 0 .. horizon = {T}; got {step!r}.")
        return dataclasses.replace(self, arrays=self.arrays._replace(goal_step=jnp.asarray(int(step))))

    def full_state_view(self) -> "Env":
        """The same task seen through the full state x (C = I).

        The cost is lifted so that it is the same function of the controls:
        Q_x = C' Q C, QT_x = C' QT C and x* = C^+ z* (exact because C has full
        row rank). Used by the model-based iLQR, which works on the state.
        """
        if self.dims.sensors:
            raise TaskError(
                f"The task {self.name!r} observes MuJoCo sensors that are not state coordinates "
                f"({', '.join(lab for lab in self.observation_labels if lab.startswith('sensor:'))}); "
                "the model-based reference needs a cost on the state (observe joints or a matrix C). "
                "POD-iLQR itself solves it (podilqr solve without --compare or --method model-based)."
            )
        a = self.arrays
        C = np.asarray(a.C)
        nx = self.dims.nx
        x_target = np.linalg.pinv(C) @ np.asarray(a.z_target)
        arrays = a._replace(
            C=jnp.eye(nx),
            z_target=jnp.asarray(x_target),
            Q=jnp.asarray(C.T @ np.asarray(a.Q) @ C),
            QT=jnp.asarray(C.T @ np.asarray(a.QT) @ C),
            noise=a.noise._replace(v=jnp.zeros(nx)),
            D=jnp.zeros((nx, a.D.shape[1])),
        )
        dims = dataclasses.replace(self.dims, nz=nx)
        labels = _state_labels(self.mj_model)
        return dataclasses.replace(self, dims=dims, arrays=arrays, observation_labels=labels)

    @property
    def state_labels(self) -> tuple[str, ...]:
        return _state_labels(self.mj_model)

    @property
    def limited(self) -> bool:
        """True when some actuator has a ctrlrange (rollouts clamp to it and
        the backward pass solves a box-constrained QP, see ``backward``)."""
        bounds = np.concatenate([np.asarray(self.arrays.u_low), np.asarray(self.arrays.u_high)])
        return bool(np.any(np.isfinite(bounds)))

    @property
    def fully_observed(self) -> bool:
        """True when the observation has as many entries as the state (nz == nx):
        the default information state then holds one measurement (q = 1)."""
        return self.dims.nz == self.dims.nx

    @property
    def noisy(self) -> bool:
        """True when the system has any noise."""
        return not self.noise.is_zero

    def __repr__(self) -> str:
        d = self.dims
        noise = "" if self.noise.is_zero else f", noise={self.noise}"
        limits = "" if not self.limited else ", ctrl limited"
        return (
            f"Env({self.name!r}, nq={d.nq}, nv={d.nv}, nu={d.nu}, nz={d.nz}{limits}, "
            f"horizon={d.horizon}, control_dt={self.control_dt:g}{noise})"
        )


# ------------------------------------------------------------ MJX compatibility
# Options of MuJoCo that MJX refuses but that do not change the simulated
# motion: they are switched off on the copy handed to MJX, with a note.
_REPORTING_ONLY = (
    (mujoco.mjtEnableBit.mjENBL_ENERGY, "energy", "it only computes kinetic and potential energy for reporting"),
    (mujoco.mjtEnableBit.mjENBL_FWDINV, "fwdinv", "it only compares forward and inverse dynamics for reporting"),
)
_MJX_INTEGRATORS = tuple(int(getattr(mujoco.mjtIntegrator, f"mjINT_{i}")) for i in ("EULER", "RK4", "IMPLICITFAST"))


def mjx_notes(mj_model: mujoco.MjModel) -> tuple[str, ...]:
    """A note per option of ``mj_model`` that MJX's copy switches off (``mjx_model_of``), from the model's flags."""
    notes = [
        f"MuJoCo's `{flag}` flag is switched off for MJX, which does not implement it ({why})"
        for bit, flag, why in _REPORTING_ONLY
        if mj_model.opt.enableflags & int(bit)
    ]
    if mj_model.opt.solver == mujoco.mjtSolver.mjSOL_PGS:
        notes.append(
            "the constraint solver PGS is replaced by Newton for MJX, which has no PGS "
            "(both solve the same convex constraint problem)"
        )
    return tuple(notes)


def mjx_model_of(mj_model: mujoco.MjModel, name: str = "model", impl: str = "jax") -> tuple[Any, tuple[str, ...]]:
    """The ``mjx.Model`` of ``mj_model`` (MJX implementation ``impl``) and a note per option switched off.

    MJX refuses some MuJoCo options that do not change the dynamics; those are
    switched off on a copy (``mj_model`` itself is left as it is), each with a
    one-line note (``mjx_notes``, ``Env.model_notes``, ``Result.warnings``, the CLI's output):

    - ``<flag energy="enable">`` and ``<flag fwdinv="enable">``: reporting only;
    - ``solver="PGS"``: replaced by ``Newton``, which solves the same convex
      constraint problem (the forces agree to the solvers' tolerance).

    A feature that changes the dynamics and that MJX cannot simulate (an
    integrator other than Euler, RK4 and implicitfast; a geom pair without
    collision function; flex; ...) raises a :class:`ModelLoadError` that names
    it. ``Env`` catches it: such a model runs on MuJoCo's C engine.
    """
    m = copy.deepcopy(mj_model)
    for bit, _, _ in _REPORTING_ONLY:
        m.opt.enableflags &= ~int(bit)
    if m.opt.solver == mujoco.mjtSolver.mjSOL_PGS:
        m.opt.solver = int(mujoco.mjtSolver.mjSOL_NEWTON)
    if m.opt.integrator not in _MJX_INTEGRATORS:
        integrator = mujoco.mjtIntegrator(m.opt.integrator).name[6:].lower()
        raise ModelLoadError(
            f"MJX cannot simulate the model {name!r}: its integrator is {integrator!r}, and MJX steps only "
            "'Euler', 'RK4' and 'implicitfast'. To run it on MJX, set <option integrator=\"implicitfast\"/> (or "
            "RK4) in the MJCF file; this changes the discrete-time dynamics slightly."
        )
    try:
        # This process's first device (MJX's default, jax.devices()[0], is process 0's under jax.distributed).
        mjx_model = mjx.put_model(m, impl=impl, device=jax.local_devices()[0])
    except Exception as exc:
        raise ModelLoadError(
            f"MJX cannot load the model {name!r}: {type(exc).__name__}: {str(exc).rstrip('.')}. MJX supports a "
            "subset of MuJoCo (no flex; a subset of the geom pairs, sensors, actuators and options); to run it on MJX, "
            "remove or replace the feature it names (for a geom pair: contype/conaffinity = 0 on one of them)."
        ) from None
    return mjx_model, mjx_notes(mj_model)


@dataclasses.dataclass(frozen=True)
class MJXUnavailable:
    """Stands in ``EnvData.model`` for a model MJX cannot convert: an empty
    pytree (nothing is traced) that refuses, with MJX's reason, where MJX
    would run (``sim.rollout.make_data``)."""

    reason: str  # MJX's refusal, one paragraph (``mjx_model_of``), naming the task

    @property
    def message(self) -> str:
        return (
            f"{self.reason} MuJoCo's C engine runs the model as it is: set `engine` to 'native' (a task "
            "file's [solver] table, --set engine=native, or SolverConfig(engine='native')), or leave it 'auto' "
            "on a CPU."
        )

    @property
    def short(self) -> str:
        """MJX's refusal in a clause (its first sentence)."""
        return self.reason.split(". ")[0].rstrip(".")


jax.tree_util.register_pytree_node(MJXUnavailable, lambda u: ((), u.reason), lambda reason, _: MJXUnavailable(reason))


class MJXModels:
    """MJX's copies of one MuJoCo model, built on first use per implementation
    (``jax``, ``warp``) and shared by the copies of a task (``Env.replace`` and
    the like); a model MJX cannot convert is kept as its :class:`MJXUnavailable`."""

    def __init__(self, mj_model: mujoco.MjModel, name: str):
        self.mj_model, self.name = mj_model, name
        self._models: dict[tuple[str, bool], Any] = {}
        self._lock = threading.Lock()

    def get(self, impl: str = "jax", sensors: bool = False):
        """MJX's copy in ``impl``, or its :class:`MJXUnavailable`; with ``sensors``, also
        checked to compute the model's sensors (the observation reads them)."""
        with self._lock:
            key = (impl, bool(sensors))
            if key not in self._models:
                self._models[key] = self._build(impl, sensors)
            return self._models[key]

    def built(self, impl: str = "jax", sensors: bool = False):
        """What :meth:`get` returns, where it has been built already; else None (nothing is built)."""
        with self._lock:
            return self._models.get((impl, bool(sensors)))

    def _build(self, impl: str, sensors: bool):
        try:
            model, _ = mjx_model_of(self.mj_model, self.name, impl=impl)
            if sensors:
                _check_sensors_run(model, self.name)
        except ModelLoadError as exc:
            return MJXUnavailable(str(exc))
        return model


# --------------------------------------------------------------------- helpers
def _check_sensors_run(mjx_model, name: str) -> None:
    """Trace (without compiling) the ``mjx.forward`` that computes the sensors,
    so that a sensor MJX does not implement fails here with its name."""
    try:
        jax.eval_shape(mjx.forward, mjx_model, mjx.make_data(mjx_model))
    except Exception as exc:
        raise ModelLoadError(
            f"MJX cannot compute the sensors of {name!r}: {type(exc).__name__}: {exc}. To run it on MJX, observe "
            "joints (qpos/qvel) or another sensor type instead."
        ) from None


def _check_int(name: str, value: Any, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise TaskError(
            f"`{name}` must be an integer >= {minimum}; got {value!r}. "
            f"Set `{name}` to a whole number of at least {minimum}."
        )


def _state_labels(m: mujoco.MjModel) -> tuple[str, ...]:
    labels = []
    for kind, n, adr_of in (("qpos", m.nq, m.jnt_qposadr), ("qvel", m.nv, m.jnt_dofadr)):
        names = [f"{kind}[{i}]" for i in range(n)]
        for j in range(m.njnt):
            jname = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}"
            width = _joint_width(m, j, kind)
            for w in range(width):
                names[adr_of[j] + w] = f"{kind}:{jname}" + (f"[{w}]" if width > 1 else "")
        labels += names
    for i in range(m.nu):  # the activations, in MuJoCo's act order (actuators with dynamics)
        if m.actuator_actadr[i] >= 0:
            aname = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, i) or f"actuator{i}"
            width = int(m.actuator_actnum[i])
            labels += [f"act:{aname}" + (f"[{w}]" if width > 1 else "") for w in range(width)]
    return tuple(labels)


def _joint_width(m: mujoco.MjModel, j: int, kind: str) -> int:
    jtype = m.jnt_type[j]
    if jtype == mujoco.mjtJoint.mjJNT_FREE:
        return 7 if kind == "qpos" else 6
    if jtype == mujoco.mjtJoint.mjJNT_BALL:
        return 4 if kind == "qpos" else 3
    return 1


def _index_of(m: mujoco.MjModel, kind: str, entry: Any) -> list[int]:
    n = m.nq if kind == "qpos" else m.nv
    if isinstance(entry, (int, np.integer)) and not isinstance(entry, bool):
        if not 0 <= entry < n:
            raise TaskError(
                f"Observation index {kind}[{entry}] is out of range: the model has "
                f"{kind} of length {n}. Use an index in 0..{n - 1} or a joint name."
            )
        return [int(entry)]
    if isinstance(entry, str):
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, entry)
        if j < 0:
            names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, i) for i in range(m.njnt)]
            raise TaskError(f"Unknown joint {entry!r} in the {kind} observation; the model's joints are {names}.")
        adr = (m.jnt_qposadr if kind == "qpos" else m.jnt_dofadr)[j]
        return list(range(adr, adr + _joint_width(m, j, kind)))
    raise TaskError(f"Observation entries must be indices or joint names; got {entry!r} in {kind}.")


_LINEAR_SENSORS = {mujoco.mjtSensor.mjSENS_JOINTPOS: "qpos", mujoco.mjtSensor.mjSENS_JOINTVEL: "qvel"}


class Observation(NamedTuple):
    """z = C x + D sensordata, with a label per row."""

    C: np.ndarray  # [nz, nx]
    D: np.ndarray  # [nz, nsensordata]
    labels: tuple[str, ...]
    sensors: bool  # some row reads sensordata


def _sensor_rows(m: mujoco.MjModel, entry: Any) -> tuple[list[np.ndarray], list[np.ndarray], list[str]]:
    """Rows (of C and of D) and labels of the named sensor ``entry``.

    A ``jointpos``/``jointvel`` sensor of a hinge or slide joint without a
    cutoff is a coordinate of the state, so it becomes a row of C (linear, and
    usable by the model-based reference); any other sensor is read from
    ``sensordata`` after ``mjx.forward``.
    """
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_SENSOR, i) for i in range(m.nsensor)]
    if not isinstance(entry, str):
        raise TaskError(f"Sensor observations are given by name; got {entry!r}. The model's sensors are {names}.")
    i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, entry)
    if i < 0:
        raise TaskError(
            f"Unknown sensor {entry!r} in the observation; the model's sensors are {names or 'none'}. "
            "Add a named <sensor> to the MJCF file or fix the name."
        )
    stype = mujoco.mjtSensor(m.sensor_type[i])
    if m.sensor_needstage[i] == mujoco.mjtStage.mjSTAGE_ACC:
        raise TaskError(
            f"Sensor {entry!r} ({stype.name[7:].lower()}) depends on accelerations, i.e. on the control "
            "being applied, so it is not an observation of the state; use a position or velocity sensor."
        )
    nx = m.nq + m.nv
    kind = _LINEAR_SENSORS.get(stype)
    if kind is not None and m.sensor_objtype[i] == mujoco.mjtObj.mjOBJ_JOINT and m.sensor_cutoff[i] == 0:
        j = m.sensor_objid[i]
        if int(m.jnt_type[j]) in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            col = m.jnt_qposadr[j] if kind == "qpos" else m.nq + m.jnt_dofadr[j]
            return [np.eye(nx)[col]], [np.zeros(m.nsensordata)], [f"sensor:{entry}"]
    dim, adr = int(m.sensor_dim[i]), int(m.sensor_adr[i])
    labels = [f"sensor:{entry}" + (f"[{k}]" if dim > 1 else "") for k in range(dim)]
    return [np.zeros(nx)] * dim, list(np.eye(m.nsensordata)[adr : adr + dim]), labels


def _observation_matrix(m: mujoco.MjModel, observation: Any) -> Observation:
    nq, nv = m.nq, m.nv
    nx = nq + nv + m.na
    labels_all = _state_labels(m)
    if isinstance(observation, str):
        if observation == "full":
            rows = list(range(nx))
        elif observation == "qpos":
            rows = list(range(nq))
        else:
            raise TaskError(
                f"Unknown observation {observation!r}; use 'full', 'qpos', a mapping "
                "{'qpos': [...], 'qvel': [...], 'sensors': [...]} or a matrix C of shape [nz, nx] (nx = nq + nv + na)."
            )
        C = np.eye(nx)[rows]
        return Observation(C, np.zeros((len(rows), m.nsensordata)), tuple(labels_all[r] for r in rows), False)
    if isinstance(observation, Mapping):
        unknown = set(observation) - {"qpos", "qvel", "sensors"}
        if unknown:
            raise TaskError(
                f"Observation mapping has unknown key(s) {sorted(unknown)}; use 'qpos', 'qvel' and/or 'sensors'."
            )
        c_rows: list[np.ndarray] = []
        d_rows: list[np.ndarray] = []
        labels: list[str] = []
        for kind, offset in (("qpos", 0), ("qvel", nq)):
            for entry in _entries(observation, kind):
                for i in _index_of(m, kind, entry):
                    c_rows.append(np.eye(nx)[offset + i])
                    d_rows.append(np.zeros(m.nsensordata))
                    labels.append(labels_all[offset + i])
        for entry in _entries(observation, "sensors"):
            c, d, lab = _sensor_rows(m, entry)
            c_rows += c
            d_rows += d
            labels += lab
        if not labels:
            raise TaskError("The observation selects nothing (size 0); list at least one qpos, qvel or sensors entry.")
        C = np.array(c_rows).reshape(len(labels), nx)
        D = np.array(d_rows).reshape(len(labels), m.nsensordata)
        rows = np.concatenate([C, D], axis=1)
        if len(np.unique(rows, axis=0)) != len(rows):
            raise TaskError(f"The observation selects some quantity twice: {labels}; list each once.")
        sensors = bool(np.any(D))
        if not sensors and np.linalg.matrix_rank(C) < C.shape[0]:
            raise TaskError(f"The observation {labels} repeats a coordinate; list each once.")
        return Observation(C, D, tuple(labels), sensors)
    try:
        C = np.asarray(observation, dtype=float)
    except (TypeError, ValueError):
        raise TaskError(
            f"The observation must be 'full', 'qpos', a mapping or a matrix C [nz, nx]; got {observation!r}."
        ) from None
    if C.ndim != 2 or C.shape[1] != nx or C.shape[0] < 1:
        raise TaskError(
            f"The observation matrix C must have shape [nz, {'nq + nv + na' if m.na else 'nq + nv'}] = [nz, {nx}] "
            f"with nz >= 1; got shape {C.shape}."
        )
    if not np.all(np.isfinite(C)):
        raise TaskError("The observation matrix C holds non-finite numbers; use finite values.")
    if np.linalg.matrix_rank(C) < C.shape[0]:
        raise TaskError(
            f"The observation matrix C ({C.shape[0]} rows) is rank deficient: some "
            "observation is a combination of the others. Remove redundant rows."
        )
    return Observation(C, np.zeros((C.shape[0], m.nsensordata)), tuple(f"z[{i}]" for i in range(C.shape[0])), False)


def _entries(observation: Mapping, kind: str) -> list:
    entries = observation.get(kind) or []
    if isinstance(entries, (str, int)):
        entries = [entries]
    if not isinstance(entries, (list, tuple)):
        raise TaskError(f"Observation `{kind}` must be a list of names or indices; got {entries!r}.")
    return list(entries)


def control_limits(m: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """The ctrl box MuJoCo clamps to: ``ctrlrange`` where ``ctrllimited``
    (and clamping is not disabled), else (-inf, inf)."""
    low, high = np.full(m.nu, -np.inf), np.full(m.nu, np.inf)
    if not m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CLAMPCTRL:
        limited = m.actuator_ctrllimited.astype(bool)
        low[limited] = m.actuator_ctrlrange[limited, 0]
        high[limited] = m.actuator_ctrlrange[limited, 1]
    return low, high


def _vector(name: str, value: Any, n: int, what: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise TaskError(f"`{name}` must be a list of numbers; got {value!r}.") from None
    if v.shape != (n,):
        raise TaskError(f"`{name}` must have length {n} ({what}); got length {v.size}: {value!r}.")
    if not np.all(np.isfinite(v)):
        raise TaskError(f"`{name}` holds non-finite numbers ({value!r}); use finite values.")
    return v


def _start_state(m: mujoco.MjModel, x0: Any) -> np.ndarray:
    nq, nv, na = m.nq, m.nv, m.na
    if x0 is None:
        return np.concatenate([np.array(m.qpos0, dtype=float), np.zeros(nv + na)])
    if isinstance(x0, Mapping):
        allowed = {"qpos", "qvel"} | ({"act"} if na else set())
        unknown = set(x0) - allowed
        if unknown:
            keys = " and ".join(map(repr, sorted(allowed)))
            raise TaskError(f"`x0` has unknown key(s) {sorted(unknown)}; use {keys}.")
        qpos = _vector("x0.qpos", x0["qpos"], nq, "nq") if "qpos" in x0 else np.array(m.qpos0, dtype=float)
        qvel = _vector("x0.qvel", x0["qvel"], nv, "nv") if "qvel" in x0 else np.zeros(nv)
        act = _vector("x0.act", x0["act"], na, "na, the activations") if "act" in x0 else np.zeros(na)
        return np.concatenate([qpos, qvel, act])
    what = "nq + nv: qpos then qvel" if not na else "nq + nv + na: qpos, qvel, then the activations act"
    return _vector("x0", x0, nq + nv + na, what)


def _cost_matrix(name: str, value: Any, n: int, what: str, definite: bool) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise TaskError(f"`{name}` must be a number, a list or a matrix; got {value!r}.") from None
    if a.ndim == 0:
        M = float(a) * np.eye(n)
    elif a.ndim == 1 and a.shape == (n,):
        M = np.diag(a)
    elif a.ndim == 2 and a.shape == (n, n):
        M = a.copy()
    else:
        raise TaskError(
            f"`{name}` must be a scalar, a diagonal of length {n} or a matrix [{n}, {n}] ({what}); got shape {a.shape}."
        )
    if not np.all(np.isfinite(M)):
        raise TaskError(f"`{name}` holds non-finite numbers; use finite values.")
    if not np.allclose(M, M.T, rtol=1e-10, atol=1e-12):
        raise TaskError(f"`{name}` must be symmetric; got {M.tolist()}.")
    eig = np.linalg.eigvalsh(M)
    if definite and eig.min() <= 0:
        raise TaskError(
            f"`{name}` must be positive definite (smallest eigenvalue {eig.min():g}); "
            "use strictly positive control weights."
        )
    if not definite and eig.min() < -1e-12 * max(1.0, abs(eig).max()):
        raise TaskError(
            f"`{name}` must be positive semi-definite (smallest eigenvalue {eig.min():g}); use non-negative weights."
        )
    return M
