"""Specular reflectance as spherical Gaussians (Wang et al. 2009, sec. 4). Float64 NumPy/SciPy.

Frame and units: everything is in the local shading frame, +z the surface normal, +x the tangent
``u`` of the anisotropic models (the Ward ``alpha_x`` / Ashikhmin-Shirley ``nu`` direction), +y
the bitangent. ``view`` (``o``) points towards the viewer and ``light`` (``i``) towards the
light, unit vectors; ``h = (o + i) / |o + i|``. BRDF values are in 1/sr without the cosine.

A microfacet specular lobe is factored as ``rho_s(o, i) = M_o(i) D(h)`` (eq. 9): ``D`` is the
normal distribution (NDF), ``M_o`` the smooth rest (Fresnel, shadowing, normalisation). This
module provides:

* exact models as :class:`~warpshade.scene.materials.BRDF` subclasses, each with ``ndf(h)`` and
  ``remaining_factor(view, light)`` whose product is ``evaluate``: :class:`CookTorrance`
  (eq. 10-11, Fresnel eq. 14, the Cook-Torrance V-groove shadowing), :class:`Ward` (Ward 1992,
  anisotropic when ``alpha_x != alpha_y``), :class:`AshikhminShirley` (its specular lobe) and
  :class:`TabulatedMicrofacet` (eq. 13: a tabulated isotropic NDF and shadowing). The existing
  :class:`~warpshade.scene.materials.Microfacet` (Beckmann) and
  :class:`~warpshade.scene.materials.BlinnPhong` are used as they are (:func:`make_brdf`).
* :func:`ndf_lobes` -- the NDF as an :class:`~warpshade.basis.sg.SGMixture` (scalar amplitudes,
  local frame): closed forms for Cook-Torrance (eq. 12), Beckmann, Blinn-Phong and isotropic
  Ward; fits with free axes (L-BFGS-B) for anisotropic Ward and Ashikhmin-Shirley; a fit about
  z+ (Levenberg-Marquardt) for a tabulated NDF. :func:`fit_ndf` is the fitter itself.
* :func:`remaining_factor` -- ``M_o(i)`` of each model.
* :func:`view_slice` -- the spherical warp (eq. 17-22): the BRDF slice ``rho_s*(i; o)`` for one
  view as an SG mixture over the light direction ``i``.
* :func:`slice_error` -- the relative L2 error of that slice (times the cosine) against the exact
  BRDF, by quadrature.

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

Failure modes (documented, tested): the warp approximates each warped lobe as isotropic, so the
slice error grows at grazing views (sec. 4.3) -- for sharp lobes it tends to
:func:`isotropic_warp_floor` (0.072 at 30 deg, 0.34 at 60 deg, 0.62 at 75 deg, 0.96 at 85 deg);
lobes whose warped axis falls below the horizon (or whose axis faces away from the viewer) are
culled -- amplitude 0, flagged in :attr:`ViewSlice.culled`; views at or below the horizon give an
all-culled slice.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares, minimize, nnls

from ...basis.sg import SGMixture
from ...scene.materials import BRDF, BlinnPhong, Microfacet

__all__ = [
    "BECKMANN_FORMS",
    "DEFAULT_LOBES",
    "MODELS",
    "AshikhminShirley",
    "CookTorrance",
    "NDFFit",
    "TabulatedMicrofacet",
    "ViewSlice",
    "Ward",
    "beckmann_lobe",
    "eta_from_f0",
    "fit_model_ndf",
    "fit_ndf",
    "fresnel_cook_torrance",
    "fresnel_schlick",
    "isotropic_warp_floor",
    "make_brdf",
    "ndf_exact",
    "ndf_lobes",
    "remaining_factor",
    "shadowing_cook_torrance",
    "slice_error",
    "tabulated_ndf",
    "view_slice",
]

#: Model names accepted by :func:`make_brdf`, :func:`ndf_lobes` and :func:`view_slice`.
MODELS = ("beckmann", "cook-torrance", "blinn-phong", "ward", "ashikhmin-shirley", "tabulated")
#: Closed forms of the single Beckmann lobe (module docstring).
BECKMANN_FORMS = ("normalized", "paper", "taylor")
#: Default lobe counts of the fitted NDFs (the paper uses 7 for Ashikhmin-Shirley, 1-2 tabulated).
DEFAULT_LOBES = {"ward": 4, "ashikhmin-shirley": 7, "tabulated": 1}
#: Cosines are floored at this value in the ``1 / (n.i)`` and ``1 / (n.o)`` normalisations, so
#: that near-grazing directions give large but finite factors.
COS_FLOOR = 1e-6
_MAX_SHARPNESS = 1e7


def _check_positive(value, name: str, owner: str, upper: float | None = None) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}: {name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v <= 0.0 or (upper is not None and v > upper):
        bound = f" and <= {upper}" if upper is not None else ""
        raise ValueError(f"{owner}: {name} must be finite, > 0{bound}, got {value!r}")
    return v


def _check_unit_interval(value, name: str, owner: str) -> float:
    v = float(value)
    if not (0.0 <= v <= 1.0):
        raise ValueError(f"{owner}: {name} must be in [0, 1], got {value!r}")
    return v


def _unit(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape[-1:] != (3,):
        raise ValueError(f"{name}: expected directions of shape (..., 3), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: directions must be finite")
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    if np.any(n == 0.0):
        raise ValueError(f"{name}: directions must be nonzero")
    return a / n


def _half(o: np.ndarray, i: np.ndarray) -> np.ndarray:
    h = o + i
    return h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)


# ------------------------------------------------------------------------------------------------
# Fresnel and shadowing


def eta_from_f0(f0) -> np.ndarray:
    """The relative index of refraction whose normal-incidence reflectance is ``f0`` (in [0, 1)):
    ``eta = (1 + sqrt(f0)) / (1 - sqrt(f0))``."""
    f = np.asarray(f0, np.float64)
    if np.any(~np.isfinite(f)) or np.any(f < 0.0) or np.any(f >= 1.0):
        raise ValueError(f"eta_from_f0: f0 must be in [0, 1), got {f0!r}")
    s = np.sqrt(f)
    return (1.0 + s) / (1.0 - s)


def fresnel_cook_torrance(c, eta) -> np.ndarray:
    """Unpolarised dielectric Fresnel reflectance (eq. 14, Cook and Torrance 1982).

    ``F = (g - c)^2 / (2 (g + c)^2) (1 + (c (g + c) - 1)^2 / (c (g - c) + 1)^2)`` with
    ``g = sqrt(eta^2 + c^2 - 1)``; ``F(1) = ((eta - 1) / (eta + 1))^2``, ``F(0) = 1``. Where
    ``g^2 < 0`` (total internal reflection, only for eta < 1) F is 1.

    Args:
        c: ``|i.h|``, cosine between the light and the microfacet normal, clipped to [0, 1].
        eta: relative index of refraction, > 0 (broadcast with c).
    """
    c = np.clip(np.abs(np.asarray(c, np.float64)), 0.0, 1.0)
    eta = np.asarray(eta, np.float64)
    if np.any(~np.isfinite(eta)) or np.any(eta <= 0.0):
        raise ValueError(f"fresnel_cook_torrance: eta must be finite and > 0, got {eta!r}")
    g2 = eta * eta + c * c - 1.0
    g = np.sqrt(np.maximum(g2, 0.0))
    a = (g - c) / np.maximum(g + c, 1e-300)
    b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    return np.where(g2 > 0.0, 0.5 * a * a * (1.0 + b * b), 1.0)


def fresnel_schlick(f0, c) -> np.ndarray:
    """Schlick's approximation ``f0 + (1 - f0) (1 - c)^5`` (c clipped to [0, 1])."""
    c = np.clip(np.asarray(c, np.float64), 0.0, 1.0)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


