"""What the package sets up in JAX before anything of it traces or compiles.

Imported by every subpackage that uses JAX (``podilqr_jax/__init__.py`` itself
imports nothing heavy, so that ``podilqr --help`` answers at once):

- float64 (``jax_enable_x64``), unless ``PODILQR_X64=0``: the least-squares
  fit differences rollouts that deviate from the nominal by ~sigma, and in
  float32 a perturbation of 1e-4 on an angle of ~3 keeps about three
  significant digits of dz, too few for the fit (docs/algorithm.md). The
  package's ``__init__`` asks for it through ``JAX_ENABLE_X64`` already, so
  that JAX imported by the user after ``import podilqr_jax`` starts in
  float64; here it is set in JAX's config and the variable put back as it was.
- JAX's persistent compilation cache (``compilation/cache.py``);
- MJX imported with its note about the optional ``warp`` backend kept off
  stdout (the CLI's output).
"""

import contextlib
import io
import os

import jax

from . import _X64_ASKED, _X64_VARIABLE_BEFORE

if _X64_ASKED:
    jax.config.update("jax_enable_x64", True)
if _X64_VARIABLE_BEFORE is None:
    os.environ.pop("JAX_ENABLE_X64", None)
else:
    os.environ["JAX_ENABLE_X64"] = _X64_VARIABLE_BEFORE

from .compilation import cache as _cache  # noqa: E402,F401  (configures the cache on import)

with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx as _mjx  # noqa: E402,F401
