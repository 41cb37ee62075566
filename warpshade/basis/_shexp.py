"""SH exponential and logarithm: float64 mirrors and per-order tables (private).

Public entry points are :func:`warpshade.basis.sh.exp`, :func:`warpshade.basis.sh.log`,
:func:`warpshade.basis.sh.ol_table` and :func:`warpshade.basis.sh.log_cap_table` (which also
re-exports the constants and table types); the Warp versions live in
:mod:`warpshade.basis._shexp_warp` and are reached through the per-order bundle of
:func:`warpshade.basis.sh_warp.sh_kernels`.

Builds on :mod:`warpshade.basis._core` (basis, cap ZH), :mod:`warpshade.basis._gaunt` (float64
products) and :mod:`warpshade.basis.quadrature`; nothing Warp.

Everything follows Ren et al. 2006, "Real-time soft shadows in dynamic scenes using spherical
harmonic exponentiation" (the SHEXP paper), sections 4 and 5:

* the *product series* ``exp*(f) = 1 + f + f^2*/2! + f^3*/3! + ...`` (eq. 17) where
  ``f^k* = (...((f * f) * f) ... * f)`` is accumulated left to right with order-n truncated
  SH products; its limit for infinite degree is ``1 + R^T q(D) R f`` with
  ``M_f = R^T D R`` and ``q(x) = (e^x - 1) / x`` (eq. 28), available here as
  :func:`exp_series_limit` (an oracle, not a run-time method);
* PS-p: that series truncated after degree p;
* PS*-p: DC isolation (eq. 20), scaling and squaring with
  ``p_s = max(0, floor(log2 ||f^|| + 3))`` (eq. 21), and the even/odd factored series of
  degree p (eq. 22) with powers ``x^2* = x * x``, ``x^4* = x^2* * x^2*``,
  ``x^(2k)* = x^(2k-2)* * x^2*`` for k >= 3;
* OL: ``exp(f_0 / sqrt(4 pi)) (a(||f^||) 1 + b(||f^||) f^)`` (eq. 23) with a, b tabulated by the
  least-squares projection of eq. 24 over blocking caps of increasing angular radius;
* HYB: OL inside the scaling and squaring of PS* (same ``p_s`` rule);
* ``log(g) = R^T q'(D~) R (g - 1)`` with ``q'(x) = log(x) / (x - 1)`` and the eigenvalues of the
  product matrix ``M_g`` clipped at ``eps_rel`` times the largest (eqs. 30-32).

Here ``1 = (sqrt(4 pi), 0, ..., 0)`` is the constant function 1 and ``f^`` is f with its DC
coefficient zeroed (eq. 19).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from . import quadrature
from ._core import basis, cap_zh
from ._gaunt import product, product_matrix

__all__ = [
    "EXP_METHODS",
    "DEFAULT_DEGREE",
    "MAX_DEGREE",
    "MAX_SQUARINGS",
    "LOG_EPS_REL",
    "TABLE_SAMPLES",
    "CAP_THETA_MAX",
    "OLTable",
    "LogCapTable",
    "one_vector",
    "scaling_power",
    "check_degree",
    "exp_f64",
    "exp_series_limit",
    "exp_volterra",
    "log_f64",
    "ol_table",
    "log_cap_table",
]

#: SH exponential methods (SHEXP paper, sec. 4.3).
EXP_METHODS = ("ps", "ps_star", "ol", "hyb")
#: Default series degree per method (PS-10; PS*-2 as in the paper's figures 7-8).
DEFAULT_DEGREE = {"ps": 10, "ps_star": 2, "ol": 1, "hyb": 1}
#: Eigenvalue clipping threshold of the SH log relative to the largest eigenvalue (paper, sec. 5).
LOG_EPS_REL = 0.02
#: Samples of the per-order tables (the paper uses 256 in theta).
TABLE_SAMPLES = 512
#: Largest angular radius of the blocking-cap log table: a sphere seen from outside subtends at
#: most a hemisphere.
CAP_THETA_MAX = 0.5 * math.pi
#: Dense theta sampling used to build the OL curves before they are resampled in ||f^||.
_OL_BUILD_SAMPLES = 2048
#: Highest series degree accepted (factorials beyond this underflow float32 and add nothing).
MAX_DEGREE = 40
#: Upper bound on scaling/squaring steps (||f^|| up to 2^37 needs 40 steps).
MAX_SQUARINGS = 40

SQRT_4PI = math.sqrt(4.0 * math.pi)


def one_vector(order: int) -> np.ndarray:
    """SH coefficients of the constant function 1: ``(sqrt(4 pi), 0, ..., 0)``, shape (n*n,)."""
    v = np.zeros(order * order)
    v[0] = SQRT_4PI
    return v


def scaling_power(norm) -> np.ndarray:
    """Squarings of PS*/HYB for inputs of norm ||f^||: ``max(0, floor(log2 ||f^|| + 3))`` (eq. 21).

    Args:
        norm: ``||f^||`` (Euclidean norm of the coefficients without DC), any shape.

    Returns:
        int64 array of the same shape, clipped to ``MAX_SQUARINGS``.
    """
    x = np.asarray(norm, dtype=np.float64)
    with np.errstate(divide="ignore"):
        p = np.floor(np.log2(np.where(x > 0.0, x, 1.0)) + 3.0)
    p = np.where(x > 0.0, p, 0.0)
    return np.clip(p, 0, MAX_SQUARINGS).astype(np.int64)


def check_degree(method: str, degree) -> int:
    """Validate ``degree`` for an exp ``method``; None gives the method's :data:`DEFAULT_DEGREE`."""
    if method not in EXP_METHODS:
        raise ValueError(f"exp: method must be one of {EXP_METHODS}, got {method!r}")
    if degree is None:
        return DEFAULT_DEGREE[method]
    if not isinstance(degree, (int, np.integer)) or isinstance(degree, bool):
        raise ValueError(f"exp: degree must be an integer, got {degree!r}")
    degree = int(degree)
    if method in ("ps", "ps_star") and not 1 <= degree <= MAX_DEGREE:
        raise ValueError(f"exp: degree of {method!r} must be in 1..{MAX_DEGREE}, got {degree}")
    return degree


