"""docs/api/, the public-API reference, is what pdoc writes from ``podilqr_jax.__all__`` (docs/build_api.py).

A change of a public signature, docstring or of ``__all__`` fails here until the
reference is rebuilt with ``python docs/build_api.py``.
"""

from __future__ import annotations

import importlib.util
import shutil
import sys
from pathlib import Path

import pytest

pytest.importorskip("pdoc", reason="the `test` extra installs pdoc")

ROOT = Path(__file__).resolve().parent.parent
BUILDER = ROOT / "docs" / "build_api.py"
API_DIR = ROOT / "docs" / "api"
PAGE = "podilqr_jax.html"


@pytest.fixture(scope="module")
def build_api():
    name = "podilqr_docs_build_api"
    spec = importlib.util.spec_from_file_location(name, BUILDER)
    assert spec is not None and spec.loader is not None, f"cannot load {BUILDER}"
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(name, None)


def test_api_doc_is_up_to_date(build_api):
    problem = build_api.check(API_DIR)
    assert problem is None, f"docs/api/ is stale: run `python docs/build_api.py` and commit the result.\n{problem}"


def test_the_page_documents_every_public_name_and_nothing_of_this_machine(build_api, tmp_path):
    import podilqr_jax

    build_api.build(tmp_path)
    page = (tmp_path / PAGE).read_text(encoding="utf-8")
    for name in podilqr_jax.__all__:
        assert f'<section id="{name}">' in page, f"{name} is public but not on the page"
    assert " at 0x" not in page and str(ROOT) not in page
    assert "ForwardRef" not in page  # the NamedTuples' annotations resolved


def test_check_reports_a_stale_or_missing_page(build_api, tmp_path, capsys):
    stale = tmp_path / "api"
    shutil.copytree(API_DIR, stale)
    page = stale / PAGE
    page.write_text(page.read_text(encoding="utf-8").replace("</body>", "edited by hand</body>"), encoding="utf-8")
    problem = build_api.check(stale)
    assert problem is not None and PAGE in problem and "python docs/build_api.py" in problem

    assert build_api.main(["--check", "--output", str(stale)]) == 1
    assert "out of date" in capsys.readouterr().err

    page.unlink()
    assert "pdoc writes" in build_api.check(stale)
    assert build_api.check(tmp_path / "missing") is not None
