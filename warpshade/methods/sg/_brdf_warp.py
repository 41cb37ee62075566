"""SG specular reflectance on the Warp device: the per-pixel mirror of :mod:`._brdf` (float32).

For a per-pixel shading kernel the BRDF is one isotropic model with its parameters read from
textures or arrays, identified by an integer (:data:`MODEL_IDS`). All directions are in the local
shading frame (+z the normal), ``view_local`` towards the viewer.

* ``specular_slice(view_local, model, roughness, f0) -> SG`` -- the single NDF lobe about z+
  (closed forms of :func:`._ndf.ndf_lobes`: Beckmann ``form="normalized"``, Cook-Torrance eq. 12,
  Blinn-Phong, isotropic Ward) warped to the view (eq. 17-22): axis ``2 (o.z) z - o`` (the mirror
  direction), sharpness ``lambda / (4 o_z)``, amplitude ``vec3(M_o(p_W) mu)`` (grey: the caller
  multiplies by the specular colour ``ks``). ``roughness`` is Beckmann's alpha, Cook-Torrance's
  ``m``, Ward's ``alpha``, or, for Blinn-Phong, the exponent. ``f0`` is the normal-incidence
  reflectance (Schlick's for Beckmann; converted to the index of refraction of eq. 14 for
  Cook-Torrance; unused by Blinn-Phong and Ward). A view at or below the horizon gives a lobe of
  amplitude 0 (axis z+, sharpness 1).
* ``ndf_lobe(model, roughness) -> SG`` -- the unwarped lobe (axis z+, amplitude ``vec3(mu)``).
* ``remaining_factor(model, view_local, light_local, roughness, f0) -> float`` -- ``M_o(i)``
  (1/sr, ``ks = 1``), 0 below either horizon.
* ``fresnel_cook_torrance(c, eta)`` (eq. 14), ``fresnel_schlick(f0, c)``, ``eta_from_f0(f0)``,
  ``shadowing_cook_torrance(n_h, n_o, n_i, o_h)`` (V-groove) and ``smith_g_beckmann(n_o, n_i,
  alpha)`` (the separable Smith term of :class:`~warpshade.scene._materials.Microfacet`, through
  :mod:`warpshade.scene._materials_warp`'s ``Lambda``).

The float64 oracle is :func:`._slices.view_slice` on the same models (:func:`specular_slices_f64`
runs it for arrays of views); :func:`specular_slices` launches :data:`specular_slice_kernel`.
"""

from __future__ import annotations

import numpy as np

from ..._wp import wp
from ...basis.sg_warp import SG, sg_make
from ...scene import _materials_warp as materials_warp
from ._brdf import COS_FLOOR
from ._slices import view_slice

wp.set_module_options({"enable_backward": False})

__all__ = [
    "MODEL_IDS",
    "eta_from_f0",
    "fresnel_cook_torrance",
    "fresnel_schlick",
    "model_id",
    "ndf_lobe",
    "specular_slices_f64",
    "remaining_factor",
    "shadowing_cook_torrance",
    "slice_parameters",
    "smith_g_beckmann",
    "specular_slice",
    "specular_slice_kernel",
    "specular_slices",
]

#: Integer model ids of :func:`specular_slice` (and :func:`remaining_factor`).
MODEL_IDS = {"beckmann": 0, "cook-torrance": 1, "blinn-phong": 2, "ward": 3}

_COS_FLOOR = wp.constant(float(COS_FLOOR))
_PI = 3.141592653589793


def model_id(name: str) -> int:
    """The id of a model name in :data:`MODEL_IDS` (ValueError naming the model otherwise)."""
    if name not in MODEL_IDS:
        raise ValueError(f"brdf_warp: model must be one of {tuple(MODEL_IDS)}, got {name!r}")
    return MODEL_IDS[name]


@wp.func
def fresnel_cook_torrance(c: float, eta: float) -> float:
    """Eq. 14: unpolarised Fresnel reflectance at ``c = |i.h|`` for relative index ``eta``."""
    cc = wp.clamp(wp.abs(c), 0.0, 1.0)
    g2 = eta * eta + cc * cc - 1.0
    if g2 <= 0.0:
        return 1.0
    g = wp.sqrt(g2)
    a = (g - cc) / (g + cc)
    b = (cc * (g + cc) - 1.0) / (cc * (g - cc) + 1.0)
    return 0.5 * a * a * (1.0 + b * b)


@wp.func
def fresnel_schlick(f0: float, c: float) -> float:
    """``f0 + (1 - f0) (1 - c)^5``, c clamped to [0, 1]."""
    x = 1.0 - wp.clamp(c, 0.0, 1.0)
    x2 = x * x
    return f0 + (1.0 - f0) * x2 * x2 * x


