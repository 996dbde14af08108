"""The solver's jitted stages, kept on disk as traced programs: no tracing in a warm run.

JAX's persistent compilation cache (``cache``) keeps compiled XLA programs,
keyed on the lowered module, so a second run still traces and lowers every
stage to find its key: for an MJX model that is most of a warm run's compile
time (tracing ``mjx.step`` and its ``jax.jacfwd``, benchmarks/journal.md).
``stage`` jits a function like ``jax.jit(fun, static_argnames=...)`` and, when
the package's cache is on, also keeps each traced stage on disk with
``jax.export``:

- the first call for a new key traces and exports the stage once, writes
  the serialized program to ``<cache folder>/podilqr-stages/<key>``, and runs
  it as every later run will: through ``Exported.call``, so a cold and a warm
  run execute the same program and give the same numbers, bit for bit;
- a later process with the same key reads and deserializes it (milliseconds)
  and the compile that follows loads from the persistent cache.

The key hashes everything the traced program depends on: the stage's name,
the package's own source (any edit of the package starts afresh), the JAX,
jaxlib and MuJoCo versions, x64, the backend, the static arguments, the
pytree structure of the traced ones (with their static fields: MJX's model
options, joint types and sizes) and their shapes and dtypes.

Inside a lockstep group (``lockstep``: the solves of ``restarts``, one per
thread) a stage call waits for the other solves' calls and runs with them as
one ``vmap`` of the stage (a plain jit, not kept on disk).

Where a stage cannot go this way it is the plain jitted function: the
package's cache off (``PODILQR_CACHE=0``) or a cache the user configured
for JAX, a call from inside another trace (``vmap``, ``jit``), more than one
device (an exported program fixes its shardings), or an export that JAX
refuses (remembered per key; the reason is in ``fallbacks``).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib.metadata
import inspect
import os
import sys
import warnings
from typing import Any, Callable, Optional, Sequence

import jax
import numpy as np

from ..atomic import write_atomic
from . import cache, lockstep, xla_options

FOLDER_NAME = "podilqr-stages"
fallbacks: dict[str, str] = {}  # stage name -> why it runs as a plain jit (the last refusal)
counts = {"exported": 0, "loaded": 0}  # stage programs traced and written / read from disk, this process


def folder() -> Optional[str]:
    """Where traced stages are kept, or None when they are not (the package's cache is off)."""
    info = cache._state
    if info["source"] != "podilqr" or not info["directory"]:
        return None
    return os.path.join(info["directory"], FOLDER_NAME)


PACKAGE_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # podilqr_jax/, above compilation/


def source_files() -> list[str]:
    """Every Python file of the package (all subpackages), relative to its root, in a fixed order:
    what a stage's key hashes, so that an edit anywhere in the package starts afresh."""
    files = []
    for dirpath, dirnames, filenames in os.walk(PACKAGE_ROOT):
        dirnames.sort()
        files += [
            os.path.relpath(os.path.join(dirpath, n), PACKAGE_ROOT) for n in sorted(filenames) if n.endswith(".py")
        ]
    return files


@functools.lru_cache(maxsize=1)
def _versions() -> str:
    """The package's source and the versions it runs on, as one digest."""
    h = hashlib.sha256()
    for rel in source_files():
        h.update(rel.encode())
        with open(os.path.join(PACKAGE_ROOT, rel), "rb") as f:
            h.update(f.read())
    for dist in ("jax", "jaxlib", "mujoco", "mujoco-mjx"):
        try:
            h.update(f"{dist}={importlib.metadata.version(dist)};".encode())
        except importlib.metadata.PackageNotFoundError:
            h.update(f"{dist}=none;".encode())
    h.update(sys.version.encode())
    return h.hexdigest()


def _register_outputs(types: Sequence[type]) -> None:
    """Let ``jax.export`` serialize the stage's NamedTuple outputs."""
    for t in types:
        name = f"podilqr_jax.{t.__module__.rsplit('.', 1)[-1]}.{t.__qualname__}"
        try:
            jax.export.register_namedtuple_serialization(t, serialized_name=name)
        except ValueError:  # registered already (a module reloaded)
            pass


def stage(static_argnames: Sequence[str] = (), outputs: Sequence[type] = ()) -> Callable[[Callable], Callable]:
    """Decorator: ``jax.jit(fun, static_argnames=...)``, with the traced program kept
    on disk (module docstring). ``outputs``: the NamedTuple types in its result."""
    static_argnames = tuple(static_argnames)
    _register_outputs(outputs)

    def wrap(fun: Callable) -> Callable:
        jitted = xla_options.jit(fun, static_argnames=static_argnames)
        signature = inspect.signature(fun)
        name = f"{fun.__module__}.{fun.__qualname__}"
        runners: dict[Any, Callable] = {}

        def split(args, kwargs) -> tuple[dict, dict]:
            """The call's arguments by name: (the static ones, in ``static_argnames`` order; the traced ones)."""
            bound = signature.bind(*args, **kwargs)
            bound.apply_defaults()
            static = {k: bound.arguments[k] for k in static_argnames}
            return static, {k: v for k, v in bound.arguments.items() if k not in static_argnames}

        def target(args, kwargs) -> tuple[Callable, tuple, dict]:
            """What runs this call: (a callable, its positional and keyword arguments)."""
            where = folder()
            if where is None or jax.device_count() > 1 or _native_engine(args, kwargs):
                return jitted, args, kwargs
            static, traced = split(args, kwargs)
            static = tuple(static.items())
            leaves, treedef = jax.tree_util.tree_flatten(traced)
            if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
                return jitted.plain, args, kwargs  # inside another trace: its compiler options apply
            avals = tuple(jax.typeof(leaf) for leaf in leaves)
            memo = (static, treedef, avals)
            runner = runners.get(memo)
            if runner is None:
                runner = runners[memo] = _runner(name, fun, jitted, where, static, treedef, avals)
            if runner is jitted:
                return jitted.top(), args, kwargs
            return runner, tuple(leaves), {}

        def alone(args, kwargs):
            fn, a, kw = target(args, kwargs)
            return fn(*a, **kw)

        @functools.wraps(fun)
        def call(*args, **kwargs):
            member = lockstep.current()
            if member is not None:  # one of several solves in lockstep (``lockstep``): batched with theirs
                static, traced = split(args, kwargs)
                if not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(traced)):
                    return member.submit(name, fun, static, traced, lambda: alone(args, kwargs))
            return alone(args, kwargs)

        call.lower = jitted.lower  # the plain jit's (memory analysis, ``bench.line_search_memory``)
        return call

    return wrap


