"""SH rotation matrices (private; see :func:`warpshade.basis.sh.rotate`).

Builds on :mod:`warpshade.basis._core` and :mod:`warpshade.basis.quadrature`;
:mod:`warpshade.basis.sh` (float64 mirror) and :mod:`warpshade.basis.sh_warp` (the x90
blocks of the Warp kernel) build on it.

Two independent constructions:

* :func:`ivanic_ruedenberg_bands` -- the float64 mirror. Ivanic & Ruedenberg's recurrences
  (J. Phys. Chem. 1996, with the 1998 erratum) build the band-l block from band l-1 and the
  3x3 rotation itself. They are written for real SH *without* the Condon-Shortley phase, whose
  band-1 functions are proportional to (y, z, x); Sloan's real SH equal
  ``diag((-1)^|m|)`` times those, so each block is conjugated by that diagonal sign matrix.
* :func:`x90_bands` + :func:`zyz_euler_angles` -- the pieces of the "zxzxz" factorisation
  ``R = Rz(alpha) Rx(-90) Rz(beta) Rx(90) Rz(gamma)`` used by the Warp kernel: constant per-band
  matrices of the 90-degree rotation about x (obtained here by exact quadrature of rotated
  basis functions, independently of the recurrences) and cheap z rotations.

Both give the block-diagonal matrix ``D(R)`` with ``coeffs of f(R^-1 s) = D(R) @ coeffs of f``;
per band, ``y_l(R s) = D_l(R) y_l(s)`` for the column vector of band-l basis functions.
"""

from __future__ import annotations

import functools

import numpy as np

from . import quadrature
from ._core import basis

__all__ = ["ivanic_ruedenberg_bands", "x90_bands", "zyz_euler_angles", "rotation_from_zyz"]

# Band-1 real SH without the Condon-Shortley phase are proportional to (y, z, x) for m = -1, 0, 1.
_PERM_YZX = np.array([1, 2, 0])


def _band_signs(l: int) -> np.ndarray:
    m = np.arange(-l, l + 1)
    return np.where(np.abs(m) % 2 == 1, -1.0, 1.0)


def ivanic_ruedenberg_bands(rotations: np.ndarray, order: int) -> list[np.ndarray]:
    """Per-band SH rotation blocks for a batch of rotation matrices (float64).

    Args:
        rotations: proper rotation matrices, shape (B, 3, 3), float64.
        order: SH order n.

    Returns:
        List of n arrays; entry l has shape (B, 2l+1, 2l+1) (rows/columns ``m + l``) and maps the
        band-l coefficients of f to those of ``f(R^-1 s)`` in Sloan's convention.
    """
    batch = rotations.shape[0]
    r1 = rotations[:, _PERM_YZX][:, :, _PERM_YZX]  # no-Condon-Shortley band-1 block
    blocks_nocs = [np.ones((batch, 1, 1))]
    if order > 1:
        blocks_nocs.append(r1)
    for l in range(2, order):
        prev = blocks_nocs[-1]  # (B, 2l-1, 2l-1), index offset l-1

        def p_row(i: int, a: int) -> np.ndarray:
            """Ivanic-Ruedenberg P(i, l, a, b) for all b = -l..l at once, shape (B, 2l+1)."""
            r_i1 = r1[:, i + 1, 2][:, None]
            r_im1 = r1[:, i + 1, 0][:, None]
            r_i0 = r1[:, i + 1, 1][:, None]
            row = prev[:, a + l - 1, :]  # b = -(l-1)..(l-1)
            out = np.empty((batch, 2 * l + 1))
            out[:, 1 : 2 * l] = r_i0 * row
            out[:, 0] = (r_i1 * row[:, :1] + r_im1 * row[:, -1:])[:, 0]
            out[:, 2 * l] = (r_i1 * row[:, -1:] - r_im1 * row[:, :1])[:, 0]
            return out

        mp = np.arange(-l, l + 1)
        denom = np.where(np.abs(mp) < l, (l + mp) * (l - mp), 2 * l * (2 * l - 1)).astype(np.float64)
        block = np.zeros((batch, 2 * l + 1, 2 * l + 1))
        for m in range(-l, l + 1):
            am = abs(m)
            d0 = 1.0 if m == 0 else 0.0
            u = np.sqrt((l + m) * (l - m) / denom)
            v = 0.5 * np.sqrt((1.0 + d0) * (l + am - 1) * (l + am) / denom) * (1.0 - 2.0 * d0)
            w = -0.5 * np.sqrt((l - am - 1) * (l - am) / denom) * (1.0 - d0)
            row = np.zeros((batch, 2 * l + 1))
            if am < l:
                row += u * p_row(0, m)
            if m == 0:
                vv = p_row(1, 1) + p_row(-1, -1)
            elif m > 0:
                d1 = 1.0 if m == 1 else 0.0
                vv = p_row(1, m - 1) * np.sqrt(1.0 + d1) - (p_row(-1, -m + 1) * (1.0 - d1) if m != 1 else 0.0)
            else:
                d1 = 1.0 if m == -1 else 0.0
                vv = (p_row(1, m + 1) * (1.0 - d1) if m != -1 else 0.0) + p_row(-1, -m - 1) * np.sqrt(1.0 + d1)
            row += v * vv
            if am < l - 1 and m != 0:
                if m > 0:
                    ww = p_row(1, m + 1) + p_row(-1, -m - 1)
                else:
                    ww = p_row(1, m - 1) - p_row(-1, -m + 1)
                row += w * ww
            block[:, m + l, :] = row
        blocks_nocs.append(block)
    out = []
    for l, block in enumerate(blocks_nocs):
        s = _band_signs(l)
        out.append(block * s[None, :, None] * s[None, None, :])
    return out


