"""The XLA options the package compiles its MJX programs with: a cheaper cold compile.

On a CPU most of a first run's wait is XLA compiling the rollout programs
(``mjx.step`` under ``vmap``, ``scan`` and, for the model-based reference, a
JVP). XLA's CPU backend emits its fusions through MLIR ("fusion emitters")
by default; its older LLVM IR emitters compile the same HLO faster and, for
these programs, run them no slower:

- ``xla_cpu_use_fusion_emitters = False``: on 2 CPU cores the cold compile of
  ``cartpole-partial`` drops from 9.0 to 6.3 s (POD-iLQR) and from 11.3 to
  8.3 s (model-based), and a noiseless 1024-rollout cart-pole iteration runs
  in 235 instead of 282 ms, with the same costs to every printed digit
  (benchmarks/journal.md gives the commands and the table for every task).

The options go into every top-level jitted program of the package that runs
MJX (its stages, ``rollout_batch``, ``observations_of``, the episode
programs) through :func:`jit`, never into a process-wide ``XLA_FLAGS``: the user's own
JAX programs are compiled as they would be without the package. They are CPU
options; other backends ignore them. The persistent compilation cache keys
on them, so executables compiled with and without them never mix.

``PODILQR_XLA_DEFAULTS=1`` (read at import) compiles with XLA's own defaults
instead (to compare, or should a future XLA make its new emitters the faster).
"""

from __future__ import annotations

import functools
from typing import Any, Callable

import jax

from .. import environment

ENV_DEFAULTS = environment.XLA_DEFAULTS
COMPILER_OPTIONS: dict[str, Any] = {"xla_cpu_use_fusion_emitters": False}


@functools.lru_cache(maxsize=1)
def options() -> dict[str, Any]:
    """The compiler options for ``jax.jit(..., compiler_options=...)``: empty
    when ``PODILQR_XLA_DEFAULTS=1``, or when this JAX's XLA does not know them
    (tried once, on a trivial program, at the first compile that asks)."""
    if environment.switch(ENV_DEFAULTS, False):
        return {}
    try:
        jax.jit(lambda: 0, compiler_options=COMPILER_OPTIONS).lower().compile()
    except Exception:  # noqa: BLE001 - an XLA without these options: its defaults
        return {}
    return dict(COMPILER_OPTIONS)


def top_level(fun: Callable, **kwargs) -> Callable:
    """``jax.jit(fun, **kwargs)`` with :func:`options`, for calls known to come
    from outside any trace (``stages`` knows; elsewhere use :func:`jit`)."""
    return jax.jit(fun, compiler_options=options() or None, **kwargs)


def jit(fun: Callable | None = None, **kwargs) -> Callable:
    """``jax.jit`` with :func:`options`; usable as ``@jit`` or ``@jit(static_argnames=...)``.

    JAX takes compiler options on top-level calls only, so a call from inside
    another trace (``jit``, ``vmap``, ``grad``) runs the plain ``jax.jit`` of
    ``fun`` (``.plain``): the enclosing program's options apply to it. The
    options are read at the first top-level call (``.top()``), not at import
    (nothing touches a device before ``jax.distributed.initialize``)."""
    if fun is None:
        return functools.partial(jit, **kwargs)
    plain = jax.jit(fun, **kwargs)

    @functools.lru_cache(maxsize=1)
    def top() -> Callable:
        return top_level(fun, **kwargs) if options() else plain

    @functools.wraps(fun)
    def call(*args, **kw):
        nested = any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves((args, kw)))
        return (plain if nested else top())(*args, **kw)

    call.plain, call.top = plain, top
    call.lower = lambda *args, **kw: top().lower(*args, **kw)
    return call
