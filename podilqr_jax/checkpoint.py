"""The solver's state between iterations, and checkpoints of it on disk.

Everything the outer loop carries from one iteration to the next is a
:class:`SolverState`: the nominal (u_bar, its measured rollout and information
states), the gains of the current policy, the identified model when the next
iteration reuses it (after a rejected noiseless step), the regularisation mu
and its failure count, both PRNG keys, the counters and every history. Saving
it after an iteration and loading it gives the driver exactly what it had, so
a resumed solve takes the same steps, bit for bit, as one that never stopped
(same machine, same task and settings).

A checkpoint is one file, ``DIR/checkpoint.npz``: the arrays and a JSON header
(format version, the fingerprint of the task and settings, the scalars and
histories). It is written to a temporary file in DIR and renamed over the old
one (atomic on POSIX), so an interrupted write leaves the previous checkpoint
intact. ``load_checkpoint`` refuses a checkpoint of another task or other
settings (``max_iterations`` may differ: that is how a run is extended).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import tempfile
from typing import Any, Optional

import jax.numpy as jnp
import numpy as np

from .errors import ConfigError
from .sysid import LinearModel

FILE = "checkpoint.npz"
FORMAT = 2  # 2: the sysid scale, its history and the mirrored switch
_RESUMABLE_CHANGES = ("max_iterations",)


@dataclasses.dataclass
class Nominal:
    """The nominal trajectory: controls and their measured rollout."""

    u_bar: jnp.ndarray  # [T, nu]
    z_bar: jnp.ndarray  # [T+1, nz] (as measured)
    x_bar: jnp.ndarray  # [T+1, nx]
    Z_bar: jnp.ndarray  # [T+1, nZ]
    cost: float

    @classmethod
    def measured(cls, ls) -> "Nominal":
        """The line search's chosen rollout as the new nominal."""
        return cls(ls.trajectory.u, ls.trajectory.z, ls.trajectory.x, ls.Z, float(ls.cost))


@dataclasses.dataclass
class SolverState:
    """What the outer loop carries between iterations (host scalars, device arrays)."""

    iteration: int  # iterations completed
    nominal: Nominal
    gains: jnp.ndarray  # K of the current policy [T, nu, nZ]
    model: Optional[LinearModel]  # reused by the next iteration when not None
    back_k: Optional[jnp.ndarray]  # the last backward pass's k [T, nu]
    key: jnp.ndarray  # sysid PRNG key
    ls_key: jnp.ndarray  # line-search PRNG key
    mu: float
    sigma: float = float("nan")  # the sysid scale (adapted with cfg.adapt_sigma) before re-identification factors
    mirrored: int = 0  # 1 once the identification runs mirrored pairs (configured, or a recovery)
    open_loop: int = 0  # 1 once a recovery switched a closed-loop identification to open loop
    failures: int = 0  # consecutive rejected steps (mu grows by factor^failures)
    rejected: int = 0
    remeasured: int = 0
    streak: int = 0
    longest_streak: int = 0
    rollouts: int = 0
    diverged_rollouts: int = 0  # sysid rollouts left out of the fit (non-finite)
    diverged_candidates: int = 0  # line-search candidates rejected as non-finite
    mu_retries: int = 0  # backward passes redone with a larger mu after a rejected step
    reidentified: int = 0  # re-identifications since the last accepted step (sets the sigma scale)
    reidentifications: int = 0  # in all
    stopped: Optional[list] = None  # [status, message] once a stopping rule fired
    cost_history: list = dataclasses.field(default_factory=list)
    true_history: list = dataclasses.field(default_factory=list)
    open_history: list = dataclasses.field(default_factory=list)
    alpha_history: list = dataclasses.field(default_factory=list)
    mu_history: list = dataclasses.field(default_factory=list)
    grad_history: list = dataclasses.field(default_factory=list)
    sigma_history: list = dataclasses.field(default_factory=list)  # the sigma of every identification

    _COUNTERS = (
        "iteration",
        "failures",
        "rejected",
        "remeasured",
        "streak",
        "longest_streak",
        "rollouts",
        "diverged_rollouts",
        "diverged_candidates",
        "mu_retries",
        "reidentified",
        "reidentifications",
        "mirrored",
        "open_loop",
    )
    _HISTORIES = (
        "cost_history",
        "true_history",
        "open_history",
        "alpha_history",
        "mu_history",
        "grad_history",
        "sigma_history",
    )

    def snapshot(self) -> "SolverState":
        """A shallow copy of the state at an iteration boundary, in O(1): arrays
        are immutable and the histories only grow, so their lengths are kept
        and ``restored`` cuts the shared lists back to them."""
        copy = dataclasses.replace(self)
        copy._lengths = {name: len(getattr(self, name)) for name in self._HISTORIES}
        return copy

    def restored(self) -> "SolverState":
        """This snapshot, its histories cut back to their length when it was taken."""
        for name, n in self._lengths.items():
            del getattr(self, name)[n:]
        return self


