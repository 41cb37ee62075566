"""One subpackage per technique; importing this package registers every built-in stage type.

Each method subpackage holds ``kernels.py`` (Warp kernels) beside ``stages.py`` (the stages
that orchestrate them), registers its stage types on import, and may define
``harness_rows(quick)`` for the speed-vs-accuracy harness (:mod:`warpshade.methods.rows`).
Subpackages are discovered, so adding a method needs no edit here.
"""

import importlib
import pkgutil


#: Method subpackages, discovered at import (each registers its stages).
METHOD_PACKAGES = tuple(
    sorted(m.name for m in pkgutil.iter_modules(__path__) if m.ispkg)
)
for _name in METHOD_PACKAGES:
    importlib.import_module(f"{__name__}.{_name}")

__all__ = ["METHOD_PACKAGES"]
