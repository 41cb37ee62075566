"""The kernels' argument structs of ``sg.shade`` (:mod:`._kernels`): its settings, the SSDF
visibility, the per-point materials, and the G-buffer rays of per-pixel shading with their
materials interpolated from the vertices or given per pixel."""

from __future__ import annotations

import numpy as np

from ..._wp import wp
from ...basis import sg
from ..stage import StageError
from . import _kernels as kernels
from ._brdf_warp import MODEL_IDS
from ._model import decode_maps

#: Specular of narrow lights: the exact BRDF at the light ("brdf") or the paper's SG product ("sg").
NARROW_LIGHT_MODES = ("brdf", "sg")
#: A light lobe this many times sharper than the BRDF slice counts as narrow.
NARROW_LIGHT_RATIO = 8.0
#: The exact models of the "brdf" mode: codes of warpshade.scene._materials_warp.BRDF_MODELS.
EXACT_MODEL_CODES = {"beckmann": 4, "blinn-phong": 2}


def settings_struct(p: dict, terms: int, resolution: int):
    """The :class:`~._kernels.Settings` of parameters ``p`` for SSDFs of ``terms`` PCA terms and
    ``resolution``^2 maps; its ``lobes`` and ``svbrdf`` are the caller's to fill."""
    st = kernels.Settings()
    st.model = int(MODEL_IDS.get(p["brdf"], 0))  # multi-lobe models: unused (st.lobes)
    st.f0 = float(p["f0"])
    cos_axis, cos_lam, cos_mu = sg.clamped_cosine(np.array([0.0, 0.0, 1.0]), p["cosine"])
    st.cos_sharpness, st.cos_amplitude = float(cos_lam), float(cos_mu)
    st.component = kernels.COMPONENTS.index(p["component"])
    st.pca = 0 if p["ssdf"] == "maps" else 1
    st.terms = int(terms)
    st.resolution = int(resolution)
    st.horizon = 1 if p["horizon"] else 0
    st.exact_model = int(EXACT_MODEL_CODES.get(p["brdf"], -1)) if p["narrow_lights"] == "brdf" else -1
    st.exact_ratio = float(NARROW_LIGHT_RATIO)
    return st


def ssdf_visibility(model, mode: str, frames, device):
    """The :class:`~._kernels.Visibility` of an :class:`~warpshade.transfer.SSDFModel` in the
    tangent ``frames`` (V,) mat33: decoded maps (``mode = 'maps'``) or the PCA itself ('pca')."""
    vis = kernels.Visibility()
    if mode == "maps":
        vis.maps = wp.array(decode_maps(model), dtype=float, device=device)
        vis.mean = wp.zeros(1, dtype=float, device=device)
        vis.basis = wp.zeros((1, 1), dtype=float, device=device)
        vis.coeffs = wp.zeros((1, 1), dtype=float, device=device)
    else:
        vis.maps = wp.zeros((1, 1, 1), dtype=float, device=device)
        vis.mean = wp.array(model.mean.astype(np.float32), dtype=float, device=device)
        vis.basis = wp.array(model.basis.astype(np.float32), dtype=float, device=device)
        vis.coeffs = wp.array(model.coeffs.astype(np.float32), dtype=float, device=device)
    vis.frames = frames
    return vis


def materials_struct(albedo, specular, roughness):
    """A :class:`~._kernels.Materials` over per-point arrays (albedo, specular (P,) vec3; roughness (P,) float)."""
    m = kernels.Materials()
    m.albedo, m.specular, m.roughness = albedo, specular, roughness
    return m


def vertex_points(points, normals, eye, tangents):
    """A :class:`~._kernels.VertexPoints` over the frame's (V,) vec3 points, normals and tangents
    and the (1,) vec3 eye."""
    v = kernels.VertexPoints()
    v.position, v.normal = points, normals
    v.eye = eye
    v.tangent = tangents
    return v


def pixel_hits(gbuffer, normals, eye, tangents):
    """A G-buffer's rays as a :class:`~._kernels.PixelHits` with shading ``normals`` (N,) vec3, the
    (1,) vec3 ``eye`` and the per-vertex ``tangents`` (V,) vec3."""
    hits = kernels.PixelHits()
    hits.hit, hits.position, hits.normal = gbuffer.hit, gbuffer.position, normals
    hits.face, hits.bary, hits.faces, hits.eye = gbuffer.face, gbuffer.bary, gbuffer.faces, eye
    hits.tangent = tangents
    return hits


def interpolated_materials(hits, n: int, vertex_materials, device):
    """The per-vertex materials at each of the ``n`` rays of ``hits`` (0 for misses), new per-pixel arrays."""
    px = materials_struct(wp.zeros(n, dtype=wp.vec3, device=device), wp.zeros(n, dtype=wp.vec3, device=device),
                          wp.zeros(n, dtype=float, device=device))
    wp.launch(kernels.interpolate_materials_kernel, dim=n, device=device, inputs=[hits, vertex_materials, px])
    return px


def override_pixels(hits, px, gbuffer, device, stage: str, albedo=None, specular=None, roughness=None, normals=None) -> None:
    """Write the per-pixel arrays given into ``px`` (albedo, specular (N, 3); roughness (N,):
    finite, non-negative) and ``hits.normal`` (normals (N, 3), unit at the hits)."""
    n = gbuffer.pixel_count
    for name, value, buf, rgb in (("albedo", albedo, px.albedo, True), ("specular", specular, px.specular, True),
                                  ("roughness", roughness, px.roughness, False)):
        if value is None:
            continue
        a = np.asarray(value, np.float32)
        want = (n, 3) if rgb else (n,)
        if a.shape != want or not np.all(np.isfinite(a)) or np.any(a < 0):
            raise StageError(f"stage {stage!r}: render_pixels {name} must be finite, non-negative, shape {want}; "
                             f"got {a.shape}")
        buf.assign(a)
    if normals is not None:
        a = np.asarray(normals, np.float32)
        hit = gbuffer.hit.numpy().astype(bool)
        bad = a.shape != (n, 3) or not np.all(np.isfinite(a))
        if not bad and np.any(np.abs(np.linalg.norm(a[hit], axis=-1) - 1.0) > 1e-3):
            bad = True
        if bad:
            raise StageError(f"stage {stage!r}: render_pixels normals must be finite unit vectors, shape {(n, 3)}; "
                             f"got {a.shape}")
        hits.normal = wp.array(a, dtype=wp.vec3, device=device)
