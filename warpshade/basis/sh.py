"""Real spherical harmonics: evaluation, projection and the SH algebra.

Convention (used everywhere in warpshade):

* real, orthonormal on the unit sphere: ``integral y_i(s) y_j(s) ds = delta_ij``;
* coefficient index ``i = l*l + l + m`` for band ``l >= 0`` and ``-l <= m <= l``;
* the sign convention of Sloan's "Stupid SH Tricks", i.e. real SH built from complex SH
  *with* the Condon-Shortley phase: ``y(1,-1) = -0.488603 y``, ``y(1,0) = 0.488603 z``,
  ``y(1,1) = -0.488603 x``; for ``m > 0``, ``y_lm = sqrt(2) Re Y_l^m`` and
  ``y_l,-m = sqrt(2) Im Y_l^m`` with ``Y_l^m`` the complex SH of ``scipy.special.sph_harm_y``;
* "order n" means bands ``l = 0..n-1``, i.e. ``n*n`` coefficients (the papers' usage).

Contents: evaluation (:func:`basis`) and projection (:func:`project`); products through the
exact Gaunt tensor (:func:`triple_product_tensor`, :func:`product`, :func:`product_matrix`,
:func:`square`; :func:`complex_gaunt` for the complex SH integrals); rotation (:func:`rotate`,
:func:`rotation_matrix`); zonal harmonics (:func:`zh_to_sh`, :func:`zh_from_sh_about_axis`,
:func:`clamped_cosine_zh`, :func:`clamped_cosine_sh`, :func:`cap_zh`); frequency-space windows (:func:`window`,
:func:`window_weights`); converters to and from other public conventions (:func:`to_convention`,
:func:`from_convention`); the SH exponential and logarithm of the SHEXP paper (:func:`exp`,
:func:`log`, with the oracles :func:`exp_series_limit` and :func:`exp_volterra`, the squaring
rule :func:`scaling_power`, the per-order tables :func:`ol_table` and :func:`log_cap_table`
(:class:`OLTable`, :class:`LogCapTable`) and the constants ``EXP_METHODS``, ``DEFAULT_DEGREE``,
``LOG_EPS_REL``, ``CAP_THETA_MAX``).

Host functions accept NumPy arrays with any leading batch shape and return NumPy arrays. By
default they run the float64 mirror (the oracle); functions with a ``device`` argument
run the float32 Warp kernel on that device instead (``device="cpu"`` or ``"cuda:0"``). The same
operations exist as ``@wp.func`` for use inside other kernels: see
:func:`warpshade.basis.sh_warp.sh_kernels`.

This module is the public facade of the SH algebra and the top of the SH layers: it imports the
private modules (:mod:`~warpshade.basis._core`, :mod:`~warpshade.basis._gaunt`,
:mod:`~warpshade.basis._rotation`, :mod:`~warpshade.basis._conventions`,
:mod:`~warpshade.basis._shexp`, :mod:`~warpshade.basis._shexp_kernels`) and
:mod:`~warpshade.basis.sh_warp` at the top, and none of them imports it. Names defined in the
private modules that callers need are re-exported here (see ``__all__``); import them from here.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from .._wp import cpu_workers, launch_parallel, resolve_device, wp
from . import _conventions, _gaunt, _rotation, _shexp, _shexp_kernels, quadrature
from ._core import (
    MAX_ORDER,
    band_of,
    band_scale,
    cap_zh,
    check_coeffs,
    check_order,
    chunk_rows,
    coeff_count,
    index,
    unit_directions,
)
from ._core import basis as _basis_reference
from ._gaunt import complex_gaunt
from ._shexp import CAP_THETA_MAX, DEFAULT_DEGREE, LogCapTable, OLTable, scaling_power
from .sh_warp import MAX_KERNEL_ORDER, sh_kernels

__all__ = [
    "MAX_ORDER",
    "coeff_count",
    "index",
    "band_of",
    "basis",
    "project",
    # products
    "triple_product_tensor",
    "complex_gaunt",
    "product",
    "product_matrix",
    "square",
    # rotation
    "rotate",
    "rotation_matrix",
    # zonal harmonics
    "zh_to_sh",
    "zh_from_sh_about_axis",
    "clamped_cosine_zh",
    "clamped_cosine_sh",
    "cap_zh",
    # windowing
    "WINDOWS",
    "window_weights",
    "window",
    # other conventions
    "CONVENTIONS",
    "to_convention",
    "from_convention",
    # exponential and logarithm
    "EXP_METHODS",
    "DEFAULT_DEGREE",
    "LOG_EPS_REL",
    "CAP_THETA_MAX",
    "OLTable",
    "LogCapTable",
    "exp",
    "log",
    "scaling_power",
    "exp_series_limit",
    "exp_volterra",
    "ol_table",
    "log_cap_table",
]


def basis(dirs, order: int, device=None) -> np.ndarray:
    """Evaluate all real SH of an order at unit directions.

    Args:
        dirs: directions, shape (..., 3); normalised before evaluation.
        order: SH order n (bands 0..n-1).
        device: None for the float64 NumPy reference, or a Warp device (``"cpu"``,
            ``"cuda:0"``) to run the float32 kernel.

    Returns:
        ``y_i(dirs)``, shape (..., n*n); float64 (reference) or float32 (Warp).
    """
    if device is None:
        return _basis_reference(dirs, order)
    order = check_order(order)
    d = unit_directions(dirs)
    batch = d.shape[:-1]
    return _basis_warp(d.reshape(-1, 3), order, device).reshape(*batch, order * order)


def _basis_warp(flat_dirs: np.ndarray, order: int, device) -> np.ndarray:
    dev = resolve_device(device)
    k = sh_kernels(order)
    dirs_wp = wp.array(flat_dirs.astype(np.float32), dtype=wp.vec3, device=dev)
    out = wp.empty((flat_dirs.shape[0], k.coeff_count), dtype=wp.float32, device=dev)
    _launch_rows(k.basis_kernel, flat_dirs.shape[0], [dirs_wp, out], {0, 1}, dev)
    return out.numpy()


def project(
    fn: Callable[[np.ndarray], np.ndarray],
    order: int,
    samples: quadrature.SphereSamples | None = None,
) -> np.ndarray:
    """Project a function on the sphere onto real SH: ``f_i = integral f(s) y_i(s) ds``.

    Args:
        fn: callable taking unit directions of shape (N, 3) and returning values of shape (N,)
            or (N, C) (C channels, e.g. RGB).
        order: SH order n.
        samples: quadrature rule; default is a Gauss-Legendre product rule exact for
            band-limited integrands up to degree ``2 * (order - 1) + 16`` (enough for smooth
            functions; pass a denser rule for functions with discontinuities).

    Returns:
        Coefficients, shape (n*n,) or (C, n*n) for multi-channel functions, float64.
    """
    order = check_order(order)
    if samples is None:
        samples = quadrature.gauss_legendre(2 * (order - 1) + 16)
    values = np.asarray(fn(samples.directions), dtype=np.float64)
    if values.shape[0] != len(samples):
        raise ValueError(
            f"project: fn returned {values.shape[0]} values for {len(samples)} directions"
        )
    y = basis(samples.directions, order)
    weighted = y * samples.weights[:, None]
    coeffs = np.tensordot(values, weighted, axes=(0, 0))  # (n*n,) or (C, n*n)
    return coeffs


# ----------------------------------------------------------------------------------------------
# Shared helpers for the SH algebra
# ----------------------------------------------------------------------------------------------

#: Largest ``max |R^T R - I|`` accepted for a rotation matrix (float32 inputs round to ~1e-7;
#: anything beyond this is not a rotation and is rejected rather than silently used).
ROTATION_TOLERANCE = 1e-5


def _device_order(order: int, name: str) -> None:
    if order > MAX_KERNEL_ORDER:
        raise ValueError(f"{name}: SH order {order} exceeds the Warp kernel maximum {MAX_KERNEL_ORDER}")


def _wp_rows(values: np.ndarray, dev):
    return wp.array(np.ascontiguousarray(values, dtype=np.float32), dtype=wp.float32, device=dev)


#: CPU launches over at least this many rows are split into one chunk per core, launched from a
#: thread pool: Warp runs a CPU launch on one thread and releases the GIL. On the 2-core
#: reference machine this is 1.2-2x faster for 10^5..10^6 rows and slower for ~10^4
#: (benchmarks/bench_sh.py, "single/chunked").
CPU_CHUNK_MIN_ROWS = 32768

def _launch_rows(kernel, count: int, inputs: list, row_args: set, dev) -> None:
    """Launch a one-thread-per-row kernel; on the CPU, chunk large launches over a thread pool
    (:func:`warpshade._wp.launch_parallel`, one chunk per core).

    ``row_args`` are the positions in ``inputs`` of arrays indexed by the thread id; they are
    sliced along their first axis per chunk (contiguous views), the others are shared.
    """

    def chunk(lo, hi):
        return [a[lo:hi] if i in row_args else a for i, a in enumerate(inputs)]

    launch_parallel(kernel, count, chunk, dev, min_count=CPU_CHUNK_MIN_ROWS, chunks=cpu_workers())


# ----------------------------------------------------------------------------------------------
# Triple products
# ----------------------------------------------------------------------------------------------


def triple_product_tensor(order: int) -> tuple[np.ndarray, np.ndarray]:
    """The SH triple product tensor ``Gamma_ijk = integral y_i(s) y_j(s) y_k(s) ds`` (sparse).

    Exact Gaunt integrals of three real SH in Sloan's sign convention: the complex Gaunt
    coefficient ``sqrt((2a+1)(2b+1)(2c+1)/4pi) (a b c; 0 0 0) (a b c; ma mb mc)`` with Wigner 3j
    symbols from Racah's formula in exact integer arithmetic, then the unitary complex -> real
    change of basis (only the final square root is rounded). The result is cached per order.

    Every nonzero ordered triple is listed (the tensor is fully symmetric), sorted by
    ``(i, j, k)``; entries allowed by the selection rules but zero by accident (e.g.
    ``(3 3 2; 2 -2 0) = 0``) are omitted. ``K`` is 10, 83, 353, 1158, 2907 for orders 2..6,
    against ``order**6`` dense entries.

    Args:
        order: SH order n (1..MAX_ORDER).

    Returns:
        ``(indices, values)``: flat coefficient indices, shape (K, 3), int64, and the integrals,
        shape (K,), float64. Both arrays are read-only (shared by the cache).
    """
    return _gaunt.real_gaunt_tensor(check_order(order))


def product(f, g, device=None) -> np.ndarray:
    """Order-n truncated SH product: the projection of ``f(s) g(s)`` onto order-n SH.

    ``(f * g)_i = sum_jk Gamma_ijk f_j g_k`` (SHEXP paper, eq. 3). The true product of two
    order-n functions has order 2n-1; to keep more of it, zero-pad the inputs to a higher order.
    The product is commutative but not associative.

    Args:
        f: SH coefficients, shape (..., n*n).
        g: SH coefficients, shape (..., n*n); batch shapes broadcast against ``f``.
        device: None for the float64 mirror; a Warp device to run the float32 kernel.

    Returns:
        Coefficients of the product, shape (broadcast batch, n*n); float64 or float32 (Warp).
    """
    fb, gb, order, batch = _gaunt.product_operands(f, g, "product")
    n2 = order * order
    if device is not None:
        _device_order(order, "product")
        return _product_warp(fb, gb, order, device).reshape(batch + (n2,))
    return _gaunt.product_rows(fb, gb, order).reshape(batch + (n2,))


def _product_warp(f: np.ndarray, g: np.ndarray, order: int, device) -> np.ndarray:
    dev = resolve_device(device)
    k = sh_kernels(order)
    count = f.shape[0]
    out = wp.empty((count, order * order), dtype=wp.float32, device=dev)
    _launch_rows(k.product_kernel, count, [_wp_rows(f, dev), _wp_rows(g, dev), k.tables(dev), out], {0, 1, 3}, dev)
    return out.numpy()


def square(f, device=None) -> np.ndarray:
    """``product(f, f)``: the order-n projection of ``f(s)**2``, shape (..., n*n)."""
    return product(f, f, device=device)


def product_matrix(f, device=None) -> np.ndarray:
    """The SH product matrix ``M_f`` with ``M_f @ g = product(f, g)`` for every g.

    ``(M_f)_ij = sum_k Gamma_ijk f_k`` (SHEXP paper, eq. 5); symmetric.

    Args:
        f: SH coefficients, shape (..., n*n).
        device: None for the float64 mirror; a Warp device to run the float32 kernel.

    Returns:
        Product matrices, shape (..., n*n, n*n); float64 or float32 (Warp).
    """
    f, order = check_coeffs(f, "product_matrix: f")
    n2 = order * order
    batch = f.shape[:-1]
    flat = f.reshape(-1, n2)
    if device is not None:
        _device_order(order, "product_matrix")
        dev = resolve_device(device)
        k = sh_kernels(order)
        out = wp.zeros((flat.shape[0], n2, n2), dtype=wp.float32, device=dev)
        _launch_rows(k.product_matrix_kernel, flat.shape[0], [_wp_rows(flat, dev), k.tables(dev), out], {0, 2}, dev)
        return out.numpy().reshape(batch + (n2, n2))
    return _gaunt.product_matrix_rows(flat, order).reshape(batch + (n2, n2))


# ----------------------------------------------------------------------------------------------
# Rotation
# ----------------------------------------------------------------------------------------------


def _rotations(rotation, name: str) -> np.ndarray:
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape[-2:] != (3, 3):
        raise ValueError(f"{name}: expected rotation matrices of shape (..., 3, 3), got {r.shape}")
    if not np.all(np.isfinite(r)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    err = np.abs(np.swapaxes(r, -1, -2) @ r - np.eye(3)).max(initial=0.0)
    if err > ROTATION_TOLERANCE:
        raise ValueError(f"{name}: not orthonormal (max |R^T R - I| = {err:.3e} > {ROTATION_TOLERANCE})")
    if r.size and np.linalg.det(r).min() <= 0.0:
        raise ValueError(f"{name}: determinant must be +1 (a reflection is not a rotation)")
    return r


def rotation_matrix(rotation, order: int) -> np.ndarray:
    """Block-diagonal SH rotation matrix ``D(R)`` with ``rotate(f, R) = D(R) @ f`` (float64).

    Built by the Ivanic-Ruedenberg recurrences (stable to high orders), conjugated by
    ``diag((-1)^|m|)`` to Sloan's sign convention. Band l is the orthogonal (2l+1)x(2l+1) block
    at rows/columns ``l*l .. l*l + 2l``; all other entries are 0.

    Args:
        rotation: proper rotation matrices, shape (..., 3, 3).
        order: SH order n.

    Returns:
        Shape (..., n*n, n*n), float64.
    """
    order = check_order(order)
    r = _rotations(rotation, "rotation_matrix: rotation")
    batch = r.shape[:-2]
    flat = r.reshape(-1, 3, 3)
    out = np.zeros((flat.shape[0], order * order, order * order))
    for l, block in enumerate(_rotation.ivanic_ruedenberg_bands(flat, order)):
        out[:, l * l : (l + 1) ** 2, l * l : (l + 1) ** 2] = block
    return out.reshape(batch + (order * order, order * order))


def rotate(f, rotation, device=None) -> np.ndarray:
    """Rotate SH functions: coefficients of ``f(R^-1 s)``, i.e. the function carried by R.

    A lobe of f pointing along ``d`` points along ``R d`` after rotation. The float64
    reference applies the Ivanic-Ruedenberg band blocks (:func:`rotation_matrix`); the Warp
    kernel uses an independent factorisation ``R = Rz(alpha) Rx(-90) Rz(beta) Rx(90) Rz(gamma)``
    (ZYZ Euler angles, constant 90-degree x-rotation blocks). Both are stable to order 10+.

    Args:
        f: SH coefficients, shape (..., n*n).
        rotation: proper rotation matrices, shape (..., 3, 3); batch shapes broadcast against f
            (one rotation for many functions, many rotations of one function, or pairs).
        device: None for the float64 mirror; a Warp device to run the float32 kernel.

    Returns:
        Rotated coefficients, shape (broadcast batch, n*n); float64 or float32 (Warp).
    """
    f, order = check_coeffs(f, "rotate: f")
    r = _rotations(rotation, "rotate: rotation")
    n2 = order * order
    batch = np.broadcast_shapes(f.shape[:-1], r.shape[:-2])
    if device is not None:
        _device_order(order, "rotate")
        fb = np.broadcast_to(f, batch + (n2,)).reshape(-1, n2)
        rb = np.broadcast_to(r, batch + (3, 3)).reshape(-1, 3, 3)
        return _rotate_warp(fb, rb, order, device).reshape(batch + (n2,))
    if r.reshape(-1, 3, 3).shape[0] == 1:  # one rotation: build the blocks once
        fb = np.broadcast_to(f, batch + (n2,))
        out = np.empty(batch + (n2,))
        for l, block in enumerate(_rotation.ivanic_ruedenberg_bands(r.reshape(1, 3, 3), order)):
            sl = slice(l * l, (l + 1) ** 2)
            out[..., sl] = fb[..., sl] @ block[0].T
        return out
    fb = np.broadcast_to(f, batch + (n2,)).reshape(-1, n2)
    rb = np.broadcast_to(r, batch + (3, 3)).reshape(-1, 3, 3)
    out = np.empty((fb.shape[0], n2))
    step = chunk_rows(8 * 4 * (2 * order - 1) ** 2)
    for s in range(0, fb.shape[0], step):
        for l, block in enumerate(_rotation.ivanic_ruedenberg_bands(rb[s : s + step], order)):
            sl = slice(l * l, (l + 1) ** 2)
            out[s : s + step, sl] = np.einsum("bij,bj->bi", block, fb[s : s + step, sl])
    return out.reshape(batch + (n2,))


def _rotate_warp(f: np.ndarray, r: np.ndarray, order: int, device) -> np.ndarray:
    dev = resolve_device(device)
    k = sh_kernels(order)
    count = f.shape[0]
    rot = wp.array(np.ascontiguousarray(r, dtype=np.float32), dtype=wp.mat33, device=dev)
    out = wp.empty((count, order * order), dtype=wp.float32, device=dev)
    _launch_rows(k.rotate_kernel, count, [_wp_rows(f, dev), rot, k.tables(dev), out], {0, 1, 3}, dev)
    return out.numpy()


# ----------------------------------------------------------------------------------------------
# Zonal harmonics
# ----------------------------------------------------------------------------------------------


def zh_to_sh(axis, zh_coeffs, device=None) -> np.ndarray:
    """SH coefficients of a zonal (circularly symmetric) function rotated onto ``axis``.

    A zonal function about +z is ``g(s) = sum_l g_l y_l0(s)``, ``g_l`` its ZH coefficients
    (the m = 0 SH coefficients, e.g. :func:`cap_zh`). Rotated so that +z maps to ``axis`` its SH
    coefficients are ``f_lm = sqrt(4 pi / (2l + 1)) * g_l * y_lm(axis)`` (Sloan et al. 2005,
    eq. 6). A delta function at ``axis`` has ``g_l = sqrt((2l + 1) / (4 pi))``.

    Args:
        axis: lobe axes, shape (..., 3); normalised here (zero length is an error).
        zh_coeffs: ZH coefficients ``g_l``, shape (..., n); batch shapes broadcast against axis.
        device: None for the float64 mirror; a Warp device to run the float32 kernel.

    Returns:
        Shape (broadcast batch, n*n); float64 or float32 (Warp).
    """
    a = unit_directions(axis, "zh_to_sh: axis")
    zh = np.asarray(zh_coeffs, dtype=np.float64)
    if zh.ndim < 1 or zh.shape[-1] < 1:
        raise ValueError(f"zh_to_sh: zh_coeffs must have shape (..., order), got {zh.shape}")
    order = check_order(zh.shape[-1])
    if not np.all(np.isfinite(zh)):
        raise ValueError("zh_to_sh: zh_coeffs contains NaN or infinite values")
    n2 = order * order
    batch = np.broadcast_shapes(a.shape[:-1], zh.shape[:-1])
    if device is not None:
        _device_order(order, "zh_to_sh")
        dev = resolve_device(device)
        k = sh_kernels(order)
        ab = np.broadcast_to(a, batch + (3,)).reshape(-1, 3)
        zb = np.broadcast_to(zh, batch + (order,)).reshape(-1, order)
        out = wp.empty((ab.shape[0], n2), dtype=wp.float32, device=dev)
        axes = wp.array(ab.astype(np.float32), dtype=wp.vec3, device=dev)
        _launch_rows(k.zh_to_sh_kernel, ab.shape[0], [axes, _wp_rows(zb, dev), out], {0, 1, 2}, dev)
        return out.numpy().reshape(batch + (n2,))
    scaled = (zh * band_scale(order))[..., band_of(order)]
    return np.broadcast_to(basis(a, order) * scaled, batch + (n2,)).copy()


def zh_from_sh_about_axis(f, axis, device=None) -> np.ndarray:
    """Project SH functions onto the zonal functions about an axis (the inverse of zh_to_sh).

    Returns the ZH coefficients ``g_l`` of the best L2 approximation of f by a function that is
    circularly symmetric about ``axis``:
    ``g_l = sqrt(4 pi / (2l + 1)) * sum_m f_lm y_lm(axis)``. The zonal function of band l about
    ``axis`` is ``sqrt(4 pi / (2l + 1)) sum_m y_lm(axis) y_lm(s)`` (addition theorem), which has
    unit norm, so this is the orthogonal projection, and
    ``zh_from_sh_about_axis(zh_to_sh(a, g), a) == g``. ``g_l`` is also the m = 0 coefficient
    of f rotated so that ``axis`` maps to +z.

    Args:
        f: SH coefficients, shape (..., n*n).
        axis: unit axes, shape (..., 3) (normalised here); batch shapes broadcast against f.
        device: None for the float64 mirror; a Warp device to run the float32 kernel.

    Returns:
        ZH coefficients, shape (broadcast batch, n); float64 or float32 (Warp).
    """
    f, order = check_coeffs(f, "zh_from_sh_about_axis: f")
    a = unit_directions(axis, "zh_from_sh_about_axis: axis")
    n2 = order * order
    batch = np.broadcast_shapes(f.shape[:-1], a.shape[:-1])
    if device is not None:
        _device_order(order, "zh_from_sh_about_axis")
        dev = resolve_device(device)
        k = sh_kernels(order)
        fb = np.broadcast_to(f, batch + (n2,)).reshape(-1, n2)
        ab = np.broadcast_to(a, batch + (3,)).reshape(-1, 3)
        out = wp.empty((fb.shape[0], order), dtype=wp.float32, device=dev)
        axes = wp.array(ab.astype(np.float32), dtype=wp.vec3, device=dev)
        _launch_rows(k.zh_from_sh_kernel, fb.shape[0], [_wp_rows(fb, dev), axes, out], {0, 1, 2}, dev)
        return out.numpy().reshape(batch + (order,))
    terms = np.broadcast_to(f * basis(a, order), batch + (n2,))
    band_starts = np.arange(order) ** 2
    return np.add.reduceat(terms, band_starts, axis=-1) * band_scale(order)


def clamped_cosine_zh(order: int, normalization: str = "convolution") -> np.ndarray:
    """Per-band coefficients of the clamped cosine ``max(cos theta, 0)`` about +z.

    Two normalisations are in use in the literature; both are available:

    * ``"convolution"`` (default): ``A_l = sqrt(4 pi / (2l + 1)) * g_l`` =
      pi, 2pi/3, pi/4, 0, -pi/24, 0, pi/64, ... (Ramamoorthi & Hanrahan's irradiance factors,
      Sloan et al.'s ``g*_l``). Irradiance at normal n from radiance coefficients ``L_lm`` is
      ``E(n) = integral L(s) max(n.s, 0) ds = sum_lm A_l L_lm y_lm(n)``, i.e. convolution:
      ``E = basis(n, order) @ (A[band_of(order)] * L)``. For odd l > 1, ``A_l = 0``; for even
      l, ``A_l = 2 pi (-1)^(l/2 - 1) / ((l + 2)(l - 1)) * binom(l, l/2) / 2^l``.
    * ``"zh"``: the ZH coefficients ``g_l = integral max(z, 0) y_l0(s) ds`` (the same
      normalisation as :func:`cap_zh`, suitable for :func:`zh_to_sh`):
      sqrt(pi)/2, sqrt(pi/3), sqrt(5 pi)/8, 0, ...

    Args:
        order: SH order n.
        normalization: ``"convolution"`` or ``"zh"``.

    Returns:
        Shape (n,), float64.
    """
    order = check_order(order)
    if normalization not in ("convolution", "zh"):
        raise ValueError(f"clamped_cosine_zh: normalization must be 'convolution' or 'zh', got {normalization!r}")
    conv = np.zeros(order)
    for l in range(order):
        if l == 0:
            conv[l] = np.pi
        elif l == 1:
            conv[l] = 2.0 * np.pi / 3.0
        elif l % 2 == 0:
            sign = -1.0 if (l // 2 - 1) % 2 else 1.0
            conv[l] = 2.0 * np.pi * sign / ((l + 2) * (l - 1)) * math.comb(l, l // 2) / 2.0**l
    if normalization == "zh":
        return conv / band_scale(order)
    return conv


def clamped_cosine_sh(order: int) -> np.ndarray:
    """SH coefficients of the clamped cosine ``max(s_z, 0)`` about +z (the local normal).

    The zonal coefficients ``g_l`` of :func:`clamped_cosine_zh` (``normalization="zh"``) at the
    ``m = 0`` slots ``i = l*l + l``, zero elsewhere; its product matrix (:func:`product_matrix`) is
    the ``C`` that turns local visibility into local diffuse transfer.

    Args:
        order: SH order n.

    Returns:
        Shape (n*n,), float64.
    """
    zh = clamped_cosine_zh(order, normalization="zh")
    out = np.zeros(zh.size * zh.size)
    out[[l * l + l for l in range(zh.size)]] = zh
    return out


# ----------------------------------------------------------------------------------------------
# Windowing
# ----------------------------------------------------------------------------------------------

#: Window kinds accepted by :func:`window` / :func:`window_weights`.
WINDOWS = ("cosine", "hanning", "lanczos", "gaussian")


def window_weights(kind: str, order: int, size: float | None = None, strength: float | None = None) -> np.ndarray:
    """Per-band attenuation factors ``alpha_l`` of a frequency-space window, shape (n,), float64.

    Kinds (``h`` = ``size``, the band at which the window reaches 0; ``alpha_l = 0`` for l >= h):

    * ``"cosine"``: ``alpha_l = cos(pi/2 * l/h)``, default ``h = 2n`` (SHEXP paper, sec. 7;
      smaller h windows more strongly);
    * ``"hanning"``: ``alpha_l = (1 + cos(pi l/h)) / 2``, default ``h = n``;
    * ``"lanczos"``: ``alpha_l = sin(pi l/h) / (pi l/h)`` (``alpha_0 = 1``), default ``h = n``;
    * ``"gaussian"``: ``alpha_l = exp(-strength * l (l + 1))`` (heat-kernel smoothing; no size),
      ``strength >= 0`` required.
    """
    order = check_order(order)
    if kind not in WINDOWS:
        raise ValueError(f"window: kind must be one of {WINDOWS}, got {kind!r}")
    l = np.arange(order, dtype=np.float64)
    if kind == "gaussian":
        if strength is None or not np.isfinite(strength) or strength < 0.0:
            raise ValueError(f"window: 'gaussian' needs strength >= 0, got {strength!r}")
        return np.exp(-float(strength) * l * (l + 1.0))
    if strength is not None:
        raise ValueError(f"window: 'strength' applies to the 'gaussian' window only, not {kind!r}")
    h = float(2 * order if kind == "cosine" else order) if size is None else float(size)
    if not np.isfinite(h) or h <= 0.0:
        raise ValueError(f"window: size must be > 0, got {size!r}")
    x = l / h
    if kind == "cosine":
        alpha = np.cos(0.5 * np.pi * x)
    elif kind == "hanning":
        alpha = 0.5 * (1.0 + np.cos(np.pi * x))
    else:
        alpha = np.sinc(x)  # numpy sinc is sin(pi x) / (pi x)
    return np.where(x < 1.0, alpha, 0.0)


def window(coeffs, kind: str, *, size: float | None = None, strength: float | None = None) -> np.ndarray:
    """Apply a frequency-space window to SH coefficients: ``f_lm * alpha_l``.

    Windowing attenuates high bands to reduce ringing (Gibbs oscillation) of band-limited
    reconstructions; see :func:`window_weights` for the kinds and their parameters.

    Args:
        coeffs: SH coefficients, shape (..., n*n).
        kind: one of :data:`WINDOWS`.
        size: window size h in bands (cosine, hanning, lanczos).
        strength: smoothing strength (gaussian).

    Returns:
        Windowed coefficients, shape (..., n*n), float64.
    """
    f, order = check_coeffs(coeffs, "window: coeffs")
    return f * window_weights(kind, order, size=size, strength=strength)[band_of(order)]


# ----------------------------------------------------------------------------------------------
# Other conventions
# ----------------------------------------------------------------------------------------------

#: Conventions accepted by :func:`to_convention` / :func:`from_convention`.
CONVENTIONS = _conventions.CONVENTIONS


def to_convention(coeffs, convention: str, *, normalization: str = "4pi", csphase: int = 1) -> np.ndarray:
    """Convert warpshade SH coefficients into another public convention.

    All conventions describe the same function ``f(s) = sum_i f_i y_i(s)``:

    * ``"sloan"``: warpshade's own (a copy).
    * ``"real_no_cs"``: real orthonormal SH *without* the Condon-Shortley phase
      (``y(1,1) = +0.488603 x``; e.g. the Ivanic-Ruedenberg, e3nn-style sign choice, same
      index order ``l*l + l + m``): coefficient ``(-1)^|m| f_lm``. Self-inverse.
    * ``"complex"``: complex orthonormal SH with the Condon-Shortley phase, as
      ``scipy.special.sph_harm_y(l, m, theta, phi)``: ``f = sum c_lm Y_l^m``, complex
      coefficients at index ``l*l + l + m`` (``c_l,-m = (-1)^m conj(c_lm)`` for real f).
    * ``"shtools"``: SHTOOLS real arrays ``cilm`` of shape (..., 2, n, n): ``cilm[0, l, m]``
      multiplies ``N_lm P_lm(cos theta) cos(m phi)``, ``cilm[1, l, m]`` multiplies
      ``N_lm P_lm(cos theta) sin(m phi)`` (m >= 1), entries with m > l are 0.
      ``normalization``: ``"4pi"`` (``integral Y^2 = 4 pi``, SHTOOLS default), ``"ortho"``
      (``= 1``), ``"schmidt"`` (``= 4 pi / (2l+1)``), ``"unnorm"`` (``N_lm = 1``);
      ``csphase``: 1 (no Condon-Shortley phase in ``P_lm``, SHTOOLS default) or -1 (with it).

    Args:
        coeffs: warpshade coefficients, shape (..., n*n).
        convention: one of :data:`CONVENTIONS`.
        normalization: SHTOOLS normalisation (``"shtools"`` only).
        csphase: SHTOOLS Condon-Shortley phase flag (``"shtools"`` only).

    Returns:
        float64 (..., n*n) for ``"sloan"``/``"real_no_cs"``, complex128 (..., n*n) for
        ``"complex"``, float64 (..., 2, n, n) for ``"shtools"``.
    """
    check_coeffs(coeffs, "to_convention: coeffs")
    return _conventions.to_convention(coeffs, convention, normalization=normalization, csphase=csphase)


def from_convention(coeffs, convention: str, *, normalization: str = "4pi", csphase: int = 1) -> np.ndarray:
    """Convert coefficients from another public convention into warpshade's (inverse of
    :func:`to_convention`; see there for the conventions).

    For ``"complex"`` the input must describe a real function (``c_l,-m = (-1)^m conj(c_lm)``
    within a relative 1e-6); otherwise ValueError. For ``"shtools"`` the input has shape
    (..., 2, n, n) and the order is n.

    Returns:
        warpshade coefficients, shape (..., n*n), float64.
    """
    return _conventions.from_convention(coeffs, convention, normalization=normalization, csphase=csphase)


# ----------------------------------------------------------------------------------------------
# Exponential and logarithm (SHEXP paper, sections 4-5)
# ----------------------------------------------------------------------------------------------

#: SH exponential methods: product series, DC-isolated scaled/squared factored series, optimal
#: linear, hybrid (scaling/squaring around optimal linear).
EXP_METHODS = _shexp.EXP_METHODS
#: Default eigenvalue clipping of :func:`log`, relative to the largest eigenvalue.
LOG_EPS_REL = _shexp.LOG_EPS_REL


def exp(f, method: str = "ps_star", degree: int | None = None, device=None) -> np.ndarray:
    """SH exponential: an order-n approximation of the projection of ``exp(f(s))``.

    Methods (Ren et al. 2006, sec. 4; ``1`` = constant function, ``f^`` = f without DC):

    * ``"ps"`` -- PS-p, the product series ``1 + f + f^2*/2! + ... + f^p*/p!`` with the powers
      amassed left to right by order-n truncated products (eq. 17); diverges in float for large
      ``||f||`` at fixed p;
    * ``"ps_star"`` -- PS*-p: ``exp(f_0/sqrt(4 pi))`` times the degree-p even/odd factored
      series (eq. 22) of ``f^ / 2^s``, squared s times with ``s = max(0, floor(log2||f^|| + 3))``
      (eqs. 20-21);
    * ``"ol"`` -- optimal linear ``exp(f_0/sqrt(4 pi)) (a(||f^||) 1 + b(||f^||) f^)`` with the
      tables of :func:`ol_table` (eqs. 23-24); accurate while ``||f^||`` stays in the range
      where blocker models agree (about 4.8 at n = 4), clamped to the table's last entries
      beyond it;
    * ``"hyb"`` -- OL inside the scaling/squaring of PS* (same s).

    Args:
        f: SH coefficients, shape (..., n*n), finite.
        method: one of :data:`EXP_METHODS`.
        degree: series degree p for ``"ps"`` (default 10) and ``"ps_star"`` (default 2),
            1..40; ignored by ``"ol"``/``"hyb"``.
        device: None for the float64 mirror; a Warp device to run the float32 kernel.

    Returns:
        exp(f), shape (..., n*n); float64 or float32 (Warp).
    """
    f, order = check_coeffs(f, "exp: f")
    degree = _shexp.check_degree(method, degree)
    n2 = order * order
    batch = f.shape[:-1]
    flat = f.reshape(-1, n2)
    if device is not None:
        _device_order(order, "exp")
        dev = resolve_device(device)
        k = sh_kernels(order)
        out = wp.empty((flat.shape[0], n2), dtype=wp.float32, device=dev)
        _launch_rows(
            _shexp_kernels.exp_kernel(order, method), flat.shape[0],
            [_wp_rows(flat, dev), degree, k.tables(dev), k.exp_tables(dev), out], {0, 4}, dev,
        )
        return out.numpy().reshape(batch + (n2,))
    return _shexp.exp_f64(flat, method, degree).reshape(batch + (n2,))


def log(g, eps_rel: float = LOG_EPS_REL, device=None) -> np.ndarray:
    """SH logarithm by eigen-inversion of the product matrix (Ren et al. 2006, eqs. 27-32).

    ``log(g) = R^T q'(D~) R (g - 1)`` with ``M_g = R^T D R`` the product matrix of g,
    ``D~ = max(D, eps_rel * max(D))`` (eigenvalue clipping) and ``q'(x) = log(x) / (x - 1)``.
    It inverts the infinite product series exp* (so ``exp(log(g))`` undoes truncation better
    than projecting ``log(g(s))``), and clipping eigenvalues rather than sampled values of g
    adds no artificial high frequencies.

    Args:
        g: SH coefficients of a positive-ish function (visibility), shape (..., n*n), finite.
        eps_rel: clipping threshold relative to the largest eigenvalue, in (0, 1).
        device: None for the float64 mirror (``numpy.linalg.eigh``); a Warp device to run
            the float32 kernel (cyclic Jacobi; ``O(n^6)`` per row, for tables and checks).

    Returns:
        log(g), shape (..., n*n); float64 or float32 (Warp).

    Raises:
        ValueError: non-finite input, ``eps_rel`` outside (0, 1), or (float64 path) a row whose
            product matrix has no positive eigenvalue.
    """
    g, order = check_coeffs(g, "log: g")
    if not (isinstance(eps_rel, (int, float)) and np.isfinite(eps_rel) and 0.0 < eps_rel < 1.0):
        raise ValueError(f"log: eps_rel must be in (0, 1), got {eps_rel!r}")
    n2 = order * order
    batch = g.shape[:-1]
    flat = g.reshape(-1, n2)
    if device is not None:
        _device_order(order, "log")
        dev = resolve_device(device)
        k = sh_kernels(order)
        out = wp.empty((flat.shape[0], n2), dtype=wp.float32, device=dev)
        _launch_rows(
            _shexp_kernels.log_kernel(order), flat.shape[0],
            [_wp_rows(flat, dev), float(eps_rel), k.tables(dev), out], {0, 3}, dev,
        )
        return out.numpy().reshape(batch + (n2,))
    return _shexp.log_f64(flat, float(eps_rel)).reshape(batch + (n2,))


def exp_series_limit(f) -> np.ndarray:
    """The product series exp*(f) summed to infinite degree (eq. 28), float64, (..., n*n).

    ``1 + R^T q(D) R f`` with ``M_f = R^T D R``, ``q(x) = (e^x - 1)/x``: what PS-p converges to
    as p grows. An oracle for the run-time methods.
    """
    f, order = check_coeffs(f, "exp_series_limit: f")
    n2 = order * order
    return _shexp.exp_series_limit(f.reshape(-1, n2)).reshape(f.shape)


def exp_volterra(f, quadrature_degree: int | None = None) -> np.ndarray:
    """The projection of ``exp(f(s))`` by quadrature (eq. 10, no product truncation), float64."""
    f, order = check_coeffs(f, "exp_volterra: f")
    n2 = order * order
    return _shexp.exp_volterra(f.reshape(-1, n2), quadrature_degree).reshape(f.shape)


def ol_table(order: int, samples: int = _shexp.TABLE_SAMPLES) -> OLTable:
    """The optimal-linear a/b table of an order (built once and cached): :class:`OLTable`."""
    return _shexp.ol_table(check_order(order), samples)


def log_cap_table(order: int, samples: int = _shexp.TABLE_SAMPLES) -> LogCapTable:
    """The blocking-cap log visibility table of an order (built once and cached):
    :class:`LogCapTable` (ZH coefficients over the cap radius)."""
    return _shexp.log_cap_table(check_order(order), samples)
