"""Multi-lobe and anisotropic SG reflectance on the Warp device: the NDF as a few SG lobes in the
tangent frame of each shading point, each warped to the view (Wang et al. 2009, sec. 4.3).

The isotropic single-lobe models of :mod:`._brdf_warp` have their lobe about the normal. The
fitted NDFs of :mod:`._ndf` -- anisotropic Ward and Ashikhmin-Shirley (free axes, L-BFGS-B) and
tabulated NDFs (1-2 lobes about z+, eq. 13) -- are K lobes ``(p_k, lambda_k, mu_k)`` in the local
frame (+x the tangent ``u`` of the anisotropic models), the same at every point of a material
(:class:`NDFLobes`). At a point with tangent frame rows ``(t, n x t, n)`` (``t`` the tangent
direction projected on the tangent plane, :func:`warpshade.scene._materials_warp.tangent_frame`)
and local view ``o``, each lobe is warped by eq. 18-22 as :func:`._slices.view_slice` does:

* ``p_W = 2 (o.p) p - o`` (normalised), ``lambda_W = lambda / (4 |o.p|)``,
  ``mu_W = mu M_o(p_W)``, the warped lobe approximated as isotropic (the paper's per-lobe warp);
* culled (amplitude 0) where ``o.p <= 0``, ``p_W`` is at or below the horizon, or the view is.

``M_o(i)`` is the model's remaining factor (:func:`._brdf.remaining_factor`): Ward
``ks / (4 pi a_x a_y sqrt((n.i)(n.o)))``; Ashikhmin-Shirley ``ks sqrt((nu+1)(nv+1)) / (8 pi)
F_schlick(o.h) / ((o.h) max(n.i, n.o))``; tabulated (eq. 13) ``ks F_CT(|i.h|, eta) S(o) S(i) /
(pi (n.i)(n.o))`` with ``S`` a table over the polar angle (linear interpolation, uniform samples
over [0, pi/2]). The kernels take ``ks = 1`` (the stage's specular colour multiplies).

:func:`warped_lobe` is the kernel function; :func:`warped_slices` launches :data:`warped_slices_kernel`
over arrays of views and tangent frames; its float64 mirror is :func:`._mirror.warped_slices_f64`.
"""

from __future__ import annotations

import numpy as np

from ..._wp import wp
from ...basis.sg_warp import SG, sg_make
from ...scene._materials_warp import BRDFParams
from ._brdf import COS_FLOOR, MAX_SHARPNESS
from ._brdf_warp import fresnel_cook_torrance, fresnel_schlick

wp.set_module_options({"enable_backward": False})

__all__ = [
    "LOBE_MODELS",
    "NDFLobes",
    "lobe_remaining_factor",
    "upload_lobes",
    "warped_lobe",
    "warped_slices",
    "warped_slices_kernel",
]

#: Models shaded as fitted lobes in a tangent frame, by the code of :class:`NDFLobes` ``model``.
LOBE_MODELS = {"ward": 5, "ashikhmin-shirley": 6, "tabulated-ndf": 8}

_COS_FLOOR = wp.constant(float(COS_FLOOR))
_MAX_SHARPNESS = wp.constant(float(MAX_SHARPNESS))
_PI = 3.141592653589793


@wp.struct
class NDFLobes:
    """A material's NDF lobes and the parameters of its remaining factor.

    Fields:
        axes: lobe axes, local frame (+x tangent, +z normal), (K,) vec3; sharpness: (K,);
            amplitude: (K,) float, in the NDF's units (peak-1 NDFs of :mod:`._brdf`).
        count: K (0: the material is one of :mod:`._brdf_warp`'s single-lobe models).
        model: :data:`LOBE_MODELS` code.
        param_x, param_y: Ward ``a_x, a_y`` or Ashikhmin-Shirley ``nu, nv`` (unused for tabulated).
        f0: Ashikhmin-Shirley ``rs``; eta: the tabulated model's index of refraction.
        shadow: the tabulated model's ``S`` at ``shadow.shape[0]`` uniform polar angles over [0, pi/2]
            (empty: S = 1).
        exact: the exact BRDF (``scale = 1``) for narrow lights (:func:`warpshade.scene._materials_warp.brdf_eval`;
            model -1 when it has none: tabulated).
    """

    axes: wp.array(dtype=wp.vec3)
    sharpness: wp.array(dtype=float)
    amplitude: wp.array(dtype=float)
    count: int
    model: int
    param_x: float
    param_y: float
    f0: float
    eta: float
    shadow: wp.array(dtype=float)
    exact: BRDFParams


@wp.func
def _shadow(lobes: NDFLobes, cos_t: float) -> float:
    count = lobes.shadow.shape[0]
    if count < 2:
        return 1.0
    theta = wp.acos(wp.clamp(cos_t, 0.0, 1.0))
    x = theta / (0.5 * _PI) * float(count - 1)
    i = wp.clamp(int(wp.floor(x)), 0, count - 2)
    f = wp.clamp(x - float(i), 0.0, 1.0)
    return (1.0 - f) * lobes.shadow[i] + f * lobes.shadow[i + 1]


