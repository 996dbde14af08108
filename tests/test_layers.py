"""The package's modules import one another without a circle.

Every import of every module counts, those inside functions too (a lazy
import is still a dependency of the module's code). A package's
``__init__.py`` counts only for what it imports itself: ``from ..sim import
contacts`` is an import of ``sim/contacts.py``. The package root
(``podilqr_jax/__init__.py``) is left out: it is the lazy facade that loads
every public name on first use, above everything, and the one module that
reads from it, ``_runtime.py``, reads the x64 switch it recorded before JAX
was imported.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "podilqr_jax"


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path, modules: set[str]) -> set[str]:
    """The package modules that ``path`` imports."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names if alias.name in modules)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                origin = ".".join(base + ([node.module] if node.module else []))
            else:
                origin = node.module or ""
            for alias in node.names:
                sub = f"{origin}.{alias.name}"
                if sub in modules:
                    found.add(sub)
                elif origin in modules:
                    found.add(origin)
    found.discard(name)
    return found


def _graph() -> dict[str, set[str]]:
    files = [p for p in PACKAGE.rglob("*.py") if p != PACKAGE / "__init__.py"]
    modules = {_module_name(p) for p in files}
    return {_module_name(p): _imports(p, modules) for p in files}


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_checker_sees_a_circle():
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    graph = _graph()
    assert "podilqr_jax.ilqr.stopping" in graph["podilqr_jax.ilqr.driver"]  # imports are read
    assert "podilqr_jax.viz.animate" in graph["podilqr_jax.ilqr.result"]  # those inside functions too


def test_no_module_of_the_package_imports_itself_back():
    assert _circles(_graph()) == []


def test_the_compile_machinery_imports_nothing_of_the_solver():
    """podilqr_jax/compilation/ (how programs compile) sits below the algorithm's
    subpackages: it may import the package's top-level helpers, never them."""
    graph = _graph()
    below = {m for m in graph if m.startswith("podilqr_jax.compilation")}
    assert len(below) >= 5
    for module in below:
        upward = {d for d in graph[module] if not d.startswith("podilqr_jax.compilation")}
        assert upward <= {"podilqr_jax.environment", "podilqr_jax.atomic"}, (module, upward)
