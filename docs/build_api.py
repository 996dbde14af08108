"""Write docs/api/, the reference of podilqr_jax's public API, with pdoc (https://pdoc.dev).

pdoc documents ``podilqr_jax.__all__``: every name's signature, docstring,
fields, methods and properties, as one HTML page (``docs/api/podilqr_jax.html``;
open it in a browser, or browse the live package with ``pdoc podilqr_jax``).

Usage (from the repository root)::

    python docs/build_api.py           # (re)write docs/api/
    python docs/build_api.py --check   # exit 1 when docs/api/ is not what pdoc writes now

tests/test_api_doc.py runs the check, so a change of the public API that is not
followed by a rebuild fails the test suite. The page is the same on every
machine for one pdoc version, which is why the ``test`` extra pins pdoc.

One adjustment before pdoc runs: the ``__new__`` that ``typing.NamedTuple``
generates belongs to no module, so pdoc cannot resolve its string annotations
(``"jnp.ndarray"``, under ``from __future__ import annotations``) and would print
them as ``ForwardRef(...)``; each public NamedTuple's ``__new__`` is given its
class's module while pdoc runs.
"""

from __future__ import annotations

import argparse
import filecmp
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUTPUT = ROOT / "docs" / "api"
COMMAND = "python docs/build_api.py"


def build(output: Path) -> None:
    """pdoc's page of the public API, written into ``output``."""
    import pdoc
    import pdoc.render

    import podilqr_jax

    named_tuples = [getattr(podilqr_jax, name) for name in podilqr_jax.__all__]
    named_tuples = [c for c in named_tuples if isinstance(c, type) and issubclass(c, tuple) and hasattr(c, "_fields")]
    before = [c.__new__.__module__ for c in named_tuples]
    try:
        for cls in named_tuples:
            cls.__new__.__module__ = cls.__module__
        pdoc.render.configure(docformat="google", show_source=False, search=False)
        pdoc.pdoc("podilqr_jax", output_directory=output)
    finally:  # the classes as they were, for whatever else runs in this process (the test suite)
        for cls, module in zip(named_tuples, before, strict=True):
            cls.__new__.__module__ = module


def check(expected: Path = OUTPUT) -> str | None:
    """None when ``expected`` holds what :func:`build` writes now, else what differs and how to fix it."""
    with tempfile.TemporaryDirectory() as tmp:
        build(Path(tmp))
        fresh = sorted(p.relative_to(tmp) for p in Path(tmp).rglob("*") if p.is_file())
        kept = sorted(p.relative_to(expected) for p in expected.rglob("*") if p.is_file()) if expected.is_dir() else []
        if fresh != kept:
            return f"{expected} holds {[str(p) for p in kept]}, pdoc writes {[str(p) for p in fresh]}: run `{COMMAND}`"
        stale = [str(p) for p in fresh if not filecmp.cmp(Path(tmp) / p, expected / p, shallow=False)]
    return f"{', '.join(stale)} in {expected} out of date: run `{COMMAND}` and commit the result" if stale else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 when docs/api/ is out of date; write nothing")
    parser.add_argument("--output", type=Path, default=OUTPUT, help="the folder (default: docs/api/)")
    args = parser.parse_args(argv)
    if args.check:
        problem = check(args.output)
        if problem:
            print(problem, file=sys.stderr)
            return 1
        return 0
    build(args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main())
