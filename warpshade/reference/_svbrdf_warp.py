"""The ray-traced reference's BRDF of a surface point: a model of
:mod:`warpshade.scene._materials_warp`, or the texel of a texture of eq.-13 materials
(:class:`~warpshade.scene._svbrdf.SVBRDFMaterial`, ``brdf = "svbrdf"``) that the point looks up.
Its maths is its own: nothing here comes from the SG shading it measures
(:mod:`warpshade.methods.sg`); the texture, its texel look-up and the cosine floor of eq. 13 are
the scene's (:mod:`warpshade.scene._svbrdf`).

An SVBRDF is uploaded as one :class:`~warpshade.scene._materials_warp.BRDFParams` of model
:data:`SVBRDF_MODEL` (:func:`upload_svbrdf_material`): ``table`` the address of a flat float32
buffer of every texel's ``D`` curve, then every texel's ``S`` curve (texels row-major, ``samples``
values each), then every texel's sampling alpha and lobe probability
(:meth:`~warpshade.scene._svbrdf.SVBRDFMaterial.sampling_lobes`); ``table_dims`` =
(texels, samples, the texel shaded, 0); ``exponent`` the Fresnel index. Each receiver of the
estimator takes its texel (:func:`brdf_with_texel`, from a per-point texel index), which also
sets ``roughness`` and ``f0`` to that texel's sampling alpha and lobe probability.

* :func:`surface_brdf_eval` -- the texel's eq.-13 BRDF (:func:`texel_eval`: ``D`` log-linear in
  ``cos theta_h``, ``S`` linear in theta, the dielectric Fresnel reflectance of its own
  :func:`fresnel_dielectric`; the float32 counterpart of
  :meth:`~warpshade.scene._svbrdf.SVBRDFMaterial.evaluate_texels`), any other model
  by :func:`~warpshade.scene._materials_warp.brdf_eval`;
* :func:`surface_brdf_sample`, :func:`surface_brdf_pdf` -- the texel's GGX + cosine mixture, which
  is the tabulated model's (:func:`~warpshade.scene._materials_warp.brdf_sample` of model 8 with the
  texel's alpha and probability): positive wherever the BRDF can be, so the estimators stay
  unbiased.

Texels are looked up as the scene defines it (:func:`warpshade.scene._svbrdf.nearest_texel`: nearest
texel, ``u`` repeats, ``v`` clamped), as the SG shading does, at the same UVs: per vertex the mesh's float32 UV
(:func:`vertex_texels`), per camera hit ``w0 uv0 + w1 uv1 + w2 uv2`` of the hit triangle's
corners with the G-buffer's Warp barycentrics ``(u, v, 1 - u - v)`` (:func:`hit_texels`), as
``sg.shade``'s pixel kernel does.
"""

from __future__ import annotations

import numpy as np

from .._wp import wp
from ..scene._svbrdf import SVBRDF_COS_FLOOR, SVBRDFMaterial, nearest_texel, scene_uvs
from ..scene._materials_warp import (TABULATED_MODEL, BRDFParams, brdf_eval, brdf_pdf, brdf_sample, brdf_with_roughness,
                                    upload_brdf_passes)

wp.set_module_options({"enable_backward": False})

__all__ = ["SVBRDF_MODEL", "brdf_with_texel", "check_texels", "fresnel_dielectric", "hit_texels", "surface_brdf_eval",
           "surface_brdf_pdf", "surface_brdf_sample", "surface_texels", "texel_eval", "upload_surface_passes",
           "upload_svbrdf_material", "vertex_texels"]

#: Model code of an SVBRDF texel in :class:`~warpshade.scene._materials_warp.BRDFParams` (past the
#: codes of :data:`~warpshade.scene._materials_warp.BRDF_MODELS`, which this layer does not extend).
SVBRDF_MODEL = 10
_SVBRDF = wp.constant(SVBRDF_MODEL)
_TABULATED = wp.constant(TABULATED_MODEL)
#: The cosine floor of eq. 13's denominator, as the texture defines it.
_COS_FLOOR = wp.constant(float(SVBRDF_COS_FLOOR))
_HALF_PI = wp.constant(0.5 * np.pi)


