"""The NDF of a microfacet model (:mod:`._brdf`) as spherical Gaussians (Wang et al. 2009, sec. 4.2).
Float64 NumPy/SciPy; local frame, +z the normal.

* :func:`ndf_lobes` -- the NDF as an :class:`~warpshade.basis.sg.SGMixture` (scalar amplitudes,
  local frame): closed forms for Cook-Torrance (eq. 12), Beckmann, Blinn-Phong and isotropic
  Ward; fits with free axes (L-BFGS-B) for anisotropic Ward and Ashikhmin-Shirley; a fit about
  z+ (Levenberg-Marquardt) for a tabulated NDF. :func:`fit_ndf` is the fitter itself.

Closed forms (``lambda``, ``mu``) of the single NDF lobe ``mu exp(lambda (h_z - 1))``:

=================  =========================  ====================================================
model              D(h)                       lobe
=================  =========================  ====================================================
cook-torrance      ``exp(-(theta_h / m)^2)``   ``2 / m^2``, 1 (eq. 12)
beckmann           ``exp(-tan^2 / a^2) /       ``2 / a^2``, ``lambda^2 / (2 pi (lambda - 1 +
                   (pi a^2 cos^4)``            e^-lambda))`` (``form="normalized"``, default)
blinn-phong        ``h_z^p``                   ``p``, 1 (``h_z^p = exp(p ln h_z)``, ``ln h_z ~ h_z - 1``)
ward (isotropic)   ``exp(-tan^2 / alpha^2)``   ``2 / alpha^2``, 1
=================  =========================  ====================================================

Beckmann: ``tan^2 theta ~ 2 (1 - cos theta)`` gives the sharpness. For the amplitude three
closed forms were measured (relative L2 error of the lobe against ``D`` over the hemisphere of
``h``, ``benchmarks/bench_sg_fit.py``): ``"paper"`` (``mu = 1 / (pi a^2)``, the peak value; 0.031
at a = 0.2, 0.18 at 0.5), ``"taylor"`` (also matching the ``cos^-4`` to second order,
``lambda = 2 / a^2 - 4``; worse: 0.041 and 0.44, and undefined for a >= 0.707) and
``"normalized"`` (``mu`` such that the lobe keeps the NDF's projected-area normalisation
``integral D(h) h_z dh = 1``; 0.019 and 0.12; at most 1.35 times the error of the L2-optimal
single lobe for a in [0.02, 1.5], within 1 % of it for a >= 0.7). ``"normalized"`` is the default.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares, minimize, nnls

from ...basis.sg import SGMixture
from ._brdf import BECKMANN_FORMS, DEFAULT_LOBES, MAX_SHARPNESS, check_positive, microfacet_brdf, split_params

__all__ = [
    "NDFFit",
    "beckmann_lobe",
    "fit_model_ndf",
    "fit_ndf",
]


def _key(model: str, params: dict):
    """A hashable key of a model and its parameters (arrays by shape and bytes)."""
    items = []
    for k in sorted(params):
        v = params[k]
        if isinstance(v, (np.ndarray, list, tuple)):
            a = np.asarray(v, np.float64)
            v = (a.shape, a.tobytes())
        items.append((k, v))
    return (model, tuple(items))


def beckmann_lobe(roughness: float, form: str = "normalized") -> tuple[float, float]:
    """(sharpness, amplitude) of the single SG lobe about z+ for the Beckmann NDF
    ``exp(-tan^2 / a^2) / (pi a^2 cos^4)`` (module docstring for the forms)."""
    a = check_positive(roughness, "roughness", "beckmann_lobe", 2.0)
    if form == "paper":
        return 2.0 / (a * a), 1.0 / (np.pi * a * a)
    if form == "taylor":
        lam = 2.0 / (a * a) - 4.0
        if lam <= 0.0:
            raise ValueError(f"beckmann_lobe: form 'taylor' needs roughness < 1/sqrt(2), got {roughness!r}")
        return lam, 1.0 / (np.pi * a * a)
    if form == "normalized":
        lam = 2.0 / (a * a)
        # integral_H mu exp(lam (z - 1)) z dw = 2 pi mu (lam - 1 + e^-lam) / lam^2 := 1
        den = lam - (-math.expm1(-lam)) if lam > 1e-3 else lam * lam * (0.5 - lam / 6.0)
        return lam, lam * lam / (2.0 * np.pi * den)
    raise ValueError(f"beckmann_lobe: form must be one of {BECKMANN_FORMS}, got {form!r}")


def _z_lobe(lam: float, mu: float) -> SGMixture:
    return SGMixture(np.array([[0.0, 0.0, 1.0]]), np.array([lam]), np.array([mu]))


_FIT_CACHE: dict = {}
_FIT_CACHE_SIZE = 64


def ndf_lobes(model: str, **params) -> SGMixture:
    """The NDF of a model as SG lobes in the local frame (scalar amplitudes, sorted by increasing
    sharpness).

    Closed forms (one lobe about z+, module docstring): ``cook-torrance`` (``m``), ``beckmann``
    (``roughness``, ``form`` in :data:`BECKMANN_FORMS`), ``blinn-phong`` (``exponent``), isotropic
    ``ward`` (``alpha_x == alpha_y``) and isotropic ``ashikhmin-shirley`` (``nu == nv``: lobe
    ``(nu, 1)``). Fits: anisotropic ``ward`` and ``ashikhmin-shirley`` with ``lobes`` free-axis
    lobes (L-BFGS-B, :func:`fit_ndf`); ``tabulated-ndf`` (``theta_h``, ``ndf_values``) with ``lobes``
    (1 or 2) lobes about z+ (Levenberg-Marquardt). Fits are cached per parameter set.

    Parameters that only the exact BRDF uses (``f0``, ``eta``, ``specular``, ...) are accepted.

    Raises:
        ValueError: unknown model or parameter, or parameters out of range (named).
    """
    b, opts = split_params(model, params, "ndf_lobes")
    brdf = microfacet_brdf(model, **b)
    if model == "cook-torrance":
        return _z_lobe(2.0 / brdf.m**2, 1.0)
    if model == "beckmann":
        return _z_lobe(*beckmann_lobe(brdf.roughness, opts.get("form", "normalized")))
    if model == "blinn-phong":
        return _z_lobe(float(brdf.exponent), 1.0)
    if model == "ward" and brdf.isotropic:
        return _z_lobe(2.0 / brdf.alpha_x**2, 1.0)
    if model == "ashikhmin-shirley" and brdf.isotropic:
        return _z_lobe(brdf.nu, 1.0)
    m = fit_model_ndf(model, **params).mixture
    return SGMixture(m.axes.copy(), m.sharpness.copy(), m.amplitude.copy())


def fit_model_ndf(model: str, **params) -> "NDFFit":
    """The fit behind :func:`ndf_lobes` for the fitted models (anisotropic ``ward`` and
    ``ashikhmin-shirley``: free axes, L-BFGS-B; ``tabulated-ndf``: about z+, Levenberg-Marquardt), with
    its error report. Cached per parameter set (the last 64), so a following :func:`ndf_lobes` or
    :func:`view_slice` with the same parameters does not fit again.

    Raises:
        ValueError: a model with a closed form (use :func:`ndf_lobes`), or bad parameters.
    """
    b, opts = split_params(model, params, "fit_model_ndf")
    brdf = microfacet_brdf(model, **b)
    if model not in DEFAULT_LOBES or getattr(brdf, "isotropic", False):
        raise ValueError(f"fit_model_ndf: model {model!r} with these parameters has a closed form (ndf_lobes)")
    lobes = opts.get("lobes", DEFAULT_LOBES[model])
    if isinstance(lobes, bool) or not isinstance(lobes, (int, np.integer)) or not 1 <= int(lobes) <= 16:
        raise ValueError(f"ndf_lobes: lobes must be an integer in 1..16, got {lobes!r}")
    if model == "tabulated-ndf" and int(lobes) > 2:
        raise ValueError(f"ndf_lobes: lobes for model 'tabulated-ndf' must be 1 or 2 (fixed z+ axes), got {lobes!r}")
    key = _key(model, {**b, "lobes": int(lobes)})
    if key not in _FIT_CACHE:
        axes = "fixed" if model == "tabulated-ndf" else "free"
        fit = fit_ndf(brdf.ndf, int(lobes), axes=axes)
        if len(_FIT_CACHE) >= _FIT_CACHE_SIZE:
            _FIT_CACHE.pop(next(iter(_FIT_CACHE)))
        _FIT_CACHE[key] = fit
    return _FIT_CACHE[key]


# ------------------------------------------------------------------------------------------------
# NDF fitting


@dataclass
class NDFFit:
    """Result of :func:`fit_ndf`.

    Attributes:
        mixture: the fitted lobes (local frame, scalar amplitudes in the NDF's units, sorted by
            increasing sharpness).
        relative_error: ``||D* - D|| / ||D||`` (L2 over the fitting cap, see :func:`fit_ndf`).
        initial_error: the same for the starting guess.
        theta_max: polar radius of the fitting cap about z+ (radians).
        iterations: optimiser iterations; success / message: the optimiser's report.
    """

    mixture: SGMixture
    relative_error: float
    initial_error: float
    theta_max: float
    iterations: int
    success: bool
    message: str


def _cap_quadrature(theta_max: float, theta_nodes: int, azimuth_nodes: int):
    """Gauss-Legendre in theta on [0, theta_max] x uniform azimuths: (dirs (N, 3), weights (N,))."""
    x, w = np.polynomial.legendre.leggauss(theta_nodes)
    t = 0.5 * theta_max * (x + 1.0)
    wt = 0.5 * theta_max * w * np.sin(t)
    phi = (np.arange(azimuth_nodes) + 0.5) * (2.0 * np.pi / azimuth_nodes)
    tt, pp = np.meshgrid(t, phi, indexing="ij")
    st = np.sin(tt)
    dirs = np.stack([st * np.cos(pp), st * np.sin(pp), np.cos(tt)], -1).reshape(-1, 3)
    return dirs, np.repeat(wt * (2.0 * np.pi / azimuth_nodes), azimuth_nodes)


def _support_radius(ndf_fn, threshold: float = 1e-6) -> float:
    """Polar radius about z+ beyond which the NDF stays under ``threshold`` times its peak."""
    theta = np.concatenate([np.geomspace(1e-4, 0.5 * np.pi, 600)])
    phi = np.linspace(0.0, 2.0 * np.pi, 48, endpoint=False)
    tt, pp = np.meshgrid(theta, phi, indexing="ij")
    dirs = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], -1)
    vals = np.asarray(ndf_fn(dirs), np.float64)
    if vals.shape != tt.shape:
        raise ValueError(f"fit_ndf: ndf_fn must map directions (..., 3) to values (...,), got shape {vals.shape}")
    if not np.all(np.isfinite(vals)) or np.any(vals < 0.0):
        raise ValueError("fit_ndf: ndf_fn returned negative or non-finite values")
    row = vals.max(axis=1)
    peak = row.max()
    if not peak > 0.0:
        raise ValueError("fit_ndf: ndf_fn is zero everywhere on the hemisphere")
    above = np.nonzero(row >= threshold * peak)[0]
    return float(min(0.5 * np.pi, 1.5 * theta[above[-1]] + 1e-3))


def _unpack(x, k):
    q = x[: 3 * k].reshape(k, 3)
    qn = np.maximum(np.linalg.norm(q, axis=1), 1e-12)
    return q / qn[:, None], qn, np.exp(x[3 * k : 4 * k]), x[4 * k :]


def _objective_free(x, dirs, w, d, scale, k):
    """Relative squared L2 error and its gradient for free axes (q, ln lambda, mu)."""
    p, qn, lam, mu = _unpack(x, k)
    c = dirs @ p.T
    g = np.exp(lam * (c - 1.0))
    r = g @ mu - d
    wr = w * r
    e = float(wr @ r) * scale
    gm = 2.0 * scale * (wr @ g)                                     # dE/dmu
    gl = 2.0 * scale * ((wr @ (g * (c - 1.0))) * mu) * lam          # dE/dln(lambda)
    gp = 2.0 * scale * ((g * wr[:, None]).T @ dirs) * (mu * lam)[:, None]   # dE/dp
    gq = (gp - np.sum(gp * p, axis=1, keepdims=True) * p) / qn[:, None]
    return e, np.concatenate([gq.ravel(), gl, gm])


def _free_start(dirs, w, d, k, spread: float):
    """Starting lobes from the NDF's moments: axes along its principal (widest) direction about the
    mean axis, sharpness from the narrow direction, amplitudes by NNLS."""
    wd = w * d
    mean = wd @ dirs
    p0 = mean / np.linalg.norm(mean)
    helper = np.array([1.0, 0.0, 0.0]) if abs(p0[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(p0, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(p0, t1)
    xy = np.stack([dirs @ t1, dirs @ t2], -1)
    cov = (xy * wd[:, None]).T @ xy / wd.sum()
    ev, evec = np.linalg.eigh(cov)
    var_minor, var_major = max(ev[0], 1e-12), max(ev[1], 1e-12)
    major = evec[0, 1] * t1 + evec[1, 1] * t2
    if k == 1:
        axes = p0[None]
        lam = np.array([1.0 / math.sqrt(var_minor * var_major)])
    else:
        s = spread * math.sqrt(var_major) * np.linspace(-1.0, 1.0, k)
        axes = np.cos(s)[:, None] * p0 + np.sin(s)[:, None] * major
        lam = np.full(k, 1.0 / max(var_minor, (s[1] - s[0]) ** 2))
    g = np.exp(lam * (dirs @ axes.T - 1.0))
    sw = np.sqrt(w)
    mu, _ = nnls(g * sw[:, None], d * sw)
    mu = np.where(mu > 0.0, mu, 1e-3 * max(mu.max(), 1e-3))
    return np.concatenate([axes.ravel(), np.log(np.clip(lam, 1e-2, MAX_SHARPNESS)), mu])


def fit_ndf(ndf_fn, lobes: int, axes: str = "free", theta_max: float | None = None, theta_nodes: int = 64,
            azimuth_nodes: int | None = None, max_iterations: int = 1000) -> NDFFit:
    """Fit ``lobes`` SG lobes to an NDF in L2 over a cap about z+ (eq. 6, sec. 4.2).

    ``axes="free"``: axes, sharpness and amplitudes by L-BFGS-B
    (``scipy.optimize.minimize(method="L-BFGS-B")``, analytic gradient; axes as free 3-vectors
    normalised inside, ``ln lambda`` in [ln 0.01, ln 1e7], ``mu >= 0``), started from the NDF's
    moments (lobes spread along its widest direction) and from a tighter spread; the better result
    is kept. ``axes="fixed"``: every axis is z+ and ``ln lambda``, ``ln mu`` are fitted by
    Levenberg-Marquardt (``scipy.optimize.least_squares(method="lm")``) from half-maximum-width
    starts (for several lobes, sharpness spread geometrically about it by factors 4, 16 and 64;
    the best result is kept).

    Args:
        ndf_fn: callable, local half vectors (..., 3) -> D (...,), float64, >= 0.
        lobes: number of lobes (>= 1; with fixed axes more than 2 are redundant).
        axes: ``"free"`` or ``"fixed"``.
        theta_max: cap radius (radians); default: 1.5 times the polar angle beyond which D stays
            under 1e-6 of its peak (at most pi/2).
        theta_nodes, azimuth_nodes: Gauss-Legendre nodes in theta, uniform azimuths (default 192
            free, 32 fixed).
        max_iterations: optimiser limit.

    Returns:
        :class:`NDFFit`. Errors are relative L2 over the cap with the quadrature above.

    Raises:
        ValueError: bad ``lobes``/``axes``/``theta_max`` or an NDF that is zero, negative or NaN.
    """
    if isinstance(lobes, bool) or not isinstance(lobes, (int, np.integer)) or lobes < 1:
        raise ValueError(f"fit_ndf: lobes must be an integer >= 1, got {lobes!r}")
    if axes not in ("free", "fixed"):
        raise ValueError(f"fit_ndf: axes must be 'free' or 'fixed', got {axes!r}")
    k = int(lobes)
    if theta_max is None:
        theta_max = _support_radius(ndf_fn)
    elif not (0.0 < float(theta_max) <= 0.5 * np.pi + 1e-12):
        raise ValueError(f"fit_ndf: theta_max must be in (0, pi/2], got {theta_max!r}")
    theta_max = float(theta_max)
    azimuth_nodes = azimuth_nodes or (192 if axes == "free" else 32)
    dirs, w = _cap_quadrature(theta_max, int(theta_nodes), int(azimuth_nodes))
    d_raw = np.asarray(ndf_fn(dirs), np.float64)
    if d_raw.shape != w.shape or not np.all(np.isfinite(d_raw)) or np.any(d_raw < 0.0):
        raise ValueError("fit_ndf: ndf_fn must return finite values >= 0 of shape (N,) for (N, 3) directions")
    peak = float(d_raw.max())
    if not peak > 0.0:
        raise ValueError("fit_ndf: ndf_fn is zero on the fitting cap")
    d = d_raw / peak
    scale = 1.0 / float(w @ (d * d))

    if axes == "fixed":
        z = dirs[:, 2]
        sw = np.sqrt(w * scale)
        # half-maximum start: exp(lam (cos t_half - 1)) = 1/2 along the azimuthal mean
        theta = np.linspace(0.0, theta_max, 400)
        prof = np.asarray(ndf_fn(np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], -1)), np.float64) / peak
        below = np.nonzero(prof < 0.5 * prof[0])[0]
        t_half = theta[below[0]] if below.size else theta_max
        lam0 = math.log(2.0) / max(1.0 - math.cos(t_half), 1e-12)
        spreads = (1.0,) if k == 1 else (4.0, 16.0, 64.0)

        def resid(x):
            lam, mu = np.exp(x[:k]), np.exp(x[k:])
            g = np.exp(lam[None] * (z[:, None] - 1.0))
            return sw * (g @ mu - d)

        def jac(x):
            lam, mu = np.exp(x[:k]), np.exp(x[k:])
            g = np.exp(lam[None] * (z[:, None] - 1.0)) * mu[None]
            return sw[:, None] * np.concatenate([g * (z[:, None] - 1.0) * lam[None], g], axis=1)

        e0, res = None, None
        for spread in spreads:
            # starts with the sharpness spread geometrically over a factor ``spread`` about lam0
            factors = np.geomspace(1.0 / math.sqrt(spread), math.sqrt(spread), k) if k > 1 else np.ones(1)
            x0 = np.concatenate([np.log(np.clip(lam0 * factors, 1e-2, MAX_SHARPNESS)),
                                 np.log(np.full(k, prof[0] / k))])
            e = float(np.linalg.norm(resid(x0)))
            e0 = e if e0 is None else min(e0, e)
            r = least_squares(resid, x0, jac=jac, method="lm", max_nfev=max_iterations * (2 * k + 1))
            if np.all(np.isfinite(r.x)) and (res is None or r.cost < res.cost):
                res = r
        x = res.x
        lam = np.clip(np.exp(x[:k]), 0.0, MAX_SHARPNESS)
        mu = np.exp(x[k:])
        err = float(np.linalg.norm(resid(np.concatenate([np.log(lam), x[k:]]))))
        order = np.argsort(lam, kind="stable")
        mix = SGMixture(np.tile([0.0, 0.0, 1.0], (k, 1)), lam[order], mu[order] * peak)
        return NDFFit(mix, err, e0, theta_max, int(res.nfev), bool(res.success), str(res.message))

    bounds = [(None, None)] * (3 * k) + [(math.log(1e-2), math.log(MAX_SHARPNESS))] * k + [(0.0, None)] * k
    best, best_scale = None, None
    e_start = None
    for spread in (1.5, 0.75):
        x0 = _free_start(dirs, w, d, k, spread)
        e0 = _objective_free(x0, dirs, w, d, scale, k)[0]
        e_start = e0 if e_start is None else min(e_start, e0)
        # the optimiser sees axis vectors scaled by sqrt(lambda) (one lobe width ~ 1 unit), so that
        # all variables move the objective by comparable amounts
        var_scale = np.concatenate([np.full(3 * k, 1.0 / math.sqrt(float(np.exp(np.median(x0[3 * k : 4 * k]))))),
                                    np.ones(2 * k)])

        def scaled(y, s=var_scale):
            e, g = _objective_free(y * s, dirs, w, d, scale, k)
            return e, g * s

        res = minimize(scaled, x0 / var_scale, jac=True, method="L-BFGS-B", bounds=bounds,
                       options={"maxiter": max_iterations, "ftol": 1e-13, "gtol": 1e-9})
        if best is None or res.fun < best.fun:
            best, best_scale = res, var_scale
        if k == 1:
            break
    p, _, lam, mu = _unpack(best.x * best_scale, k)
    order = np.argsort(lam, kind="stable")
    mix = SGMixture(p[order], lam[order], mu[order] * peak)
    return NDFFit(mix, math.sqrt(max(best.fun, 0.0)), math.sqrt(e_start), theta_max, int(best.nit), bool(best.success),
                  str(best.message))