def shadowing_cook_torrance(n_h, n_o, n_i, o_h) -> np.ndarray:
    """The V-groove geometric attenuation ``min(1, 2 (n.h)(n.o) / (o.h), 2 (n.h)(n.i) / (o.h))``
    (Cook and Torrance 1982; Blinn 1977). Arguments are cosines (broadcast); result in [0, 1]."""
    n_h, n_o, n_i, o_h = (np.asarray(x, np.float64) for x in (n_h, n_o, n_i, o_h))
    inv = 2.0 * np.maximum(n_h, 0.0) / np.maximum(o_h, 1e-12)
    return np.clip(np.minimum(inv * n_o, inv * n_i), 0.0, 1.0)


# ------------------------------------------------------------------------------------------------
# exact models


class _Factored(BRDF):
    """A BRDF written as ``M_o(i) D(h)``: subclasses define :meth:`ndf` and :meth:`_factor`."""

    def ndf(self, h) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _factor(self, o, i, h) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def remaining_factor(self, view, light) -> np.ndarray:
        """``M_o(i)`` (1/sr), 0 where either direction is at or below the horizon."""
        o = _unit(view, f"{self.name}: view")
        i = _unit(light, f"{self.name}: light")
        o, i = np.broadcast_arrays(o, i)
        above = (o[..., 2] > 0.0) & (i[..., 2] > 0.0)
        return np.where(above, self._factor(o, i, _half(o, i)), 0.0)

    def _eval(self, v, s):
        h = _half(v, s)
        return self._factor(v, s, h) * self.ndf(h)


