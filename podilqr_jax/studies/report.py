"""One way every study reports: ``podilqr evaluate``, ``podilqr reproduce`` and ``podilqr bench``.

Each study's JSON opens with the same :func:`header`: its settings (a frozen
dataclass, validated in Python before anything runs) and the machine the
numbers were measured on (``machine.describe``). :func:`write` puts the JSON
(written atomically: a run cut short never leaves half a file), the Markdown
table and the figures into one folder.
"""

from __future__ import annotations

import os
from typing import Any, Callable, Mapping, Optional

from ..atomic import write_json_atomic
from .machine import describe
from .settings import Sized


def header(settings: Sized) -> dict[str, Any]:
    """What opens every study's JSON: ``settings`` (its ``as_dict``) and ``machine``."""
    return {"settings": settings.as_dict(), "machine": describe()}


def write(
    out: str | os.PathLike,
    name: str,
    report: Any,
    *,
    table: Optional[str] = None,
    figures: Mapping[str, Callable[[str], Any]] = {},
) -> list[str]:
    """Write ``out``/``name``.json, ``out``/table.md (when ``table`` is given)
    and each figure (``figures`` maps a file name to a function that draws it
    to a path). Returns the paths written."""
    out = os.fspath(out)
    os.makedirs(out, exist_ok=True)
    paths = [os.path.join(out, f"{name}.json")]
    write_json_atomic(paths[0], report)
    for filename, draw in figures.items():
        paths.append(os.path.join(out, filename))
        draw(paths[-1])
    if table is not None:
        paths.append(os.path.join(out, "table.md"))
        with open(paths[-1], "w") as f:
            f.write(table + "\n")
    return paths
