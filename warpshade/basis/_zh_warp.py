"""Zonal-harmonic lobes as Warp functions and kernels, generated per SH order.

``zh_kernels(order)`` returns a :class:`ZHKernels` bundle (cached per order, each kernel in its
own Warp module). Lobe coefficients are the convolution coefficients ``g*`` of
:mod:`warpshade.basis.zh` in a ``bands`` vector (length n, float32); SH vectors are the ``vec``
type of :func:`warpshade.basis.sh_warp.sh_kernels` (length n*n).

Functions (usable inside other kernels):

* ``lobe_sh(axis: vec3, g: bands) -> vec`` -- SH of one lobe, ``y_lm(axis) g*_l`` (eq. 6);
* ``accumulate_sh(acc: vec, axis, g) -> vec`` -- ``acc + lobe_sh(axis, g)``;
* ``lobe_eval(axis, g, d: vec3) -> float`` -- the lobe's value at a direction,
  ``sum_l g*_l (2l+1)/(4 pi) P_l(axis . d)`` (addition theorem, Legendre recurrence);
* ``light_bands(e: vec, axis) -> bands`` -- ``e^_l(axis) = sum_m y_lm(axis) e_lm`` (eq. 24);
* ``lobe_dot(axis, g, e: vec) -> float`` -- ``sum_l g*_l e^_l(axis)``: a lobe dotted with
  lighting by direct SH evaluation (O(n^2) per lobe);
* ``table_lookup(table: array4d, d: vec3) -> rgb_bands`` -- bilinear look-up of the
  light-specialised table ``e^(s)`` (eq. 24-25; O(n) per lobe and channel), all three colour
  channels at once (a 3 x n matrix, row c = channel c);
* ``load_bands(a: array3d, i, j) -> bands``.

Kernels: ``to_sh_kernel(axes: array2d(vec3), coeffs: array3d, counts: array(int32),
out: array2d)`` (one thread per lobe set, the first ``counts[i]`` lobes),
``evaluate_kernel(axes, coeffs, counts, directions: array2d(vec3), out: array2d)`` (one thread
per (set, direction)), ``table_kernel(light: array2d (3, n*n), rebuild: array(int32),
table: array4d (H, W, 3, n))`` (one thread per texel; the SH basis is evaluated once for the
three channels; nothing is written when ``rebuild[0] == 0``, so a frame loop can skip the
rebuild while the lighting is unchanged and still launch the same kernels every frame).

Table layout (:func:`table_directions`): a lat-long grid in the frame of the lighting, rows
``theta_i = i pi / (H - 1)`` for i = 0..H-1 (both poles are rows, so no clamping is needed),
columns ``phi_j = 2 pi j / W`` for j = 0..W-1 (periodic); bilinear interpolation in
(theta, phi). The paper uses 64 x 32.

Layer: builds on :mod:`warpshade.basis.sh_warp` (the order's ``vec``/``bands`` types and
``eval``); :mod:`warpshade.basis.zh` re-exports :func:`zh_kernels`, :class:`ZHKernels` and
:func:`table_directions` (import them from there).
"""

# No "from __future__ import annotations": Warp resolves closure types in annotations.

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._wp import wp
from .sh_warp import MAX_KERNEL_ORDER, sh_kernels

wp.set_module_options({"enable_backward": False})

__all__ = ["ZHKernels", "table_directions", "zh_kernels"]


def table_directions(height: int, width: int) -> np.ndarray:
    """Directions of the light-specialised table's grid points, shape (height, width, 3), float64."""
    theta = np.arange(height) * (np.pi / (height - 1))
    phi = np.arange(width) * (2.0 * np.pi / width)
    st = np.sin(theta)[:, None]
    return np.stack([st * np.cos(phi)[None, :], st * np.sin(phi)[None, :],
                     np.broadcast_to(np.cos(theta)[:, None], (height, width))], axis=-1)


@dataclass(frozen=True)
class ZHKernels:
    """Warp functions and kernels for ZH lobes of one SH order (see module docstring)."""

    order: int
    vec: Any
    bands: Any
    rgb_bands: Any
    lobe_sh: Any
    accumulate_sh: Any
    lobe_eval: Any
    light_bands: Any
    lobe_dot: Any
    table_lookup: Any
    load_bands: Any
    to_sh_kernel: Any
    evaluate_kernel: Any
    table_kernel: Any