@dataclass
class CookTorrance(_Factored):
    """The Cook-Torrance specular lobe in the paper's form (eq. 10-11):
    ``rho_s = ks F(|i.h|, eta) S(o, i) / (pi (n.i)(n.o)) exp(-(theta_h / m)^2)``.

    Attributes:
        m: roughness (radians of microfacet slope), in (0, 2].
        eta: relative index of refraction (> 1), ignored when ``f0`` is given.
        f0: normal-incidence reflectance in (0, 1); sets ``eta = eta_from_f0(f0)``.
        specular: ``ks``, >= 0.

    ``D`` is unnormalised (peak 1), as in the paper: ``ks`` carries the scale.
    """

    m: float = 0.2
    eta: float = 1.33
    f0: float | None = None
    specular: float = 1.0
    name = "cook-torrance"

    def __post_init__(self):
        self.m = _check_positive(self.m, "m", "CookTorrance", 2.0)
        if self.f0 is not None:
            f0 = float(self.f0)
            if not 0.0 < f0 < 1.0:
                raise ValueError(f"CookTorrance: f0 must be in (0, 1), got {self.f0!r}")
            self.eta = float(eta_from_f0(f0))
        eta = float(self.eta)
        if not math.isfinite(eta) or eta <= 1.0:
            raise ValueError(f"CookTorrance: eta must be finite and > 1, got {self.eta!r}")
        self.eta = eta
        if not float(self.specular) >= 0.0:
            raise ValueError(f"CookTorrance: specular must be >= 0, got {self.specular!r}")

    def ndf(self, h) -> np.ndarray:
        theta = np.arccos(np.clip(np.asarray(h, np.float64)[..., 2], -1.0, 1.0))
        return np.exp(-((theta / self.m) ** 2))

    def _factor(self, o, i, h):
        oh = np.sum(o * h, axis=-1)
        f = fresnel_cook_torrance(oh, self.eta)
        s = shadowing_cook_torrance(h[..., 2], o[..., 2], i[..., 2], oh)
        return self.specular * f * s / (np.pi * np.maximum(o[..., 2], COS_FLOOR) * np.maximum(i[..., 2], COS_FLOOR))


@dataclass
class Ward(_Factored):
    """Ward's (1992) anisotropic Gaussian lobe:
    ``rho_s = ks / (4 pi ax ay sqrt((n.i)(n.o))) exp(-tan^2 theta_h (cos^2 phi_h / ax^2 +
    sin^2 phi_h / ay^2))``, factored with ``D(h) = exp(-(h_x^2 / ax^2 + h_y^2 / ay^2) / h_z^2)``
    (peak 1) and ``M_o(i) = ks / (4 pi ax ay sqrt((n.i)(n.o)))``.

    Attributes:
        alpha_x: slope deviation along the tangent +x, in (0, 1].
        alpha_y: along the bitangent +y (default: ``alpha_x``, isotropic), in (0, 1].
        specular: ``ks`` (>= 0).
    """

    alpha_x: float = 0.2
    alpha_y: float | None = None
    specular: float = 1.0
    name = "ward"

    def __post_init__(self):
        self.alpha_x = _check_positive(self.alpha_x, "alpha_x", "Ward", 1.0)
        self.alpha_y = self.alpha_x if self.alpha_y is None else _check_positive(self.alpha_y, "alpha_y", "Ward", 1.0)
        if not float(self.specular) >= 0.0:
            raise ValueError(f"Ward: specular must be >= 0, got {self.specular!r}")

    @property
    def isotropic(self) -> bool:
        return self.alpha_x == self.alpha_y

    def ndf(self, h) -> np.ndarray:
        h = np.asarray(h, np.float64)
        z2 = np.maximum(h[..., 2], 0.0) ** 2
        q = (h[..., 0] / self.alpha_x) ** 2 + (h[..., 1] / self.alpha_y) ** 2
        return np.where(z2 > 0.0, np.exp(-q / np.maximum(z2, 1e-300)), 0.0)

    def _factor(self, o, i, h):
        c = np.maximum(o[..., 2], COS_FLOOR) * np.maximum(i[..., 2], COS_FLOOR)
        return self.specular / (4.0 * np.pi * self.alpha_x * self.alpha_y * np.sqrt(c))


