"""Specular reflectance as spherical Gaussians (Wang et al. 2009, sec. 4). Float64 NumPy/SciPy.

Frame and units: everything is in the local shading frame, +z the surface normal, +x the tangent
``u`` of the anisotropic models (the Ward ``alpha_x`` / Ashikhmin-Shirley ``nu`` direction), +y
the bitangent. ``view`` (``o``) points towards the viewer and ``light`` (``i``) towards the
light, unit vectors; ``h = (o + i) / |o + i|``. BRDF values are in 1/sr without the cosine.

A microfacet specular lobe is factored as ``rho_s(o, i) = M_o(i) D(h)`` (eq. 9): ``D`` is the
normal distribution (NDF), ``M_o`` the smooth rest (Fresnel, shadowing, normalisation). This
module provides:

* exact models as :class:`~warpshade.scene._materials.BRDF` subclasses, each with ``ndf(h)`` and
  ``remaining_factor(view, light)`` whose product is ``evaluate``: :class:`CookTorrance`
  (eq. 10-11, Fresnel eq. 14, the Cook-Torrance V-groove shadowing), :class:`Ward` (Ward 1992,
  anisotropic when ``alpha_x != alpha_y``), :class:`AshikhminShirley` (its specular lobe) and
  :class:`TabulatedMicrofacet` (model ``tabulated-ndf``, eq. 13: a tabulated isotropic NDF and
  shadowing). The existing :class:`~warpshade.scene._materials.Microfacet` (Beckmann) and
  :class:`~warpshade.scene._materials.BlinnPhong` are used as they are.
* :func:`remaining_factor` -- ``M_o(i)`` of each model.
* :func:`microfacet_brdf` -- the exact BRDF of a microfacet model name (:data:`MODELS`) and its
  parameters (the scene's BRDF kinds are :func:`warpshade.scene._brdfs.make_brdf`'s);
  :func:`ndf_exact` its NDF.

The NDF as SG lobes is :mod:`._ndf`; the warp of those lobes to one view's slice is :mod:`._slices`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ...scene._materials import BRDF, BlinnPhong, Microfacet

__all__ = [
    "BECKMANN_FORMS",
    "COS_FLOOR",
    "DEFAULT_LOBES",
    "MAX_SHARPNESS",
    "MODELS",
    "AshikhminShirley",
    "CookTorrance",
    "TabulatedMicrofacet",
    "Ward",
    "check_positive",
    "eta_from_f0",
    "fresnel_cook_torrance",
    "fresnel_schlick",
    "ndf_exact",
    "remaining_factor",
    "shadowing_cook_torrance",
    "split_params",
    "tabulated_ndf",
    "unit_directions",
]

#: Model names accepted by :func:`microfacet_brdf`, :func:`._ndf.ndf_lobes` and :func:`._slices.view_slice`.
MODELS = ("beckmann", "cook-torrance", "blinn-phong", "ward", "ashikhmin-shirley", "tabulated-ndf")
#: Closed forms of the single Beckmann lobe (module docstring).
BECKMANN_FORMS = ("normalized", "paper", "taylor")
#: Default lobe counts of the fitted NDFs (the paper uses 7 for Ashikhmin-Shirley, 1-2 tabulated).
DEFAULT_LOBES = {"ward": 4, "ashikhmin-shirley": 7, "tabulated-ndf": 1}
#: Cosines are floored at this value in the ``1 / (n.i)`` and ``1 / (n.o)`` normalisations, so
#: that near-grazing directions give large but finite factors.
COS_FLOOR = 1e-6
#: Largest lobe sharpness (and Blinn-Phong exponent) accepted or produced.
MAX_SHARPNESS = 1e7


def check_positive(value, name: str, owner: str, upper: float | None = None) -> float:
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


def unit_directions(v, name: str) -> np.ndarray:
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
        o = unit_directions(view, f"{self.name}: view")
        i = unit_directions(light, f"{self.name}: light")
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
        self.m = check_positive(self.m, "m", "CookTorrance", 2.0)
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
        self.alpha_x = check_positive(self.alpha_x, "alpha_x", "Ward", 1.0)
        self.alpha_y = self.alpha_x if self.alpha_y is None else check_positive(self.alpha_y, "alpha_y", "Ward", 1.0)
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
        self.nu = check_positive(self.nu, "nu", "AshikhminShirley", 1e5)
        self.nv = check_positive(self.nv, "nv", "AshikhminShirley", 1e5)
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
    name = "tabulated-ndf"

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
    "tabulated-ndf": ("theta_h", "ndf_values", "shadow_theta", "shadow_values", "eta", "specular"),
}
_LOBE_PARAMS = {"beckmann": ("form",), "ward": ("lobes",), "ashikhmin-shirley": ("lobes",), "tabulated-ndf": ("lobes",)}


def split_params(model: str, params: dict, caller: str):
    """``(BRDF parameters, lobe options)`` of ``params`` for ``model``; raises ValueError naming
    ``caller`` for an unknown model or parameter."""
    if model not in MODELS:
        raise ValueError(f"{caller}: model must be one of {MODELS}, got {model!r}")
    brdf_keys, lobe_keys = _BRDF_PARAMS[model], _LOBE_PARAMS.get(model, ())
    for key in params:
        if key not in brdf_keys and key not in lobe_keys:
            raise ValueError(f"{caller}: unknown parameter {key!r} for model {model!r} "
                             f"(accepted: {', '.join(brdf_keys + lobe_keys)})")
    return ({k: v for k, v in params.items() if k in brdf_keys}, {k: v for k, v in params.items() if k in lobe_keys})


def microfacet_brdf(model: str, **params) -> BRDF:
    """The exact BRDF of a model name and its parameters (see :data:`MODELS`).

    ``beckmann``: :class:`~warpshade.scene._materials.Microfacet` (``roughness``, ``f0``,
    ``specular``); ``blinn-phong``: :class:`~warpshade.scene._materials.BlinnPhong` (``exponent``,
    ``specular``); the others the classes of this module (their attributes as keywords).
    Lobe options (``form``, ``lobes``) are accepted and ignored.
    """
    b, _ = split_params(model, params, "microfacet_brdf")
    if model == "beckmann":
        if "roughness" not in b:
            raise ValueError("microfacet_brdf: model 'beckmann' needs parameter 'roughness'")
        return Microfacet(distribution="beckmann", **b)
    if model == "blinn-phong":
        if "exponent" not in b:
            raise ValueError("microfacet_brdf: model 'blinn-phong' needs parameter 'exponent'")
        p = float(b["exponent"])
        if not math.isfinite(p) or p < 0.0 or p > MAX_SHARPNESS:
            raise ValueError(f"microfacet_brdf: exponent must be finite and in [0, {MAX_SHARPNESS:g}], "
                             f"got {b['exponent']!r}")
        return BlinnPhong(**b)
    cls = {"cook-torrance": CookTorrance, "ward": Ward, "ashikhmin-shirley": AshikhminShirley,
           "tabulated-ndf": TabulatedMicrofacet}[model]
    return cls(**b)



def ndf_exact(model: str, h, **params) -> np.ndarray:
    """The exact NDF ``D(h)`` of a model at local half vectors ``h`` (..., 3) -> (...,), float64.

    For ``beckmann`` it is :class:`~warpshade.scene._materials.Microfacet`'s own ``D`` (normalised,
    ``integral D h_z = 1``); for ``blinn-phong`` ``max(0, h_z)^p``; the others are the classes'
    ``ndf`` (peak 1)."""
    brdf = microfacet_brdf(model, **params)
    hh = unit_directions(h, "ndf_exact: h")
    if isinstance(brdf, Microfacet):
        return np.where(hh[..., 2] > 0.0, brdf._d(hh[..., 2]), 0.0)
    if isinstance(brdf, BlinnPhong):
        return np.maximum(hh[..., 2], 0.0) ** brdf.exponent
    return brdf.ndf(hh)


def remaining_factor(model: str, view, light, **params) -> np.ndarray:
    """``M_o(i)`` of eq. 9 (1/sr), so that ``M_o(i) ndf_exact(h) == microfacet_brdf(...).evaluate(o, i)``.

    ``beckmann``: exactly :class:`~warpshade.scene._materials.Microfacet`'s
    ``ks F_schlick(o.h) G_smith(o, i) / (4 (n.o)(n.i))``; ``blinn-phong``: ``ks (p + 8) / (8 pi)``;
    the others: the classes' :meth:`remaining_factor`. 0 where o or i is below the horizon.

    Args:
        view, light: local unit directions (..., 3), broadcast against each other.
    """
    brdf = microfacet_brdf(model, **params)
    o = unit_directions(view, "remaining_factor: view")
    i = unit_directions(light, "remaining_factor: light")
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
