"""JAX's persistent compilation cache, on by default: compile once per machine, not per run.

The package points JAX's persistent compilation cache at a folder in
the user's cache directory, so a second run of the same task (same shapes,
same JAX, same machine) loads the solver's executables from disk instead of
compiling them (benchmarks/journal.md measures what it saves):

- the folder: ``$PODILQR_CACHE_DIR`` when set, else
  ``$XDG_CACHE_HOME/podilqr_jax/jax``, else ``~/.cache/podilqr_jax/jax``;
- ``PODILQR_CACHE=0`` switches it off (nothing is written anywhere);
- a folder the user can read but not write (a shared, prepared cache) is
  read and never written, with one line saying so; ``PODILQR_CACHE=read``
  asks for that of any folder;
- a cache the user configured for JAX (``JAX_COMPILATION_CACHE_DIR`` or
  ``jax.config.update("jax_compilation_cache_dir", ...)`` before importing
  the package, or ``jax_enable_compilation_cache=False``) is left as it is,
  thresholds included.

Nothing is written into the working directory. Every executable is cached,
however short its compile (``jax_persistent_cache_min_compile_time_secs = 0``:
JAX's default of 1 s would keep out most of the solver's stages, which
compile in 0.1-1 s each on a CPU) and however small
(``jax_persistent_cache_min_entry_size_bytes = -1``). The folder grows with
every new shape and is never pruned; delete it to start afresh. JAX treats the
cache as trusted code, so the folder is created readable by its owner only.

:func:`cache_info` says what was set up and what the folder holds.
Importing this module runs :func:`configure`. The package imports it before
any of its own programs trace (``podilqr_jax/_runtime.py``): on ``import
podilqr_jax`` when JAX is loaded already, else on first use of a part that
needs JAX.
"""

from __future__ import annotations

import os
import warnings
from typing import NamedTuple, Optional

import jax

from .. import environment

ENV_DIR = environment.CACHE_DIR
ENV_SWITCH = environment.CACHE
MIN_COMPILE_TIME_S = 0.0
MIN_ENTRY_SIZE_BYTES = -1  # JAX: no size restriction, and no filesystem-dependent override


class CacheInfo(NamedTuple):
    """What :func:`configure` did and what the cache folder holds.

    ``source``: ``"podilqr"`` (the package's folder), ``"jax"`` (a cache the
    user configured for JAX, left alone), ``"off"`` (``PODILQR_CACHE=0``, or
    JAX's cache disabled), ``"unwritable"`` (the folder could not be created or
    read; no cache). ``read_only``: the package's folder is read but not
    written.
    """

    enabled: bool
    directory: Optional[str]
    source: str
    entries: int
    size_bytes: int
    read_only: bool = False


_state = {"directory": None, "source": "off", "read_only": False}


def read_only() -> bool:
    """Whether the package's cache folder is read and never written (read-only, or ``PODILQR_CACHE=read``)."""
    return bool(_state["read_only"])


def mode() -> str:
    """The cache this process's solves get, without looking into its folder:
    ``on``, ``read`` (read, never written), ``jax`` (a cache the user
    configured for JAX) or ``off`` (switched off, or a folder it could not use)."""
    source = _state["source"]
    if source == "podilqr":
        return "read" if _state["read_only"] else "on"
    return "jax" if source == "jax" else "off"


def setting() -> str:
    """``PODILQR_CACHE``: ``on`` (the default), ``off``, or ``read`` (read, never written)."""
    return str(environment.choice(ENV_SWITCH, "on", {"read": "read", "read-only": "read", "ro": "read"}))


def default_cache_dir() -> str:
    """``$PODILQR_CACHE_DIR``, else ``$XDG_CACHE_HOME/podilqr_jax/jax``, else ``~/.cache/podilqr_jax/jax``."""
    explicit = environment.folder(ENV_DIR)
    if explicit:
        return explicit
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(os.path.abspath(base), "podilqr_jax", "jax")


def configure() -> CacheInfo:
    """Set up the persistent compilation cache (called once, on import of the package)."""
    mode = setting()
    if mode == "off":
        _state.update(directory=None, source="off")
    elif not jax.config.jax_enable_compilation_cache:
        _state.update(directory=None, source="off")
    elif jax.config.jax_compilation_cache_dir:
        _state.update(directory=jax.config.jax_compilation_cache_dir, source="jax")
    else:
        path = default_cache_dir()
        asked = mode == "read"
        try:
            if not asked:
                os.makedirs(path, mode=0o700, exist_ok=True)
            writable = not asked and os.access(path, os.W_OK | os.X_OK)
        except OSError:
            writable = False
        readable = os.path.isdir(path) and os.access(path, os.R_OK | os.X_OK)
        if writable or readable:
            jax.config.update("jax_compilation_cache_dir", path)
            jax.config.update("jax_persistent_cache_min_entry_size_bytes", MIN_ENTRY_SIZE_BYTES)
            # A read-only folder is read; nothing compiles for long enough to be written to it.
            jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S if writable else 1e30)
            _state.update(directory=path, source="podilqr", read_only=not writable)
            if not writable and not asked:
                warnings.warn(
                    f"podilqr_jax: the compilation cache folder {path!r} is read-only: reading it, writing nothing.",
                    stacklevel=2,
                )
        elif asked:
            _state.update(directory=None, source="off")  # nothing there to read
        else:
            _state.update(directory=path, source="unwritable")
            warnings.warn(
                f"podilqr_jax: cannot write the compilation cache folder {path!r}, so every run compiles afresh. "
                f"Point {ENV_DIR} at a writable folder, or set {ENV_SWITCH}=0 to silence this.",
                stacklevel=2,
            )
    return cache_info()


def cache_info() -> CacheInfo:
    """The cache as set up on import: whether it is on, its folder, who set it,
    and the number and total size of the entries in the folder now."""
    directory, source = _state["directory"], _state["source"]
    entries = size = 0
    if directory and source in ("podilqr", "jax") and os.path.isdir(directory):
        with os.scandir(directory) as it:
            for entry in it:
                if entry.is_file() and entry.name.endswith("-cache"):
                    entries += 1
                    size += entry.stat().st_size
    return CacheInfo(source in ("podilqr", "jax"), directory, source, entries, size, read_only())


configure()
