"""One subpackage per technique; importing this package registers every built-in stage type.

Each method subpackage holds ``_kernels.py`` (Warp kernels) beside ``_stages.py`` (the stages
that orchestrate them), registers its stage types on import, and may define
``harness_rows(quick)`` for the speed-vs-accuracy harness (:mod:`warpshade.methods._rows`).
Subpackages are discovered, so adding a method needs no edit here.

A method package imports no other method package, with one declared exception: ``heightfield``
is RPO over a height field and builds on ``rpo`` (its operators, shading parameters, glossy
stage and view quadrature). What several methods share lives below them: :mod:`._common` (stage
parameters, the frame's SH lighting), :mod:`._shared` (the pose inputs and training clips of the
data-driven methods), or the lower layers (``basis``, ``transfer``). ``_``-prefixed packages are
not methods and are not discovered (``tests/test_layers.py`` checks both rules).
"""

import importlib
import pkgutil


#: Method subpackages, discovered at import (each registers its stages).
METHOD_PACKAGES = tuple(
    sorted(m.name for m in pkgutil.iter_modules(__path__) if m.ispkg and not m.name.startswith("_"))
)
for _name in METHOD_PACKAGES:
    importlib.import_module(f"{__name__}.{_name}")

__all__ = ["METHOD_PACKAGES"]
