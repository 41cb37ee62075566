"""Real SH and their gradients with respect to the direction (private; used by the ZH fit).

Imports no other basis module; :mod:`warpshade.basis._zh_fit` builds on it and
:mod:`warpshade.basis.zh` re-exports :func:`basis_and_gradient`.

The SH of :mod:`warpshade.basis.sh` are evaluated by the recurrence
``y_lm(x, y, z) = sqrt(2) P_l^m(z) Re/Im (x + i y)^m`` (``P_l^m`` the orthonormal associated
Legendre polynomial divided by ``sin^m(theta)``, a polynomial in z). That expression is a
polynomial in (x, y, z), i.e. an extension of ``y_lm`` off the unit sphere; differentiating the
recurrence gives its gradient in closed form:

* ``d/dz P_l^m`` from the derivative of the three-term recurrence;
* ``d/dx (x + i y)^m = m (x + i y)^(m-1)`` and ``d/dy (x + i y)^m = i m (x + i y)^(m-1)``.

Only the tangential part of that gradient is intrinsic to the sphere. The ZH fit substitutes
``h(s) = s / |s|`` for the lobe axis (Sloan et al. 2005, eq. 21), whose chain rule
``J_h^T grad y = (I - u u^T) grad y / |s|`` (u = h(s)) keeps exactly that part, so the choice of
extension does not matter.
"""

from __future__ import annotations

import numpy as np

__all__ = ["basis_and_gradient", "normalised_gradient"]


def basis_and_gradient(dirs: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """SH basis and its polynomial-extension gradient at directions (float64).

    Args:
        dirs: directions, shape (B, 3) (used as given; pass unit vectors for ``y`` itself).
        order: SH order n.

    Returns:
        ``(y, grad)``: shape (B, n*n) and (B, n*n, 3).
    """
    d = np.asarray(dirs, dtype=np.float64)
    x, y, z = d[:, 0], d[:, 1], d[:, 2]
    count = d.shape[0]
    n2 = order * order
    out = np.empty((count, n2))
    grad = np.zeros((count, n2, 3))
    sqrt2 = np.sqrt(2.0)
    c, s = np.ones_like(x), np.zeros_like(x)  # Re, Im of (x + i y)^m
    c_prev, s_prev = np.zeros_like(x), np.zeros_like(x)  # (x + i y)^(m-1)
    pmm = 0.5 / np.sqrt(np.pi)
    for m in range(order):
        if m > 0:
            pmm = -np.sqrt((2.0 * m + 1.0) / (2.0 * m)) * pmm
        # d/dx and d/dy of (c + i s) = (x + i y)^m
        dc_dx, ds_dx = m * c_prev, m * s_prev
        dc_dy, ds_dy = -m * s_prev, m * c_prev
        p_prev, dp_prev = np.zeros_like(x), np.zeros_like(x)
        p_cur, dp_cur = np.full_like(x, pmm), np.zeros_like(x)
        for l in range(m, order):
            if l == m + 1:
                k = np.sqrt(2.0 * m + 3.0)
                p_prev, dp_prev, p_cur, dp_cur = p_cur, dp_cur, k * z * pmm, np.full_like(x, k * pmm)
            elif l > m + 1:
                a = np.sqrt((4.0 * l * l - 1.0) / (l * l - m * m))
                b = np.sqrt(((l - 1.0) ** 2 - m * m) / (4.0 * (l - 1.0) ** 2 - 1.0))
                p_next = a * (z * p_cur - b * p_prev)
                dp_next = a * (p_cur + z * dp_cur - b * dp_prev)
                p_prev, dp_prev, p_cur, dp_cur = p_cur, dp_cur, p_next, dp_next
            if m == 0:
                i = l * l + l
                out[:, i] = p_cur
                grad[:, i, 2] = dp_cur
            else:
                ip, im = l * l + l + m, l * l + l - m
                out[:, ip] = sqrt2 * p_cur * c
                out[:, im] = sqrt2 * p_cur * s
                grad[:, ip, 0] = sqrt2 * p_cur * dc_dx
                grad[:, ip, 1] = sqrt2 * p_cur * dc_dy
                grad[:, ip, 2] = sqrt2 * dp_cur * c
                grad[:, im, 0] = sqrt2 * p_cur * ds_dx
                grad[:, im, 1] = sqrt2 * p_cur * ds_dy
                grad[:, im, 2] = sqrt2 * dp_cur * s
        c_prev, s_prev = c, s
        c, s = c * x - s * y, c * y + s * x
    return out, grad


def normalised_gradient(raw_axes: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``y(h(s))`` and ``grad_s y(h(s)) = J_h^T grad y`` for unnormalised axes s (eq. 21).

    Args:
        raw_axes: shape (B, 3), nonzero.
        order: SH order n.

    Returns:
        ``(unit_axes (B, 3), y (B, n*n), grad (B, n*n, 3))``.
    """
    s = np.asarray(raw_axes, dtype=np.float64)
    length = np.linalg.norm(s, axis=-1, keepdims=True)
    length = np.maximum(length, 1e-300)
    u = s / length
    y, g = basis_and_gradient(u, order)
    # J_h = (I - u u^T) / |s| is symmetric: project out the radial component and divide by |s|.
    radial = np.einsum("bjk,bk->bj", g, u)
    g = (g - radial[:, :, None] * u[:, None, :]) / length[:, :, None]
    return u, y, g
