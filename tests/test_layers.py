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


#: Method packages that build on a sibling, each declared in its docstring and in
#: ``warpshade.methods.__doc__`` (importer, imported). What several methods share lives below
#: them (``methods.common``, ``methods._shared``, ``basis``, ``transfer``), not in a sibling.
DECLARED_METHOD_DEPENDENCIES = {("heightfield", "rpo")}


def _method_packages() -> set[str]:
    return {p.name for p in (PACKAGE / "methods").iterdir()
            if (p / "__init__.py").is_file() and not p.name.startswith("_")}


def _method_package_of(module: str, methods: set[str]) -> str | None:
    parts = module.split(".")
    return parts[2] if len(parts) > 2 and parts[1] == "methods" and parts[2] in methods else None


def _method_home(module: str, methods: set[str]) -> str:
    """The method package a module belongs to (``warpshade.methods.rpo``), else the module itself."""
    package = _method_package_of(module, methods)
    return f"warpshade.methods.{package}" if package else module


def test_method_packages_import_only_their_declared_siblings():
    methods = _method_packages()
    graph = package_import_graph(PACKAGE)
    found, undeclared = set(), []
    for source, targets in graph.items():
        a = _method_package_of(source, methods)
        for target, sites in targets.items():
            b = _method_package_of(target, methods)
            if a and b and a != b:
                found.add((a, b))
                if (a, b) not in DECLARED_METHOD_DEPENDENCIES:
                    undeclared += [f"{source} -> {target} ({site})" for site in sites]
    assert not undeclared, "a method imports a sibling method (move the shared piece below both):\n" + \
        "\n".join(sorted(undeclared))
    assert DECLARED_METHOD_DEPENDENCIES <= found, "a declared dependency no longer exists: drop it here and in the docs"


def test_no_method_imports_a_private_name_of_another_method_package():
    methods = _method_packages()
    wrong = []
    for path in sorted((PACKAGE / "methods").rglob("*.py")):
        parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
            package = ".".join(parts)
        else:
            package = ".".join(parts[:-1])
        own = _method_home(package, methods)
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.ImportFrom):
                continue
            target = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                target = ".".join(anchor + ([node.module] if node.module else []))
            home = _method_home(target, methods)
            if home.startswith("warpshade.methods") and home != own and not home.startswith(own + "."):
                wrong += [f"{path.relative_to(PACKAGE)}:{node.lineno} {a.name} from {target}" for a in node.names
                          if a.name.startswith("_") and not a.name.startswith("__")]
    assert not wrong, "private names imported from another method package:\n" + "\n".join(wrong)


def test_the_reference_shares_no_code_with_the_methods_it_measures():
    graph = package_import_graph(PACKAGE)
    shared = [f"{s} -> {t}" for s, targets in graph.items() if s.startswith("warpshade.reference")
              for t in targets if t.startswith("warpshade.methods")]
    assert not shared, "the ground truth imports a method (give it its own code, or move the piece below both):\n" + \
        "\n".join(shared)
