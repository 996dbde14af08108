"""How a study is sized and configured: one way for ``podilqr reproduce``, ``evaluate`` and ``bench``.

A study's settings are a frozen dataclass that derives from :class:`Sized`. It
comes in three sizes: the default (the measurement), ``quick()`` (minutes on a
CPU) and ``tiny()`` (a smoke run of every part; the numbers mean nothing). A
command line offers the sizes as ``--quick`` / ``--tiny``
(:func:`add_size_flags`), builds the settings of the size asked for
(:meth:`Sized.sized`), then changes single fields from its options
(:meth:`Sized.changed`: an option left out, None, keeps the size's value).
Lists of names (``--systems``, ``--tasks``) go through :func:`parse_names` and
the output path through :func:`check_writable` before anything runs, so a bad
input fails in seconds with a :class:`~podilqr_jax.errors.ConfigError` that
says what was expected, what was given and how to fix it.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from typing import Any, Sequence, TypeVar

from ..errors import ConfigError

SIZES = ("default", "quick", "tiny")

S = TypeVar("S", bound="Sized")


class Sized:
    """The sizes and changes every study's settings dataclass shares."""

    @classmethod
    def quick(cls: type[S]) -> S:
        """Minutes on a CPU (a study overrides this)."""
        return cls()

    @classmethod
    def tiny(cls: type[S]) -> S:
        """A smoke run of every part (a study overrides this)."""
        return cls.quick()

    @classmethod
    def sized(cls: type[S], size: str) -> S:
        """The settings of ``size``: one of ``default``, ``quick``, ``tiny``."""
        if size not in SIZES:
            raise ConfigError(f"A study's size is one of {', '.join(SIZES)}; got {size!r}.")
        return cls() if size == "default" else getattr(cls, size)()

    def changed(self: S, **changes: Any) -> S:
        """A copy with the fields of ``changes`` that are not None replaced."""
        return dataclasses.replace(self, **{k: v for k, v in changes.items() if v is not None})

    def as_dict(self) -> dict[str, Any]:
        """The settings as plain JSON values (what opens the study's report)."""
        return dataclasses.asdict(self)


def add_size_flags(parser: argparse.ArgumentParser, *, quick: str, tiny: str) -> None:
    """``--quick`` and ``--tiny``, mutually exclusive, with what each runs as its help."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--quick", action="store_true", help=quick)
    group.add_argument("--tiny", action="store_true", help=tiny)


def size_of(args: argparse.Namespace) -> str:
    """The size the parsed ``--quick`` / ``--tiny`` ask for."""
    return "quick" if args.quick else "tiny" if args.tiny else "default"


def parse_names(text: str, allowed: Sequence[str], flag: str) -> tuple[str, ...]:
    """A comma-separated, non-empty subset of ``allowed`` given to ``flag``."""
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    unknown = [name for name in names if name not in allowed]
    if unknown or not names:
        what = f"unknown: {', '.join(unknown)}" if unknown else "none given"
        raise ConfigError(f"{flag} takes a comma-separated subset of {', '.join(allowed)}; got {text!r} ({what}).")
    return names


def check_writable(path: str) -> None:
    """Make the folder of the output file ``path`` and check that ``path`` can be written,
    before any work whose result would be lost."""
    directory = os.path.dirname(os.path.abspath(path)) or "."
    try:
        os.makedirs(directory, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise ConfigError(
            f"Cannot create the output folder {directory!r}: a file of that name (or of a parent folder's) "
            "is in the way. Choose another --out."
        ) from None
    except OSError as exc:
        raise ConfigError(
            f"Cannot create the output folder {directory!r}: {exc.strerror}. Choose another --out."
        ) from None
    if not os.access(directory, os.W_OK) or (os.path.exists(path) and not os.access(path, os.W_OK)):
        raise ConfigError(f"The output path {path!r} is not writable. Choose another --out.")
    if os.path.isdir(path):
        raise ConfigError(
            f"--out {path!r} is a folder; give a file name such as {os.path.join(path, 'result.json')!r}."
        )