def _native_engine(args, kwargs) -> bool:
    """Whether the call runs MuJoCo's C engine (``sim.native``): its host
    callbacks cannot be exported, and there is little to save (the native
    engine's programs trace and compile in a fraction of a second)."""
    return any(getattr(a, "native", None) is not None for a in (*args, *kwargs.values()))


def _canon(obj) -> str:
    """A text that is equal for equal static values in any process (``repr``
    can hold an address: MJX wraps its static numpy fields in a hashable
    object without a ``repr`` of its own)."""
    if isinstance(obj, np.ndarray):
        data = np.ascontiguousarray(obj)
        return f"array({data.dtype.str},{data.shape},{hashlib.sha256(data.tobytes()).hexdigest()})"
    if isinstance(obj, (list, tuple)):
        return f"{type(obj).__qualname__}(" + ",".join(_canon(o) for o in obj) + ")"
    if isinstance(obj, dict):
        items = sorted(obj.items(), key=lambda kv: repr(kv[0]))
        return "{" + ",".join(f"{_canon(k)}:{_canon(v)}" for k, v in items) + "}"
    if isinstance(obj, type):
        return f"{obj.__module__}.{obj.__qualname__}"
    if dataclasses.is_dataclass(obj):
        fields = ",".join(f"{f.name}={_canon(getattr(obj, f.name))}" for f in dataclasses.fields(obj))
        return f"{type(obj).__qualname__}({fields})"
    if isinstance(getattr(obj, "array", None), np.ndarray):  # MJX's _NumPyArrayHashWrapper
        return _canon(obj.array)
    with np.printoptions(threshold=sys.maxsize):  # numpy fields inside other objects in full, never elided
        text = repr(obj)
    if " at 0x" in text:
        raise TypeError(f"no stable text for a static value of type {type(obj).__qualname__}")
    return text


def _canon_tree(treedef) -> str:
    """``_canon`` of a pytree structure: node types, their static data, children."""
    node = treedef.node_data()
    if node is None:
        return "*"
    kind, aux = node
    return f"{_canon(kind)}[{_canon(aux)}](" + ",".join(_canon_tree(c) for c in treedef.children()) + ")"


def _key(name, static, treedef, avals) -> str:
    h = hashlib.sha256()
    for part in (name, _versions(), _canon(static), _canon_tree(treedef), repr(avals)):
        h.update(part.encode())
        h.update(b"\0")
    h.update(f"x64={jax.config.jax_enable_x64};{jax.default_backend()}".encode())
    return h.hexdigest()


MAGIC = b"podilqr-stage\0"  # a stage file: MAGIC, its key, NUL, the serialized program


def _runner(name, fun, jitted, where, static, treedef, avals) -> Callable:
    """``jax.jit(exported.call)`` for this key, exporting it first where it is new."""
    try:
        key = _key(name, static, treedef, avals)
        path = os.path.join(where, key)
        kwargs = dict(static)

        def flat(*leaves):
            return fun(**kwargs, **jax.tree_util.tree_unflatten(treedef, leaves))

        specs = [jax.ShapeDtypeStruct(a.shape, a.dtype, weak_type=a.weak_type) for a in avals]
        exported = _load(path, key, name, specs) if os.path.isfile(path) else None
        if exported is None:
            exported = jax.export.export(jax.jit(flat))(*specs)
            blob = MAGIC + key.encode() + b"\0" + exported.serialize()
            if not cache.read_only():
                os.makedirs(where, mode=0o700, exist_ok=True)
                write_atomic(path, lambda f: f.write(blob))
            counts["exported"] += 1
        return xla_options.top_level(exported.call)
    except Exception as exc:  # noqa: BLE001 - any refusal means: run it as a plain jit
        fallbacks[name] = f"{type(exc).__name__}: {exc}"[:500]
        return jitted


def _load(path: str, key: str, name: str, specs) -> Optional[jax.export.Exported]:
    """The stage program in ``path`` when it is this key's and takes these
    arguments; else None, after one line saying the entry is dropped."""
    try:
        with open(path, "rb") as f:
            blob = f.read()
        head = MAGIC + key.encode() + b"\0"
        if not blob.startswith(head):
            raise ValueError("it was written for another key (a file moved, swapped or damaged)")
        exported = jax.export.deserialize(bytearray(blob[len(head) :]))
        wanted = tuple((s.shape, s.dtype) for s in specs)
        if tuple((a.shape, a.dtype) for a in exported.in_avals) != wanted:
            raise ValueError("its program takes other arguments")
    except Exception as exc:  # noqa: BLE001 - any fault of the file: trace afresh
        reason = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
        warnings.warn(
            f"podilqr_jax: dropped the cached stage {path!r} ({name}): {reason[:200]}; tracing it afresh.",
            stacklevel=2,
        )
        try:
            os.unlink(path)
        except OSError:
            pass
        return None
    counts["loaded"] += 1
    return exported