@wp.func
def eta_from_f0(f0: float) -> float:
    """``(1 + sqrt(f0)) / (1 - sqrt(f0))`` (f0 in [0, 1); clamped below 1)."""
    s = wp.sqrt(wp.clamp(f0, 0.0, 0.999999))
    return (1.0 + s) / (1.0 - s)


@wp.func
def shadowing_cook_torrance(n_h: float, n_o: float, n_i: float, o_h: float) -> float:
    """``min(1, 2 (n.h)(n.o) / (o.h), 2 (n.h)(n.i) / (o.h))`` clamped to [0, 1]."""
    inv = 2.0 * wp.max(n_h, 0.0) / wp.max(o_h, 1.0e-12)
    return wp.clamp(wp.min(inv * n_o, inv * n_i), 0.0, 1.0)


@wp.func
def smith_g_beckmann(n_o: float, n_i: float, alpha: float) -> float:
    """``1 / ((1 + Lambda(n.o)) (1 + Lambda(n.i)))`` with Beckmann's rational Lambda."""
    p = materials_warp.BRDFParams()
    p.model = 4
    p.scale = 1.0
    p.exponent = 0.0
    p.roughness = alpha
    p.f0 = 0.0
    return 1.0 / ((1.0 + materials_warp._smith_lambda(p, n_o)) * (1.0 + materials_warp._smith_lambda(p, n_i)))


@wp.func
def ndf_lobe(model: int, roughness: float) -> SG:
    """The NDF's closed-form lobe about z+ (``roughness`` = exponent for Blinn-Phong)."""
    lam = float(0.0)
    mu = float(1.0)
    if model == 2:
        lam = roughness
    else:
        lam = 2.0 / (roughness * roughness)
        if model == 0:
            # "normalized": integral over the hemisphere of mu e^(lam (z-1)) z = 1
            mu = lam * lam / (2.0 * _PI * (lam - 1.0 + wp.exp(-lam)))
    return sg_make(wp.vec3(0.0, 0.0, 1.0), lam, wp.vec3(mu, mu, mu))


@wp.func
def remaining_factor(model: int, view_local: wp.vec3, light_local: wp.vec3, roughness: float, f0: float) -> float:
    """``M_o(i)`` of the model (1/sr, ``ks = 1``); 0 when o or i is at or below the horizon."""
    n_o = view_local[2]
    n_i = light_local[2]
    if n_o <= 0.0 or n_i <= 0.0:
        return 0.0
    if model == 2:
        return (roughness + 8.0) / (8.0 * _PI)
    co = wp.max(n_o, _COS_FLOOR)
    ci = wp.max(n_i, _COS_FLOOR)
    if model == 3:
        return 1.0 / (4.0 * _PI * roughness * roughness * wp.sqrt(co * ci))
    h = wp.normalize(view_local + light_local)
    o_h = wp.clamp(wp.dot(view_local, h), 0.0, 1.0)
    if model == 0:
        return fresnel_schlick(f0, o_h) * smith_g_beckmann(n_o, n_i, roughness) / (4.0 * co * ci)
    f = fresnel_cook_torrance(o_h, eta_from_f0(f0))
    return f * shadowing_cook_torrance(h[2], n_o, n_i, o_h) / (_PI * co * ci)


@wp.func
def specular_slice(view_local: wp.vec3, model: int, roughness: float, f0: float) -> SG:
    """The warped single-lobe BRDF slice of one view (module docstring); amplitude grey vec3."""
    z = wp.vec3(0.0, 0.0, 1.0)
    o_z = view_local[2]
    if o_z <= 0.0:
        return sg_make(z, 1.0, wp.vec3(0.0, 0.0, 0.0))
    g = ndf_lobe(model, roughness)
    axis = wp.normalize(2.0 * o_z * z - view_local)
    lam = g.sharpness / (4.0 * wp.max(o_z, 1.0e-6))
    m = remaining_factor(model, view_local, axis, roughness, f0)
    return sg_make(axis, lam, g.amplitude * m)


@wp.kernel
def specular_slice_kernel(views: wp.array(dtype=wp.vec3), models: wp.array(dtype=wp.int32),
                          roughness: wp.array(dtype=float), f0: wp.array(dtype=float),
                          axes: wp.array(dtype=wp.vec3), sharpness: wp.array(dtype=float),
                          amplitude: wp.array(dtype=wp.vec3)):
    """One thread per view: :func:`specular_slice` of element i into the output arrays."""
    i = wp.tid()
    g = specular_slice(views[i], models[i], roughness[i], f0[i])
    axes[i] = g.axis
    sharpness[i] = g.sharpness
    amplitude[i] = g.amplitude