@dataclass
class AshikhminShirley(_Factored):
    """The specular lobe of Ashikhmin and Shirley (2000):
    ``rho_s = ks sqrt((nu + 1)(nv + 1)) / (8 pi) (n.h)^e / ((o.h) max(n.i, n.o)) F(o.h)``,
    ``e = (nu h_x^2 + nv h_y^2) / (1 - h_z^2)``, F Schlick's with ``rs``. Factored with
    ``D(h) = (n.h)^e`` (peak 1) and the rest as ``M_o``.

    Attributes:
        nu: exponent along the tangent +x (> 0, <= 1e5). nv: along +y.
        rs: normal-incidence specular reflectance in [0, 1]. specular: ``ks`` (>= 0).
    """

    nu: float = 75.0
    nv: float = 1200.0
    rs: float = 0.05
    specular: float = 1.0
    name = "ashikhmin-shirley"

    def __post_init__(self):
        self.nu = _check_positive(self.nu, "nu", "AshikhminShirley", 1e5)
        self.nv = _check_positive(self.nv, "nv", "AshikhminShirley", 1e5)
        self.rs = _check_unit_interval(self.rs, "rs", "AshikhminShirley")
        if not float(self.specular) >= 0.0:
            raise ValueError(f"AshikhminShirley: specular must be >= 0, got {self.specular!r}")

    @property
    def isotropic(self) -> bool:
        return self.nu == self.nv

    def ndf(self, h) -> np.ndarray:
        h = np.asarray(h, np.float64)
        z = np.clip(h[..., 2], 0.0, 1.0)
        r2 = h[..., 0] ** 2 + h[..., 1] ** 2
        expo = np.where(r2 > 1e-300, (self.nu * h[..., 0] ** 2 + self.nv * h[..., 1] ** 2) / np.maximum(r2, 1e-300),
                        0.5 * (self.nu + self.nv))
        with np.errstate(divide="ignore"):
            return np.where(z > 0.0, np.exp(expo * np.log(np.maximum(z, 1e-300))), 0.0)

    def _factor(self, o, i, h):
        oh = np.sum(o * h, axis=-1)
        norm = self.specular * math.sqrt((self.nu + 1.0) * (self.nv + 1.0)) / (8.0 * np.pi)
        f = fresnel_schlick(self.rs, oh)
        return norm * f / (np.maximum(oh, COS_FLOOR) * np.maximum(np.maximum(o[..., 2], i[..., 2]), COS_FLOOR))


def tabulated_ndf(theta_h, values):
    """An isotropic NDF from samples ``D(theta_h)``: a callable ``h (..., 3) -> (...,)``
    interpolating linearly in ``theta_h = arccos(h_z)`` (0 beyond the last sample).

    Args:
        theta_h: increasing angles in [0, pi/2], radians, shape (n,), n >= 2.
        values: D at those angles, finite and >= 0, not all 0, shape (n,).
    """
    t = np.asarray(theta_h, np.float64).reshape(-1)
    d = np.asarray(values, np.float64).reshape(-1)
    if t.shape != d.shape or t.size < 2:
        raise ValueError(f"tabulated_ndf: theta_h and values must be 1-D of equal length >= 2, "
                         f"got {t.shape}, {d.shape}")
    if not np.all(np.isfinite(t)) or t[0] < 0.0 or t[-1] > 0.5 * np.pi + 1e-12 or np.any(np.diff(t) <= 0.0):
        raise ValueError("tabulated_ndf: theta_h must be finite, increasing and within [0, pi/2]")
    if not np.all(np.isfinite(d)) or np.any(d < 0.0) or not np.any(d > 0.0):
        raise ValueError("tabulated_ndf: values must be finite, >= 0 and not all 0")

    def ndf(h):
        theta = np.arccos(np.clip(np.asarray(h, np.float64)[..., 2], -1.0, 1.0))
        return np.interp(theta, t, d, left=d[0], right=0.0)

    return ndf


@dataclass
class TabulatedMicrofacet(_Factored):
    """The general microfacet model of eq. 13 with tabulated isotropic NDF and shadowing:
    ``rho_s = ks F(|i.h|, eta) S(o) S(i) / (pi (n.i)(n.o)) D(h)``.

    Attributes:
        theta_h, ndf_values: the NDF samples (:func:`tabulated_ndf`).
        shadow_theta, shadow_values: ``S(theta)`` samples over the polar angle of o or i
            (radians, increasing in [0, pi/2]; values in [0, 1]); None: S = 1.
        eta: relative index of refraction (> 1; the paper uses 1.33). specular: ``ks``.
    """

    theta_h: np.ndarray = field(default_factory=lambda: np.linspace(0.0, 0.5 * np.pi, 91))
    ndf_values: np.ndarray = field(default_factory=lambda: np.exp(-((np.linspace(0.0, 0.5 * np.pi, 91) / 0.2) ** 2)))
    shadow_theta: np.ndarray | None = None
    shadow_values: np.ndarray | None = None
    eta: float = 1.33
    specular: float = 1.0
    name = "tabulated"

    def __post_init__(self):
        self.theta_h = np.asarray(self.theta_h, np.float64)
        self.ndf_values = np.asarray(self.ndf_values, np.float64)
        self._ndf = tabulated_ndf(self.theta_h, self.ndf_values)
        if (self.shadow_theta is None) != (self.shadow_values is None):
            raise ValueError("TabulatedMicrofacet: shadow_theta and shadow_values must be given together")
        if self.shadow_theta is not None:
            st = np.asarray(self.shadow_theta, np.float64).reshape(-1)
            sv = np.asarray(self.shadow_values, np.float64).reshape(-1)
            if st.shape != sv.shape or st.size < 2 or np.any(np.diff(st) <= 0.0):
                raise ValueError("TabulatedMicrofacet: shadow_theta must be increasing, "
                                 "the same length as shadow_values")
            if not np.all(np.isfinite(sv)) or np.any(sv < 0.0) or np.any(sv > 1.0):
                raise ValueError("TabulatedMicrofacet: shadow_values must be in [0, 1]")
            self.shadow_theta, self.shadow_values = st, sv
        eta = float(self.eta)
        if not math.isfinite(eta) or eta <= 1.0:
            raise ValueError(f"TabulatedMicrofacet: eta must be finite and > 1, got {self.eta!r}")
        self.eta = eta

    def shadowing(self, cos_theta) -> np.ndarray:
        """``S(theta)`` at the given cosines (1 without a table)."""
        c = np.asarray(cos_theta, np.float64)
        if self.shadow_theta is None:
            return np.ones_like(c)
        return np.interp(np.arccos(np.clip(c, -1.0, 1.0)), self.shadow_theta, self.shadow_values)

    def ndf(self, h) -> np.ndarray:
        return self._ndf(h)

    def _factor(self, o, i, h):
        oh = np.sum(o * h, axis=-1)
        s = self.shadowing(o[..., 2]) * self.shadowing(i[..., 2])
        f = fresnel_cook_torrance(oh, self.eta)
        return self.specular * f * s / (np.pi * np.maximum(o[..., 2], COS_FLOOR) * np.maximum(i[..., 2], COS_FLOOR))

    def describe(self) -> dict:
        return {"model": self.name, "samples": int(self.theta_h.size), "eta": self.eta, "specular": self.specular}


