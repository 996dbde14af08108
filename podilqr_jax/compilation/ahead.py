"""Compile ahead: a solve's stages compiled side by side before its first iteration.

A cold solve compiles its stages one after the other as the first iteration
reaches them, and on a CPU XLA compiles each on one core: on 2 cores the
second core idles through most of the compile (benchmarks/journal.md). Before
the first iteration the driver therefore runs the iteration *dry*
(``driver.compile_ahead``): inside :func:`dry_run` every call of a stage
(``stages.stage``) is traced and lowered at once, handed to a pool of
threads to compile, and answered with zeros of its output's shapes, so the
host code after it runs on and reaches the next stage. XLA compiles outside
Python's lock, so the pool's compiles run side by side with each other and
with the tracing of the stages still to come. The dry run returns when
every compile has finished; the iteration that follows calls the same
stages with arguments of the same shapes, placement and types, and JAX finds
the executables compiled.

Nothing the dry run computes is kept: the zeros only carry shapes to the
next stage, and the driver's state is untouched. A stage the dry run did
not reach, or reached with other arguments, compiles when it is called, as
without it. The dry run is skipped where it cannot help or might not match:
one core (``os.sched_getaffinity``), more than one device or process, or
``PODILQR_COMPILE_AHEAD=0`` (read per solve, see :func:`workers`). Any error
inside it abandons it (the solve then compiles as it goes; the reason is in
``last_error``).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import os
import threading
from typing import Any, Callable, Iterator, Optional

import jax
import numpy as np

from .. import environment

ENV_SWITCH = environment.COMPILE_AHEAD
MAX_WORKERS = 4
last_error: Optional[str] = None  # why the last dry run was abandoned (None: it was not)

_local = threading.local()


def workers() -> int:
    """Threads to compile with, or 0 where the dry run is off (module docstring).

    ``PODILQR_COMPILE_AHEAD``: unset, ``1`` or ``on``: the cores this process
    may run on, at most ``MAX_WORKERS``, and off on one core; ``0`` or
    ``off``: off; an integer N >= 2: N threads, however many cores."""
    setting = environment.choice(ENV_SWITCH, "on", counts=True)
    if setting == "off" or jax.process_count() > 1 or jax.device_count() > 1:
        return 0
    if isinstance(setting, int):
        return setting
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cores = os.cpu_count() or 1
    return min(cores, MAX_WORKERS) if cores >= 2 else 0


class DryRun:
    """The stages lowered so far and their compiles in flight."""

    def __init__(self, pool: concurrent.futures.ThreadPoolExecutor, place: Callable[[np.ndarray], Any]) -> None:
        self.pool = pool
        self.place = place
        self.compiles: list[tuple[str, concurrent.futures.Future]] = []  # (stage name, its compile)
        self.outputs: dict = {}  # a call's ``_memo`` -> its output's shapes, for a program met again

    def submit(self, name: str, target: Callable, args: tuple, kwargs: dict):
        """Lower ``target(*args, **kwargs)`` (the stage ``name``) now, compile it
        in the pool, and return zeros shaped like its output (placed as a
        stage's outputs are)."""
        memo = _memo(name, args, kwargs)
        if memo is not None and memo in self.outputs:
            out_info = self.outputs[memo]  # the same program again: compiling once
        else:
            lowered = target.lower(*args, **kwargs)
            self.compiles.append((name, self.pool.submit(lowered.compile)))
            out_info = lowered.out_info
            if memo is not None:
                self.outputs[memo] = out_info
        return jax.tree_util.tree_map(lambda s: self.place(np.zeros(s.shape, s.dtype)), out_info)


def _memo(name: str, args: tuple, kwargs: dict):
    """A key equal for two calls of stage ``name`` that run the same program
    (the same static values, array shapes, dtypes and placement), or None
    where a value cannot be hashed."""
    leaves, treedef = jax.tree_util.tree_flatten((args, kwargs))
    parts = []
    for leaf in leaves:
        if isinstance(leaf, jax.Array):
            parts.append((leaf.shape, leaf.dtype, leaf.weak_type, leaf.sharding))
        elif isinstance(leaf, np.ndarray):
            parts.append(("np", leaf.shape, leaf.dtype))
        else:
            parts.append(leaf)
    key = (name, treedef, tuple(parts))
    try:
        hash(key)
    except TypeError:
        return None
    return key


def current() -> Optional[DryRun]:
    """The dry run this thread is inside, or None."""
    return getattr(_local, "run", None)


@contextlib.contextmanager
def dry_run(n_workers: int, place: Callable[[np.ndarray], Any]) -> Iterator[DryRun]:
    """Inside: every stage call is lowered, compiled in a pool of ``n_workers``
    threads and answered with zeros (``place`` puts them where stage outputs
    live). On leaving, waits for every compile; an error inside is swallowed
    (``last_error``), the compiles already submitted still finish."""
    global last_error
    last_error = None
    with concurrent.futures.ThreadPoolExecutor(max_workers=n_workers, thread_name_prefix="podilqr-compile") as pool:
        run = DryRun(pool, place)
        _local.run = run
        try:
            yield run
        except Exception as exc:  # noqa: BLE001 - the solve compiles as it goes instead
            last_error = f"{type(exc).__name__}: {exc}"[:500]
        finally:
            _local.run = None
            for name, future in run.compiles:
                try:
                    future.result()
                except Exception as exc:  # noqa: BLE001 - the stage compiles again when it is called
                    last_error = f"{name}: {type(exc).__name__}: {exc}"[:500]
