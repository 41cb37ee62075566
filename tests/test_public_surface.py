"""One public import path per name.

Public modules are the modules of ``warpshade`` whose dotted path has no ``_``-prefixed part (the
asset generator, a tool, excepted). A public name is one listed in a public module's ``__all__``.
Each object is public in exactly one module, and the tests, the benchmarks, the examples and the README import
every public name from that module (Warp's public modules over ``_src``; Newton's "expose each
public symbol once").
"""

from __future__ import annotations

import ast
import importlib
import re
import sys
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PRIMITIVES = (int, float, str, bool, tuple, frozenset, bytes, type(None))


def _public_modules() -> dict[str, Path]:
    out = {}
    for path in sorted((ROOT / "warpshade").rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if any(p.startswith("_") for p in parts) or "usd_assets" in parts:
            continue
        out[".".join(parts)] = path
    return out


#: What users import (README "Layout"): every package's ``__init__``, the basis's maths modules,
#: the stage contract, the task executor and the command. Every other module is internal and
#: ``_``-prefixed; a new public module is a decision, made here.
PUBLIC_MODULES = {
    "warpshade", "warpshade.cli", "warpshade.tasks",
    "warpshade.basis", "warpshade.basis.quadrature", "warpshade.basis.sg", "warpshade.basis.sg_warp",
    "warpshade.basis.sh", "warpshade.basis.sh_warp", "warpshade.basis.zh",
    "warpshade.geometry", "warpshade.geometry.spheres", "warpshade.graph", "warpshade.io", "warpshade.measure",
    "warpshade.reference", "warpshade.render", "warpshade.scene", "warpshade.transfer",
    "warpshade.methods", "warpshade.methods.stage",
    *(f"warpshade.methods.{m}" for m in ("datadriven", "heightfield", "hybrid", "ldprt", "prt", "rpo", "sg",
                                         "shexp", "visibility")),
}


def test_the_public_modules_are_the_decided_ones():
    found = set(_public_modules())
    assert found == PUBLIC_MODULES, (f"public modules not decided on: {sorted(found - PUBLIC_MODULES)}; "
                                     f"decided but missing: {sorted(PUBLIC_MODULES - found)}")


def _module_imports(source: str):
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("warpshade"):
            yield node.lineno, node.module
        elif isinstance(node, ast.Import):
            yield from ((node.lineno, a.name) for a in node.names if a.name.startswith("warpshade"))


def test_users_are_shown_public_modules_only():
    """The README, the docs and the examples import from public modules only, and name no internal
    module in their text (a method author's page, docs/adding-a-method.md, excepted for the text)."""
    wrong = []
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "examples").rglob("*.py"))]:
        text = path.read_text()
        code = _python_blocks(text) if path.suffix == ".md" else text
        wrong += [f"{path.relative_to(ROOT)}:{line}: imports {m}" for line, m in _module_imports(code)
                  if any(part.startswith("_") for part in m.split("."))]
        if path.name != "adding-a-method.md":
            wrong += [f"{path.relative_to(ROOT)}: names {m}" for m in sorted(set(re.findall(r"warpshade(?:\.\w+)*\._\w+", text)))
                      if m != "warpshade.__version__"]
    assert not wrong, "internal modules shown to users:\n" + "\n".join(wrong)


def _all_of(path: Path) -> list[str]:
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
            return list(ast.literal_eval(node.value))
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and node.target.id == "__all__":
            return list(ast.literal_eval(node.value))
    return []


def _identity(name: str, obj) -> tuple:
    """What makes two exported names the same thing: the definition for classes, functions and
    modules; the name and value for plain constants; the object otherwise."""
    if isinstance(obj, type(sys)):
        return ("module", obj.__name__)
    if not isinstance(obj, PRIMITIVES) and hasattr(obj, "__module__") and hasattr(obj, "__qualname__"):
        return ("def", obj.__module__, obj.__qualname__)
    if isinstance(obj, PRIMITIVES):
        return ("value", name, repr(obj))
    return ("object", id(obj))


@pytest.fixture(scope="module")
def surface():
    exports: dict[tuple, list[tuple[str, str]]] = defaultdict(list)
    public: dict[str, set[str]] = {}
    for module, path in _public_modules().items():
        names = _all_of(path)
        public[module] = set(names)
        if not names:
            continue
        mod = importlib.import_module(module)
        for name in names:
            assert hasattr(mod, name), f"{module}.__all__ lists {name!r}, which the module does not define"
            exports[_identity(name, getattr(mod, name))].append((module, name))
    return exports, public


def test_every_public_object_has_one_import_path(surface):
    exports, _ = surface
    twice = {k: v for k, v in exports.items() if len({m for m, _ in v}) > 1}
    lines = [" and ".join(f"{m}.{n}" for m, n in v) for v in twice.values()]
    assert not twice, f"{len(twice)} objects are public in more than one module:\n" + "\n".join(sorted(lines))


def _imports(source: str):
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("warpshade"):
            for alias in node.names:
                yield node.lineno, node.module, alias.name


def _python_blocks(markdown: str) -> str:
    return "\n".join(re.findall(r"```python\n(.*?)```", markdown, re.S))


def test_consumers_import_public_names_from_their_module(surface):
    exports, public = surface
    sources = [(p, p.read_text()) for d in ("tests", "benchmarks", "examples") for p in sorted((ROOT / d).rglob("*.py"))]
    sources += [(p, _python_blocks(p.read_text())) for p in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]]
    wrong = []
    for path, text in sources:
        for line, module, name in _imports(text):
            if module not in public or name in public[module] or name == "*":
                continue
            obj = getattr(importlib.import_module(module), name, None)
            if obj is None or isinstance(obj, type(sys)):
                continue  # a submodule imported by name, or a name the module does not have
            homes = [m for m, _ in exports.get(_identity(name, obj), [])]
            if homes:
                wrong.append(f"{path.relative_to(ROOT)}:{line}: {name} from {module}, public in {homes[0]}")
    assert not wrong, "imports through a second path:\n" + "\n".join(wrong)


def test_the_top_level_package_is_only_a_version():
    import warpshade

    assert warpshade.__all__ == ["__version__"]
    assert not hasattr(warpshade, "load_usd"), "load_usd's one path is warpshade.io"
