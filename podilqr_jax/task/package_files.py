"""Model files inside installed Python packages: ``pkg://PACKAGE/PATH``.

A task file (or :meth:`Env.from_xml`) can name an MJCF file that ships inside
an installed package instead of a path on disk::

    model = "pkg://dm_control/suite/cartpole.xml"
    model = "pkg://gymnasium/envs/mujoco/assets/inverted_pendulum.xml"

``PACKAGE`` is the top-level import name (``dm_control``, not the pip name
``dm-control``) and ``PATH`` a ``/``-separated path inside the package's folder.
The package is located with ``importlib.util.find_spec``, which reads the
import system's metadata without importing (running) the package, so naming a
heavy package costs nothing. MuJoCo then loads the file in place, and its
``<include>`` files, meshes and textures resolve relative to it as usual.
"""

from __future__ import annotations

import importlib.util
import os

from ..errors import ModelLoadError

PREFIX = "pkg://"

# The pip distribution of import names whose models the gallery uses
# (the import name is not always the pip name).
_PIP_NAMES = {"dm_control": "dm-control", "gymnasium": "gymnasium", "podilqr_jax": "podilqr_jax"}


def is_package_path(path: str) -> bool:
    return isinstance(path, str) and path.startswith(PREFIX)


def resolve_model_path(path: str, base_dir: str = ".") -> str:
    """The file a task names: ``pkg://PACKAGE/PATH`` resolved inside the
    installed package, any other path relative to ``base_dir``."""
    if not is_package_path(path):
        return os.path.join(base_dir, path)
    rest = path[len(PREFIX) :]
    package, _, inner = rest.partition("/")
    parts = [p for p in inner.split("/") if p not in ("", ".")]
    if not package or not package.isidentifier() or not parts or ".." in parts:
        raise ModelLoadError(
            f"{path!r} is not a package file path: write pkg://PACKAGE/PATH with PACKAGE a top-level "
            "import name and PATH a file inside it, e.g. pkg://dm_control/suite/cartpole.xml."
        )
    roots = package_folders(package)
    for root in roots:
        full = os.path.join(root, *parts)
        if os.path.isfile(full):
            return full
    folder = os.path.dirname(os.path.join(roots[0], *parts))
    listing = sorted(f for f in os.listdir(folder) if f.endswith(".xml")) if os.path.isdir(folder) else []
    hint = f" Its .xml files there: {', '.join(listing)}." if listing else ""
    raise ModelLoadError(
        f"The package {package!r} (at {roots[0]}) has no file {'/'.join(parts)!r}, named by {path!r}.{hint} "
        "Check the path, or the package version (files move between releases)."
    )


def package_folders(package: str) -> list[str]:
    """The folder(s) of the installed top-level package ``package``, found
    without importing it."""
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        spec = None
    if spec is None:
        if package in _PIP_NAMES:
            how = f"`pip install {_PIP_NAMES[package]}`"
        else:
            how = f"pip, from the distribution that provides the module (often named {package.replace('_', '-')!r})"
        raise ModelLoadError(
            f"The package {package!r} is not installed, so its files cannot be loaded. Install it with {how}; "
            'this project\'s `pip install -e ".[test]"` installs dm-control and gymnasium.'
        )
    locations = list(spec.submodule_search_locations or [])
    if not locations:
        raise ModelLoadError(f"{package!r} is a module, not a package folder; pkg:// names files inside packages.")
    return locations
