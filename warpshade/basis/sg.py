"""Spherical Gaussians (SGs): evaluation, products, rotation, mixtures, the clamped cosine and the
hemisphere integral of a lobe (Wang et al. 2009, sec. 3, 5.3 and the appendix). Float64 NumPy.

A spherical Gaussian is ``G(v; p, lambda, mu) = mu exp(lambda (v.p - 1))`` (eq. 2) with unit
axis ``p``, sharpness ``lambda > 0`` and amplitude ``mu`` (a scalar, or RGB in a trailing axis of
length 3 where a function says so). Every function broadcasts: axes and directions are arrays
of unit vectors with a trailing axis of 3, sharpness and amplitude arrays of the leading shape.

* :func:`evaluate` (eq. 2), :func:`integral` (over the sphere), :func:`inner_product` (eq. 4,
  written ``4 pi mu1 mu2 exp(d - l1 - l2) (1 - exp(-2 d)) / (2 d)`` so that it stays finite for
  any sharpness), :func:`product` (eq. 5, exact), :func:`rotate` (eq. 7);
* :func:`area` / :func:`sharpness_for_area`: the epsilon-support area ``f_a`` of eq. 3 and its
  inverse (used by the spherical warp, eq. 19, and the light lobes, eq. 32-33);
* :func:`clamped_cosine`: ``max(0, v.n)`` as one lobe, the paper's ``lambda = 2.133,
  mu = 1.170`` (eq. 40) or the least-squares-optimal lobe (:func:`fit_clamped_cosine`);
* :func:`hemisphere_integral`: ``f_h(theta_d, lambda)`` of eq. 30, the integral of a unit lobe
  over the hemisphere whose boundary great circle passes at signed angle ``theta_d`` from its
  axis (``theta_d = pi/2``: the hemisphere centred on the axis, ``2 pi / lambda (1 - e^-lambda)``;
  ``theta_d = -pi/2``: the opposite one). ``method="quadrature"`` is the oracle (1-D Gauss-
  Legendre over the height along the hemisphere's pole, the azimuth integrated exactly by a
  Bessel function), ``"paper"`` the appendix's sigmoid (eq. 46-49), ``"erf"`` (default) the
  closed form below;
* :func:`visible_fraction`: ``f_h(theta_d, lambda) / f_h(pi/2, lambda)``, the amplitude factor of
  an SG times an SSDF visibility (eq. 31);
* :class:`SGMixture`: a sum of lobes (eq. 6) with evaluation, rotation, products and inner
  products (all pairs, O(n m)).

The erf form of ``f_h``. With ``F = 2 pi / lambda (1 - e^(-2 lambda))`` the integral over the
whole sphere, the exact fraction ``R(theta_d) = f_h / F`` is odd about 1/2
(``R(-t) = 1 - R(t)``) and known exactly at the pole, ``R(pi/2) = 1 / (1 + e^-lambda)``. For a
sharp lobe the cut is a half-plane through a 2-D Gaussian of variance ``1/lambda``, so ``R``
tends to ``(1 + erf(sqrt(lambda/2) theta_d)) / 2``; for a broad lobe it is linear in
``sin theta_d``. The form::

    R ~ 1/2 + (R(pi/2) - 1/2) erf(s sin theta_d) / erf(s),
    s = sqrt(lambda / 2) tanh(0.5739 sqrt(lambda) + 0.0478 lambda)

is exact at both poles and at the horizon and has both limits; the two constants were fitted
(minimax) against the quadrature over lambda in [0.01, 2000]. It is within 0.4 % of
``f_h(pi/2, lambda)`` everywhere on that range (``tests/test_sg_basis.py`` checks it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import erf, i0e

__all__ = [
    "CLAMPED_COSINE_PAPER",
    "ERF_SHAPE",
    "FH_METHODS",
    "PAPER_FH_A",
    "PAPER_FH_POLY",
    "SGMixture",
    "area",
    "clamped_cosine",
    "evaluate",
    "fit_clamped_cosine",
    "hemisphere_integral",
    "inner_product",
    "integral",
    "product",
    "rotate",
    "sharpness_for_area",
    "visible_fraction",
]

#: The paper's single-lobe clamped cosine, (sharpness, amplitude) (eq. 40).
CLAMPED_COSINE_PAPER = (2.133, 1.170)
#: Support threshold epsilon of the area function (sec. 3: 0.1).
AREA_EPSILON = 0.1
#: Constants (a, b) of the erf form's ``s = sqrt(l/2) tanh(a sqrt(l) + b l)`` (module docstring).
ERF_SHAPE = (0.5739, 0.0478)
#: The appendix's sigmoid scale ``a`` (eq. 47) and the cubic ``k(l)`` (eq. 48), highest power first.
PAPER_FH_A = 1.05
PAPER_FH_POLY = (0.204, -0.892, 2.995, 0.067)
#: ``hemisphere_integral`` methods.
FH_METHODS = ("erf", "paper", "quadrature")


def _axes(a, name: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.shape[-1:] != (3,):
        raise ValueError(f"sg: {name} must have a trailing axis of 3, got shape {a.shape}")
    return a


def _sharpness(lam, name: str = "sharpness") -> np.ndarray:
    lam = np.asarray(lam, dtype=np.float64)
    if not np.all(np.isfinite(lam)) or np.any(lam < 0.0):
        raise ValueError(f"sg: {name} must be finite and >= 0")
    return lam


def evaluate(dirs, axis, sharpness, amplitude=1.0) -> np.ndarray:
    """``mu exp(lambda (v.p - 1))`` (eq. 2), broadcast over the leading shapes of all arguments."""
    d = _axes(dirs, "dirs")
    p = _axes(axis, "axis")
    lam = _sharpness(sharpness)
    return np.asarray(amplitude, np.float64) * np.exp(lam * (np.sum(d * p, axis=-1) - 1.0))


def integral(sharpness, amplitude=1.0) -> np.ndarray:
    """The integral of a lobe over the sphere, ``2 pi mu (1 - e^(-2 lambda)) / lambda`` (4 pi mu at 0)."""
    lam = _sharpness(sharpness)
    safe = np.where(lam > 1e-12, lam, 1.0)
    val = np.where(lam > 1e-12, -np.expm1(-2.0 * safe) / safe, 2.0 - 2.0 * lam)
    return 2.0 * np.pi * np.asarray(amplitude, np.float64) * val


def _sinhc_scaled(d, total):
    """``exp(-total) sinh(d) / d`` written as ``exp(d - total) (1 - e^(-2d)) / (2 d)`` (d >= 0)."""
    safe = np.where(d > 1e-12, d, 1.0)
    ratio = np.where(d > 1e-12, -np.expm1(-2.0 * safe) / (2.0 * safe), 1.0 - d)
    return np.exp(d - total) * ratio


def inner_product(axis1, sharpness1, amplitude1, axis2, sharpness2, amplitude2) -> np.ndarray:
    """``integral G1 G2`` over the sphere (eq. 4): ``4 pi mu1 mu2 e^(-l1-l2) sinh(d) / d``,
    ``d = |l1 p1 + l2 p2|``, evaluated as ``exp(d - l1 - l2) (1 - e^-2d) / (2d)`` (no overflow)."""
    l1, l2 = _sharpness(sharpness1, "sharpness1"), _sharpness(sharpness2, "sharpness2")
    pm = l1[..., None] * _axes(axis1, "axis1") + l2[..., None] * _axes(axis2, "axis2")
    d = np.linalg.norm(pm, axis=-1)
    return 4.0 * np.pi * np.asarray(amplitude1, np.float64) * np.asarray(amplitude2, np.float64) * _sinhc_scaled(d, l1 + l2)


def product(axis1, sharpness1, amplitude1, axis2, sharpness2, amplitude2):
    """The direction-wise product ``G1(v) G2(v)``, exactly one SG (eq. 5 / 45).

    Returns:
        (axis, sharpness, amplitude): ``p = u / |u|`` with ``u = l1 p1 + l2 p2``, ``lambda = |u|``,
        ``mu = mu1 mu2 exp(|u| - l1 - l2)``. Where ``u = 0`` (equal, opposite lobes: a constant)
        the axis is ``axis1`` and the sharpness 0.
    """
    l1, l2 = _sharpness(sharpness1, "sharpness1"), _sharpness(sharpness2, "sharpness2")
    p1 = _axes(axis1, "axis1")
    u = l1[..., None] * p1 + l2[..., None] * _axes(axis2, "axis2")
    lam = np.linalg.norm(u, axis=-1)
    fallback = np.broadcast_to(p1, u.shape)
    axis = np.where(lam[..., None] > 1e-300, u / np.where(lam > 1e-300, lam, 1.0)[..., None], fallback)
    amp = np.asarray(amplitude1, np.float64) * np.asarray(amplitude2, np.float64) * np.exp(lam - l1 - l2)
    return axis, lam, amp


def rotate(axis, rotation) -> np.ndarray:
    """Axes turned by a rotation matrix (3, 3): ``R p`` (eq. 7); sharpness and amplitude unchanged."""
    return _axes(axis, "axis") @ np.asarray(rotation, np.float64).T


def area(sharpness, epsilon: float = AREA_EPSILON) -> np.ndarray:
    """The epsilon-support area ``f_a = -2 pi ln(eps) / lambda`` (eq. 3; meaningful for lambda > -ln eps)."""
    lam = _sharpness(sharpness)
    return -2.0 * np.pi * math.log(epsilon) / np.maximum(lam, 1e-300)


def sharpness_for_area(support_area, epsilon: float = AREA_EPSILON) -> np.ndarray:
    """``f_a^-1``: the sharpness whose epsilon-support has the given area (steradians)."""
    a = np.asarray(support_area, np.float64)
    if np.any(a <= 0.0) or not np.all(np.isfinite(a)):
        raise ValueError("sg.sharpness_for_area: area must be finite and > 0")
    return -2.0 * np.pi * math.log(epsilon) / a


@lru_cache(maxsize=1)
def fit_clamped_cosine() -> tuple[float, float]:
    """The single lobe ``mu exp(lambda (cos - 1))`` closest to ``max(0, cos)`` in L2 over the sphere.

    Solved with the amplitude eliminated (linear least squares for fixed sharpness) and a bounded
    scalar search over the sharpness, on a 400-node Gauss-Legendre rule in ``cos``.
    """
    from scipy.optimize import minimize_scalar

    x, w = np.polynomial.legendre.leggauss(400)
    target = np.maximum(x, 0.0)

    def residual(lam):
        g = np.exp(lam * (x - 1.0))
        mu = np.sum(w * g * target) / np.sum(w * g * g)
        return np.sum(w * (mu * g - target) ** 2), mu

    res = minimize_scalar(lambda lam: residual(lam)[0], bounds=(0.5, 10.0), method="bounded", options={"xatol": 1e-10})
    return float(res.x), float(residual(res.x)[1])


def clamped_cosine(normal, fit: str = "paper"):
    """``max(0, v.n)`` as one SG about ``n`` (eq. 40).

    Args:
        normal: unit normals (..., 3).
        fit: ``"paper"`` (lambda 2.133, mu 1.170) or ``"l2"`` (:func:`fit_clamped_cosine`).

    Returns:
        (axis, sharpness, amplitude), sharpness and amplitude broadcast to the normals' leading shape.
    """
    n = _axes(normal, "normal")
    if fit == "paper":
        lam, mu = CLAMPED_COSINE_PAPER
    elif fit == "l2":
        lam, mu = fit_clamped_cosine()
    else:
        raise ValueError(f"sg.clamped_cosine: fit must be 'paper' or 'l2', got {fit!r}")
    shape = n.shape[:-1]
    return n, np.full(shape, lam), np.full(shape, mu)


# ------------------------------------------------------------------------------------------------
# hemisphere integral f_h (eq. 30) and the visibility factor (eq. 31)

_GL_NODES = 600


@lru_cache(maxsize=1)
def _gauss_legendre01():
    x, w = np.polynomial.legendre.leggauss(_GL_NODES)
    return 0.5 * (x + 1.0), 0.5 * w


def _fh_quadrature(theta_d, lam) -> np.ndarray:
    """Oracle: with ``z`` the height along the visible hemisphere's pole ``n`` (``n.p = sin theta_d``),
    ``f_h = integral_0^1 2 pi I0(lambda sqrt(1-z^2) cos theta_d) exp(lambda (z sin theta_d - 1)) dz``."""
    z, w = _gauss_legendre01()
    t = np.asarray(theta_d, np.float64)[..., None]
    l = np.asarray(lam, np.float64)[..., None]
    a = l * np.sqrt(1.0 - z * z) * np.cos(t)
    # i0e(a) = I0(a) e^-|a|: keep the exponent in one piece so that nothing overflows
    f = i0e(a) * np.exp(np.abs(a) + l * (z * np.sin(t) - 1.0))
    return 2.0 * np.pi * np.sum(w * f, axis=-1)


def _pole(lam) -> np.ndarray:
    """``f_h(pi/2, lambda) = 2 pi (1 - e^-lambda) / lambda`` (2 pi at 0)."""
    safe = np.where(lam > 1e-12, lam, 1.0)
    return 2.0 * np.pi * np.where(lam > 1e-12, -np.expm1(-safe) / safe, 1.0 - 0.5 * lam)


def _erf_fraction(theta_d, lam) -> np.ndarray:
    """``f_h / F`` by the erf form (module docstring)."""
    a, b = ERF_SHAPE
    r = np.sqrt(lam)
    s = np.sqrt(0.5 * lam) * np.tanh(a * r + b * lam)
    sin_t = np.sin(theta_d)
    safe = np.where(s > 1e-6, s, 1.0)
    shape = np.where(s > 1e-6, erf(safe * sin_t) / erf(safe), sin_t)
    pole = 1.0 / (1.0 + np.exp(-lam))
    return 0.5 + (pole - 0.5) * shape


def hemisphere_integral(theta_d, sharpness, method: str = "erf") -> np.ndarray:
    """``f_h(theta_d, lambda)`` (eq. 30): a unit lobe integrated over the hemisphere whose boundary
    passes at signed angle ``theta_d`` in [-pi/2, pi/2] from its axis (module docstring).

    Args:
        theta_d: signed angular distance(s) in radians (clamped to [-pi/2, pi/2]).
        sharpness: lambda (broadcast with theta_d), >= 0.
        method: ``"erf"`` (closed form, default), ``"paper"`` (appendix eq. 46-49, fitted by the
            paper for lambda in [1, 105] only) or ``"quadrature"`` (the oracle).
    """
    t = np.clip(np.asarray(theta_d, np.float64), -0.5 * np.pi, 0.5 * np.pi)
    lam = _sharpness(sharpness)
    t, lam = np.broadcast_arrays(t, lam)
    if method == "quadrature":
        return _fh_quadrature(t, lam)
    if method == "erf":
        return integral(lam) * _erf_fraction(t, lam)
    if method == "paper":
        k = np.polyval(PAPER_FH_POLY, lam)
        # eq. 47 with k^(-theta_d) (the reading that reproduces the paper's stated accuracy)
        sig = PAPER_FH_A / (1.0 + np.power(np.maximum(k, 1e-12), -t)) + 0.5 * (1.0 - PAPER_FH_A)
        return sig * _pole(lam)
    raise ValueError(f"sg.hemisphere_integral: method must be one of {FH_METHODS}, got {method!r}")


def visible_fraction(theta_d, sharpness, method: str = "erf") -> np.ndarray:
    """``f_h(theta_d, lambda) / f_h(pi/2, lambda)``: the amplitude factor of eq. 31 (an SG times the
    hemisphere visibility reconstructed from an SSDF value ``theta_d`` at its axis)."""
    lam = _sharpness(sharpness)
    return hemisphere_integral(theta_d, lam, method) / _pole(lam)


# ------------------------------------------------------------------------------------------------
# mixtures


@dataclass
class SGMixture:
    """A sum of SG lobes (eq. 6).

    Attributes:
        axes: unit axes, shape (K, 3), float64.
        sharpness: shape (K,), float64, >= 0.
        amplitude: shape (K,) or (K, C) (C channels, e.g. RGB), float64.
    """

    axes: np.ndarray
    sharpness: np.ndarray
    amplitude: np.ndarray

    def __post_init__(self):
        self.axes = _axes(self.axes, "axes").reshape(-1, 3)
        self.sharpness = _sharpness(self.sharpness).reshape(-1)
        self.amplitude = np.asarray(self.amplitude, np.float64)
        k = self.axes.shape[0]
        if self.sharpness.shape[0] != k or self.amplitude.shape[:1] != (k,):
            raise ValueError(f"SGMixture: {k} axes but sharpness {self.sharpness.shape}, amplitude {self.amplitude.shape}")

    @property
    def lobe_count(self) -> int:
        return int(self.axes.shape[0])

    def _amp(self) -> np.ndarray:
        return self.amplitude if self.amplitude.ndim == 2 else self.amplitude[:, None]

    def evaluate(self, dirs) -> np.ndarray:
        """Values at directions (..., 3): shape (...,) for scalar amplitudes, (..., C) otherwise."""
        d = _axes(dirs, "dirs")
        g = np.exp(self.sharpness * (d @ self.axes.T - 1.0))  # (..., K)
        out = g @ self._amp()
        return out[..., 0] if self.amplitude.ndim == 1 else out

    def rotated(self, rotation) -> "SGMixture":
        return SGMixture(rotate(self.axes, rotation), self.sharpness.copy(), self.amplitude.copy())

    def integral(self) -> np.ndarray:
        out = integral(self.sharpness)[:, None] * self._amp()
        return out.sum(0)[0] if self.amplitude.ndim == 1 else out.sum(0)

    def product(self, other: "SGMixture") -> "SGMixture":
        """The direction-wise product, K*M lobes (channels multiply element-wise)."""
        a, b = self, other
        axis, lam, amp = product(a.axes[:, None], a.sharpness[:, None], 1.0, b.axes[None], b.sharpness[None], 1.0)
        channels = a._amp()[:, None, :] * b._amp()[None, :, :] * amp[..., None]
        scalar = a.amplitude.ndim == 1 and b.amplitude.ndim == 1
        flat = channels.reshape(-1, channels.shape[-1])
        return SGMixture(axis.reshape(-1, 3), lam.reshape(-1), flat[:, 0] if scalar else flat)

    def inner_product(self, other: "SGMixture") -> np.ndarray:
        """``integral self * other`` over the sphere: a scalar, or (C,)."""
        a, b = self, other
        w = inner_product(a.axes[:, None], a.sharpness[:, None], 1.0, b.axes[None], b.sharpness[None], 1.0)
        out = np.einsum("km,kc,mc->c", w, a._amp(), b._amp())
        return out[0] if (a.amplitude.ndim == 1 and b.amplitude.ndim == 1) else out
