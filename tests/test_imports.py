"""The edges of the house: no import circles, nothing imports the package root, and the
registries, the command line and `import cooploc` load no heavy dependency.

Import times themselves are measured (``python -X importtime``), not asserted: a timed
assertion fails on a loaded machine. What makes them short is checked here instead —
which modules get imported.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
#: imported only where used: each costs 0.1–1 s at start-up
HEAVY = ("numba", "scipy", "gtsam", "matplotlib", "pyarrow", "stonesoup", "dask", "sumolib", "traci",
         "plotly")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _module_level_imports(path: Path, modules: set[str]) -> set[str]:
    """cooploc modules imported at module level (TYPE_CHECKING blocks included: an import
    for annotations is still a dependency), not those inside functions. `from p import m`
    of a submodule m counts as importing p.m, not the package p."""
    package = _module_name(path) if path.name == "__init__.py" else _module_name(path).rpartition(".")[0]
    found: set[str] = set()

    def visit(nodes: list[ast.stmt]) -> None:
        for node in nodes:
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parent = package.split(".")
                    parent = parent[: len(parent) - (node.level - 1)]
                    base = ".".join([*parent, base] if base else parent)
                names = [f"{base}.{a.name}" for a in node.names]
                found.update(n for n in names if n in modules)
                if any(n not in modules for n in names):
                    found.add(base)
            elif isinstance(node, ast.If | ast.Try):
                visit(node.body)
                visit(getattr(node, "orelse", []))
                for handler in getattr(node, "handlers", []):
                    visit(handler.body)

    visit(ast.parse(path.read_text()).body)
    return found


def _graph() -> dict[str, set[str]]:
    modules = {_module_name(p): p for p in SRC.rglob("*.py")}
    return {name: {m for m in _module_level_imports(path, set(modules)) if m in modules and m != name}
            for name, path in modules.items()}


def test_no_import_circles() -> None:
    graph = _graph()
    # Tarjan's strongly connected components: a component of two or more is a circle
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles: list[list[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                connect(w)
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
                circles.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in sorted(graph):
        if v not in index:
            connect(v)
    assert not circles, f"import circles: {circles}"


def test_no_module_imports_the_package_root() -> None:
    offenders = sorted(name for name, deps in _graph().items() if "cooploc" in deps and name != "cooploc")
    assert not offenders, f"modules importing the package root `cooploc`: {offenders}"


@pytest.mark.parametrize("code", [
    "import cooploc",
    "import cooploc.cli",
    "import cooploc.registry as r; r.estimators(); r.presets()",
    "from cooploc.reproduce import experiments; experiments()",
])
def test_start_up_loads_no_heavy_dependency(code: str) -> None:
    probe = f"{code}; import sys; print(sorted(m for m in {HEAVY!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", f"{code!r} imports {out.stdout.strip()}"


def test_import_cooploc_loads_no_numpy() -> None:
    """`cooploc --help` needs only the package root and the CLI module."""
    probe = "import cooploc.cli, sys; print('numpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
