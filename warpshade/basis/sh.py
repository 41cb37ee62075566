"""Real spherical harmonics: evaluation, projection and the SH algebra.

Convention (used everywhere in warpshade):

* real, orthonormal on the unit sphere: ``integral y_i(s) y_j(s) ds = delta_ij``;
* coefficient index ``i = l*l + l + m`` for band ``l >= 0`` and ``-l <= m <= l``;
* the sign convention of Sloan's "Stupid SH Tricks", i.e. real SH built from complex SH
  *with* the Condon-Shortley phase: ``y(1,-1) = -0.488603 y``, ``y(1,0) = 0.488603 z``,
  ``y(1,1) = -0.488603 x``; for ``m > 0``, ``y_lm = sqrt(2) Re Y_l^m`` and
  ``y_l,-m = sqrt(2) Im Y_l^m`` with ``Y_l^m`` the complex SH of ``scipy.special.sph_harm_y``;
* "order n" means bands ``l = 0..n-1``, i.e. ``n*n`` coefficients (the papers' usage).

Host functions accept NumPy arrays with any leading batch shape and return NumPy arrays. By
default they run the float64 reference path (the oracle); functions with a ``device`` argument
run the float32 Warp kernel on that device instead (``device="cpu"`` or ``"cuda:0"``). The same
operations exist as ``@wp.func`` for use inside other kernels: see
:func:`warpshade.basis.sh_warp.sh_kernels`.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from . import quadrature

__all__ = [
    "MAX_ORDER",
    "coeff_count",
    "index",
    "band_of",
    "basis",
    "project",
]

#: Highest SH order supported by the float64 reference path.
MAX_ORDER = 16


def coeff_count(order: int) -> int:
    """Number of coefficients of an order-``order`` SH expansion (``order**2``)."""
    return order * order


def index(l: int, m: int) -> int:
    """Flat coefficient index of band ``l``, degree ``m`` (``l*l + l + m``)."""
    if abs(m) > l:
        raise ValueError(f"index: need |m| <= l, got l={l}, m={m}")
    return l * l + l + m


def band_of(order: int) -> np.ndarray:
    """Band ``l`` of every coefficient of an order-``order`` expansion, shape (order**2,), int."""
    return np.concatenate([np.full(2 * l + 1, l) for l in range(order)]).astype(np.int64)


def _check_order(order: int, limit: int = MAX_ORDER) -> int:
    if not isinstance(order, (int, np.integer)) or not 1 <= int(order) <= limit:
        raise ValueError(f"SH order must be an integer in 1..{limit}, got {order!r}")
    return int(order)


def _unit_directions(dirs, name: str = "dirs") -> np.ndarray:
    d = np.asarray(dirs, dtype=np.float64)
    if d.shape[-1:] != (3,):
        raise ValueError(f"{name}: expected shape (..., 3), got {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    if np.any(norm == 0.0):
        raise ValueError(f"{name}: contains zero-length directions")
    return d / norm


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
    order = _check_order(order)
    d = _unit_directions(dirs)
    batch = d.shape[:-1]
    flat = d.reshape(-1, 3)
    if device is not None:
        return _basis_warp(flat, order, device).reshape(*batch, order * order)
    x, y, z = flat[:, 0], flat[:, 1], flat[:, 2]
    out = np.empty((flat.shape[0], order * order), dtype=np.float64)
    # Orthonormal associated Legendre recurrences; (x + i y)^m carries sin^m(theta) e^{i m phi}.
    c = np.ones_like(x)
    s = np.zeros_like(x)
    pmm = np.full_like(x, 0.5 / np.sqrt(np.pi))
    sqrt2 = np.sqrt(2.0)
    for m in range(order):
        if m > 0:
            pmm = -np.sqrt((2.0 * m + 1.0) / (2.0 * m)) * pmm
        p_prev = np.zeros_like(x)
        p_cur = pmm
        for l in range(m, order):
            if l == m + 1:
                p_prev, p_cur = p_cur, np.sqrt(2.0 * m + 3.0) * z * pmm
            elif l > m + 1:
                a = np.sqrt((4.0 * l * l - 1.0) / (l * l - m * m))
                b = np.sqrt(((l - 1.0) ** 2 - m * m) / (4.0 * (l - 1.0) ** 2 - 1.0))
                p_prev, p_cur = p_cur, a * (z * p_cur - b * p_prev)
            if m == 0:
                out[:, l * l + l] = p_cur
            else:
                out[:, l * l + l + m] = sqrt2 * p_cur * c
                out[:, l * l + l - m] = sqrt2 * p_cur * s
        c, s = c * x - s * y, c * y + s * x
    return out.reshape(*batch, order * order)


def _basis_warp(flat_dirs: np.ndarray, order: int, device) -> np.ndarray:
    from .._wp import resolve_device, wp
    from .sh_warp import sh_kernels

    dev = resolve_device(device)
    k = sh_kernels(order)
    dirs_wp = wp.array(flat_dirs.astype(np.float32), dtype=wp.vec3, device=dev)
    out = wp.empty((flat_dirs.shape[0], k.coeff_count), dtype=wp.float32, device=dev)
    wp.launch(k.basis_kernel, dim=flat_dirs.shape[0], inputs=[dirs_wp, out], device=dev)
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
    order = _check_order(order)
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
