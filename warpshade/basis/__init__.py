"""Spherical-function algebra: pure maths, no scene objects.

Submodules: :mod:`~warpshade.basis.sh` (real spherical harmonics), :mod:`~warpshade.basis.sh_warp`
(the same operations as Warp functions), :mod:`~warpshade.basis.zh` (zonal-harmonic lobes: rotation
and fitting), :mod:`~warpshade.basis.sg` and :mod:`~warpshade.basis.sg_warp` (spherical Gaussians,
float64 and Warp), :mod:`~warpshade.basis.quadrature` (sample sets). Import public names from these
six; the ``_``-prefixed modules are private, and what callers need from them is re-exported by
``sh``, ``sh_warp`` or ``zh``.

Module order, bottom to top: each module imports only modules listed above it (imports inside
functions included), so the import graph is acyclic (``tests/test_basis_imports.py``)::

    quadrature      sphere sample sets                               <- (none)
    _core           float64 SH basis, index helpers, checks, cap ZH  <- (none)
    _gaunt          exact Gaunt tensor, float64 products             <- _core
    _conventions    converters to other SH conventions               <- _gaunt
    _rotation       SH rotation blocks (float64)                     <- quadrature, _core
    _shexp          float64 SH exp/log, OL and log-cap tables        <- quadrature, _core, _gaunt
    _shexp_warp     exp/log @wp.func generator, SHExpTables          <- _shexp
    sh_warp         per-order Warp SH bundle, sh_kernels             <- _gaunt, _rotation, _shexp_warp
    _shexp_kernels  per-order exp/log kernels                        <- _shexp_warp, sh_warp
    sh              public SH facade                                 <- all of the above
    _zh_grad        SH basis with its direction gradient             <- (none)
    _zh_fit         batched ZH lobe fitting                          <- _core, _zh_grad
    _zh_global      global ZH fit (variable projection, beam scan)   <- _core, _zh_grad, _zh_fit
    _zh_warp        per-order Warp ZH bundle, zh_kernels             <- sh_warp
    zh              public ZH facade                                 <- _core, _zh_grad, _zh_fit, _zh_global, _zh_warp
    sg              float64 spherical Gaussians, f_h                 <- (none)
    sg_warp         spherical Gaussians as Warp functions            <- sg

``_shexp_warp``, ``sh_warp``, ``_shexp_kernels``, ``sh``, ``_zh_warp`` and ``sg_warp`` also import
:mod:`warpshade._wp` (Warp set-up), which is outside this package.
"""

from . import quadrature, sg, sh, zh

__all__ = ["quadrature", "sg", "sh", "zh"]