@wp.func
def fresnel_dielectric(c: float, eta: float) -> float:
    """Unpolarised Fresnel reflectance at incidence cosine ``|c|`` for relative index ``eta > 1``,
    from the s- and p-polarised amplitude ratios (the float64 form:
    :func:`warpshade.scene._svbrdf.fresnel_dielectric`)."""
    cc = wp.clamp(wp.abs(c), 0.0, 1.0)
    cos_t = wp.sqrt(wp.max(1.0 - (1.0 - cc * cc) / (eta * eta), 0.0))
    r_s = (cc - eta * cos_t) / (cc + eta * cos_t)
    r_p = (eta * cc - cos_t) / (eta * cc + cos_t)
    return 0.5 * (r_s * r_s + r_p * r_p)


@wp.func
def _value(b: BRDFParams, i: int) -> float:
    t = b.table_dims[0]
    values = wp.array(ptr=b.table, shape=(2 * t * b.table_dims[1] + 2 * t,), dtype=float)
    return values[i]


@wp.func
def brdf_with_texel(b: BRDFParams, texel: int) -> BRDFParams:
    """``b`` for the texel of flat index ``texel`` (row * width + column): its curves, sampling
    alpha (``roughness``) and lobe probability (``f0``); other models are returned unchanged."""
    out = brdf_with_roughness(b, b.roughness)
    if b.model == _SVBRDF:
        t = b.table_dims[0]
        n = b.table_dims[1]
        out.table_dims = wp.vec4i(t, n, texel, 0)
        out.roughness = _value(b, 2 * t * n + texel)
        out.f0 = _value(b, 2 * t * n + t + texel)
    return out


@wp.func
def _bracket(n: int, cos_t: float) -> wp.vec4:
    """The samples around a polar angle: (index i, fraction in theta, cos theta_i, cos theta_i+1)."""
    step = _HALF_PI / float(n - 1)
    x = wp.acos(wp.clamp(cos_t, 0.0, 1.0)) / step
    i = wp.clamp(int(wp.floor(x)), 0, n - 2)
    return wp.vec4(float(i), wp.clamp(x - float(i), 0.0, 1.0), wp.cos(float(i) * step), wp.cos(float(i + 1) * step))


@wp.func
def _texel_ndf(b: BRDFParams, cos_h: float) -> float:
    n = b.table_dims[1]
    c = wp.clamp(cos_h, 0.0, 1.0)
    k = _bracket(n, c)
    i = int(k[0])
    base = b.table_dims[2] * n
    d0 = _value(b, base + i)
    d1 = _value(b, base + i + 1)
    t = wp.clamp((k[2] - c) / (k[2] - k[3]), 0.0, 1.0)
    if d0 > 0.0 and d1 > 0.0:
        return wp.exp((1.0 - t) * wp.log(d0) + t * wp.log(d1))
    return (1.0 - t) * d0 + t * d1


@wp.func
def _texel_shadow(b: BRDFParams, cos_t: float) -> float:
    n = b.table_dims[1]
    k = _bracket(n, cos_t)
    i = int(k[0])
    base = (b.table_dims[0] + b.table_dims[2]) * n
    return wp.clamp((1.0 - k[1]) * _value(b, base + i) + k[1] * _value(b, base + i + 1), 0.0, 1.0)


@wp.func
def texel_eval(b: BRDFParams, n: wp.vec3, v: wp.vec3, s: wp.vec3) -> float:
    """The texel's eq.-13 BRDF (1/sr, times ``b.scale``) about the unit normal ``n``; 0 below either horizon."""
    nv = wp.dot(n, v)
    ns = wp.dot(n, s)
    if nv <= 0.0 or ns <= 0.0:
        return 0.0
    h = v + s
    hl = wp.length(h)
    if hl <= 1.0e-12:
        return 0.0
    h = h / hl
    f = fresnel_dielectric(wp.dot(s, h), b.exponent)
    return (b.scale * f * _texel_shadow(b, nv) * _texel_shadow(b, ns) * _texel_ndf(b, wp.dot(n, h))
            / (wp.pi * wp.max(nv, _COS_FLOOR) * wp.max(ns, _COS_FLOOR)))


