"""The package layout: imports point one way down the pipeline, no cycles, no module over 500 lines.

The import graph is read from the source with :mod:`ast` (every ``import``/``from ... import`` of a
bayesdamper module, including those inside functions), so the check does not depend on what happens to
be imported at run time.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "bayesdamper"
#: The pipeline, lowest layer first: a module may import its own layer and the layers before it.
LAYERS = ("core", "physics", "io", "inference", "diagnosis", "report", "run", "cli")
#: Top-level modules that are not a layer: the version and the lazy public API (``__init__``, which imports
#: only core and the version eagerly) and ``__main__`` (calls the CLI).
FREE = {"bayesdamper", "bayesdamper._version", "bayesdamper.__main__"}
MAX_LINES = 500


def module_name(path: Path, package: Path = PACKAGE) -> str:
    parts = list(path.relative_to(package.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """``{module: {bayesdamper modules it imports}}`` for every module under ``package``."""
    modules = {module_name(p, package): p for p in package.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        deps: set[str] = set()
        is_pkg = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = name.split(".") if is_pkg else name.split(".")[:-1]
                    base = base[: len(base) - node.level + 1]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                # "from pkg import module" imports the module; "from module import name" the module
                targets = [f"{mod}.{a.name}" if f"{mod}.{a.name}" in modules else mod for a in node.names]
            else:
                continue
            deps |= {t for t in targets if t in modules and t != name}
        graph[name] = deps
    return graph


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's algorithm: the strongly connected components with more than one node (= import cycles)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def layer(module: str) -> int | None:
    if module in FREE:
        return None
    return LAYERS.index(module.split(".")[1])


def test_cycle_finder_finds_a_planted_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert strongly_connected(graph) == [["a", "b", "c"]]
    assert strongly_connected({"a": {"b"}, "b": set()}) == []


def test_graph_reader_sees_relative_and_function_level_imports(tmp_path):
    pkg = tmp_path / "bayesdamper"
    (pkg / "core").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "core" / "__init__.py").write_text("")
    (pkg / "core" / "a.py").write_text("def f():\n    from . import b\n")
    (pkg / "core" / "b.py").write_text("from bayesdamper.core.a import f\n")
    graph = import_graph(pkg)
    assert graph["bayesdamper.core.a"] == {"bayesdamper.core.b"}
    assert graph["bayesdamper.core.b"] == {"bayesdamper.core.a"}
    assert strongly_connected(graph) == [["bayesdamper.core.a", "bayesdamper.core.b"]]


def test_no_import_cycle():
    assert strongly_connected(import_graph()) == []


def test_imports_point_down_the_pipeline():
    graph = import_graph()
    up = [(m, d) for m, deps in graph.items() for d in deps
          if layer(m) is not None and layer(d) is not None and layer(d) > layer(m)]
    assert up == [], f"imports of a higher layer: {up}"
    # the lazy public API may import only core eagerly (the rest through __getattr__)
    eager = {d for d in graph["bayesdamper"] if d not in FREE}
    assert all(d.startswith("bayesdamper.core.") for d in eager), eager


def test_every_layer_is_a_documented_subpackage():
    for name in LAYERS[:-1]:
        init = PACKAGE / name / "__init__.py"
        doc = ast.get_docstring(ast.parse(init.read_text()))
        assert doc and "import" in doc, f"{init} must say what it owns and what it may import"


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_module_length(path):
    n = len(path.read_text().splitlines())
    assert n <= MAX_LINES, f"{path.name} has {n} lines"


def test_public_api_resolves():
    import bayesdamper

    for name in bayesdamper.__all__:
        assert getattr(bayesdamper, name) is not None
    with pytest.raises(AttributeError):
        bayesdamper.no_such_name  # noqa: B018
