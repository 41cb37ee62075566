"""The import graph of ``warpshade.basis`` is acyclic and follows its documented module order.

Every ``import`` / ``from ... import`` of every ``warpshade/basis/*.py`` counts, at module level
and inside functions (an import inside a function is still an edge); imports under
``if TYPE_CHECKING:`` do not. The graph is read statically by :mod:`imports_graph`, which is
checked first on a small package built here.
"""

import ast
import textwrap
from pathlib import Path

from imports_graph import cyclic_components, find_cycles, format_cycle, package_import_graph

BASIS = Path(__file__).resolve().parents[1] / "warpshade" / "basis"


def _write_package(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))


def test_graph_counts_function_level_and_relative_imports_but_not_type_checking(tmp_path):
    _write_package(tmp_path / "pkg", {
        "__init__.py": "from . import a\n",
        "a.py": """\
            from typing import TYPE_CHECKING

            import numpy as np

            from .b import value

            if TYPE_CHECKING:
                from . import c
            else:
                from .sub import d
            """,
        "b.py": """\
            def late():
                from . import a

                return a
            """,
        "c.py": "",
        "sub/__init__.py": "",
        "sub/d.py": "from .. import c\nimport pkg.b\n",
    })
    graph = package_import_graph(tmp_path / "pkg")
    assert {m: set(t) for m, t in graph.items()} == {
        "pkg": {"pkg.a"},
        "pkg.a": {"pkg.b", "pkg.sub.d"},
        "pkg.b": {"pkg.a"},
        "pkg.c": set(),
        "pkg.sub": set(),
        "pkg.sub.d": {"pkg.c", "pkg.b"},
    }
    assert [str(s) for s in graph["pkg.b"]["pkg.a"]] == ["line 2 in late()"]
    assert cyclic_components(graph) == [["pkg.a", "pkg.b", "pkg.sub.d"]]
    assert find_cycles(graph) == [["pkg.a", "pkg.b", "pkg.a"]]
    assert "pkg.b imports pkg.a (line 2 in late())" in format_cycle(graph, find_cycles(graph)[0])


def test_basis_import_graph_is_acyclic():
    graph = package_import_graph(BASIS)
    assert len(graph) >= 10 and "warpshade.basis.sh_warp" in graph["warpshade.basis.sh"]
    report = [
        f"on a cycle together: {', '.join(component)}\n  e.g. {format_cycle(graph, cycle)}"
        for component, cycle in zip(cyclic_components(graph), find_cycles(graph))
    ]
    assert not report, "import cycles in warpshade.basis:\n" + "\n".join(report)


def _documented_order() -> list[str]:
    """Module names of the order table in ``warpshade/basis/__init__.py``'s docstring."""
    doc = ast.get_docstring(ast.parse((BASIS / "__init__.py").read_text())) or ""
    assert "Module order" in doc, "warpshade/basis/__init__.py documents no module order"
    block = doc.split("Module order", 1)[1].split("::", 1)[1]
    names = []
    for line in block.splitlines():
        if line.startswith("    ") and "<-" in line:
            names.append(line.split()[0])
        elif names and line.strip():
            break
    return names


def test_basis_modules_import_only_modules_listed_above_them():
    graph = package_import_graph(BASIS)
    order = ["warpshade.basis." + name for name in _documented_order()]
    assert sorted(order) == sorted(m for m in graph if m != "warpshade.basis"), "order table out of date"
    rank = {m: i for i, m in enumerate(order)}
    wrong = [
        f"{source} imports {target} ({', '.join(map(str, sites))}), listed above it"
        for source in order
        for target, sites in graph[source].items()
        if rank[target] >= rank[source]
    ]
    assert not wrong, "\n".join(wrong)

