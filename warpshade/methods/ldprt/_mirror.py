"""Float64 mirrors of the LDPRT kernels (the oracles of the tests).

Local frame: the per-vertex tangent frame ``F`` (rows tangent, bitangent, normal) of
:mod:`warpshade.geometry._frames`; local -> world is ``F^T``. Diffuse radiance is
``albedo / pi * dot(L, t~_world)`` (the convention of static PRT), glossy exit radiance
``u(v_local) . (rows_world L)`` (eq. 16).
"""

from __future__ import annotations

import numpy as np

from ...basis import zh
from ._glossy import GlossyModel
from ._model import LDPRTModel

__all__ = [
    "parallax_uv_f64",
    "patch_tangent_frames_f64",
    "patch_vertex_tangents_f64",
    "rotate_stored",
    "shade_glossy_f64",
    "shade_patch_f64",
    "shade_unshadowed_f64",
]


def rotate_stored(stored: np.ndarray, rotations: np.ndarray, order: int) -> np.ndarray:
    """Stored DC + linear bands rotated to world, as SH (V, n*n) float64 (zero from band 2)."""
    out = np.zeros((stored.shape[0], order * order))
    out[:, 0] = stored[:, 0]
    if order > 1:
        w = np.stack([-stored[:, 3], -stored[:, 1], stored[:, 2]], axis=1).astype(np.float64)
        ww = np.einsum("vij,vj->vi", rotations, w)
        out[:, 1], out[:, 2], out[:, 3] = -ww[:, 1], ww[:, 2], -ww[:, 0]
    return out


def world_transfer_f64(model: LDPRTModel, frames: np.ndarray) -> np.ndarray:
    """World-frame transfer of the model under per-vertex frames (float64), (V, n*n).

    Args:
        frames: (V, 3, 3) tangent frames (rows t, b, n); local -> world is ``F^T``.
    """
    rot = np.swapaxes(np.asarray(frames, np.float64), 1, 2)
    axes = zh.rotate(model.axes.astype(np.float64), rot)
    mask = np.arange(model.lobe_capacity)[None, :] < model.counts[:, None]
    t = zh.to_sh(axes, model.coeffs.astype(np.float64) * mask[:, :, None])
    return t + rotate_stored(model.stored, rot, model.order)


def shade_f64(model: LDPRTModel, frames: np.ndarray, light: np.ndarray, albedo: np.ndarray) -> np.ndarray:
    """Float64 mirror of the LDPRT shading kernels, (V, 3) linear RGB.

    ``radiance_c = albedo_c / pi * dot(L_c, t~_world)`` with ``L`` the world-frame lighting SH
    (3, n*n).
    """
    t = world_transfer_f64(model, frames)
    return np.asarray(albedo, np.float64) / np.pi * (t @ np.asarray(light, np.float64).T)


def shade_glossy_f64(model: GlossyModel, frames, view_world, light) -> np.ndarray:
    """Float64 mirror of the glossy shading kernel: (V, C) exit radiance.

    Args:
        frames: (V, 3, 3) tangent frames (rows t, b, n). view_world: (V, 3) unit directions
            towards the viewer. light: (C, n*n) world lighting SH.
    """
    f = np.asarray(frames, dtype=np.float64)
    rot = np.swapaxes(f, 1, 2)
    view_local = np.einsum("vij,vj->vi", f, np.asarray(view_world, np.float64))
    u = model.factorization.view_factors_at(view_local)  # (V, n_b)
    axes = zh.rotate(model.axes.astype(np.float64), rot[:, None])  # (V, n_b, N, 3)
    rows = zh.to_sh(axes, model.coeffs.astype(np.float64))  # (V, n_b, n^2)
    stored = np.stack([rotate_stored(model.stored[:, j], rot, model.order) for j in range(model.rank)], axis=1)
    rows_world = rows + stored
    # negative radiance (SH truncation) is clamped to zero, as the kernel does
    return np.maximum(np.einsum("vj,vjk,ck->vc", u, rows_world, np.asarray(light, np.float64)), 0.0)


def any_perpendicular_f64(n: np.ndarray) -> np.ndarray:
    """Float64 mirror of ``patch_warp.any_perpendicular``: unit vectors perpendicular to unit (N, 3)."""
    a = np.where(np.abs(n[:, :1]) > 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
    t = a - n * np.sum(n * a, axis=1, keepdims=True)
    return t / np.linalg.norm(t, axis=1, keepdims=True)


def patch_tangent_frames_f64(normals, tangents, bitangents, eps: float = 1e-12) -> np.ndarray:
    """Float64 mirror of ``patch_warp.tangent_frame``: (N, 3, 3) rows (t, b, n), always finite."""
    with np.errstate(invalid="ignore", over="ignore"):
        nv = np.asarray(normals, np.float64).reshape(-1, 3)
        tv = np.asarray(tangents, np.float64).reshape(-1, 3)
        bv = np.asarray(bitangents, np.float64).reshape(-1, 3)
        nl = np.linalg.norm(nv, axis=1, keepdims=True)
        ok = (nl > eps) & (nl < 1e30)
        n = np.where(ok, nv / np.where(ok, nl, 1.0), [[0.0, 0.0, 1.0]])
        t = tv - n * np.sum(n * tv, axis=1, keepdims=True)
        tl = np.linalg.norm(t, axis=1, keepdims=True)
        ok = (tl > eps) & (tl < 1e30)
        t = np.where(ok, t / np.where(ok, tl, 1.0), any_perpendicular_f64(n))
        b = np.cross(n, t)
        b = np.where(np.sum(b * bv, axis=1, keepdims=True) < 0.0, -b, b)
    return np.stack([t, b, n], axis=1)


def patch_vertex_tangents_f64(points, faces, uvs, patched) -> tuple[np.ndarray, np.ndarray]:
    """Float64 mirror of ``patch_warp.accumulate_tangents_kernel``: per-vertex dP/du, dP/dv summed
    over the triangles of patched meshes, each times its UV area (sign of the UV orientation)."""
    p, f, uv = np.asarray(points, np.float64), np.asarray(faces, np.int64), np.asarray(uvs, np.float64)
    f = f[np.asarray(patched)[f[:, 0]] != 0]
    e1, e2 = p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]
    d1, d2 = uv[f[:, 1]] - uv[f[:, 0]], uv[f[:, 2]] - uv[f[:, 0]]
    s = np.sign(d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1])[:, None]
    dpdu = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * s
    dpdv = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * s
    t, b = np.zeros_like(p), np.zeros_like(p)
    for k in range(3):
        np.add.at(t, f[:, k], dpdu)
        np.add.at(b, f[:, k], dpdv)
    return t, b


