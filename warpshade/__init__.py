"""warpshade: soft shadows and relighting for animated USD scenes on NVIDIA Warp.

The package is layered (lower layers never import upper ones)::

    basis -> geometry -> scene -> io -> transfer -> methods -> reference -> graph -> render -> cli

Only ``warpshade.io`` imports ``pxr``.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__"]
