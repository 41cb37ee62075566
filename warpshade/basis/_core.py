"""Float64 SH building blocks shared by every other basis module (private; bottom layer).

Imports no other module of :mod:`warpshade.basis`: :mod:`~warpshade.basis._gaunt`,
:mod:`~warpshade.basis._rotation`, :mod:`~warpshade.basis._shexp`, :mod:`~warpshade.basis._zh_fit`
and the public facades :mod:`~warpshade.basis.sh` / :mod:`~warpshade.basis.zh` build on it. The
public names (``MAX_ORDER``, ``coeff_count``, ``index``, ``band_of``, ``cap_zh``) are re-exported
by :mod:`warpshade.basis.sh`; :func:`basis` here is the float64 mirror behind
:func:`warpshade.basis.sh.basis` (which adds the Warp path).

Convention (see :mod:`warpshade.basis.sh`): real, orthonormal SH in Sloan's sign convention,
coefficient index ``l*l + l + m``, "order n" = bands ``0..n-1`` = ``n*n`` coefficients.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "MAX_ORDER",
    "coeff_count",
    "index",
    "band_of",
    "check_order",
    "unit_directions",
    "check_coeffs",
    "band_scale",
    "chunk_rows",
    "basis",
    "cap_zh",
]

#: Highest SH order supported by the float64 mirror.
MAX_ORDER = 16

# Rows processed at once by the float64 mirrors (bounds temporaries to ~32 MB).
_REFERENCE_CHUNK_BYTES = 32 * 1024 * 1024


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


def check_order(order: int, limit: int = MAX_ORDER) -> int:
    """Validate an SH order (an integer in 1..limit) and return it as an int."""
    if not isinstance(order, (int, np.integer)) or not 1 <= int(order) <= limit:
        raise ValueError(f"SH order must be an integer in 1..{limit}, got {order!r}")
    return int(order)


def unit_directions(dirs, name: str = "dirs") -> np.ndarray:
    """Validate directions of shape (..., 3) (finite, nonzero) and normalise them, float64."""
    d = np.asarray(dirs, dtype=np.float64)
    if d.shape[-1:] != (3,):
        raise ValueError(f"{name}: expected shape (..., 3), got {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    if np.any(norm == 0.0):
        raise ValueError(f"{name}: contains zero-length directions")
    return d / norm


def check_coeffs(values, name: str, limit: int = MAX_ORDER) -> tuple[np.ndarray, int]:
    """Validate SH coefficients of shape (..., n*n); return them as float64 and the order n."""
    f = np.asarray(values, dtype=np.float64)
    if f.ndim < 1:
        raise ValueError(f"{name}: expected shape (..., order**2), got a scalar")
    order = int(round(math.sqrt(f.shape[-1])))
    if order < 1 or order * order != f.shape[-1]:
        raise ValueError(f"{name}: last axis must hold order**2 coefficients, got {f.shape[-1]}")
    if order > limit:
        raise ValueError(f"{name}: SH order {order} exceeds the supported maximum {limit}")
    if not np.all(np.isfinite(f)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    return f, order


def band_scale(order: int) -> np.ndarray:
    """``sqrt(4 pi / (2l + 1))`` for l = 0..order-1, shape (order,), float64."""
    l = np.arange(order, dtype=np.float64)
    return np.sqrt(4.0 * np.pi / (2.0 * l + 1.0))


def chunk_rows(row_bytes: int) -> int:
    """Rows per chunk of a float64 mirror loop whose temporaries take ``row_bytes`` per row."""
    return max(1, _REFERENCE_CHUNK_BYTES // max(1, row_bytes))


def basis(dirs, order: int) -> np.ndarray:
    """All real SH of an order at directions, float64 mirror.

    Args:
        dirs: directions, shape (..., 3); normalised before evaluation.
        order: SH order n (bands 0..n-1), 1..MAX_ORDER.

    Returns:
        ``y_i(dirs)``, shape (..., n*n), float64.
    """
    order = check_order(order)
    d = unit_directions(dirs)
    batch = d.shape[:-1]
    flat = d.reshape(-1, 3)
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


def cap_zh(theta, order: int, blocked: bool = False) -> np.ndarray:
    """ZH coefficients of the indicator of a spherical cap of half-angle theta about +z.

    ``g_l = integral_{cap} y_l0(s) ds = 2 pi sqrt((2l+1)/(4 pi)) integral_{cos theta}^1 P_l(z) dz``,
    in closed form ``g_0 = sqrt(pi) (1 - cos theta)`` and
    ``g_l = sqrt(pi / (2l + 1)) (P_{l-1}(cos theta) - P_{l+1}(cos theta))`` for l >= 1. With
    ``blocked=True`` the result is the visibility of a blocker covering the cap (1 outside,
    0 inside; SHEXP paper eq. 33): ``sqrt(4 pi) delta_l0 - g_l``. Rotate onto any axis with
    :func:`warpshade.basis.sh.zh_to_sh`.

    Args:
        theta: cap half-angle(s) in radians, in [0, pi]; scalar or shape (...,).
        order: SH order n.
        blocked: return the blocker visibility instead of the cap indicator.

    Returns:
        Shape (..., n), float64 (shape (n,) for a scalar theta).
    """
    order = check_order(order)
    t = np.asarray(theta, dtype=np.float64)
    if not np.all(np.isfinite(t)) or np.any(t < 0.0) or np.any(t > np.pi):
        raise ValueError("cap_zh: theta must be finite and in [0, pi] radians")
    c = np.cos(t)
    legendre = [np.ones_like(c), c]
    for l in range(1, order):  # P_{l+1} = ((2l+1) c P_l - l P_{l-1}) / (l+1)
        legendre.append(((2 * l + 1) * c * legendre[l] - l * legendre[l - 1]) / (l + 1))
    out = np.empty(t.shape + (order,))
    out[..., 0] = np.sqrt(np.pi) * (1.0 - c)
    for l in range(1, order):
        out[..., l] = np.sqrt(np.pi / (2 * l + 1)) * (legendre[l - 1] - legendre[l + 1])
    if blocked:
        out = -out
        out[..., 0] += np.sqrt(4.0 * np.pi)
    return out