def _split_dc(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(exp(f_0 / sqrt(4 pi)) per row, f^) for rows of shape (B, n*n)."""
    fhat = f.copy()
    fhat[:, 0] = 0.0
    return np.exp(f[:, 0] / SQRT_4PI), fhat


def _exp_ps(f: np.ndarray, degree: int) -> np.ndarray:
    out = f.copy()
    out[:, 0] += SQRT_4PI
    term = f
    inv_factorial = 1.0
    for k in range(2, degree + 1):
        term = product(term, f)  # f^k* = f^(k-1)* * f, left to right (eq. 17)
        inv_factorial /= k
        out += inv_factorial * term
    return out


def _factored_series(x: np.ndarray, degree: int) -> np.ndarray:
    """Degree-``degree`` product series of exp, even/odd factored (eq. 22)."""
    order = int(round(math.sqrt(x.shape[1])))
    one = one_vector(order)
    even = np.broadcast_to(one, x.shape).copy()
    if degree < 2:
        return even + x
    odd = np.broadcast_to(one, x.shape).copy()
    x2 = product(x, x)
    power = x2
    inv_factorial = 1.0
    for k in range(2, degree + 1):
        inv_factorial /= k
        if k % 2 == 0:
            if k == 4:
                power = product(x2, x2)
            elif k > 4:
                power = product(power, x2)
            even += inv_factorial * power
        else:
            odd += inv_factorial * power  # power = x^(k-1)*
    if degree < 3:
        return even + x  # odd part is x * 1 = x exactly
    return even + product(x, odd)


def _scaled(fhat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = scaling_power(np.linalg.norm(fhat, axis=1))
    return fhat / np.exp2(p)[:, None], p


def _square_rows(h: np.ndarray, p: np.ndarray) -> np.ndarray:
    for k in range(int(p.max(initial=0))):
        rows = p > k
        h[rows] = product(h[rows], h[rows])
    return h


def _exp_ps_star(f: np.ndarray, degree: int) -> np.ndarray:
    dc, fhat = _split_dc(f)
    x, p = _scaled(fhat)
    h = _square_rows(_factored_series(x, degree), p)
    return dc[:, None] * h


def _ol(x: np.ndarray, table: "OLTable") -> np.ndarray:
    norm = np.linalg.norm(x, axis=1)
    a, b = table.lookup(norm)
    out = b[:, None] * x
    out[:, 0] += a * SQRT_4PI
    return out


def _exp_ol(f: np.ndarray) -> np.ndarray:
    order = int(round(math.sqrt(f.shape[1])))
    dc, fhat = _split_dc(f)
    return dc[:, None] * _ol(fhat, ol_table(order))


def _exp_hyb(f: np.ndarray) -> np.ndarray:
    order = int(round(math.sqrt(f.shape[1])))
    dc, fhat = _split_dc(f)
    x, p = _scaled(fhat)
    h = _square_rows(_ol(x, ol_table(order)), p)
    return dc[:, None] * h


def exp_f64(f: np.ndarray, method: str, degree=None) -> np.ndarray:
    """float64 SH exponential of rows ``f`` (shape (B, n*n)) by one of :data:`EXP_METHODS`."""
    degree = check_degree(method, degree)
    if method == "ps":
        return _exp_ps(f, degree)
    if method == "ps_star":
        return _exp_ps_star(f, degree)
    if method == "ol":
        return _exp_ol(f)
    return _exp_hyb(f)


def exp_series_limit(f: np.ndarray) -> np.ndarray:
    """The product series exp*(f) summed to infinite degree, ``1 + R^T q(D) R f`` (eq. 28).

    This is the limit of PS-p as p grows (left-to-right products equal powers of ``M_f`` by
    commutativity), computed by an eigendecomposition of the product matrix: an oracle for the
    run-time methods, too slow for per-receiver use. Rows of shape (B, n*n), float64.
    """
    m = product_matrix(f)
    w, r = np.linalg.eigh(m)
    small = np.abs(w) < 1e-8
    q = np.where(small, 1.0 + 0.5 * w, np.expm1(w) / np.where(small, 1.0, w))
    coeff = np.einsum("bji,bj->bi", r, f) * q
    out = np.einsum("bij,bj->bi", r, coeff)
    out[:, 0] += SQRT_4PI
    return out


def exp_volterra(f: np.ndarray, quadrature_degree: int | None = None) -> np.ndarray:
    """The SH projection of ``exp(f(s))`` by numerical integration (eq. 10), rows (B, n*n).

    Unlike the product series this does not truncate after each product; it is the function
    the series approximates. Gauss-Legendre quadrature of degree ``quadrature_degree``
    (default ``8 n + 24``).
    """
    order = int(round(math.sqrt(f.shape[1])))
    q = quadrature.gauss_legendre(quadrature_degree or 8 * order + 24)
    y = basis(q.directions, order)
    return (np.exp(f @ y.T) * q.weights) @ y


def log_f64(g: np.ndarray, eps_rel: float = LOG_EPS_REL) -> np.ndarray:
    """float64 SH logarithm of rows ``g`` (B, n*n) by eigen-inversion of ``M_g`` (eqs. 30-32)."""
    if not (np.isfinite(eps_rel) and 0.0 < eps_rel < 1.0):
        raise ValueError(f"log: eps_rel must be in (0, 1), got {eps_rel!r}")
    m = product_matrix(g)
    w, r = np.linalg.eigh(m)
    largest = w[:, -1:]
    if np.any(largest <= 0.0):
        bad = int(np.flatnonzero(largest[:, 0] <= 0.0)[0])
        raise ValueError(
            f"log: row {bad} has a product matrix without a positive eigenvalue (largest "
            f"{largest[bad, 0]:.3g}); g is not a visibility-like function"
        )
    w = np.maximum(w, eps_rel * largest)
    near_one = np.abs(w - 1.0) < 1e-6
    t = w - 1.0
    qp = np.where(near_one, 1.0 - 0.5 * t + t * t / 3.0, np.log(w) / np.where(near_one, 1.0, t))
    d = g.copy()
    d[:, 0] -= SQRT_4PI
    coeff = np.einsum("bji,bj->bi", r, d) * qp
    return np.einsum("bij,bj->bi", r, coeff)


# ----------------------------------------------------------------------------------------------
# Tables
# ----------------------------------------------------------------------------------------------


def _zonal_full(zh: np.ndarray, order: int) -> np.ndarray:
    """ZH coefficients about +z (..., n) as full SH vectors (..., n*n)."""
    out = np.zeros(zh.shape[:-1] + (order * order,))
    for l in range(order):
        out[..., l * l + l] = zh[..., l]
    return out


@dataclass(frozen=True)
class OLTable:
    """Optimal-linear coefficients a(||f^||), b(||f^||) of one SH order (eqs. 23-24).

    Attributes:
        order: SH order n.
        norm: uniform grid of ``||f^||`` from 0 to ``norm_max``, shape (S,), float64.
        a, b: the coefficients on that grid, shape (S,) each.
        norm_max: end of the table: the largest ``||f^||`` reached by a blocking cap before
            ``||f^||(theta)`` stops increasing (inputs beyond it use the last entries).
        theta_max: cap angular radius (radians) at which ``norm_max`` is reached.
        curve_theta, curve_norm, curve_a, curve_b: the raw curves over cap radius theta
            (before resampling), shape (K,) each, for plots and checks.
    """

    order: int
    norm: np.ndarray
    a: np.ndarray
    b: np.ndarray
    norm_max: float
    theta_max: float
    curve_theta: np.ndarray
    curve_norm: np.ndarray
    curve_a: np.ndarray
    curve_b: np.ndarray

    def lookup(self, norm) -> tuple[np.ndarray, np.ndarray]:
        """Linearly interpolated (a, b) at ``norm`` (clamped to the table's ends)."""
        x = np.asarray(norm, np.float64)
        return np.interp(x, self.norm, self.a), np.interp(x, self.norm, self.b)


@dataclass(frozen=True)
class LogCapTable:
    """ZH coefficients of the SH log of a blocking cap's visibility over its angular radius.

    ``zh[k]`` are the per-band coefficients ``f_l(theta_k)`` of ``log(g(theta_k))`` where
    ``g(theta)`` is the visibility of a blocker covering the cap of half-angle theta about +z
    (:func:`warpshade.basis.sh.cap_zh` with ``blocked=True``); rotate onto any axis with the ZH
    rule :func:`warpshade.basis.sh.zh_to_sh` (SHEXP paper eq. 34).

    Attributes:
        order: SH order n.
        theta: uniform grid over [0, ``CAP_THETA_MAX``], radians, shape (S,).
        zh: shape (S, n), float64.
        eps_rel: the eigenvalue clipping used by the log.
    """

    order: int
    theta: np.ndarray
    zh: np.ndarray
    eps_rel: float

    def lookup(self, theta) -> np.ndarray:
        """Linearly interpolated ZH coefficients at ``theta`` (clamped to [0, theta_max]), (..., n)."""
        t = np.clip(np.asarray(theta, np.float64), 0.0, self.theta[-1])
        pos = t / self.theta[-1] * (len(self.theta) - 1)
        i0 = np.minimum(np.floor(pos).astype(np.int64), len(self.theta) - 2)
        w = (pos - i0)[..., None]
        return (1.0 - w) * self.zh[i0] + w * self.zh[i0 + 1]


def _check_samples(samples) -> int:
    if not isinstance(samples, (int, np.integer)) or samples < 16:
        raise ValueError(f"table samples must be an integer >= 16, got {samples!r}")
    return int(samples)


@functools.lru_cache(maxsize=None)
def log_cap_table(order: int, samples: int = TABLE_SAMPLES, eps_rel: float = LOG_EPS_REL) -> LogCapTable:
    """Build (once per order) the table of blocking-cap log visibility, see :class:`LogCapTable`."""
    samples = _check_samples(samples)
    theta = np.linspace(0.0, CAP_THETA_MAX, samples)
    g = _zonal_full(cap_zh(theta, order, blocked=True), order)
    f = log_f64(g, eps_rel)
    zh = f[:, [l * l + l for l in range(order)]]
    zh[0] = 0.0  # log of the unblocked sphere is exactly 0
    theta.setflags(write=False)
    zh.setflags(write=False)
    return LogCapTable(order, theta, zh, float(eps_rel))


@functools.lru_cache(maxsize=None)
def ol_table(order: int, samples: int = TABLE_SAMPLES, eps_rel: float = LOG_EPS_REL) -> OLTable:
    """Build (once per order) the OL a/b table by the least-squares projection of eq. 24.

    For blocking caps of angular radius theta in (0, pi/2]: ``g`` = cap visibility,
    ``f = log(g)`` (eq. 30), ``f^`` = f without DC, ``g^ = exp(-f_0 / sqrt(4 pi)) g``; then
    ``a = g^_0 / sqrt(4 pi)`` and ``b = (g^ . f^) / (f^ . f^)``. The curves are kept while
    ``||f^||`` increases with theta, then resampled on a uniform grid in ``||f^||`` (a = b = 1 at
    0, the limit of a vanishing cap).
    """
    samples = _check_samples(samples)
    theta = np.linspace(0.0, CAP_THETA_MAX, _OL_BUILD_SAMPLES + 1)[1:]
    g = _zonal_full(cap_zh(theta, order, blocked=True), order)
    f = log_f64(g, eps_rel)
    fhat = f.copy()
    fhat[:, 0] = 0.0
    norm = np.linalg.norm(fhat, axis=1)
    ghat = np.exp(-f[:, :1] / SQRT_4PI) * g
    a = ghat[:, 0] / SQRT_4PI
    b = np.einsum("bi,bi->b", ghat, fhat) / np.maximum(norm * norm, 1e-300)
    stop = np.flatnonzero(np.diff(norm) <= 0.0)
    end = int(stop[0]) + 1 if stop.size else norm.size
    c_theta = np.r_[0.0, theta[:end]]
    c_norm = np.r_[0.0, norm[:end]]
    c_a = np.r_[1.0, a[:end]]
    c_b = np.r_[1.0, b[:end]]
    grid = np.linspace(0.0, c_norm[-1], samples)
    arrays = [grid, np.interp(grid, c_norm, c_a), np.interp(grid, c_norm, c_b), c_theta, c_norm, c_a, c_b]
    for arr in arrays:
        arr.setflags(write=False)
    return OLTable(order, arrays[0], arrays[1], arrays[2], float(c_norm[-1]), float(c_theta[-1]), *arrays[3:])
