"""Counting XLA compilations and the time spent tracing, lowering and compiling.

JAX reports every backend compilation, jaxpr trace and MLIR lowering through
``jax.monitoring``; one module-level listener forwards them to whichever
:class:`CompileWatch` objects are active. The solver uses it to report compile
time separately from run time and to prove that no iteration after the first
compiles anything.
"""

from __future__ import annotations

import threading

import jax

_BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"
# An executable loaded from the persistent compilation cache (``cache``) is
# reported as a backend compilation too (its duration then is the load), and
# besides by this event, counted in ``cache_loads``.
_CACHE_LOAD = "/jax/compilation_cache/cache_retrieval_time_sec"
_COMPILE_EVENTS = (
    _BACKEND_COMPILE,
    "/jax/core/compile/jaxpr_trace_duration",
    "/jax/core/compile/jaxpr_to_mlir_module_duration",
)

_active: list["CompileWatch"] = []
_lock = threading.Lock()
_installed = False


def _listener(event: str, duration: float, **_: object) -> None:
    if event == _CACHE_LOAD:
        for watch in list(_active):
            watch.cache_loads += 1
        return
    if event not in _COMPILE_EVENTS:
        return
    for watch in list(_active):
        watch.seconds += duration
        if event == _BACKEND_COMPILE:
            watch.compiles += 1


def _install() -> None:
    global _installed
    with _lock:
        if not _installed:
            jax.monitoring.register_event_duration_secs_listener(_listener)
            _installed = True


class CompileWatch:
    """Context manager: ``compiles`` (backend compilations and executables
    loaded from the persistent cache), ``cache_loads`` (the latter alone) and
    ``seconds`` (trace + lower + compile or load) seen while active."""

    def __init__(self) -> None:
        _install()
        self.compiles = 0
        self.cache_loads = 0
        self.seconds = 0.0

    def __enter__(self) -> "CompileWatch":
        _active.append(self)
        return self

    def __exit__(self, *exc: object) -> None:
        _active.remove(self)