def fingerprint(method: str, env, dims, cfg) -> dict[str, Any]:
    """What a checkpoint must match to be resumed: the method, the task (its
    dimensions and a hash of its arrays) and the settings."""
    data = env.data
    digest = hashlib.sha256()
    for a in (data.C, data.D, data.x0, data.z_target, data.Q, data.QT, data.R, data.u_low, data.u_high):
        digest.update(np.ascontiguousarray(np.asarray(a, dtype=float)).tobytes())
    for a in data.noise:
        digest.update(np.ascontiguousarray(np.asarray(a, dtype=float)).tobytes())
    digest.update(str(int(data.goal_step)).encode())
    config = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in _RESUMABLE_CHANGES}
    return {
        "method": method,
        "task": env.name,
        "dims": dataclasses.asdict(dims),
        "task_arrays": digest.hexdigest(),
        "config": config,
    }


def save_checkpoint(directory: str | os.PathLike, state: SolverState, print_: dict[str, Any]) -> str:
    """Write ``state`` to ``directory/checkpoint.npz`` atomically; returns the path."""
    directory = os.fspath(directory)
    os.makedirs(directory, exist_ok=True)
    n = state.nominal
    arrays = {
        "u_bar": n.u_bar,
        "z_bar": n.z_bar,
        "x_bar": n.x_bar,
        "Z_bar": n.Z_bar,
        "gains": state.gains,
        "key": state.key,
        "ls_key": state.ls_key,
    }
    if state.model is not None:
        arrays["A"], arrays["B"] = state.model.A, state.model.B
    if state.back_k is not None:
        arrays["back_k"] = state.back_k
    header = {
        "format": FORMAT,
        "fingerprint": print_,
        "nominal_cost": n.cost,
        "mu": state.mu,
        "sigma": state.sigma,
        "stopped": state.stopped,
        **{name: getattr(state, name) for name in SolverState._COUNTERS},
        **{name: getattr(state, name) for name in SolverState._HISTORIES},
    }
    arrays = {k: np.asarray(v) for k, v in arrays.items()}
    arrays["header"] = np.array(json.dumps(header, allow_nan=True))
    path = os.path.join(directory, FILE)
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".npz", dir=directory)
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def load_checkpoint(path: str | os.PathLike, expected: dict[str, Any], to_device) -> SolverState:
    """The state saved in ``path`` (a checkpoint folder or its checkpoint.npz),
    checked against the ``expected`` fingerprint; ``to_device`` places arrays."""
    path = os.fspath(path)
    file = os.path.join(path, FILE) if os.path.isdir(path) else path
    if not os.path.isfile(file):
        raise ConfigError(
            f"No checkpoint at {path!r} (expected {FILE} there); write one with "
            "`podilqr solve TASK --checkpoint DIR --every N`."
        )
    try:
        with np.load(file, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
        header = json.loads(str(arrays.pop("header")))
    except (OSError, ValueError, KeyError) as exc:
        raise ConfigError(f"The checkpoint {file!r} cannot be read ({exc}); it is not a podilqr checkpoint.") from None
    if header.get("format") != FORMAT:
        raise ConfigError(f"The checkpoint {file!r} has format {header.get('format')!r}; this version reads {FORMAT}.")
    saved = header["fingerprint"]
    if saved != expected:
        diff = sorted(k for k in set(saved) | set(expected) if saved.get(k) != expected.get(k))
        detail = []
        if "config" in diff:
            a, b = saved.get("config", {}), expected.get("config", {})
            detail = [f"{k}: {a.get(k)!r} -> {b.get(k)!r}" for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
        raise ConfigError(
            f"The checkpoint {file!r} belongs to another solve: {', '.join(diff)} differ"
            + (f" ({'; '.join(detail)})" if detail else "")
            + ". Resume with the same task and settings (only max_iterations may change)."
        )

    def dev(name):
        return to_device(arrays[name])

    model = LinearModel(dev("A"), dev("B")) if "A" in arrays else None
    nominal = Nominal(dev("u_bar"), dev("z_bar"), dev("x_bar"), dev("Z_bar"), float(header["nominal_cost"]))
    state = SolverState(
        iteration=0,
        nominal=nominal,
        gains=dev("gains"),
        model=model,
        back_k=dev("back_k") if "back_k" in arrays else None,
        key=jnp.asarray(arrays["key"]),
        ls_key=jnp.asarray(arrays["ls_key"]),
        mu=float(header["mu"]),
        sigma=float(header["sigma"]),
        stopped=header.get("stopped"),
    )
    for name in SolverState._COUNTERS:
        setattr(state, name, int(header[name]))
    for name in SolverState._HISTORIES:
        setattr(state, name, [float("nan") if v is None else float(v) for v in header[name]])
    return state
