"""Spatially varying measured materials on the Warp device (Wang et al. 2009, sec. 4.2 and 7):
the per-texel SG lobes of the NDF and the PCA-compressed shadowing of :mod:`._svbrdf`, looked up
per vertex or per pixel and warped to the view.

At a point with texture coordinates ``uv`` the texel is the nearest one (:func:`svbrdf_texel`: the
scene's look-up :func:`warpshade.scene._svbrdf.nearest_texel`, ``u`` repeats, ``v`` is clamped, row
0 at ``v = 1``, as :meth:`._svbrdf.SVBRDFTexture.texel_of`).
Its lobes ``(z+, lambda_k, mu_k)`` are warped as :func:`._lobes_warp.warped_lobe` does (eq. 18-22):
``p_W = 2 (o.z) z - o``, ``lambda_W = lambda / (4 o.z)``, ``mu_W = mu M_o(p_W)`` with eq. 13's
``M_o(i) = F(|i.h|, eta) S(o) S(i) / (pi (n.i)(n.o))``; ``S`` is decoded from the texel's PCA
coefficients at the two samples around the angle (``mean + sum_r c_r basis_r``), interpolated
linearly in the polar angle and clipped to [0, 1] (:func:`svbrdf_shadow`).

:func:`svbrdf_slices` launches :data:`svbrdf_slices_kernel` (the tests' entry); its float64 mirror
is :func:`._svbrdf.svbrdf_slices_f64`.
"""

from __future__ import annotations

import numpy as np

from ..._wp import wp
from ...basis.sg_warp import SG, sg_make
from ...scene._svbrdf import nearest_texel
from ._brdf import COS_FLOOR, MAX_SHARPNESS
from ._brdf_warp import fresnel_cook_torrance

wp.set_module_options({"enable_backward": False})

__all__ = ["SVBRDFTextureWarp", "empty_svbrdf", "svbrdf_shadow", "svbrdf_slices", "svbrdf_slices_kernel", "svbrdf_texel",
           "svbrdf_warped_lobe", "upload_svbrdf"]

_COS_FLOOR = wp.constant(float(COS_FLOOR))
_MAX_SHARPNESS = wp.constant(float(MAX_SHARPNESS))
_PI = 3.141592653589793


@wp.struct
class SVBRDFTextureWarp:
    """A fitted SVBRDF texture on the device.

    Fields:
        sharpness, amplitude: per-texel NDF lobes about z+, (H, W, K).
        shadow_mean: (N,); shadow_basis: (R, N); shadow_coeffs: (H, W, R) -- the shadowing PCA
            over N uniform polar angles in [0, pi/2].
        uv: per-vertex texture coordinates of the scene, (V,) vec2 (looked up per vertex, or
            interpolated at a pixel's hit).
        lobes: K (0: no SVBRDF, the stage's other models); terms: R; eta: Fresnel index.
    """

    sharpness: wp.array3d(dtype=float)
    amplitude: wp.array3d(dtype=float)
    shadow_mean: wp.array(dtype=float)
    shadow_basis: wp.array2d(dtype=float)
    shadow_coeffs: wp.array3d(dtype=float)
    uv: wp.array(dtype=wp.vec2)
    lobes: int
    terms: int
    eta: float


@wp.func
def svbrdf_texel(tex: SVBRDFTextureWarp, uv: wp.vec2) -> wp.vec2i:
    """Nearest texel (row, column) of ``uv`` in the texture: u repeats, v is clamped."""
    return nearest_texel(uv, tex.sharpness.shape[0], tex.sharpness.shape[1])


@wp.func
def _shadow_sample(tex: SVBRDFTextureWarp, r: int, c: int, j: int) -> float:
    s = tex.shadow_mean[j]
    for t in range(tex.terms):
        s += tex.shadow_coeffs[r, c, t] * tex.shadow_basis[t, j]
    return s


@wp.func
def svbrdf_shadow(tex: SVBRDFTextureWarp, texel: wp.vec2i, cos_t: float) -> float:
    """``S`` of a texel at a polar angle's cosine (PCA decode, linear in theta, clipped to [0, 1])."""
    n = tex.shadow_mean.shape[0]
    theta = wp.acos(wp.clamp(cos_t, 0.0, 1.0))
    x = theta / (0.5 * _PI) * float(n - 1)
    i = wp.clamp(int(wp.floor(x)), 0, n - 2)
    f = wp.clamp(x - float(i), 0.0, 1.0)
    s = (1.0 - f) * _shadow_sample(tex, texel[0], texel[1], i) + f * _shadow_sample(tex, texel[0], texel[1], i + 1)
    return wp.clamp(s, 0.0, 1.0)


@wp.func
def svbrdf_remaining_factor(tex: SVBRDFTextureWarp, texel: wp.vec2i, o: wp.vec3, i: wp.vec3) -> float:
    """Eq. 13's ``M_o(i)`` (1/sr, ``ks = 1``) of a texel at local view ``o`` and light ``i``; 0 below either horizon."""
    co = o[2]
    ci = i[2]
    if co <= 0.0 or ci <= 0.0:
        return 0.0
    h = wp.normalize(o + i)
    f = fresnel_cook_torrance(wp.dot(o, h), tex.eta)
    return (f * svbrdf_shadow(tex, texel, co) * svbrdf_shadow(tex, texel, ci)
            / (_PI * wp.max(co, _COS_FLOOR) * wp.max(ci, _COS_FLOOR)))