def zyz_euler_angles(rotations: np.ndarray) -> np.ndarray:
    """Angles (alpha, beta, gamma) with ``R = Rz(alpha) Ry(beta) Rz(gamma)``, shape (B, 3).

    ``beta = atan2(hypot(R02, R12), R22)`` keeps full precision near the poles; at
    ``sin(beta) = 0`` the split between alpha and gamma is arbitrary and gamma is set to 0.
    """
    r = rotations
    sb = np.hypot(r[:, 0, 2], r[:, 1, 2])
    beta = np.arctan2(sb, r[:, 2, 2])
    alpha = np.arctan2(r[:, 1, 2], r[:, 0, 2])
    gamma = np.arctan2(r[:, 2, 1], -r[:, 2, 0])
    degenerate = sb < 1e-12
    up = r[:, 2, 2] > 0
    alpha = np.where(degenerate & up, np.arctan2(r[:, 1, 0], r[:, 0, 0]), alpha)
    alpha = np.where(degenerate & ~up, np.arctan2(-r[:, 1, 0], r[:, 1, 1]), alpha)
    gamma = np.where(degenerate, 0.0, gamma)
    return np.stack([alpha, beta, gamma], axis=-1)


def rotation_from_zyz(angles: np.ndarray) -> np.ndarray:
    """``Rz(alpha) Ry(beta) Rz(gamma)`` for angles of shape (B, 3), returns (B, 3, 3)."""
    a, b, g = angles[:, 0], angles[:, 1], angles[:, 2]

    def rz(t):
        c, s = np.cos(t), np.sin(t)
        z, o = np.zeros_like(t), np.ones_like(t)
        return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)

    c, s = np.cos(b), np.sin(b)
    z, o = np.zeros_like(b), np.ones_like(b)
    ry = np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)
    return rz(a) @ ry @ rz(g)


@functools.lru_cache(maxsize=None)
def x90_bands(order: int) -> tuple[np.ndarray, ...]:
    """Per-band blocks of the SH rotation by +90 degrees about x (Sloan convention), float64.

    ``J_l[i, j] = integral y_li(s) y_lj(Rx90^-1 s) ds`` by a Gauss-Legendre product rule that is
    exact for the degree-2(n-1) integrand; independent of the Ivanic-Ruedenberg recurrences.
    Entries below 1e-14 in magnitude (exact zeros of the true matrix) are set to 0.
    """
    q = quadrature.gauss_legendre(2 * (order - 1))
    rx90 = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    y = basis(q.directions, order)
    y_rot = basis(q.directions @ rx90, order)  # rows: Rx90^-1 s = Rx90^T s
    blocks = []
    for l in range(order):
        sl = slice(l * l, (l + 1) * (l + 1))
        j = (y[:, sl] * q.weights[:, None]).T @ y_rot[:, sl]
        j[np.abs(j) < 1e-14] = 0.0
        j.setflags(write=False)
        blocks.append(j)
    return tuple(blocks)