# ------------------------------------------------------------------------------------------------
# the model registry: model name + parameters -> exact BRDF and lobe options

_BRDF_PARAMS = {
    "beckmann": ("roughness", "f0", "specular"),
    "cook-torrance": ("m", "eta", "f0", "specular"),
    "blinn-phong": ("exponent", "specular"),
    "ward": ("alpha_x", "alpha_y", "specular"),
    "ashikhmin-shirley": ("nu", "nv", "rs", "specular"),
    "tabulated": ("theta_h", "ndf_values", "shadow_theta", "shadow_values", "eta", "specular"),
}
_LOBE_PARAMS = {"beckmann": ("form",), "ward": ("lobes",), "ashikhmin-shirley": ("lobes",), "tabulated": ("lobes",)}


def _split(model: str, params: dict, caller: str):
    if model not in MODELS:
        raise ValueError(f"{caller}: model must be one of {MODELS}, got {model!r}")
    brdf_keys, lobe_keys = _BRDF_PARAMS[model], _LOBE_PARAMS.get(model, ())
    for key in params:
        if key not in brdf_keys and key not in lobe_keys:
            raise ValueError(f"{caller}: unknown parameter {key!r} for model {model!r} "
                             f"(accepted: {', '.join(brdf_keys + lobe_keys)})")
    return ({k: v for k, v in params.items() if k in brdf_keys}, {k: v for k, v in params.items() if k in lobe_keys})


def make_brdf(model: str, **params) -> BRDF:
    """The exact BRDF of a model name and its parameters (see :data:`MODELS`).

    ``beckmann``: :class:`~warpshade.scene.materials.Microfacet` (``roughness``, ``f0``,
    ``specular``); ``blinn-phong``: :class:`~warpshade.scene.materials.BlinnPhong` (``exponent``,
    ``specular``); the others the classes of this module (their attributes as keywords).
    Lobe options (``form``, ``lobes``) are accepted and ignored.
    """
    b, _ = _split(model, params, "make_brdf")
    if model == "beckmann":
        if "roughness" not in b:
            raise ValueError("make_brdf: model 'beckmann' needs parameter 'roughness'")
        return Microfacet(distribution="beckmann", **b)
    if model == "blinn-phong":
        if "exponent" not in b:
            raise ValueError("make_brdf: model 'blinn-phong' needs parameter 'exponent'")
        p = float(b["exponent"])
        if not math.isfinite(p) or p < 0.0 or p > _MAX_SHARPNESS:
            raise ValueError(f"make_brdf: exponent must be finite and in [0, {_MAX_SHARPNESS:g}], "
                             f"got {b['exponent']!r}")
        return BlinnPhong(**b)
    cls = {"cook-torrance": CookTorrance, "ward": Ward, "ashikhmin-shirley": AshikhminShirley,
           "tabulated": TabulatedMicrofacet}[model]
    return cls(**b)


def _key(model: str, params: dict):
    items = []
    for k in sorted(params):
        v = params[k]
        if isinstance(v, (np.ndarray, list, tuple)):
            a = np.asarray(v, np.float64)
            v = (a.shape, a.tobytes())
        items.append((k, v))
    return (model, tuple(items))


