"""Exact Gaunt integrals of three real SH and the float64 products over them (private).

Builds on :mod:`warpshade.basis._core` only; :mod:`warpshade.basis.sh` (``triple_product_tensor``,
``product``, ``product_matrix``), :mod:`warpshade.basis._shexp` and
:mod:`warpshade.basis.sh_warp` (the Warp product tables) build on it.

The complex Gaunt coefficient

    integral Y_a^ma Y_b^mb Y_c^mc ds
        = sqrt((2a+1)(2b+1)(2c+1) / (4 pi)) * (a b c; 0 0 0) * (a b c; ma mb mc)

is built from two Wigner 3j symbols evaluated by Racah's closed formula in exact integer
arithmetic: each 3j symbol is ``rational * sqrt(rational)``, so the Gaunt coefficient is
``rational * sqrt(rational) / sqrt(4 pi)`` and only the last square root and the division by
``sqrt(4 pi)`` are rounded. The real Gaunt coefficient follows from the unitary complex -> real
change of basis of :func:`real_from_complex_matrix` (Sloan's sign convention, i.e. real SH
built from complex SH *with* the Condon-Shortley phase).

The order-n truncated product ``(f * g)_i = sum_jk Gamma_ijk f_j g_k`` and the product matrix
``(M_f)_ij = sum_k Gamma_ijk f_k`` (SHEXP paper, eqs. 3 and 5) are evaluated here in float64
from the sparse tensor: :func:`product` and :func:`product_matrix` (validated, any batch shape)
over the row kernels :func:`product_rows` and :func:`product_matrix_rows`.
"""

from __future__ import annotations

import functools
import math
from fractions import Fraction

import numpy as np

from ._core import check_coeffs, chunk_rows

__all__ = [
    "wigner_3j_exact",
    "complex_gaunt",
    "real_from_complex_matrix",
    "real_gaunt_tensor",
    "product_operands",
    "product_rows",
    "product",
    "product_matrix_rows",
    "product_matrix",
]


@functools.lru_cache(maxsize=None)
def _factorial(k: int) -> int:
    return math.factorial(k)


@functools.lru_cache(maxsize=None)
def wigner_3j_exact(a: int, b: int, c: int, ma: int, mb: int, mc: int) -> tuple[Fraction, Fraction]:
    """Wigner 3j symbol ``(a b c; ma mb mc)`` for integer arguments, exactly.

    Racah's formula: ``(-1)^(a-b-mc) sqrt(Delta(abc) prod (j +- m)!) sum_k (-1)^k / (...)``.

    Returns:
        ``(s, q)`` with the symbol equal to ``s * sqrt(q)``; ``s`` and ``q >= 0`` are Fractions
        (``(0, 0)`` when a selection rule makes the symbol vanish).
    """
    if ma + mb + mc != 0 or abs(ma) > a or abs(mb) > b or abs(mc) > c:
        return Fraction(0), Fraction(0)
    if c > a + b or c < abs(a - b):
        return Fraction(0), Fraction(0)
    f = _factorial
    delta = Fraction(f(a + b - c) * f(a - b + c) * f(-a + b + c), f(a + b + c + 1))
    q = delta * (f(a + ma) * f(a - ma) * f(b + mb) * f(b - mb) * f(c + mc) * f(c - mc))
    k_min = max(0, b - c - ma, a - c + mb)
    k_max = min(a + b - c, a - ma, b + mb)
    total = Fraction(0)
    for k in range(k_min, k_max + 1):
        den = (
            f(k) * f(c - b + k + ma) * f(c - a + k - mb) * f(a + b - c - k) * f(a - k - ma) * f(b - k + mb)
        )
        total += Fraction(-1 if k % 2 else 1, den)
    sign = -1 if (a - b - mc) % 2 else 1
    return sign * total, q


