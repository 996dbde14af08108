"""Files written whole or not at all, and the temporary files a killed writer leaves.

Every file the package writes for a user (a result JSON, a checkpoint, a traced
stage in the cache) goes through :func:`write_atomic`: the bytes go to a
temporary file beside the target, which is renamed over it, so a reader sees
the old file or the whole new one, never a torn one. A writer killed between
the two (``kill -9``, a power cut) leaves its temporary file behind; the next
write to that folder removes such leftovers (:func:`sweep`).

A temporary file is named ``.tmp-<pid>@<host>~<random><suffix>``, so that a
leftover can be told from a file another process is still writing: one of
this host whose process is gone is removed at once, one of another host (a
shared filesystem) or of an older name only once it is a day old.
"""

from __future__ import annotations

import json
import math
import os
import socket
import tempfile
import time
from typing import IO, Any, Callable

import numpy as np

PREFIX = ".tmp-"
STALE_S = 24 * 3600.0  # age after which a temporary file of another host is a leftover


def _host() -> str:
    return socket.gethostname().replace("@", "_").replace("~", "_") or "localhost"


def write_atomic(
    path: str | os.PathLike,
    write: Callable[[IO[bytes]], None],
    *,
    suffix: str = "",
    mode: int | None = None,
    fsync: bool = False,
) -> str:
    """Write ``path`` through ``write(f)`` on a temporary file renamed over it.

    ``mode``: the file's permissions (default: owner-only, as ``mkstemp``
    makes it); ``fsync``: flush it to disk before the rename. Leftover
    temporary files in the folder are removed first (:func:`sweep`).
    """
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    sweep(directory)
    fd, tmp = tempfile.mkstemp(prefix=f"{PREFIX}{os.getpid()}@{_host()}~", suffix=suffix, dir=directory)
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
            if fsync:
                f.flush()
                os.fsync(f.fileno())
        if mode is not None:
            os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def sweep(directory: str | os.PathLike) -> list[str]:
    """Remove the leftover temporary files of killed writers in ``directory``;
    returns their names. Files another live process may be writing are kept."""
    removed = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    now, host, me = time.time(), _host(), os.getpid()
    for entry in entries:
        if not entry.name.startswith(PREFIX) or not entry.is_file(follow_symlinks=False):
            continue
        if _left_over(entry, now, host, me):
            try:
                os.unlink(entry.path)
                removed.append(entry.name)
            except OSError:
                pass  # removed by another sweep, or not ours to remove
    return removed


def _left_over(entry: os.DirEntry, now: float, host: str, me: int) -> bool:
    pid_text, _, rest = entry.name[len(PREFIX) :].partition("@")
    writer_host, tilde, _ = rest.partition("~")
    if tilde and writer_host == host and pid_text.isdigit():
        pid = int(pid_text)
        return pid != me and not _alive(pid)
    try:
        return now - entry.stat(follow_symlinks=False).st_mtime > STALE_S
    except OSError:
        return False


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # someone else's live process
    return True


def write_json_atomic(path: str | os.PathLike, obj: Any) -> None:
    """Write ``obj`` as JSON to ``path`` whole or not at all (``atomic.write_atomic``),
    with the permissions a plain ``open(path, "w")`` would give."""
    text = json.dumps(_jsonable(obj), indent=1).encode()
    write_atomic(path, lambda f: f.write(text), suffix=".json", mode=0o666 & ~_umask())


def _umask() -> int:
    """The process's umask, read without changing it where Linux reports it
    (setting it, even for a moment, would race the threads that create files)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    umask = os.umask(0o022)
    os.umask(umask)
    return umask


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, np.generic):
        return _jsonable(obj.item())
    return obj