@functools.cache
def zh_kernels(order: int) -> ZHKernels:
    """Return the cached Warp ZH bundle for ``order`` (1 <= order <= MAX_KERNEL_ORDER)."""
    if not 1 <= order <= MAX_KERNEL_ORDER:
        raise ValueError(f"zh_kernels: order must be in 1..{MAX_KERNEL_ORDER}, got {order}")
    shk = sh_kernels(order)
    ORDER = order
    vec_t = shk.vec
    bands_t = shk.bands
    rgb_t = wp.types.matrix(shape=(3, order), dtype=wp.float32)
    sh_eval = shk.eval
    INV_4PI = 1.0 / (4.0 * math.pi)

    @wp.func
    def lobe_sh(axis: wp.vec3, g: bands_t) -> vec_t:
        y = sh_eval(axis)
        out = vec_t()
        for l in range(ORDER):
            for m in range(-l, l + 1):
                out[l * l + l + m] = g[l] * y[l * l + l + m]
        return out

    @wp.func
    def accumulate_sh(acc: vec_t, axis: wp.vec3, g: bands_t) -> vec_t:
        return acc + lobe_sh(axis, g)

    @wp.func
    def lobe_eval(axis: wp.vec3, g: bands_t, d: wp.vec3) -> float:
        x = wp.clamp(wp.dot(axis, d), -1.0, 1.0)
        p_prev = float(1.0)
        p_cur = x
        acc = g[0] * float(INV_4PI)
        for l in range(1, ORDER):
            if l > 1:
                p_next = (float(2 * l - 1) * x * p_cur - float(l - 1) * p_prev) / float(l)
                p_prev = p_cur
                p_cur = p_next
            acc += g[l] * float(2 * l + 1) * float(INV_4PI) * p_cur
        return acc

    @wp.func
    def light_bands(e: vec_t, axis: wp.vec3) -> bands_t:
        y = sh_eval(axis)
        out = bands_t()
        for l in range(ORDER):
            acc = float(0.0)
            for m in range(-l, l + 1):
                acc += y[l * l + l + m] * e[l * l + l + m]
            out[l] = acc
        return out

    @wp.func
    def lobe_dot(axis: wp.vec3, g: bands_t, e: vec_t) -> float:
        b = light_bands(e, axis)
        acc = float(0.0)
        for l in range(ORDER):
            acc += g[l] * b[l]
        return acc

    @wp.func
    def table_lookup(table: wp.array4d(dtype=wp.float32), d: wp.vec3) -> rgb_t:
        height = table.shape[0]
        width = table.shape[1]
        theta = wp.acos(wp.clamp(d[2], -1.0, 1.0))
        phi = wp.atan2(d[1], d[0])
        if phi < 0.0:
            phi += 2.0 * wp.pi
        fi = theta / wp.pi * float(height - 1)
        i0 = wp.clamp(int(wp.floor(fi)), 0, height - 2)
        ti = fi - float(i0)
        fj = phi / (2.0 * wp.pi) * float(width)
        j0f = wp.floor(fj)
        tj = fj - j0f
        j0 = int(j0f) % width
        j1 = (j0 + 1) % width
        w00 = (1.0 - ti) * (1.0 - tj)
        w01 = (1.0 - ti) * tj
        w10 = ti * (1.0 - tj)
        w11 = ti * tj
        out = rgb_t()
        for c in range(3):
            for l in range(ORDER):
                out[c, l] = (w00 * table[i0, j0, c, l] + w01 * table[i0, j1, c, l]
                             + w10 * table[i0 + 1, j0, c, l] + w11 * table[i0 + 1, j1, c, l])
        return out

    @wp.func
    def load_bands(a: wp.array3d(dtype=wp.float32), i: int, j: int) -> bands_t:
        out = bands_t()
        for l in range(ORDER):
            out[l] = a[i, j, l]
        return out

    @wp.kernel(enable_backward=False, module="unique")
    def to_sh_kernel(
        axes: wp.array2d(dtype=wp.vec3),
        coeffs: wp.array3d(dtype=wp.float32),
        counts: wp.array(dtype=wp.int32),
        out: wp.array2d(dtype=wp.float32),
    ):
        i = wp.tid()
        acc = vec_t()
        for k in range(counts[i]):
            acc = accumulate_sh(acc, wp.normalize(axes[i, k]), load_bands(coeffs, i, k))
        for j in range(ORDER * ORDER):
            out[i, j] = acc[j]

    @wp.kernel(enable_backward=False, module="unique")
    def evaluate_kernel(
        axes: wp.array2d(dtype=wp.vec3),
        coeffs: wp.array3d(dtype=wp.float32),
        counts: wp.array(dtype=wp.int32),
        directions: wp.array2d(dtype=wp.vec3),
        out: wp.array2d(dtype=wp.float32),
    ):
        i, k = wp.tid()
        d = wp.normalize(directions[i, k])
        acc = float(0.0)
        for lobe in range(counts[i]):
            acc += lobe_eval(wp.normalize(axes[i, lobe]), load_bands(coeffs, i, lobe), d)
        out[i, k] = acc

    @wp.kernel(enable_backward=False, module="unique")
    def table_kernel(light: wp.array2d(dtype=wp.float32), rebuild: wp.array(dtype=wp.int32),
                     table: wp.array4d(dtype=wp.float32)):
        if rebuild[0] == 0:
            return
        i, j = wp.tid()
        height = table.shape[0]
        width = table.shape[1]
        theta = float(i) * wp.pi / float(height - 1)
        phi = float(j) * 2.0 * wp.pi / float(width)
        st = wp.sin(theta)
        y = sh_eval(wp.vec3(st * wp.cos(phi), st * wp.sin(phi), wp.cos(theta)))
        for c in range(3):
            for l in range(ORDER):
                acc = float(0.0)
                for m in range(-l, l + 1):
                    acc += y[l * l + l + m] * light[c, l * l + l + m]
                table[i, j, c, l] = acc

    return ZHKernels(
        order=order,
        vec=vec_t,
        bands=bands_t,
        rgb_bands=rgb_t,
        lobe_sh=lobe_sh,
        accumulate_sh=accumulate_sh,
        lobe_eval=lobe_eval,
        light_bands=light_bands,
        lobe_dot=lobe_dot,
        table_lookup=table_lookup,
        load_bands=load_bands,
        to_sh_kernel=to_sh_kernel,
        evaluate_kernel=evaluate_kernel,
        table_kernel=table_kernel,
    )