@wp.func
def _sampling_lobe(b: BRDFParams) -> BRDFParams:
    """The tabulated model's GGX + cosine mixture with the texel's alpha and lobe probability."""
    out = brdf_with_roughness(b, b.roughness)
    out.model = _TABULATED
    return out


@wp.func
def surface_brdf_eval(b: BRDFParams, n: wp.vec3, v: wp.vec3, s: wp.vec3) -> float:
    """``b(v, s)`` (1/sr, no cosine): an SVBRDF texel's, else :func:`~warpshade.scene._materials_warp.brdf_eval`."""
    if b.model == _SVBRDF:
        return texel_eval(b, n, v, s)
    return brdf_eval(b, n, v, s)


@wp.func
def surface_brdf_sample(b: BRDFParams, n: wp.vec3, v: wp.vec3, u1: float, u2: float) -> wp.vec3:
    """A direction from the BRDF's sampling lobe (an SVBRDF texel: its GGX + cosine mixture)."""
    if b.model == _SVBRDF:
        return brdf_sample(_sampling_lobe(b), n, v, u1, u2)
    return brdf_sample(b, n, v, u1, u2)


@wp.func
def surface_brdf_pdf(b: BRDFParams, n: wp.vec3, v: wp.vec3, s: wp.vec3) -> float:
    """Solid-angle pdf of :func:`surface_brdf_sample` at ``s``."""
    if b.model == _SVBRDF:
        return brdf_pdf(_sampling_lobe(b), n, v, s)
    return brdf_pdf(b, n, v, s)


# ---- host side ---------------------------------------------------------------------------------


def upload_svbrdf_material(material: SVBRDFMaterial, device) -> BRDFParams:
    """The :class:`BRDFParams` of an SVBRDF (module docstring) on ``device``; its buffer lives as
    long as the params (``table_array``). Texel 0 is selected (:func:`brdf_with_texel` selects others)."""
    alpha, weight = material.sampling_lobes()
    t = material.texel_count
    buffer = np.concatenate([material.ndf.reshape(-1), material.shadow.reshape(-1), alpha, weight]).astype(np.float32)
    array = wp.array(buffer, dtype=float, device=device)
    p = BRDFParams()
    p.model, p.scale, p.exponent, p.roughness, p.f0 = SVBRDF_MODEL, 1.0, float(material.eta), float(alpha[0]), float(weight[0])
    p.roughness_y, p.exponent_y, p.tangent = 0.0, 0.0, wp.vec3(1.0, 0.0, 0.0)
    p.table = wp.uint64(array.ptr)
    p.table_dims = wp.vec4i(t, material.samples, 0, 0)
    object.__setattr__(p, "table_array", array)
    return p


def upload_surface_passes(brdf, device, caller: str, roughness=None, tangents=None) -> list:
    """:func:`~warpshade.scene._materials_warp.upload_brdf_passes`, or for an SVBRDF its one pass
    (weights 1); an SVBRDF takes neither a per-point ``roughness`` nor ``tangents`` (ValueError)."""
    if not isinstance(brdf, SVBRDFMaterial):
        return upload_brdf_passes(brdf, device)
    _refuse_overrides(caller, roughness, tangents)
    return [(upload_svbrdf_material(brdf, device), np.ones(3))]


def _refuse_overrides(caller, roughness, tangents) -> None:
    for name, value in (("roughness", roughness), ("tangents", tangents)):
        if value is not None:
            raise ValueError(f"{caller}: {name} does not apply to an SVBRDF texture (every texel is its own material)")


def _scene_uv_array(scene, device) -> wp.array:
    """The scene's per-vertex UVs (:func:`~warpshade.scene._svbrdf.scene_uvs`) as float32 vec2 on ``device``."""
    return wp.array(np.asarray(scene_uvs(scene), np.float32).reshape(-1, 2), dtype=wp.vec2, device=device)


@wp.kernel
def _vertex_texels_kernel(uv: wp.array(dtype=wp.vec2), height: int, width: int, out: wp.array(dtype=wp.int32)):
    i = wp.tid()
    rc = nearest_texel(uv[i], height, width)
    out[i] = rc[0] * width + rc[1]