@wp.func
def lobe_remaining_factor(lobes: NDFLobes, o: wp.vec3, i: wp.vec3) -> float:
    """``M_o(i)`` (1/sr, ``ks = 1``) of the material at local view ``o`` and light ``i``; 0 below either horizon."""
    co = o[2]
    ci = i[2]
    if co <= 0.0 or ci <= 0.0:
        return 0.0
    co = wp.max(co, _COS_FLOOR)
    ci = wp.max(ci, _COS_FLOOR)
    if lobes.model == 5:
        return 1.0 / (4.0 * _PI * lobes.param_x * lobes.param_y * wp.sqrt(co * ci))
    h = wp.normalize(o + i)
    oh = wp.dot(o, h)
    if lobes.model == 6:
        norm = wp.sqrt((lobes.param_x + 1.0) * (lobes.param_y + 1.0)) / (8.0 * _PI)
        return norm * fresnel_schlick(lobes.f0, oh) / (wp.max(oh, _COS_FLOOR) * wp.max(co, ci))
    f = fresnel_cook_torrance(oh, lobes.eta)
    return f * _shadow(lobes, o[2]) * _shadow(lobes, i[2]) / (_PI * co * ci)


@wp.func
def warped_lobe(lobes: NDFLobes, k: int, o: wp.vec3) -> SG:
    """Lobe ``k`` warped to the local view ``o`` (eq. 18-22), local frame; amplitude grey vec3 (0 when culled)."""
    p = lobes.axes[k]
    op = wp.dot(o, p)
    pw = 2.0 * op * p - o
    pl = wp.length(pw)
    if o[2] <= 0.0 or op <= 0.0 or pl <= 0.0:
        return sg_make(wp.vec3(0.0, 0.0, 1.0), 1.0, wp.vec3(0.0))
    pw = pw / pl
    if pw[2] <= 0.0:
        return sg_make(wp.vec3(0.0, 0.0, 1.0), 1.0, wp.vec3(0.0))
    lam = wp.min(lobes.sharpness[k] / (4.0 * wp.max(wp.abs(op), 1.0e-6)), _MAX_SHARPNESS)
    mu = lobes.amplitude[k] * lobe_remaining_factor(lobes, o, pw)
    return sg_make(pw, lam, wp.vec3(mu, mu, mu))


@wp.kernel
def warped_slices_kernel(lobes: NDFLobes, views: wp.array(dtype=wp.vec3), frames: wp.array(dtype=wp.mat33),
                         axes: wp.array2d(dtype=wp.vec3), sharpness: wp.array2d(dtype=float),
                         amplitude: wp.array2d(dtype=float)):
    """One view (world) and tangent frame (rows t, b, n): every warped lobe, in world space."""
    i = wp.tid()
    frame = frames[i]
    o = frame * views[i]
    for k in range(lobes.count):
        g = warped_lobe(lobes, k, o)
        axes[i, k] = wp.transpose(frame) * g.axis
        sharpness[i, k] = g.sharpness
        amplitude[i, k] = g.amplitude[0]


def upload_lobes(mixture, model: str, params: dict, device, exact=None) -> NDFLobes:
    """An :class:`NDFLobes` on ``device`` from a fitted :class:`~warpshade.basis.sg.SGMixture`
    (local frame, scalar amplitudes) and the model's parameters (``alpha_x``/``alpha_y``,
    ``nu``/``nv``/``rs``, or ``eta``/``shadow_values``); ``exact`` a :class:`BRDFParams` of the
    exact BRDF for narrow lights (None: none)."""
    if model not in LOBE_MODELS:
        raise ValueError(f"upload_lobes: model must be one of {tuple(LOBE_MODELS)}, got {model!r}")
    out = NDFLobes()
    out.axes = wp.array(np.asarray(mixture.axes, np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)
    out.sharpness = wp.array(np.asarray(mixture.sharpness, np.float32).reshape(-1), dtype=float, device=device)
    out.amplitude = wp.array(np.asarray(mixture.amplitude, np.float32).reshape(-1), dtype=float, device=device)
    out.count = int(mixture.lobe_count)
    out.model = LOBE_MODELS[model]
    out.param_x = float(params.get("alpha_x", params.get("nu", 0.0)))
    out.param_y = float(params.get("alpha_y", params.get("nv", out.param_x)) or out.param_x)
    out.f0 = float(params.get("rs", 0.0))
    out.eta = float(params.get("eta", 1.33))
    shadow = params.get("shadow_values")
    out.shadow = wp.array(np.zeros(0, np.float32) if shadow is None else np.asarray(shadow, np.float32).reshape(-1),
                          dtype=float, device=device)
    if exact is None:
        exact = BRDFParams()
        exact.model = -1
    out.exact = exact
    return out


def warped_slices(lobes: NDFLobes, views, frames, device=None):
    """Run :data:`warped_slices_kernel`: world views (N, 3) and tangent frames (N, 3, 3), rows
    (t, b, n) -> (axes (N, K, 3), sharpness (N, K), amplitude (N, K)), float32 NumPy, world frame."""
    v = np.asarray(views, np.float32).reshape(-1, 3)
    f = np.asarray(frames, np.float32).reshape(-1, 3, 3)
    if f.shape[0] != v.shape[0]:
        raise ValueError(f"warped_slices: {v.shape[0]} views for {f.shape[0]} frames")
    device = wp.get_device(device)
    n, k = v.shape[0], max(lobes.count, 1)
    axes = wp.zeros((n, k), dtype=wp.vec3, device=device)
    lam = wp.zeros((n, k), dtype=float, device=device)
    amp = wp.zeros((n, k), dtype=float, device=device)
    wp.launch(warped_slices_kernel, dim=n, device=device,
              inputs=[lobes, wp.array(v, dtype=wp.vec3, device=device), wp.array(f, dtype=wp.mat33, device=device)],
              outputs=[axes, lam, amp])
    return axes.numpy(), lam.numpy(), amp.numpy()