@functools.lru_cache(maxsize=None)
def complex_gaunt(a: int, b: int, c: int, ma: int, mb: int, mc: int) -> float:
    """``integral Y_a^ma Y_b^mb Y_c^mc ds`` of complex SH with the Condon-Shortley phase.

    Exact up to the final square root and the division by ``sqrt(4 pi)`` (float64).
    """
    if (a + b + c) % 2 or ma + mb + mc != 0:
        return 0.0
    s0, q0 = wigner_3j_exact(a, b, c, 0, 0, 0)
    s1, q1 = wigner_3j_exact(a, b, c, ma, mb, mc)
    s = s0 * s1
    if s == 0:
        return 0.0
    q = q0 * q1 * ((2 * a + 1) * (2 * b + 1) * (2 * c + 1))
    # sqrt of a Fraction: isqrt-free float path, accurate to ~1 ulp for these magnitudes.
    root = math.sqrt(q.numerator) / math.sqrt(q.denominator)
    return float(s) * root / math.sqrt(4.0 * math.pi)


@functools.lru_cache(maxsize=None)
def real_from_complex_matrix(l: int) -> np.ndarray:
    """Unitary U with ``y_lm = sum_m' U[m, m'] Y_l^m'`` (rows/columns indexed ``m + l``).

    Sloan's real SH: ``y_l0 = Y_l^0``; for ``m > 0``,
    ``y_lm = (Y_l^m + (-1)^m Y_l^-m) / sqrt(2)`` (= sqrt(2) Re Y_l^m) and
    ``y_l,-m = -i (Y_l^m - (-1)^m Y_l^-m) / sqrt(2)`` (= sqrt(2) Im Y_l^m).
    """
    u = np.zeros((2 * l + 1, 2 * l + 1), dtype=np.complex128)
    u[l, l] = 1.0
    r = 1.0 / math.sqrt(2.0)
    for m in range(1, l + 1):
        sgn = -1.0 if m % 2 else 1.0
        u[l + m, l + m] = r
        u[l + m, l - m] = sgn * r
        u[l - m, l + m] = -1j * r
        u[l - m, l - m] = 1j * sgn * r
    u.setflags(write=False)
    return u


def _real_gaunt_block(a: int, b: int, c: int, mu_a: int, mu_b: int, mu_c: int) -> float:
    """``integral y_a,mu_a y_b,mu_b y_c,mu_c ds`` for Sloan real SH (float64)."""
    ua, ub, uc = real_from_complex_matrix(a), real_from_complex_matrix(b), real_from_complex_matrix(c)
    total = 0.0 + 0.0j
    for ma in {mu_a, -mu_a}:
        for mb in {mu_b, -mu_b}:
            mc = -ma - mb
            if abs(mc) != abs(mu_c):
                continue
            coef = ua[mu_a + a, ma + a] * ub[mu_b + b, mb + b] * uc[mu_c + c, mc + c]
            if coef != 0:
                total += coef * complex_gaunt(a, b, c, ma, mb, mc)
    if abs(total.imag) > 1e-12:
        raise ArithmeticError(f"real Gaunt ({a},{b},{c},{mu_a},{mu_b},{mu_c}) is not real: {total}")
    return total.real


@functools.lru_cache(maxsize=None)
def real_gaunt_tensor(order: int) -> tuple[np.ndarray, np.ndarray]:
    """All nonzero ``Gamma_ijk = integral y_i y_j y_k ds`` for flat indices ``i, j, k < order**2``.

    Every ordered triple is listed (the tensor is symmetric, so each unordered triple with
    distinct indices appears 6 times), sorted lexicographically by ``(i, j, k)``.

    Returns:
        ``(indices, values)``: int64 (K, 3) and float64 (K,), both read-only.
    """
    rows: list[tuple[int, int, int]] = []
    vals: list[float] = []
    for a in range(order):
        for b in range(order):
            for c in range(abs(a - b), min(a + b, order - 1) + 1):
                if (a + b + c) % 2:
                    continue
                for mu_a in range(-a, a + 1):
                    for mu_b in range(-b, b + 1):
                        # Azimuthal selection: |mu_c| = |mu_a| +- |mu_b|; an even number of sine
                        # factors (negative mu) for a nonzero azimuthal integral.
                        for abs_c in {abs(mu_a) + abs(mu_b), abs(abs(mu_a) - abs(mu_b))}:
                            if abs_c > c:
                                continue
                            for mu_c in {abs_c, -abs_c}:
                                if ((mu_a < 0) + (mu_b < 0) + (mu_c < 0)) % 2:
                                    continue
                                v = _real_gaunt_block(a, b, c, mu_a, mu_b, mu_c)
                                if v != 0.0:
                                    rows.append((a * a + a + mu_a, b * b + b + mu_b, c * c + c + mu_c))
                                    vals.append(v)
    idx = np.asarray(rows, dtype=np.int64).reshape(-1, 3)
    val = np.asarray(vals, dtype=np.float64)
    order_ = np.lexsort((idx[:, 2], idx[:, 1], idx[:, 0]))
    idx, val = np.ascontiguousarray(idx[order_]), np.ascontiguousarray(val[order_])
    idx.setflags(write=False)
    val.setflags(write=False)
    return idx, val


