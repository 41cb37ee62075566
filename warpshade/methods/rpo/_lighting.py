"""Zonal-harmonic approximation of SH lighting (Nowrouzezahrai et al. 2009, sec. 5.4).

Eq. 11 needs the lighting in each receiver's tangent frame. A general SH rotation costs O(n^3) per
vertex and channel; a zonal lobe turns by evaluating the SH at its rotated axis. The environment's
SH ``l`` (three channels) is approximated by J lobes (the paper: 3) with one axis per lobe and
per-channel band coefficients::

    l_c,lm ~ sum_j c_jcl y_lm(a_j)

fitted as the paper describes: ``candidates`` uniformly spread directions (spherical Fibonacci)
are each tried as a single-lobe axis with the closed-form band coefficients of eq. 15 (LDPRT eq.
18: ``c_l = sum_m y_lm(a) l_lm / sum_m y_lm(a)^2``); the best seeds a BFGS over the axis and the
coefficients (``scipy.optimize.minimize``, no gradients, as the paper); the lobe is subtracted
and the next fitted to the residual. With the axes fixed the coefficients are finally re-solved
jointly by linear least squares per band (a lobe set is linear in them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from ...basis import quadrature, sh

__all__: list[str] = []


@dataclass
class ZHLighting:
    """J zonal lobes approximating (C, n*n) SH lighting.

    Attributes:
        axes: (J, 3) unit lobe axes, world frame.
        coeffs: (J, C, n) band coefficients ``c_jcl``.
        error: relative L2 error of the approximation over all channels.
        fit_s: seconds the fit took.
    """

    axes: np.ndarray
    coeffs: np.ndarray
    error: float
    fit_s: float = 0.0

    @property
    def order(self) -> int:
        return int(self.coeffs.shape[-1])

    def to_sh(self) -> np.ndarray:
        """The lobes as SH, (C, n*n) float64."""
        n = self.order
        y = sh.basis(self.axes, n)  # (J, n*n)
        band = sh.band_of(n)
        return np.einsum("jci,ji->ci", self.coeffs[:, :, band], y)

    def local(self, frames) -> np.ndarray:
        """The approximated lighting in tangent frames (V, 3, 3) (rows t, b, n): (V, C, n*n)."""
        f = np.asarray(frames, np.float64)
        a = np.einsum("vij,kj->vki", f, self.axes)  # local axes (V, J, 3)
        y = sh.basis(a, self.order)  # (V, J, n*n)
        band = sh.band_of(self.order)
        return np.einsum("jci,vji->vci", self.coeffs[:, :, band], y)


def _band_sums(y: np.ndarray, f: np.ndarray, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Per band: ``sum_m y_lm f_c,lm`` (..., C, n) and ``sum_m y_lm^2`` (..., n)."""
    band = sh.band_of(order)
    yf = np.zeros(y.shape[:-1] + (f.shape[0], order))
    yy = np.zeros(y.shape[:-1] + (order,))
    for l in range(order):
        m = band == l
        yf[..., :, l] = y[..., m] @ f[:, m].T
        yy[..., l] = np.sum(y[..., m] ** 2, axis=-1)
    return yf, yy


def _axis(theta_phi) -> np.ndarray:
    t, p = theta_phi
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def fit_zh_lighting(light, lobes: int = 3, candidates: int = 1500, refine: bool = True) -> ZHLighting:
    """Fit ``lobes`` shared-axis ZH lobes to SH lighting (see the module docstring).

    Args:
        light: (C, n*n) SH coefficients (C channels, e.g. RGB), world frame.
        lobes: J >= 1.
        candidates: candidate axes of the closed-form single-lobe search.
        refine: BFGS over each lobe's axis and coefficients after the search.

    Raises:
        ValueError: non-finite lighting or a bad lobe count.
    """
    import time

    t0 = time.perf_counter()
    f = np.atleast_2d(np.asarray(light, np.float64))
    if not np.all(np.isfinite(f)):
        raise ValueError("rpo: the lighting to fit with ZH lobes is not finite")
    if int(lobes) < 1:
        raise ValueError(f"rpo: ZH lighting needs at least one lobe, got {lobes!r}")
    order = int(round(np.sqrt(f.shape[1])))
    band = sh.band_of(order)
    cand = quadrature.fibonacci(int(candidates)).directions
    ycand = sh.basis(cand, order)
    residual = f.copy()
    axes, coeffs = [], []
    for _ in range(int(lobes)):
        yf, yy = _band_sums(ycand, residual, order)
        gain = np.sum(yf**2 / np.maximum(yy, 1e-300)[:, None, :], axis=(1, 2))  # error drop per candidate
        a = cand[int(np.argmax(gain))]
        c = yf[int(np.argmax(gain))] / np.maximum(yy[int(np.argmax(gain))], 1e-300)
        if refine:
            def objective(x, res=residual):
                y = sh.basis(_axis(x[:2]), order)
                lobe = x[2:].reshape(f.shape[0], order)[:, band] * y
                return float(np.sum((res - lobe) ** 2))

            x0 = np.concatenate([[np.arccos(np.clip(a[2], -1, 1)), np.arctan2(a[1], a[0])], c.ravel()])
            x = minimize(objective, x0, method="BFGS", options={"maxiter": 200}).x
            if objective(x) <= objective(x0):
                a, c = _axis(x[:2]), x[2:].reshape(f.shape[0], order)
        axes.append(a / np.linalg.norm(a))
        coeffs.append(c)
        residual = residual - c[:, band] * sh.basis(axes[-1], order)
    axes = np.array(axes)
    # joint least squares of the coefficients with the axes fixed, band by band
    y = sh.basis(axes, order)  # (J, n*n)
    coeffs = np.array(coeffs)
    for l in range(order):
        m = band == l
        a_mat = y[:, m].T  # (2l+1, J)
        sol, *_ = np.linalg.lstsq(a_mat, f[:, m].T, rcond=None)  # (J, C)
        coeffs[:, :, l] = sol
    out = ZHLighting(axes, coeffs, 0.0)
    out.error = float(np.linalg.norm(out.to_sh() - f) / max(np.linalg.norm(f), 1e-300))
    out.fit_s = time.perf_counter() - t0
    return out