def ndf_exact(model: str, h, **params) -> np.ndarray:
    """The exact NDF ``D(h)`` of a model at local half vectors ``h`` (..., 3) -> (...,), float64.

    For ``beckmann`` it is :class:`~warpshade.scene.materials.Microfacet`'s own ``D`` (normalised,
    ``integral D h_z = 1``); for ``blinn-phong`` ``max(0, h_z)^p``; the others are the classes'
    ``ndf`` (peak 1)."""
    brdf = make_brdf(model, **params)
    hh = _unit(h, "ndf_exact: h")
    if isinstance(brdf, Microfacet):
        return np.where(hh[..., 2] > 0.0, brdf._d(hh[..., 2]), 0.0)
    if isinstance(brdf, BlinnPhong):
        return np.maximum(hh[..., 2], 0.0) ** brdf.exponent
    return brdf.ndf(hh)


def remaining_factor(model: str, view, light, **params) -> np.ndarray:
    """``M_o(i)`` of eq. 9 (1/sr), so that ``M_o(i) ndf_exact(h) == make_brdf(...).evaluate(o, i)``.

    ``beckmann``: exactly :class:`~warpshade.scene.materials.Microfacet`'s
    ``ks F_schlick(o.h) G_smith(o, i) / (4 (n.o)(n.i))``; ``blinn-phong``: ``ks (p + 8) / (8 pi)``;
    the others: the classes' :meth:`remaining_factor`. 0 where o or i is below the horizon.

    Args:
        view, light: local unit directions (..., 3), broadcast against each other.
    """
    brdf = make_brdf(model, **params)
    o = _unit(view, "remaining_factor: view")
    i = _unit(light, "remaining_factor: light")
    o, i = np.broadcast_arrays(o, i)
    above = (o[..., 2] > 0.0) & (i[..., 2] > 0.0)
    if isinstance(brdf, Microfacet):
        h = _half(o, i)
        vh = np.clip(np.sum(o * h, axis=-1), 0.0, 1.0)
        fresnel = brdf.f0 + (1.0 - brdf.f0) * (1.0 - vh) ** 5
        g = 1.0 / ((1.0 + brdf._lambda(o[..., 2])) * (1.0 + brdf._lambda(i[..., 2])))
        denom = 4.0 * np.maximum(o[..., 2], 1e-12) * np.maximum(i[..., 2], 1e-12)
        return np.where(above, brdf.specular * fresnel * g / denom, 0.0)
    if isinstance(brdf, BlinnPhong):
        return np.where(above, brdf.specular * (brdf.exponent + 8.0) / (8.0 * np.pi), 0.0)
    return brdf.remaining_factor(o, i)


# ------------------------------------------------------------------------------------------------
# NDF lobes: closed forms


def beckmann_lobe(roughness: float, form: str = "normalized") -> tuple[float, float]:
    """(sharpness, amplitude) of the single SG lobe about z+ for the Beckmann NDF
    ``exp(-tan^2 / a^2) / (pi a^2 cos^4)`` (module docstring for the forms)."""
    a = _check_positive(roughness, "roughness", "beckmann_lobe", 2.0)
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
    lobes (L-BFGS-B, :func:`fit_ndf`); ``tabulated`` (``theta_h``, ``ndf_values``) with ``lobes``
    (1 or 2) lobes about z+ (Levenberg-Marquardt). Fits are cached per parameter set.

    Parameters that only the exact BRDF uses (``f0``, ``eta``, ``specular``, ...) are accepted.

    Raises:
        ValueError: unknown model or parameter, or parameters out of range (named).
    """
    b, opts = _split(model, params, "ndf_lobes")
    brdf = make_brdf(model, **b)
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
    ``ashikhmin-shirley``: free axes, L-BFGS-B; ``tabulated``: about z+, Levenberg-Marquardt), with
    its error report. Cached per parameter set (the last 64), so a following :func:`ndf_lobes` or
    :func:`view_slice` with the same parameters does not fit again.

    Raises:
        ValueError: a model with a closed form (use :func:`ndf_lobes`), or bad parameters.
    """
    b, opts = _split(model, params, "fit_model_ndf")
    brdf = make_brdf(model, **b)
    if model not in DEFAULT_LOBES or getattr(brdf, "isotropic", False):
        raise ValueError(f"fit_model_ndf: model {model!r} with these parameters has a closed form (ndf_lobes)")
    lobes = opts.get("lobes", DEFAULT_LOBES[model])
    if isinstance(lobes, bool) or not isinstance(lobes, (int, np.integer)) or not 1 <= int(lobes) <= 16:
        raise ValueError(f"ndf_lobes: lobes must be an integer in 1..16, got {lobes!r}")
    if model == "tabulated" and int(lobes) > 2:
        raise ValueError(f"ndf_lobes: lobes for model 'tabulated' must be 1 or 2 (fixed z+ axes), got {lobes!r}")
    key = _key(model, {**b, "lobes": int(lobes)})
    if key not in _FIT_CACHE:
        axes = "fixed" if model == "tabulated" else "free"
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
    return np.concatenate([axes.ravel(), np.log(np.clip(lam, 1e-2, _MAX_SHARPNESS)), mu])


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
            x0 = np.concatenate([np.log(np.clip(lam0 * factors, 1e-2, _MAX_SHARPNESS)),
                                 np.log(np.full(k, prof[0] / k))])
            e = float(np.linalg.norm(resid(x0)))
            e0 = e if e0 is None else min(e0, e)
            r = least_squares(resid, x0, jac=jac, method="lm", max_nfev=max_iterations * (2 * k + 1))
            if np.all(np.isfinite(r.x)) and (res is None or r.cost < res.cost):
                res = r
        x = res.x
        lam = np.clip(np.exp(x[:k]), 0.0, _MAX_SHARPNESS)
        mu = np.exp(x[k:])
        err = float(np.linalg.norm(resid(np.concatenate([np.log(lam), x[k:]]))))
        order = np.argsort(lam, kind="stable")
        mix = SGMixture(np.tile([0.0, 0.0, 1.0], (k, 1)), lam[order], mu[order] * peak)
        return NDFFit(mix, err, e0, theta_max, int(res.nfev), bool(res.success), str(res.message))

    bounds = [(None, None)] * (3 * k) + [(math.log(1e-2), math.log(_MAX_SHARPNESS))] * k + [(0.0, None)] * k
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


