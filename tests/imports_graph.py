"""Static import graph of a Python package, read with :mod:`ast` (nothing is imported).

:func:`package_import_graph` parses every ``.py`` file below a package directory and records
each ``import`` / ``from ... import`` statement wherever it stands -- module level, inside
functions, methods or other blocks -- with relative imports resolved against the importing
module's package. Imports under ``if TYPE_CHECKING:`` are skipped (they never run); their
``else:`` branch is kept. Only edges between modules of the scanned tree are kept.

A statement ``from P import X`` is an edge to ``P.X`` when that is a module of the tree, else to
``P``; ``import a.b.c`` is an edge to the longest prefix of ``a.b.c`` that is a module of the
tree. Importing a submodule also runs its parent packages' ``__init__``, but those implicit
edges are not recorded: they would put every package ``__init__`` that imports its own
submodules on a cycle.

:func:`find_cycles` and :func:`format_cycle` turn the graph into readable failures.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

__all__ = [
    "ImportSite",
    "cyclic_components",
    "find_cycles",
    "format_cycle",
    "module_name",
    "package_import_graph",
]


@dataclass(frozen=True)
class ImportSite:
    """Where an import statement stands: source line and enclosing function (None: module level)."""

    line: int
    function: str | None

    def __str__(self) -> str:
        where = f"in {self.function}()" if self.function else "at module level"
        return f"line {self.line} {where}"


#: ``graph[source][target]`` lists the statements of module ``source`` that import ``target``.
ImportGraph = dict[str, dict[str, list[ImportSite]]]


def _package_root(directory: Path) -> Path:
    """The outermost directory above (and including) ``directory`` that is still a package."""
    top = directory.resolve()
    while (top.parent / "__init__.py").is_file():
        top = top.parent
    return top


def module_name(path: Path, root: Path) -> str:
    """Dotted name of the module in ``path``, counted from the top package that contains ``root``."""
    top = _package_root(root)
    parts = list(path.resolve().relative_to(top.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


class _ImportCollector(ast.NodeVisitor):
    """Collects ``(absolute module, imported names, ImportSite)`` for every import statement."""

    def __init__(self, module: str, is_package: bool):
        self.package = module if is_package else module.rpartition(".")[0]
        self.function: list[str] = []
        self.found: list[tuple[str, list[str], ImportSite]] = []

    def _site(self, node: ast.stmt) -> ImportSite:
        return ImportSite(node.lineno, ".".join(self.function) or None)

    def _scoped(self, node) -> None:
        self.function.append(node.name)
        self.generic_visit(node)
        self.function.pop()

    visit_FunctionDef = visit_AsyncFunctionDef = _scoped

    def visit_If(self, node: ast.If) -> None:
        if _is_type_checking(node.test):
            for child in node.orelse:
                self.visit(child)
        else:
            self.generic_visit(node)

    def visit_Import(self, node: ast.Import) -> None:
        for alias in node.names:
            self.found.append((alias.name, [], self._site(node)))

    def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
        base = node.module or ""
        if node.level:
            anchor = self.package.split(".") if self.package else []
            if node.level - 1 > len(anchor):
                raise ValueError(f"relative import beyond the top package at line {node.lineno}")
            anchor = anchor[: len(anchor) - (node.level - 1)]
            base = ".".join(anchor + ([base] if base else []))
        self.found.append((base, [a.name for a in node.names if a.name != "*"], self._site(node)))


def _longest_known_prefix(name: str, modules: set[str]) -> str | None:
    parts = name.split(".")
    for end in range(len(parts), 0, -1):
        candidate = ".".join(parts[:end])
        if candidate in modules:
            return candidate
    return None


def package_import_graph(root) -> ImportGraph:
    """The import graph among the modules in and below the package directory ``root``.

    Args:
        root: a package directory (it holds ``__init__.py``), e.g. ``warpshade/basis`` or
            ``warpshade``; module names are dotted from the top package containing it.

    Returns:
        ``{module: {imported module: [ImportSite, ...]}}`` with one key per module of the tree
        (``__init__.py`` under the package's own name); targets are modules of the tree only.
    """
    root = Path(root)
    if not (root / "__init__.py").is_file():
        raise ValueError(f"package_import_graph: {root} is not a package directory")
    files = {module_name(p, root): p for p in sorted(root.rglob("*.py"))}
    modules = set(files)
    graph: ImportGraph = {}
    for module, path in files.items():
        collector = _ImportCollector(module, path.name == "__init__.py")
        collector.visit(ast.parse(path.read_text(encoding="utf-8"), filename=str(path)))
        edges: dict[str, list[ImportSite]] = {}
        for base, names, site in collector.found:
            targets = [f"{base}.{n}" for n in names if f"{base}.{n}" in modules]
            if len(targets) < len(names) or not names:  # some names are attributes of ``base``
                prefix = _longest_known_prefix(base, modules)
                if prefix is not None:
                    targets.append(prefix)
            for target in targets:
                edges.setdefault(target, []).append(site)
        graph[module] = edges
    return graph


def cyclic_components(graph: ImportGraph) -> list[list[str]]:
    """The strongly connected components of ``graph`` that contain a cycle, each sorted.

    Every module of a component is on an import cycle with every other one; a single module is
    listed only when it imports itself. Empty when the graph is acyclic.
    """
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components: list[list[str]] = []

    def strongconnect(v: str) -> None:  # Tarjan's algorithm
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
            if w not in index:
                strongconnect(w)
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
            components.append(component)

    for v in sorted(graph):
        if v not in index:
            strongconnect(v)
    return sorted(sorted(c) for c in components if len(c) > 1 or c[0] in graph.get(c[0], {}))


def find_cycles(graph: ImportGraph) -> list[list[str]]:
    """One shortest cycle through the first module of each of :func:`cyclic_components`.

    Returns:
        Cycles as module lists ``[m0, m1, ..., m0]`` (each ``m_i`` imports ``m_i+1``), one per
        component and in the same order; empty when the graph is acyclic.
    """
    cycles = []
    for component in cyclic_components(graph):
        members = set(component)
        start = component[0]
        # Shortest path back to ``start`` inside the component (breadth-first).
        parent = {start: None}
        frontier = [start]
        closing = None
        while frontier and closing is None:
            nxt = []
            for v in frontier:
                for w in sorted(graph.get(v, {})):
                    if w == start:
                        closing = v
                        break
                    if w in members and w not in parent:
                        parent[w] = v
                        nxt.append(w)
                if closing is not None:
                    break
            frontier = nxt
        path = [start]
        v = closing
        while v != start:
            path.append(v)
            v = parent[v]
        cycles.append([start] + path[1:][::-1] + [start])
    return cycles


def format_cycle(graph: ImportGraph, cycle: list[str]) -> str:
    """``a -> b -> a`` with the statements that make each edge, one edge per line."""
    lines = [" -> ".join(cycle)]
    for source, target in zip(cycle, cycle[1:]):
        sites = ", ".join(str(s) for s in graph[source][target])
        lines.append(f"    {source} imports {target} ({sites})")
    return "\n".join(lines)
