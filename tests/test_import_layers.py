"""The package's import graph points down: no cycle among modules or among subpackages, and no subpackage imports
one above it in LAYERS. Every `import` / `from ... import` in src/neumat counts, including those inside functions
(lazy imports), so a cycle cannot hide in a function body."""
from __future__ import annotations

import ast
import collections
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "neumat"

#: subpackages, bottom to top: a module may import only from its own subpackage or from one listed before it
LAYERS = ["core", "color", "warp", "nn", "io", "metrics", "reflectance", "render", "models", "fit", "export",
          "methods", "catalog", "testing", "viz", "integrations", "cli"]



def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(SRC.rglob("*.py"))}


def _edges(modules: dict[str, Path]) -> dict[str, set[str]]:
    """module -> the neumat modules it imports (a name imported from a package counts as that submodule when
    one exists, else as the package)."""
    edges: dict[str, set[str]] = collections.defaultdict(set)
    for name, path in modules.items():
        base = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    target = ".".join(base[:len(base) - (node.level - 1)] + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if target.split(".")[0] != "neumat":
                    continue
                for alias in node.names:
                    sub = f"{target}.{alias.name}"
                    edges[name].add(sub if sub in modules else target)
            elif isinstance(node, ast.Import):
                edges[name].update(a.name for a in node.names if a.name.split(".")[0] == "neumat")
    return edges


def _subpackage(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def _cycles(nodes: set[str], edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in sorted(nodes):
        if root in index:
            continue
        work = [(root, iter(sorted(edges.get(root, set()) & nodes)))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges.get(w, set()) & nodes))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
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
    return out


def _subpackage_edges(edges: dict[str, set[str]]) -> dict[tuple[str, str], list[str]]:
    """(from subpackage, to subpackage) -> the module edges behind it."""
    out: dict[tuple[str, str], list[str]] = collections.defaultdict(list)
    for a, targets in edges.items():
        for b in targets:
            sa, sb = _subpackage(a), _subpackage(b)
            if sa is None or sb is None or sa == sb:
                continue
            out[(sa, sb)].append(f"{a} -> {b}")
    return out


@pytest.fixture(scope="module")
def graph():
    modules = _modules()
    return modules, _edges(modules)


def test_every_subpackage_has_a_layer(graph):
    modules, _ = graph
    subpackages = {s for s in map(_subpackage, modules) if s is not None and (SRC / s).is_dir()}
    assert subpackages <= set(LAYERS), f"subpackages missing from LAYERS: {sorted(subpackages - set(LAYERS))}"


def test_no_module_imports_the_package_root(graph):
    _, edges = graph
    offenders = sorted(a for a, targets in edges.items() if a != "neumat" and "neumat" in targets)
    assert not offenders, f"modules importing the root package `neumat` (import from its submodules): {offenders}"


def test_no_cycle_among_modules(graph):
    modules, edges = graph
    cycles = _cycles(set(modules), edges)
    assert not cycles, "import cycles among modules:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_no_cycle_among_subpackages(graph):
    _, edges = graph
    sub_edges = _subpackage_edges(edges)
    nodes = {s for pair in sub_edges for s in pair}
    adjacency: dict[str, set[str]] = collections.defaultdict(set)
    for sa, sb in sub_edges:
        adjacency[sa].add(sb)
    cycles = _cycles(nodes, adjacency)
    detail = [f"{' <-> '.join(c)}: " + "; ".join(e for (sa, sb), es in sorted(sub_edges.items())
                                                 if sa in c and sb in c for e in es) for c in cycles]
    assert not cycles, "import cycles among subpackages:\n" + "\n".join(detail)


def test_subpackages_import_only_their_own_layer_or_lower(graph):
    _, edges = graph
    rank = {s: i for i, s in enumerate(LAYERS)}
    upward = sorted(e for (sa, sb), es in _subpackage_edges(edges).items()
                    if sa in rank and sb in rank and rank[sb] > rank[sa] for e in es)
    assert not upward, "imports of a higher layer (order: " + " < ".join(LAYERS) + "):\n" + "\n".join(upward)