# ------------------------------------------------------------------------------------------------
# the spherical warp (eq. 17-22)


@dataclass
class ViewSlice(SGMixture):
    """The BRDF slice ``rho_s*(i; o)`` of one view as SG lobes over the light direction ``i``
    (local frame; ``evaluate`` gives 1/sr, no cosine).

    Attributes (besides :class:`~warpshade.basis.sg.SGMixture`'s):
        culled: (K,) bool, lobes set to amplitude 0 because the warped axis is at or below the
            horizon, the NDF lobe faces away from the viewer (``o.p <= 0``) or the view itself is
            at or below the horizon.
        view: the (normalised) local view direction, (3,).
    """

    culled: np.ndarray = None
    view: np.ndarray = None

    def __post_init__(self):
        super().__post_init__()
        if self.culled is None:
            self.culled = np.zeros(self.lobe_count, bool)
        self.culled = np.asarray(self.culled, bool).reshape(-1)
        if self.culled.shape != (self.lobe_count,):
            raise ValueError(f"ViewSlice: culled must have shape ({self.lobe_count},), got {self.culled.shape}")


def view_slice(model: str, view_local, **params) -> ViewSlice:
    """The spherical warp of the NDF lobes to the slice of one view (eq. 17-22).

    Each NDF lobe ``(p, lambda, mu)`` of :func:`ndf_lobes` becomes ``p_W = 2 (o.p) p - o``,
    ``lambda_W = lambda / tau``, ``tau = 4 |p.o|`` (eq. 19, 21), ``mu_W = mu M_o(p_W)`` (eq. 22,
    :func:`remaining_factor` at the lobe centre). Culled lobes (:class:`ViewSlice`) get amplitude 0.

    Args:
        model: one of :data:`MODELS`. view_local: unit view direction (3,), local frame.
        **params: the model's parameters (as for :func:`ndf_lobes`).

    Returns:
        :class:`ViewSlice` (scalar amplitudes, 1/sr).

    Raises:
        ValueError: bad model, parameter or view (shape, zero, non-finite).
    """
    o = _unit(view_local, "view_slice: view_local")
    if o.shape != (3,):
        raise ValueError(f"view_slice: view_local must have shape (3,), got {o.shape}")
    ndf = ndf_lobes(model, **params)
    b, _ = _split(model, params, "view_slice")
    op = ndf.axes @ o
    pw = 2.0 * op[:, None] * ndf.axes - o
    pw /= np.maximum(np.linalg.norm(pw, axis=1, keepdims=True), 1e-300)
    culled = (op <= 0.0) | (pw[:, 2] <= 0.0) | (o[2] <= 0.0)
    tau = 4.0 * np.maximum(np.abs(op), 1e-6)
    lam = np.minimum(ndf.sharpness / tau, _MAX_SHARPNESS)
    m = remaining_factor(model, np.broadcast_to(o, pw.shape), pw, **b) if not np.all(culled) else np.zeros(len(op))
    amp = np.where(culled, 0.0, ndf.amplitude * m)
    return ViewSlice(pw, lam, amp, culled=culled, view=o)


