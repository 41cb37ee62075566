"""warpshade: soft shadows and relighting for animated USD scenes on NVIDIA Warp.

The package is layered (lower layers never import upper ones)::

    basis -> geometry -> scene -> io -> transfer -> methods -> reference -> graph -> render -> cli

Only ``warpshade.io`` imports ``pxr``.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__", "load_usd", "load_scene"]


def __getattr__(name):
    # Loading USD pulls in pxr and Warp; keep ``import warpshade`` light until it is used.
    if name in ("load_usd", "load_scene"):
        from .io import usd

        return getattr(usd, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