@wp.func
def svbrdf_warped_lobe(tex: SVBRDFTextureWarp, texel: wp.vec2i, k: int, o: wp.vec3) -> SG:
    """Lobe ``k`` of a texel warped to the local view ``o`` (eq. 18-22); amplitude grey (0 when culled)."""
    if o[2] <= 0.0:
        return sg_make(wp.vec3(0.0, 0.0, 1.0), 1.0, wp.vec3(0.0))
    pw = wp.normalize(wp.vec3(-o[0], -o[1], o[2]))
    lam = wp.min(tex.sharpness[texel[0], texel[1], k] / (4.0 * wp.max(o[2], 1.0e-6)), _MAX_SHARPNESS)
    mu = tex.amplitude[texel[0], texel[1], k] * svbrdf_remaining_factor(tex, texel, o, pw)
    return sg_make(pw, lam, wp.vec3(mu, mu, mu))


@wp.kernel
def svbrdf_slices_kernel(tex: SVBRDFTextureWarp, texels: wp.array(dtype=wp.vec2i), views: wp.array(dtype=wp.vec3),
                         axes: wp.array2d(dtype=wp.vec3), sharpness: wp.array2d(dtype=float),
                         amplitude: wp.array2d(dtype=float)):
    """One texel and local view: every warped lobe (local frame)."""
    p = wp.tid()
    o = wp.normalize(views[p])
    for k in range(tex.lobes):
        g = svbrdf_warped_lobe(tex, texels[p], k, o)
        axes[p, k] = g.axis
        sharpness[p, k] = g.sharpness
        amplitude[p, k] = g.amplitude[0]


@wp.kernel
def svbrdf_texel_kernel(tex: SVBRDFTextureWarp, uv: wp.array(dtype=wp.vec2), out: wp.array(dtype=wp.vec2i)):
    p = wp.tid()
    out[p] = svbrdf_texel(tex, uv[p])


def upload_svbrdf(texture, uv, device) -> SVBRDFTextureWarp:
    """A :class:`SVBRDFTextureWarp` on ``device`` from a fitted :class:`._svbrdf.SVBRDFTexture` and
    per-vertex UVs (V, 2) (None: no look-up by vertex)."""
    out = SVBRDFTextureWarp()
    out.sharpness = wp.array(np.asarray(texture.sharpness, np.float32), dtype=float, device=device)
    out.amplitude = wp.array(np.asarray(texture.amplitude, np.float32), dtype=float, device=device)
    out.shadow_mean = wp.array(np.asarray(texture.shadow_mean, np.float32), dtype=float, device=device)
    r, n = texture.shadow_basis.shape
    h, w = texture.shape
    basis = np.asarray(texture.shadow_basis, np.float32) if r else np.zeros((1, n), np.float32)
    coeffs = np.asarray(texture.shadow_coeffs, np.float32) if r else np.zeros((h, w, 1), np.float32)
    out.shadow_basis = wp.array(basis, dtype=float, device=device)
    out.shadow_coeffs = wp.array(coeffs, dtype=float, device=device)
    uv = np.zeros((1, 2), np.float32) if uv is None else np.asarray(uv, np.float32).reshape(-1, 2)
    out.uv = wp.array(uv, dtype=wp.vec2, device=device)
    out.lobes = int(texture.lobes)
    out.terms = int(r)
    out.eta = float(texture.eta)
    return out


def empty_svbrdf(device) -> SVBRDFTextureWarp:
    """No SVBRDF (``lobes = 0``): the placeholder of the stage's other models."""
    out = SVBRDFTextureWarp()
    out.sharpness = wp.zeros((1, 1, 1), dtype=float, device=device)
    out.amplitude = wp.zeros((1, 1, 1), dtype=float, device=device)
    out.shadow_mean = wp.zeros(2, dtype=float, device=device)
    out.shadow_basis = wp.zeros((1, 2), dtype=float, device=device)
    out.shadow_coeffs = wp.zeros((1, 1, 1), dtype=float, device=device)
    out.uv = wp.zeros(1, dtype=wp.vec2, device=device)
    out.lobes, out.terms, out.eta = 0, 0, 1.33
    return out


def svbrdf_slices(tex: SVBRDFTextureWarp, texels, views, device=None):
    """Run :data:`svbrdf_slices_kernel`: texels (P, 2) (row, column), local views (P, 3) ->
    (axes (P, K, 3), sharpness (P, K), amplitude (P, K)), float32 NumPy, local frame."""
    device = wp.get_device(device)
    rc = np.asarray(texels, np.int32).reshape(-1, 2)
    v = np.asarray(views, np.float32).reshape(-1, 3)
    if rc.shape[0] != v.shape[0]:
        raise ValueError(f"svbrdf_slices: {rc.shape[0]} texels for {v.shape[0]} views")
    n, k = v.shape[0], max(tex.lobes, 1)
    axes = wp.zeros((n, k), dtype=wp.vec3, device=device)
    lam = wp.zeros((n, k), dtype=float, device=device)
    amp = wp.zeros((n, k), dtype=float, device=device)
    wp.launch(svbrdf_slices_kernel, dim=n, device=device,
              inputs=[tex, wp.array(rc, dtype=wp.vec2i, device=device), wp.array(v, dtype=wp.vec3, device=device)],
              outputs=[axes, lam, amp])
    return axes.numpy(), lam.numpy(), amp.numpy()


def svbrdf_texels(tex: SVBRDFTextureWarp, uv, device=None) -> np.ndarray:
    """Run :data:`svbrdf_texel_kernel`: the nearest texel (row, column) of UVs (P, 2), int32 (P, 2)."""
    device = wp.get_device(device)
    a = np.asarray(uv, np.float32).reshape(-1, 2)
    out = wp.zeros(a.shape[0], dtype=wp.vec2i, device=device)
    wp.launch(svbrdf_texel_kernel, dim=a.shape[0], device=device,
              inputs=[tex, wp.array(a, dtype=wp.vec2, device=device)], outputs=[out])
    return out.numpy()
