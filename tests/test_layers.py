"""The package's import graph follows the layer order its docstring documents, with no cycle.

Every ``import`` / ``from ... import`` of every module counts, at module level and inside
functions (:mod:`imports_graph`); imports under ``if TYPE_CHECKING:`` do not. The layer order is
read from ``warpshade.__doc__`` (the line of names joined by ``->``), so the documentation and
the check cannot drift apart. ``pxr`` is imported only by ``io`` and by the asset generator
(``usd_assets``, a tool at the top beside ``cli``).
"""

import ast
import re
from pathlib import Path

import warpshade
from imports_graph import find_cycles, format_cycle, package_import_graph

PACKAGE = Path(warpshade.__file__).resolve().parent


def documented_layers() -> list[list[str]]:
    """The layer order of the package docstring: a list of layers, each a list of names."""
    line = next(ln for ln in warpshade.__doc__.splitlines() if ln.count("->") >= 5)
    return [[name.strip() for name in part.split(",")] for part in line.strip().split("->")]


def layer_of(module: str, layers) -> int | None:
    parts = module.split(".")
    if len(parts) == 1:
        return None  # the warpshade facade
    for rank, names in enumerate(layers):
        if parts[1] in names:
            return rank
    raise AssertionError(f"module {module} is in no documented layer {layers}")


def test_every_module_is_in_a_documented_layer():
    layers = documented_layers()
    assert layers[0] == ["_wp", "_fileio", "_hashing", "_limits", "tasks"] and layers[-1] == ["cli", "usd_assets"]
    top = {p.stem if p.is_file() else p.name for p in PACKAGE.iterdir()
           if (p.suffix == ".py" and p.stem != "__init__") or (p.is_dir() and (p / "__init__.py").exists())}
    assert top == {n for layer in layers for n in layer}, "the docstring lists exactly the package's modules"


def test_no_module_imports_a_higher_layer():
    layers = documented_layers()
    graph = package_import_graph(PACKAGE)
    upward = []
    for source, targets in graph.items():
        a = layer_of(source, layers)
        if a is None:
            continue
        for target, sites in targets.items():
            b = layer_of(target, layers)
            if b is not None and b > a:
                upward += [f"{source} -> {target} ({site})" for site in sites]
    assert not upward, "imports of a higher layer:\n" + "\n".join(sorted(upward))


def test_no_import_cycle():
    graph = package_import_graph(PACKAGE)
    cycles = find_cycles(graph)
    assert not cycles, "import cycles:\n" + "\n".join(format_cycle(graph, c) for c in cycles)


def test_private_basis_modules_are_imported_only_inside_basis():
    graph = package_import_graph(PACKAGE)
    private = re.compile(r"^warpshade\.basis\._")
    outside = [f"{s} -> {t}" for s, targets in graph.items() if not s.startswith("warpshade.basis")
               for t in targets if private.match(t)]
    assert not outside, outside


def test_only_io_and_the_asset_generator_import_pxr():
    allowed = ("io", "usd_assets")
    outside = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE)
        if rel.parts[0] in allowed:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
            outside += [f"{rel}:{node.lineno} imports {n}" for n in names if n.split(".")[0] == "pxr"]
    assert not outside, outside
