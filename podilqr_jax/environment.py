"""The package's environment variables, read in one place.

docs/environment.md lists every one: what it does, its values and default,
when it is read and whether it changes results. Every reader of a
``PODILQR_*`` variable asks here, by one of three rules:

- :func:`switch`: on (``1``, ``on``, ``true``, ``yes``) or off (``0``,
  ``off``, ``false``, ``no``), case and surrounding spaces ignored; unset or
  empty: the default.
- :func:`choice`: a switch or a few named values of its own (``auto``,
  ``read``).
- :func:`folder`: a path, ``~`` expanded.

A value outside its rule keeps the default and warns once, naming the
variable and the values it takes. Nothing here imports JAX, so the package
root and the command line's ``--help`` read it at no cost.
"""

from __future__ import annotations

import os
import warnings
from typing import Mapping, Optional

X64 = "PODILQR_X64"
VERBOSE = "PODILQR_VERBOSE"
CACHE = "PODILQR_CACHE"
CACHE_DIR = "PODILQR_CACHE_DIR"
XLA_DEFAULTS = "PODILQR_XLA_DEFAULTS"

ON = ("1", "on", "true", "yes")
OFF = ("0", "off", "false", "no")

_warned: set[tuple[str, str]] = set()


def _text(name: str) -> str:
    return os.environ.get(name, "").strip().lower()


def _refuse(name: str, takes: str, default: str) -> None:
    value = os.environ.get(name, "")
    if (name, value) not in _warned:
        _warned.add((name, value))
        warnings.warn(f"{name}={value!r} is not one of {takes}; using {default}", stacklevel=3)


def switch(name: str, default: bool) -> bool:
    """The switch ``name``: True for on, False for off, ``default`` where unset."""
    text = _text(name)
    if text in ON:
        return True
    if text in OFF:
        return False
    if text:
        _refuse(name, "1/on, 0/off", "on" if default else "off")
    return default


def choice(name: str, default: str, named: Mapping[str, str] = {}) -> str:
    """The setting ``name``: ``"on"`` or ``"off"`` (a switch) or the value that
    ``named`` maps its text to (aliases allowed); ``default`` where unset."""
    text = _text(name)
    if not text:
        return default
    if text in ON:
        return "on"
    if text in OFF:
        return "off"
    if text in named:
        return named[text]
    takes = ", ".join(["1/on", "0/off", *sorted(set(named))])
    _refuse(name, takes, default)
    return default


def folder(name: str) -> Optional[str]:
    """The folder ``name`` names (absolute, ``~`` expanded), or None where unset or empty."""
    text = os.environ.get(name, "").strip()
    return os.path.abspath(os.path.expanduser(text)) if text else None