@wp.kernel
def _hit_texels_kernel(uv: wp.array(dtype=wp.vec2), height: int, width: int, hit: wp.array(dtype=wp.int32),
                       face: wp.array(dtype=wp.int32), bary: wp.array(dtype=wp.vec2), faces: wp.array2d(dtype=wp.int32),
                       out: wp.array(dtype=wp.int32)):
    p = wp.tid()
    if hit[p] == 0:
        out[p] = 0
        return
    f = face[p]
    b = bary[p]
    w = wp.vec3(b[0], b[1], 1.0 - b[0] - b[1])
    rc = nearest_texel(w[0] * uv[faces[f, 0]] + w[1] * uv[faces[f, 1]] + w[2] * uv[faces[f, 2]], height, width)
    out[p] = rc[0] * width + rc[1]


def vertex_texels(material: SVBRDFMaterial, scene, device) -> wp.array:
    """The texel (flat index) of every scene vertex, at its mesh's UV, wp.array(int32) (vertex_count,);
    ValueError naming a mesh without UVs."""
    uv = _scene_uv_array(scene, device)
    h, w = material.shape
    out = wp.zeros(scene.vertex_count, dtype=wp.int32, device=device)
    wp.launch(_vertex_texels_kernel, dim=scene.vertex_count, inputs=[uv, h, w], outputs=[out], device=device)
    return out


def hit_texels(material: SVBRDFMaterial, scene, gbuffer, device) -> wp.array:
    """The texel (flat index) of every ray of a G-buffer (:func:`warpshade.render.render_gbuffer`),
    wp.array(int32) (ray_count,), 0 for misses."""
    uv = _scene_uv_array(scene, device)
    h, w = material.shape
    out = wp.zeros(gbuffer.pixel_count, dtype=wp.int32, device=device)
    wp.launch(_hit_texels_kernel, dim=gbuffer.pixel_count, device=device,
              inputs=[uv, h, w, gbuffer.hit, gbuffer.face, gbuffer.bary, gbuffer.faces], outputs=[out])
    return out


def surface_texels(brdf, scene, device, gbuffer=None) -> wp.array | None:
    """An SVBRDF's texels per vertex (:func:`vertex_texels`) or, with a ``gbuffer``, per ray
    (:func:`hit_texels`); None for any other BRDF."""
    if not isinstance(brdf, SVBRDFMaterial):
        return None
    return vertex_texels(brdf, scene, device) if gbuffer is None else hit_texels(brdf, scene, gbuffer, device)


def check_texels(params: BRDFParams, texels, count: int, device, caller: str, roughness=None, tangents=None) -> wp.array:
    """Per-point texels for :meth:`~warpshade.reference._estimator.MonteCarloShader.shade_points`:
    an SVBRDF needs one flat texel index per point (wp.array(int32) or array-like of shape
    (count,), in [0, texels)) and takes no ``roughness`` or ``tangents``; any other BRDF takes
    none (an empty array is returned). ValueError naming ``texels`` otherwise."""
    if params.model != SVBRDF_MODEL:
        if texels is not None:
            raise ValueError(f"{caller}: texels are for an SVBRDF texture, not this BRDF")
        return wp.zeros(0, dtype=wp.int32, device=device)
    _refuse_overrides(caller, roughness, tangents)
    if texels is None:
        raise ValueError(f"{caller}: an SVBRDF texture needs texels: one texel index per point")
    arr = texels.numpy() if isinstance(texels, wp.array) else np.asarray(texels)
    if arr.shape != (count,) or not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{caller}: texels must be integers of shape ({count},), got {arr.dtype} {arr.shape}")
    if arr.size and (arr.min() < 0 or arr.max() >= params.table_dims[0]):
        raise ValueError(f"{caller}: texels must be in [0, {params.table_dims[0]}), got [{arr.min()}, {arr.max()}]")
    if isinstance(texels, wp.array) and texels.dtype == wp.int32 and texels.device == device:
        return texels
    return wp.array(arr.astype(np.int32), dtype=wp.int32, device=device)
