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

The suite has its own persistent compilation cache (``podilqr_jax.compilation.cache``),
set before any test module imports the package and shared by the pytest-xdist
workers: ``.test-cache/`` in the checkout (``TEST_CACHE``; ignored by git), kept
between runs, so a module loads from disk what an earlier module or an earlier
run already compiled, and the user's ~/.cache is left alone. Compiling is most of
the suite's time: on 2 CPU cores a first run takes 481-590 s (clean clones, as CI
runs it, and this checkout with a new folder) and the next one, with the cache kept,
209-245 s (benchmarks/README.md, "The test suite's time"). A run gives the same results cold or warm: the cache
keys on everything a compiled program depends on (``compilation/cache.py``,
``compilation/stages.py``), and CI's clean clone always starts cold. The folder is emptied when it grows past
``TEST_CACHE_LIMIT_BYTES``; deleting it gives a cold run; ``PODILQR_CACHE=0``
switches the cache off; ``PODILQR_PYTEST_CACHE=DIR`` puts it elsewhere.
"""

import os
import shutil
import signal
import tempfile

import jax
import pytest

TEST_CACHE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), ".test-cache")
TEST_CACHE_LIMIT_BYTES = 2 * 2**30  # a full run writes ~65 MB; each edit of the package adds its new programs
_TEMPORARY = None  # a folder this process made because the checkout is not writable (removed at the end)


def _folder_bytes(path: str) -> int:
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, names in os.walk(path) for f in names)


if os.environ.get("PODILQR_CACHE", "1") != "0":
    # pytest-xdist's workers inherit the folder of the process that started them.
    if not os.environ.get("PODILQR_PYTEST_CACHE"):
        try:
            if os.path.isdir(TEST_CACHE) and _folder_bytes(TEST_CACHE) > TEST_CACHE_LIMIT_BYTES:
                shutil.rmtree(TEST_CACHE)
            os.makedirs(TEST_CACHE, exist_ok=True)
            if not os.access(TEST_CACHE, os.W_OK | os.X_OK):
                raise PermissionError(TEST_CACHE)
            folder = TEST_CACHE
        except OSError:  # a read-only checkout: a fresh folder for this run
            folder = _TEMPORARY = tempfile.mkdtemp(prefix="podilqr-pytest-jax-cache-")
        os.environ["PODILQR_PYTEST_CACHE"] = folder
    os.environ["PODILQR_CACHE_DIR"] = os.environ["PODILQR_PYTEST_CACHE"]


def pytest_collection_modifyitems(config, items):
    """The long end-to-end runs (marked ``slow``) first, the rest in file order:
    pytest-xdist's worksteal hands each worker a contiguous share and an idle
    worker steals from the end of another's, so the suite ends on short tests
    instead of one worker running a long one while the other waits."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


def pytest_unconfigure(config):
    if _TEMPORARY is not None:
        shutil.rmtree(_TEMPORARY, ignore_errors=True)


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


@pytest.fixture
def python_sigint():
    """Python's own Ctrl-C handler while the test runs, which the solver defers
    (``ilqr.interrupts``): a runner in the background, as CI is, ignores SIGINT."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)
