"""Test-session hygiene.

Every XLA:CPU executable keeps its own memory mappings; a single pytest
process that compiles the whole suite's functions (hundreds of shapes) passes
Linux's default limit of 65530 mappings per process (``vm.max_map_count``) and
aborts inside the compiler. JAX's in-memory caches are dropped after a test
module once the process holds more than ``MAPPINGS_BEFORE_CLEARING`` (30,000)
mappings, which leaves room for the largest module (measured: ~10,000 after
tests/test_properties.py alone); below it the next modules reuse the
programs already traced and compiled. (Dropping them after every module cost
the suite 7% more CPU time: 1,293 against 1,201 CPU-s.)

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


def pytest_collection_modifyitems(config, items):
    """The long end-to-end runs (marked ``slow``) first, the rest in file order:
    pytest-xdist's worksteal hands each worker a contiguous share and an idle
    worker steals from the end of another's, so the suite ends on short tests
    instead of one worker running a long one while the other waits."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


def pytest_unconfigure(config):
    if _TEST_CACHE is not None:
        shutil.rmtree(_TEST_CACHE, ignore_errors=True)


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_functions():
    yield
    if _mappings() > MAPPINGS_BEFORE_CLEARING:
        jax.clear_caches()


MAPPINGS_BEFORE_CLEARING = 30_000


def _mappings() -> int:
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:  # not Linux: clear after every module
        return MAPPINGS_BEFORE_CLEARING + 1
