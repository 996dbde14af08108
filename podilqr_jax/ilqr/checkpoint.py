"""Checkpoints of the solver's state on disk.

Everything the outer loop carries from one iteration to the next is a
:class:`~podilqr_jax.ilqr.state.SolverState` (``state``): the nominal, the gains
of the current policy, the identified model when the next iteration reuses
it, the regularisation, both PRNG keys, the driver's bookkeeping and the
record of counters and histories. Saving it after an iteration and loading it
gives the driver exactly what it had, so a resumed solve takes the same steps,
bit for bit, as one that never stopped (same machine, same task and settings).

A checkpoint is one file, ``DIR/checkpoint.npz``: the arrays and a JSON header
(format version, the fingerprint of the task and settings, the scalars and
histories). It is written to a temporary file in DIR and renamed over the old
one (atomic on POSIX), so an interrupted write leaves the previous checkpoint
intact. ``load_checkpoint`` refuses a checkpoint of another task or other
settings (``max_iterations`` may differ: that is how a run is extended).
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from typing import Any

import jax.numpy as jnp
import numpy as np

from ..atomic import write_atomic
from ..errors import ConfigError
from ..identify.sysid import LinearModel
from .state import Nominal, Record, SolverState

FILE = "checkpoint.npz"
FORMAT = 3  # 2: the sysid scale, its history and the mirrored switch; 3: the record under the result's names
READABLE = (2, 3)
# format 2 wrote the record's fields flat, under the driver's old names
_FORMAT_2_NAMES = {
    "iteration": "iterations",
    "rejected": "rejected_steps",
    "longest_streak": "longest_rejection_streak",
    "true_history": "true_cost_history",
    "open_history": "open_loop_cost_history",
    "grad_history": "grad_norm_history",
}
_RESUMABLE_CHANGES = ("max_iterations",)
# Settings added after format 3, left out of the fingerprint at their default,
# so that a checkpoint written before they existed still resumes.
_LATER_DEFAULTS = {
    "jacobian": "auto",
    "engine": "auto",
    "restarts": 1,
    "restart_scale": 0.3,
    "race_rung": 32,
    "race_margin": 1.5,
    "max_fit_error": 0.1,
    "paired_line_search": False,
}


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
    config = {
        k: v
        for k, v in cfg.flat().items()
        if k not in _RESUMABLE_CHANGES and not (k in _LATER_DEFAULTS and v == _LATER_DEFAULTS[k])
    }
    return {
        "method": method,
        "task": env.name,
        "dims": dims.as_dict(),
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
        **{name: getattr(state, name) for name in SolverState.SCALARS},
        "record": state.record.as_dict(),
    }
    arrays = {k: np.asarray(v) for k, v in arrays.items()}
    arrays["header"] = np.array(json.dumps(header, allow_nan=True))
    path = os.path.join(directory, FILE)
    write_atomic(path, lambda f: np.savez(f, **arrays), suffix=".npz", fsync=True)
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
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        # np.load names a file it cannot read as an archive "pickled data": say what it is instead
        raise ConfigError(
            f"The checkpoint {file!r} cannot be read: it is empty, cut short or not a podilqr checkpoint "
            f"({type(exc).__name__}). Resume from another checkpoint folder, or start the solve afresh "
            "without --resume."
        ) from None
    if header.get("format") not in READABLE:
        raise ConfigError(
            f"The checkpoint {file!r} has format {header.get('format')!r}; this version reads "
            f"{', '.join(map(str, READABLE))}."
        )
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
    if header["format"] == 2:
        header["record"] = {_FORMAT_2_NAMES.get(k, k): v for k, v in header.items()}
    return SolverState(
        nominal=nominal,
        gains=dev("gains"),
        key=jnp.asarray(arrays["key"]),
        ls_key=jnp.asarray(arrays["ls_key"]),
        model=model,
        back_k=dev("back_k") if "back_k" in arrays else None,
        record=Record.from_dict(header["record"]),
        **{name: header[name] for name in SolverState.SCALARS},  # JSON keeps their types (float, int, list)
    )