def patch_texel_weights_f64(uv, resolution: int, tiling: float) -> tuple[np.ndarray, np.ndarray]:
    """The four texels around each patch look-up and their bilinear weights: (N, 4) int, (N, 4) float64."""
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    u = np.where(np.abs(uv[:, 0] * tiling) < 1e6, uv[:, 0] * tiling, 0.0)
    v = np.where(np.abs(uv[:, 1] * tiling) < 1e6, uv[:, 1] * tiling, 0.0)
    x = (u - np.floor(u)) * resolution - 0.5
    y = (v - np.floor(v)) * resolution - 0.5
    fx, fy = x - np.floor(x), y - np.floor(y)
    i0, j0 = np.floor(x).astype(np.int64) % resolution, np.floor(y).astype(np.int64) % resolution
    i1, j1 = (i0 + 1) % resolution, (j0 + 1) % resolution
    texels = np.stack([j0 * resolution + i0, j0 * resolution + i1, j1 * resolution + i0, j1 * resolution + i1], 1)
    weights = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    return texels, weights


def shade_patch_f64(patch, uv, frames, light, albedo, tiling: float) -> np.ndarray:
    """Float64 mirror of the patch shading (``patch_warp``): (N, 3) linear RGB.

    Args:
        patch: a :class:`~._patch.PatchModel`; uv: (N, 2) surface UVs; frames: (N, 3, 3) rows
        (t, b, n); light: (3, n*n) world SH lighting; albedo: (N, 3); tiling: patches per UV unit.
    """
    texels, weights = patch_texel_weights_f64(uv, patch.resolution, tiling)
    rot = np.swapaxes(np.asarray(frames, np.float64), 1, 2)
    light = np.asarray(light, np.float64)
    out = np.zeros((texels.shape[0], 3))
    for k in range(4):
        sel = texels[:, k]
        axes = zh.rotate(patch.axes[sel].astype(np.float64), rot)
        mask = np.arange(patch.axes.shape[1])[None, :] < patch.counts[sel][:, None]
        t = zh.to_sh(axes, patch.coeffs[sel].astype(np.float64) * mask[:, :, None])
        t = t + rotate_stored(patch.stored[sel], rot, patch.order)
        out += weights[:, k:k + 1] * patch.albedo[sel].astype(np.float64) * (t @ light.T)
    return np.asarray(albedo, np.float64) / np.pi * out


def shade_unshadowed_f64(normals, light, albedo) -> np.ndarray:
    """Float64 unshadowed diffuse shading about unit normals (N, 3): ``albedo / pi * E(n)``."""
    from ...basis import sh

    order = int(round(np.sqrt(np.asarray(light).shape[1])))
    a = sh.clamped_cosine_zh(order)[sh.band_of(order)]
    y = sh.basis(np.asarray(normals, np.float64).reshape(-1, 3), order)
    return np.asarray(albedo, np.float64) / np.pi * ((y * a) @ np.asarray(light, np.float64).T)


def parallax_uv_f64(heights, uv, frames, directions, tiling: float, steps: int = 32, min_cosine: float = 0.1):
    """Float64 mirror of ``patch_warp.parallax_uv``: (N, 2) UVs of the first point of the displaced
    patch (heights about their mean) that view rays ``directions`` (N, 3) through the base points
    ``uv`` (N, 2) meet, in tangent frames (N, 3, 3) rows (t, b, n)."""
    from ._patch import sample_heights

    h = np.asarray(heights, np.float64)
    mean, top, bottom = h.mean(), h.max() - h.mean(), h.min() - h.mean()
    uv = np.asarray(uv, np.float64).reshape(-1, 2) * tiling
    uv = np.where(np.abs(uv) < 1e6, uv, 0.0)
    d = np.einsum("nij,nj->ni", np.asarray(frames, np.float64), np.asarray(directions, np.float64))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    dz = np.minimum(d[:, 2], -min_cosine)
    s0, s1 = top / dz, bottom / dz

    def f(s):
        return dz * s - (sample_heights(h, uv + s[:, None] * d[:, :2]) - mean)

    prev_s, prev_f = s0, f(s0)
    hit = s1.copy()
    found = np.zeros(uv.shape[0], bool)
    for k in range(1, steps + 1):
        s = s0 + (s1 - s0) * k / steps
        fs = f(s)
        new = ~found & (fs <= 0.0)
        denom = prev_f - fs
        t = np.where(denom > 0.0, prev_f / np.where(denom > 0.0, denom, 1.0), 1.0)
        hit = np.where(new, prev_s + (s - prev_s) * t, hit)
        found |= new
        prev_s, prev_f = s, fs
    return (uv + hit[:, None] * d[:, :2]) / tiling
