"""Spherical-function algebra: pure maths, no scene objects.

Submodules: :mod:`~warpshade.basis.sh` (real spherical harmonics), :mod:`~warpshade.basis.sh_warp`
(the same operations as Warp functions), :mod:`~warpshade.basis.zh` (zonal-harmonic lobes: rotation
and fitting), :mod:`~warpshade.basis.quadrature` (sample sets).
"""

from . import quadrature, sh, zh

__all__ = ["quadrature", "sh", "zh"]
