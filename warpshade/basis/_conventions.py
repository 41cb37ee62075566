"""Converters between warpshade's SH coefficients and other public conventions (private).

Public entry points are :func:`warpshade.basis.sh.to_convention` and
:func:`warpshade.basis.sh.from_convention`; see their docstrings for the conventions. Builds on
:mod:`warpshade.basis._gaunt` (the complex -> real change of basis) only.
"""

from __future__ import annotations

import math

import numpy as np

from ._gaunt import real_from_complex_matrix

__all__ = ["CONVENTIONS", "SHTOOLS_NORMALIZATIONS", "to_convention", "from_convention"]

#: Names accepted by :func:`to_convention` / :func:`from_convention`.
CONVENTIONS = ("sloan", "real_no_cs", "complex", "shtools")
#: SHTOOLS normalisations supported by the "shtools" convention.
SHTOOLS_NORMALIZATIONS = ("4pi", "ortho", "schmidt", "unnorm")

#: Largest imaginary part (relative to the largest coefficient) accepted by
#: ``from_convention(c, "complex")``: complex coefficients of a real function satisfy
#: ``c_l,-m = (-1)^m conj(c_lm)``; a larger residual means the input is not a real function.
_COMPLEX_REAL_RTOL = 1e-6


def _order_of(n_coeffs: int, name: str) -> int:
    order = int(round(math.sqrt(n_coeffs)))
    if order < 1 or order * order != n_coeffs:
        raise ValueError(f"{name}: last axis must hold order**2 coefficients, got {n_coeffs}")
    return order


def _nocs_signs(order: int) -> np.ndarray:
    m = np.concatenate([np.arange(-l, l + 1) for l in range(order)])
    return np.where(np.abs(m) % 2 == 1, -1.0, 1.0)


def _shtools_scale(order: int, normalization: str) -> np.ndarray:
    """kappa[l, m] with SHTOOLS basis (csphase=-1) = kappa * warpshade basis, shape (order, order)."""
    if normalization not in SHTOOLS_NORMALIZATIONS:
        raise ValueError(
            f"shtools normalization must be one of {SHTOOLS_NORMALIZATIONS}, got {normalization!r}"
        )
    kappa = np.zeros((order, order))
    for l in range(order):
        for m in range(l + 1):
            if normalization == "ortho":
                kappa[l, m] = 1.0
            elif normalization == "4pi":
                kappa[l, m] = math.sqrt(4.0 * math.pi)
            elif normalization == "schmidt":
                kappa[l, m] = math.sqrt(4.0 * math.pi / (2 * l + 1))
            else:  # unnorm: bare P_lm cos/sin(m phi); orthonormal factor inverted
                n_ortho = math.sqrt(
                    (2.0 - (m == 0)) * (2 * l + 1) / (4.0 * math.pi) * math.factorial(l - m) / math.factorial(l + m)
                )
                kappa[l, m] = 1.0 / n_ortho
    return kappa


def _check_csphase(csphase: int) -> int:
    if csphase not in (1, -1):
        raise ValueError(f"shtools csphase must be 1 or -1, got {csphase!r}")
    return int(csphase)


def to_convention(coeffs, convention: str, *, normalization: str = "4pi", csphase: int = 1) -> np.ndarray:
    """See :func:`warpshade.basis.sh.to_convention`."""
    f = np.asarray(coeffs, dtype=np.float64)
    order = _order_of(f.shape[-1], "to_convention: coeffs")
    if convention == "sloan":
        return f.copy()
    if convention == "real_no_cs":
        return f * _nocs_signs(order)
    if convention == "complex":
        out = np.empty(f.shape, dtype=np.complex128)
        for l in range(order):
            sl = slice(l * l, (l + 1) * (l + 1))
            out[..., sl] = f[..., sl] @ real_from_complex_matrix(l)  # c_m' = sum_m f_m U[m, m']
        return out
    if convention == "shtools":
        csphase = _check_csphase(csphase)
        kappa = _shtools_scale(order, normalization)
        out = np.zeros(f.shape[:-1] + (2, order, order))
        for l in range(order):
            for m in range(l + 1):
                sign = (-1.0) ** m if csphase == 1 else 1.0
                out[..., 0, l, m] = sign * f[..., l * l + l + m] / kappa[l, m]
                if m > 0:
                    out[..., 1, l, m] = sign * f[..., l * l + l - m] / kappa[l, m]
        return out
    raise ValueError(f"to_convention: convention must be one of {CONVENTIONS}, got {convention!r}")


def from_convention(coeffs, convention: str, *, normalization: str = "4pi", csphase: int = 1) -> np.ndarray:
    """See :func:`warpshade.basis.sh.from_convention`."""
    if convention == "shtools":
        c = np.asarray(coeffs, dtype=np.float64)
        if c.ndim < 3 or c.shape[-3] != 2 or c.shape[-1] != c.shape[-2]:
            raise ValueError(f"from_convention: shtools coefficients must have shape (..., 2, L, L), got {c.shape}")
        csphase = _check_csphase(csphase)
        order = c.shape[-1]
        kappa = _shtools_scale(order, normalization)
        out = np.zeros(c.shape[:-3] + (order * order,))
        for l in range(order):
            for m in range(l + 1):
                sign = (-1.0) ** m if csphase == 1 else 1.0
                out[..., l * l + l + m] = sign * kappa[l, m] * c[..., 0, l, m]
                if m > 0:
                    out[..., l * l + l - m] = sign * kappa[l, m] * c[..., 1, l, m]
        return out
    if convention == "complex":
        c = np.asarray(coeffs, dtype=np.complex128)
        order = _order_of(c.shape[-1], "from_convention: coeffs")
        out = np.empty(c.shape, dtype=np.complex128)
        for l in range(order):
            sl = slice(l * l, (l + 1) * (l + 1))
            out[..., sl] = c[..., sl] @ np.conj(real_from_complex_matrix(l)).T  # f_m = sum_m' conj(U[m,m']) c_m'
        scale = max(1.0, float(np.abs(c).max(initial=0.0)))
        residual = float(np.abs(out.imag).max(initial=0.0))
        if residual > _COMPLEX_REAL_RTOL * scale:
            raise ValueError(
                "from_convention: complex coefficients do not describe a real function "
                f"(imaginary residual {residual:.3e}); expected c_l,-m = (-1)^m conj(c_lm)"
            )
        return out.real.copy()
    f = np.asarray(coeffs, dtype=np.float64)
    order = _order_of(f.shape[-1], "from_convention: coeffs")
    if convention == "sloan":
        return f.copy()
    if convention == "real_no_cs":
        return f * _nocs_signs(order)
    raise ValueError(f"from_convention: convention must be one of {CONVENTIONS}, got {convention!r}")
