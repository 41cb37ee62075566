"""Real spherical harmonics as Warp functions and kernels, generated per SH order.

``sh_kernels(order)`` returns an :class:`SHKernels` bundle whose ``@wp.func`` members operate on
a fixed-length Warp vector of ``order**2`` float32 coefficients (``bundle.vec``). The loops over
bands are compile-time constants, so Warp unrolls them and the code is specialised to the
order; bundles are cached per order, and each kernel lives in its own Warp module so that
creating the bundle for one order never recompiles another.

Convention (see :mod:`warpshade.basis.sh`): real, orthonormal SH, coefficient index
``l*l + l + m``, with the Condon-Shortley phase of Sloan's "Stupid SH Tricks"
(``y(1,-1) = -0.488603 y``, ``y(1,0) = 0.488603 z``, ``y(1,1) = -0.488603 x``).

Functions in a bundle (all usable inside other kernels):

* ``eval(d: vec3) -> vec`` -- all ``order**2`` basis functions at a unit direction;
* ``dot(a: vec, b: vec) -> float``;
* ``zh_to_sh(axis: vec3, g: bands) -> vec`` -- the ZH rotation rule
  ``f_lm = sqrt(4 pi / (2l + 1)) * g_l * y_lm(axis)``;
* ``basis_kernel`` -- ``(dirs: array(vec3), out: array2d(float32))`` writes ``out[i, :]``.
"""

# No "from __future__ import annotations": Warp resolves closure types in annotations.

import functools
import math
from dataclasses import dataclass
from typing import Any

from .._wp import wp

__all__ = ["SHKernels", "sh_kernels", "MAX_KERNEL_ORDER"]

#: Highest SH order with generated Warp code (order n = n bands = n*n coefficients).
MAX_KERNEL_ORDER = 12


@dataclass(frozen=True)
class SHKernels:
    """Warp functions and kernels specialised to one SH order (see module docstring)."""

    order: int
    coeff_count: int
    vec: Any  # wp vector type of length order**2, float32
    bands: Any  # wp vector type of length order, float32 (per-band ZH coefficients)
    eval: Any
    dot: Any
    zh_to_sh: Any
    basis_kernel: Any


@functools.lru_cache(maxsize=None)
def sh_kernels(order: int) -> SHKernels:
    """Return the cached Warp SH bundle for ``order`` (1 <= order <= MAX_KERNEL_ORDER)."""
    if not 1 <= order <= MAX_KERNEL_ORDER:
        raise ValueError(f"sh_kernels: order must be in 1..{MAX_KERNEL_ORDER}, got {order}")
    ORDER = order
    N = order * order
    vec_t = wp.types.vector(length=N, dtype=wp.float32)
    bands_t = wp.types.vector(length=order, dtype=wp.float32)
    SQRT2 = math.sqrt(2.0)
    Y00 = 0.5 / math.sqrt(math.pi)

    @wp.func
    def sh_eval(d: wp.vec3) -> vec_t:
        # Orthonormal associated Legendre recurrences in z, with sin^m(theta) cos/sin(m phi)
        # carried as the complex power (x + i y)^m, so no trigonometric calls are needed.
        out = vec_t()
        x = d[0]
        y = d[1]
        z = d[2]
        c = float(1.0)
        s = float(0.0)
        pmm = float(Y00)
        for m in range(ORDER):
            if m > 0:
                pmm = -wp.sqrt(float(2 * m + 1) / float(2 * m)) * pmm
            p_prev = float(0.0)
            p_cur = pmm
            for l in range(m, ORDER):
                if l == m + 1:
                    p_prev = p_cur
                    p_cur = wp.sqrt(float(2 * m + 3)) * z * pmm
                elif l > m + 1:
                    a = wp.sqrt(float(4 * l * l - 1) / float(l * l - m * m))
                    b = wp.sqrt(float((l - 1) * (l - 1) - m * m) / float(4 * (l - 1) * (l - 1) - 1))
                    p_next = a * (z * p_cur - b * p_prev)
                    p_prev = p_cur
                    p_cur = p_next
                if m == 0:
                    out[l * l + l] = p_cur
                else:
                    out[l * l + l + m] = float(SQRT2) * p_cur * c
                    out[l * l + l - m] = float(SQRT2) * p_cur * s
            c_next = c * x - s * y
            s = c * y + s * x
            c = c_next
        return out

    @wp.func
    def sh_dot(a: vec_t, b: vec_t) -> float:
        acc = float(0.0)
        for i in range(N):
            acc += a[i] * b[i]
        return acc

    @wp.func
    def sh_zh_to_sh(axis: wp.vec3, g: bands_t) -> vec_t:
        y = sh_eval(axis)
        out = vec_t()
        for l in range(ORDER):
            scale = wp.sqrt(4.0 * wp.pi / float(2 * l + 1)) * g[l]
            for m in range(-l, l + 1):
                out[l * l + l + m] = scale * y[l * l + l + m]
        return out

    @wp.kernel(enable_backward=False, module="unique")
    def basis_kernel(dirs: wp.array(dtype=wp.vec3), out: wp.array2d(dtype=wp.float32)):
        i = wp.tid()
        v = sh_eval(wp.normalize(dirs[i]))
        for j in range(N):
            out[i, j] = v[j]

    return SHKernels(
        order=order,
        coeff_count=N,
        vec=vec_t,
        bands=bands_t,
        eval=sh_eval,
        dot=sh_dot,
        zh_to_sh=sh_zh_to_sh,
        basis_kernel=basis_kernel,
    )