def isotropic_warp_floor(view_cos) -> np.ndarray:
    """The slice error of the isotropic warp in the sharp-lobe limit, ``sqrt(2 - 4 sqrt(c) / (1 + c))``
    for a view at ``c = n.o`` (0 at normal view, 0.072 at 30 deg, 0.34 at 60 deg, 0.96 at 85 deg).

    For a sharp NDF lobe of width ``s`` about z+ the exact reflection (eq. 17) is a Gaussian of
    widths ``2 s`` in the plane of incidence and ``2 c s`` across it, while eq. 19 gives the
    isotropic lobe of the same area, width ``2 sqrt(c) s``; this is the relative L2 distance of
    the two (equal peaks). :func:`slice_error` tends to it as the lobe sharpens (M_o and the
    cosine are then constant over the lobe); it is the floor that no single isotropic lobe per NDF
    lobe can beat.
    """
    c = np.clip(np.asarray(view_cos, np.float64), 0.0, 1.0)
    return np.sqrt(np.maximum(2.0 - 4.0 * np.sqrt(c) / (1.0 + c), 0.0))


def _sphere_quadrature_about(axis, theta_split: float, inner_nodes: int, outer_nodes: int, azimuth_nodes: int):
    """Directions and weights over the whole sphere in polar coordinates about ``axis``: Gauss-
    Legendre on [0, theta_split] and on [theta_split, pi] in the polar angle, uniform azimuths."""
    parts = []
    for lo, hi, n in ((0.0, theta_split, inner_nodes), (theta_split, np.pi, outer_nodes)):
        if hi - lo <= 1e-12 or n <= 0:
            continue
        x, w = np.polynomial.legendre.leggauss(n)
        parts.append((lo + 0.5 * (hi - lo) * (x + 1.0), 0.5 * (hi - lo) * w))
    t = np.concatenate([p[0] for p in parts])
    wt = np.concatenate([p[1] for p in parts]) * np.sin(t)
    phi = (np.arange(azimuth_nodes) + 0.5) * (2.0 * np.pi / azimuth_nodes)
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = np.cross(axis, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(axis, t1)
    tt, pp = np.meshgrid(t, phi, indexing="ij")
    st = np.sin(tt)[..., None]
    dirs = np.cos(tt)[..., None] * axis + st * np.cos(pp)[..., None] * t1 + st * np.sin(pp)[..., None] * t2
    dirs = dirs.reshape(-1, 3)
    return dirs, np.repeat(wt * (2.0 * np.pi / azimuth_nodes), azimuth_nodes)


def slice_error(brdf_exact: BRDF, model: str, params: dict, view_local, inner_nodes: int = 160,
                outer_nodes: int = 64, azimuth_nodes: int = 256) -> float:
    """Relative L2 error of the warped slice against the exact BRDF, both times the cosine:
    ``||rho_s*(.; o) max(0, i_z) - rho(o, .) i_z|| / ||rho(o, .) i_z||`` over the hemisphere.

    Quadrature: polar coordinates about the mirror direction of ``o``, split at the radius that
    holds every non-culled warped lobe (its axis' distance plus 8 / sqrt(lambda_W)), Gauss-Legendre
    on both parts, uniform azimuths; directions below the horizon contribute 0.

    Args:
        brdf_exact: the exact BRDF (e.g. ``make_brdf(model, **params)``), local frame.
        model, params: the SG model (:func:`view_slice`).
        view_local: unit local view direction (3,), above the horizon.

    Returns:
        The relative error (float, >= 0; finite: a slice that is all culled gives 1.0).

    Raises:
        ValueError: a view at or below the horizon, or an exact BRDF that is 0 for this view.
    """
    o = _unit(view_local, "slice_error: view_local")
    if o.shape != (3,) or o[2] <= 0.0:
        raise ValueError(f"slice_error: view_local must be one direction (3,) above the horizon, got {view_local!r}")
    sl = view_slice(model, o, **params)
    mirror = np.array([-o[0], -o[1], o[2]])
    live = ~sl.culled
    if np.any(live):
        ang = np.arccos(np.clip(sl.axes[live] @ mirror, -1.0, 1.0))
        split = float(min(np.pi, np.max(ang + 8.0 / np.sqrt(np.maximum(sl.sharpness[live], 1e-6)))))
    else:
        split = np.pi
    split = max(split, 1e-3)
    dirs, w = _sphere_quadrature_about(mirror, split, inner_nodes, outer_nodes, azimuth_nodes)
    cos_i = np.maximum(dirs[:, 2], 0.0)
    up = dirs[:, 2] > 0.0
    exact = np.zeros(len(w))
    exact[up] = brdf_exact.evaluate(np.broadcast_to(o, dirs[up].shape), dirs[up]) * cos_i[up]
    approx = sl.evaluate(dirs) * cos_i
    den = float(w @ (exact * exact))
    if not den > 0.0 or not math.isfinite(den):
        raise ValueError("slice_error: the exact BRDF is zero (or not finite) for this view")
    return float(math.sqrt(float(w @ ((approx - exact) ** 2)) / den))
