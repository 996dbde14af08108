"""Test-session hygiene.

Every XLA:CPU executable keeps its own memory mappings; a single pytest
process that compiles the whole suite's functions (hundreds of shapes) passes
Linux's default limit of 65530 mappings per process (``vm.max_map_count``) and
aborts inside the compiler. Dropping JAX's caches after each test module keeps
the count to what one module needs (measured: ~10,000 after
tests/test_properties.py alone).

The suite has its own persistent compilation cache (``podilqr_jax.compilation.cache``): a
fresh folder per pytest run (shared by its pytest-xdist workers), set before any
test module imports the package and removed at the end, so a module that compiles what an earlier one already
compiled loads it from disk, and the user's ~/.cache is left alone. Every run
starts cold, so the tests stay correct without a cache. ``PODILQR_CACHE=0``
switches it off.
"""

import os
import shutil
import tempfile

import jax
import pytest

_TEST_CACHE = None  # the folder this process made (and removes at the end)
if os.environ.get("PODILQR_CACHE", "1") != "0":
    # pytest-xdist's workers inherit the folder of the process that started them.
    if not os.environ.get("PODILQR_PYTEST_CACHE"):
        _TEST_CACHE = tempfile.mkdtemp(prefix="podilqr-pytest-jax-cache-")
        os.environ["PODILQR_PYTEST_CACHE"] = _TEST_CACHE
    os.environ["PODILQR_CACHE_DIR"] = os.environ["PODILQR_PYTEST_CACHE"]


def pytest_unconfigure(config):
    if _TEST_CACHE is not None:
        shutil.rmtree(_TEST_CACHE, ignore_errors=True)


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_functions():
    yield
    jax.clear_caches()
