"""Test-session hygiene.

Every XLA:CPU executable keeps its own memory mappings; a single pytest
process that compiles the whole suite's functions (hundreds of shapes) passes
Linux's default limit of 65530 mappings per process (``vm.max_map_count``) and
aborts inside the compiler. Dropping JAX's caches after each test module keeps
the count to what one module needs (measured: ~10,000 after
tests/test_properties.py alone).
"""

import jax
import pytest


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_functions():
    yield
    jax.clear_caches()