def _check(views, models, roughness, f0):
    v = np.asarray(views, np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
        raise ValueError(f"specular_slices: views must be finite, shape (count, 3), got {v.shape}")
    norm = np.linalg.norm(v, axis=1)
    if np.any(norm == 0.0):
        raise ValueError("specular_slices: views must be nonzero")
    v = v / norm[:, None]
    count = v.shape[0]
    names = [models] * count if isinstance(models, str) else list(models)
    if len(names) != count:
        raise ValueError(f"specular_slices: models must be one name or {count} names, got {len(names)}")
    ids = np.array([model_id(n) for n in names], np.int32)
    r = np.broadcast_to(np.asarray(roughness, np.float64), (count,)).copy()
    f = np.broadcast_to(np.asarray(f0, np.float64), (count,)).copy()
    bp = ids == MODEL_IDS["blinn-phong"]
    upper = np.where(ids == MODEL_IDS["ward"], 1.0, 2.0)
    if not np.all(np.isfinite(r)) or np.any(r[~bp] <= 0.0) or np.any(r[~bp] > upper[~bp]):
        raise ValueError("specular_slices: roughness must be finite and in (0, 2] (Beckmann, Cook-Torrance) "
                         "or (0, 1] (Ward)")
    if np.any(r[bp] < 0.0) or np.any(r[bp] > 1e7):
        raise ValueError("specular_slices: roughness (the Blinn-Phong exponent) must be in [0, 1e7]")
    if not np.all(np.isfinite(f)) or np.any(f < 0.0) or np.any(f >= 1.0):
        raise ValueError("specular_slices: f0 must be in [0, 1)")
    return v, ids, r, f, names


def specular_slices(views, models, roughness, f0=0.04, device=None):
    """Run :data:`specular_slice_kernel` over views.

    Args:
        views: local view directions (count, 3) (normalised here).
        models: one model name of :data:`MODEL_IDS`, or one per view.
        roughness, f0: scalars or (count,) arrays (module docstring).
        device: Warp device (default: Warp's default device).

    Returns:
        (axes (count, 3), sharpness (count,), amplitude (count, 3)), float32 NumPy arrays.

    Raises:
        ValueError: bad shapes, unknown model names or parameters out of range.
    """
    v, ids, r, f, _ = _check(views, models, roughness, f0)
    device = wp.get_device(device)
    count = v.shape[0]
    axes = wp.zeros(count, dtype=wp.vec3, device=device)
    lam = wp.zeros(count, dtype=float, device=device)
    amp = wp.zeros(count, dtype=wp.vec3, device=device)
    wp.launch(specular_slice_kernel, dim=count, device=device,
              inputs=[wp.array(v.astype(np.float32), dtype=wp.vec3, device=device),
                      wp.array(ids, dtype=wp.int32, device=device),
                      wp.array(r.astype(np.float32), dtype=float, device=device),
                      wp.array(f.astype(np.float32), dtype=float, device=device)],
              outputs=[axes, lam, amp])
    return axes.numpy(), lam.numpy(), amp.numpy()


def slice_parameters(name: str, roughness: float, f0: float) -> dict:
    """The keyword parameters of :func:`._slices.view_slice` for a model id's (roughness, f0) pair as
    the kernels take it (Blinn-Phong: ``roughness`` is the exponent; Ward: isotropic alpha)."""
    if name == "beckmann":
        return {"roughness": roughness, "f0": f0, "form": "normalized"}
    if name == "cook-torrance":
        return {"m": roughness, "f0": f0} if f0 > 0.0 else {"m": roughness}
    if name == "blinn-phong":
        return {"exponent": roughness}
    return {"alpha_x": roughness}


def specular_slices_f64(views, models, roughness, f0=0.04):
    """The float64 oracle of :func:`specular_slices`: :func:`._slices.view_slice` per view with the
    same parameters (Cook-Torrance with ``f0 = 0`` uses the default eta 1.33 there, while the
    kernel maps f0 = 0 to eta 1: pass f0 > 0 to compare).

    Returns:
        (axes (count, 3), sharpness (count,), amplitude (count,)), float64.
    """
    v, ids, r, f, names = _check(views, models, roughness, f0)
    axes = np.zeros((len(v), 3))
    lam = np.zeros(len(v))
    amp = np.zeros(len(v))
    for k in range(len(v)):
        s = view_slice(names[k], v[k], **slice_parameters(names[k], float(r[k]), float(f[k])))
        if s.culled[0]:
            axes[k], lam[k], amp[k] = (0.0, 0.0, 1.0), 1.0, 0.0
        else:
            axes[k], lam[k], amp[k] = s.axes[0], s.sharpness[0], s.amplitude[0]
    return axes, lam, amp
