"""The method template (docs/adding-a-method.md) holds for every method package, and no module in
warpshade/ outgrows it.

* every package under ``warpshade/methods/`` has the seven modules, a docstring and
  ``harness_rows``;
* every built-in stage type is ``<package>.<name>``, registered by a class named after it
  (package prefix + CamelCase of the name + ``Stage``: ``prt.shade`` -> ``PrtShadeStage``) that
  lives in that package's ``_stages.py``; the prefix is the package's name in the capitals its
  classes give it (``DataDriven``, ``HeightField``, ``Ldprt``), the same for all of them, so a new
  package needs no entry here;
* no module in ``warpshade/`` is over :data:`MAX_MODULE_LINES` lines, save the listed ones being
  split.
"""

import importlib
from pathlib import Path

import pytest

import warpshade.methods as methods
from warpshade.graph import stage_types

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "warpshade"

#: The modules every method package has (docs/adding-a-method.md).
#: (every one but ``__init__`` internal: ``_``-prefixed, its public names exported by ``__init__``).
TEMPLATE_MODULES = ("__init__", "_model", "_kernels", "_mirror", "_stages", "_rows", "_budget")
#: Longest module, in lines.
MAX_MODULE_LINES = 800
#: Modules over the limit that are being split (path relative to warpshade/ -> why); the test
#: fails when one of them no longer needs to be here, so the list only shrinks.
OVER_LIMIT = {}


def _builtin_types() -> dict:
    return {name: cls for name, cls in stage_types().items() if cls.__module__.startswith("warpshade.")}


def test_method_packages_are_discovered():
    assert methods.METHOD_PACKAGES and all((PACKAGE / "methods" / p / "__init__.py").is_file()
                                           for p in methods.METHOD_PACKAGES)


@pytest.mark.parametrize("package", methods.METHOD_PACKAGES)
def test_method_package_has_the_template(package):
    folder = PACKAGE / "methods" / package
    missing = [m for m in TEMPLATE_MODULES if not (folder / f"{m}.py").is_file()]
    assert not missing, f"warpshade/methods/{package}/ lacks {missing}"
    mod = importlib.import_module(f"warpshade.methods.{package}")
    assert mod.__doc__ and mod.__doc__.strip(), f"warpshade.methods.{package} has no docstring"
    assert callable(getattr(mod, "harness_rows", None)), f"warpshade.methods.{package} has no harness_rows"
    budget = importlib.import_module(f"warpshade.methods.{package}._budget")
    assert isinstance(budget.GRID, dict) and callable(budget.candidates)


def _class_prefix(type_name: str, class_name: str) -> str | None:
    """The package prefix of ``class_name`` for ``type_name`` (``prt.shade``, ``PrtShadeStage`` ->
    ``Prt``): the package's name in capitals of the class's choosing, or None when the class is not
    named after its type."""
    package, _, rest = type_name.partition(".")
    suffix = "".join(part.capitalize() for part in rest.split("_")) + "Stage"
    prefix = class_name[:-len(suffix)]
    return prefix if class_name.endswith(suffix) and prefix.lower() == package else None


def test_stage_types_follow_the_naming_rule():
    types = _builtin_types()
    assert types, "no built-in stage types registered"
    wrong = []
    prefixes: dict[str, set] = {}
    for name, cls in sorted(types.items()):
        package, dot, rest = name.partition(".")
        if not dot or not rest or package not in methods.METHOD_PACKAGES:
            wrong.append(f"{name}: the prefix is not a method package")
            continue
        if cls.__module__ != f"warpshade.methods.{package}._stages":
            wrong.append(f"{name}: {cls.__name__} lives in {cls.__module__}, not warpshade.methods.{package}._stages")
        prefix = _class_prefix(name, cls.__name__)
        if prefix is None:
            wrong.append(f"{name}: class {cls.__name__}, expected <{package} in capitals>"
                         f"{''.join(p.capitalize() for p in rest.split('_'))}Stage")
        prefixes.setdefault(package, set()).add(prefix)
    wrong += [f"{package}: stage classes spell the package {sorted(p for p in spelt if p)}: one spelling"
              for package, spelt in sorted(prefixes.items()) if len(spelt - {None}) > 1]
    assert not wrong, "\n".join(wrong)


def test_every_method_package_registers_stages():
    prefixes = {name.partition(".")[0] for name in _builtin_types()}
    assert prefixes == set(methods.METHOD_PACKAGES)


def _line_count(path: Path) -> int:
    with open(path, "rb") as f:
        return sum(1 for _ in f)


def test_no_module_over_the_line_limit():
    sizes = {p.relative_to(PACKAGE).as_posix(): _line_count(p) for p in sorted(PACKAGE.rglob("*.py"))}
    over = {p: n for p, n in sizes.items() if n > MAX_MODULE_LINES and p not in OVER_LIMIT}
    assert not over, f"modules over {MAX_MODULE_LINES} lines: {over}"
    done = [p for p in OVER_LIMIT if sizes.get(p, 0) <= MAX_MODULE_LINES]
    assert not done, f"{done} are within {MAX_MODULE_LINES} lines now: remove them from OVER_LIMIT"