# ----------------------------------------------------------------------------------------------
# float64 products over the tensor
# ----------------------------------------------------------------------------------------------


def product_operands(f, g, name: str = "product") -> tuple[np.ndarray, np.ndarray, int, tuple]:
    """Validate two SH coefficient arrays of one order and broadcast their batch shapes.

    Args:
        f, g: SH coefficients, shape (..., n*n) each; batch shapes broadcast.
        name: prefix of error messages.

    Returns:
        ``(fb, gb, order, batch)``: float64 rows of shape (B, n*n) each (B = prod(batch)), the
        order n and the broadcast batch shape.
    """
    f, order = check_coeffs(f, f"{name}: f")
    g, order_g = check_coeffs(g, f"{name}: g")
    if order_g != order:
        raise ValueError(f"{name}: f has order {order} but g has order {order_g}")
    n2 = order * order
    batch = np.broadcast_shapes(f.shape[:-1], g.shape[:-1])
    fb = np.broadcast_to(f, batch + (n2,)).reshape(-1, n2)
    gb = np.broadcast_to(g, batch + (n2,)).reshape(-1, n2)
    return fb, gb, order, batch


def product_rows(f: np.ndarray, g: np.ndarray, order: int) -> np.ndarray:
    """Order-n truncated products of paired rows, float64 (B, n*n) x (B, n*n) -> (B, n*n)."""
    n2 = order * order
    idx, val = real_gaunt_tensor(order)
    starts = np.flatnonzero(np.r_[True, idx[1:, 0] != idx[:-1, 0]])  # every output i occurs
    out = np.empty((f.shape[0], n2))
    step = chunk_rows(8 * len(val))
    for s in range(0, f.shape[0], step):
        terms = f[s : s + step, idx[:, 1]] * g[s : s + step, idx[:, 2]] * val
        out[s : s + step] = np.add.reduceat(terms, starts, axis=1)
    return out


def product(f, g) -> np.ndarray:
    """float64 order-n truncated SH product of (..., n*n) arrays, shape (broadcast batch, n*n)."""
    fb, gb, order, batch = product_operands(f, g)
    return product_rows(fb, gb, order).reshape(batch + (order * order,))


def product_matrix_rows(f: np.ndarray, order: int) -> np.ndarray:
    """Product matrices ``M_f`` of rows, float64 (B, n*n) -> (B, n*n, n*n), symmetric."""
    n2 = order * order
    idx, val = real_gaunt_tensor(order)
    pair = idx[:, 0] * n2 + idx[:, 1]
    starts = np.flatnonzero(np.r_[True, pair[1:] != pair[:-1]])
    pairs = pair[starts]
    out = np.zeros((f.shape[0], n2 * n2))
    step = chunk_rows(8 * len(val))
    for s in range(0, f.shape[0], step):
        out[s : s + step, pairs] = np.add.reduceat(f[s : s + step, idx[:, 2]] * val, starts, axis=1)
    return out.reshape(-1, n2, n2)


def product_matrix(f) -> np.ndarray:
    """float64 SH product matrices of (..., n*n) coefficients, shape (..., n*n, n*n)."""
    f, order = check_coeffs(f, "product_matrix: f")
    n2 = order * order
    return product_matrix_rows(f.reshape(-1, n2), order).reshape(f.shape[:-1] + (n2, n2))
