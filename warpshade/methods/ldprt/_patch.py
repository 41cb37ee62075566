"""LDPRT texture patches (Sloan, Luna, Snyder 2005, Sec. 5): a small tileable height field whose
ray-traced transfer is fitted with ZH lobes per texel and mapped onto a deforming surface.

Patch frame: the patch is the unit square ``[0, 1)^2`` of the (u, v) plane, x along u, y along
v, z up, heights in units of the patch's side (``heights[j, i]`` at ``u = (i + 0.5) / R``,
``v = (j + 0.5) / R``; texel index ``j * R + i``). It is periodic: the transfer of a texel is ray
traced over ``tiles x tiles`` copies of the height field (:func:`tiled_mesh`), so rays leaving
the patch see its neighbours. On a surface the patch frame is the tangent frame built from the
UVs (tangent along dP/du, bitangent along dP/dv, the shading normal), the patch repeating
``tiling`` times over the unit UV square.

* :func:`patch_heights` -- procedural heights (``bumps``, ``waffle``, ``weave``, ``swirl``), a
  ``flat`` patch, or heights from an albedo texture (``texture``: its luminance, dark = deep, as
  the paper derives relief from an albedo map);
* :func:`patch_transfer` -- the diffuse transfer per texel, patch frame, (R*R, n*n); a flat patch
  is the clamped cosine about +z exactly (nothing to trace);
* :func:`bake_patch` -- heights, transfer and the per-texel ZH fit (lobe counts from an error
  budget) as a :class:`PatchModel` (the ``ldprt.patch`` artifact);
* :func:`patch_albedo` -- the albedo texture of a ``texture`` patch resampled per texel (the
  shading multiplies the surface albedo by it, as the paper's patches carry their albedo);
* :func:`sample_heights` -- bilinear, periodic look-up of the heights (float64);
* :func:`PatchGeometry` -- the displaced fine mesh the per-pixel ground truth is traced on: the
  surface subdivided (midpoint, ``levels`` times), moved along its interpolated normals by the
  patch height at its UVs, at any frame of the deforming scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._model import fit_transfer

__all__ = [
    "PATCH_SHAPES",
    "PatchGeometry",
    "PatchModel",
    "bake_patch",
    "interpolate_at_hits",
    "patch_albedo",
    "patch_heights",
    "patch_prims",
    "patch_transfer",
    "sample_heights",
    "tiled_mesh",
]

#: Height fields :func:`patch_heights` makes ("texture" reads an image).
PATCH_SHAPES = ("bumps", "waffle", "weave", "swirl", "texture", "flat")
#: Rec. 709 luminance weights (heights from an albedo texture).
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def _grid(resolution: int):
    c = (np.arange(resolution) + 0.5) / resolution
    u, v = np.meshgrid(c, c, indexing="xy")  # u[j, i] = c[i], v[j, i] = c[j]
    return u, v


def _periodic_distance(x, period_count: int):
    """Distance from x to the nearest multiple of 1 / period_count, in units of the period."""
    t = np.mod(np.asarray(x) * period_count, 1.0)
    return np.minimum(t, 1.0 - t)


def patch_heights(shape: str, resolution: int, height: float, image=None) -> np.ndarray:
    """Heights of a tileable patch, (R, R) float64 in patch widths, in ``[0, height]``.

    Args:
        shape: one of :data:`PATCH_SHAPES`.
        resolution: texels per side R (>= 4).
        height: peak-to-valley relief, in patch widths (>= 0).
        image: for ``"texture"``: an (H, W, 3) or (H, W) albedo image; its luminance, resampled
            to R x R (area average over each texel, bilinear where the image is smaller), dark = low.

    Raises:
        ValueError: an unknown shape, a resolution below 4, a negative or non-finite height, a
            missing, non-finite or constant-free image for ``"texture"`` (naming the parameter).
    """
    if shape not in PATCH_SHAPES:
        raise ValueError(f"ldprt.patch: parameter 'shape' must be one of {PATCH_SHAPES}, got {shape!r}")
    r = int(resolution)
    if r < 4:
        raise ValueError(f"ldprt.patch: parameter 'resolution' must be >= 4, got {resolution!r}")
    if not np.isfinite(height) or height < 0:
        raise ValueError(f"ldprt.patch: parameter 'height' must be finite and >= 0, got {height!r}")
    u, v = _grid(r)
    if shape == "flat":
        h = np.zeros((r, r))
    elif shape == "bumps":  # 2 x 2 round bumps (cos^2 profile) on a plane
        du, dv = _periodic_distance(u - 0.25, 2), _periodic_distance(v - 0.25, 2)
        rho = np.hypot(du, dv) / 0.4
        h = np.where(rho < 1.0, np.cos(0.5 * np.pi * np.minimum(rho, 1.0)) ** 2, 0.0)
    elif shape == "waffle":  # raised walls on a 2 x 2 grid of sunken square cells
        wall = lambda x: np.clip(1.0 - _periodic_distance(x, 2) / 0.18, 0.0, 1.0)  # noqa: E731
        h = np.maximum(wall(u), wall(v)) ** 0.5
    elif shape == "weave":  # two threads each way passing over and under each other
        warp_profile = np.cos(np.pi * _periodic_distance(u - 0.25, 2)) ** 2
        weft_profile = np.cos(np.pi * _periodic_distance(v - 0.25, 2)) ** 2
        warp_lift = 0.5 + 0.5 * np.sin(2.0 * np.pi * 2.0 * v + np.pi * np.floor(2.0 * u))
        weft_lift = 0.5 - 0.5 * np.sin(2.0 * np.pi * 2.0 * u + np.pi * np.floor(2.0 * v))
        h = np.maximum(warp_profile * (0.4 + 0.6 * warp_lift), weft_profile * (0.4 + 0.6 * weft_lift))
    elif shape == "swirl":  # a spiral ridge about the patch centre, flat at its edges (tileable)
        x, y = u - 0.5, v - 0.5
        rho, theta = np.hypot(x, y), np.arctan2(y, x)
        window = np.clip(1.0 - rho / 0.48, 0.0, 1.0) ** 0.5
        h = (0.5 + 0.5 * np.cos(2.0 * np.pi * 4.0 * rho + 3.0 * theta)) * window
    else:  # texture
        if image is None:
            raise ValueError("ldprt.patch: shape = 'texture' needs the parameter 'texture' (an albedo image file)")
        img = np.asarray(image, np.float64)
        if img.ndim == 3:
            img = img[..., :3] @ LUMINANCE[: img.shape[-1]] if img.shape[-1] >= 3 else img[..., 0]
        if img.ndim != 2 or min(img.shape) < 1 or not np.all(np.isfinite(img)):
            raise ValueError(f"ldprt.patch: parameter 'texture' must be a finite image, got shape {np.shape(image)}")
        h = _resample(img, r)
    h = np.asarray(h, np.float64)
    lo, hi = float(h.min()), float(h.max())
    h = (h - lo) / (hi - lo) if hi - lo > 1e-12 else np.zeros_like(h)
    return h * float(height)


def _resample(img: np.ndarray, r: int) -> np.ndarray:
    """(H, W) -> (r, r): box average when the image is larger, bilinear (periodic) otherwise;
    image row 0 is the top (v = 1)."""
    img = img[::-1]  # row 0 at v = 0
    hgt, wid = img.shape
    if hgt >= r and wid >= r:
        rows = (np.arange(hgt) * r) // hgt
        cols = (np.arange(wid) * r) // wid
        out = np.zeros((r, r))
        count = np.zeros((r, r))
        np.add.at(out, (rows[:, None], cols[None, :]), img)
        np.add.at(count, (rows[:, None], cols[None, :]), 1.0)
        return out / count
    u, v = _grid(r)
    return sample_heights(img, np.stack([u.ravel(), v.ravel()], 1)).reshape(r, r)


def patch_albedo(image, resolution: int, eight_bit: bool = False) -> np.ndarray:
    """Per-texel albedo of an image, (R, R, 3) float64 linear RGB in [0, 1] (texel ``[j, i]`` as
    the heights): the image resampled like :func:`patch_heights` does, sRGB-decoded first when
    it came from 8-bit values; a one-channel image is grey."""
    from ...scene._textures import srgb_to_linear

    img = np.asarray(image, np.float64)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or not np.all(np.isfinite(img)):
        raise ValueError(f"ldprt.patch: parameter 'texture' must be a finite image, got shape {np.shape(image)}")
    rgb = np.repeat(img[..., :1], 3, axis=-1) if img.shape[-1] < 3 else img[..., :3]
    if eight_bit:
        rgb = srgb_to_linear(rgb)
    out = np.stack([_resample(rgb[..., c], int(resolution)) for c in range(3)], axis=-1)
    return np.clip(out, 0.0, 1.0)


def sample_heights(heights, uv) -> np.ndarray:
    """Bilinear, periodic look-up of (R, R) texel-centre heights at patch coordinates ``uv`` (S, 2)
    (any real numbers; the patch repeats with period 1). Returns (S,) float64."""
    h = np.asarray(heights, np.float64)
    rv, ru = h.shape
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    x = np.mod(uv[:, 0], 1.0) * ru - 0.5
    y = np.mod(uv[:, 1], 1.0) * rv - 0.5
    i0, j0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = x - i0, y - j0
    i0, j0 = i0 % ru, j0 % rv
    i1, j1 = (i0 + 1) % ru, (j0 + 1) % rv
    return ((1 - fx) * (1 - fy) * h[j0, i0] + fx * (1 - fy) * h[j0, i1] + (1 - fx) * fy * h[j1, i0]
            + fx * fy * h[j1, i1])


def tiled_mesh(heights, tiles: int):
    """The height field repeated ``tiles x tiles`` times (odd ``tiles``), triangulated through the
    texel centres: ``(points (P, 3), faces (F, 3), receivers (R*R,))`` with the receivers the
    centre copy's vertices in texel order (``j * R + i``)."""
    h = np.asarray(heights, np.float64)
    r = h.shape[0]
    k = int(tiles)
    if k < 1 or k % 2 == 0:
        raise ValueError(f"ldprt.patch: parameter 'tiles' must be an odd number >= 1, got {tiles!r}")
    n = k * r
    c = (np.arange(n) + 0.5) / r - (k // 2)
    gx, gy = np.meshgrid(c, c, indexing="xy")
    gz = np.tile(h, (k, k))
    pts = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], 1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, cc, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, cc], 1), np.stack([a, cc, d], 1)]).astype(np.int32)
    off = (k // 2) * r
    receivers = idx[off : off + r, off : off + r].ravel()
    return pts, faces, receivers


def patch_transfer(heights, order: int, samples: int, tiles: int = 3, device=None, seed: int = 0) -> np.ndarray:
    """Diffuse transfer of every texel, patch frame, (R*R, n*n) float64 (texel ``j * R + i``).

    Visibility is ray traced over ``tiles x tiles`` copies of the height field
    (:func:`warpshade.transfer.compute`, cosine about the height field's own normal). A flat patch
    has no occlusion: its transfer is the clamped cosine about +z, exactly.
    """
    from ...basis import sh
    from ...scene import Mesh, Scene
    from ...transfer import compute

    h = np.asarray(heights, np.float64)
    if np.ptp(h) <= 0.0:
        cosine = sh.zh_to_sh(np.array([0.0, 0.0, 1.0]), sh.clamped_cosine_zh(order, "zh"))
        return np.tile(cosine, (h.size, 1))
    pts, faces, receivers = tiled_mesh(h, tiles)
    scene = Scene.from_meshes([Mesh("/patch", pts, faces)])
    res = compute(scene, 0.0, order, samples, space="world", device=device, seed=seed, vertices=receivers)
    return np.asarray(res.transfer, np.float64)


@dataclass
class PatchModel:
    """The ``ldprt.patch`` artifact: a tileable height field and its per-texel ZH transfer.

    Attributes:
        heights: (R, R) float32, patch widths (texel ``[j, i]`` at ``((i + .5) / R, (j + .5) / R)``).
        axes: (R*R, L, 3) float32 lobe axes, patch frame; coeffs: (R*R, L, n) float32 ``g*``;
        counts: (R*R,) int32 lobes per texel; stored: (R*R, 4) float32 DC + linear SH;
        fit_error: (R*R,) float32 per-texel fit error relative to the RMS transfer norm;
        albedo: (R*R, 3) float32 linear albedo per texel, multiplying the surface's (ones for the
        procedural shapes).
    """

    heights: np.ndarray
    axes: np.ndarray
    coeffs: np.ndarray
    counts: np.ndarray
    stored: np.ndarray
    fit_error: np.ndarray
    albedo: np.ndarray

    @property
    def resolution(self) -> int:
        return int(self.heights.shape[0])

    @property
    def order(self) -> int:
        return int(self.coeffs.shape[-1])

    def arrays(self) -> dict:
        return {"heights": self.heights, "axes": self.axes, "coeffs": self.coeffs, "counts": self.counts,
                "stored": self.stored, "fit_error": self.fit_error, "albedo": self.albedo}

    @classmethod
    def from_arrays(cls, arrays: dict) -> "PatchModel":
        """Rebuild and check (shapes, dtypes, finiteness); ValueError naming the array otherwise."""
        need = ("heights", "axes", "coeffs", "counts", "stored", "fit_error", "albedo")
        missing = [k for k in need if k not in arrays]
        if missing:
            raise ValueError(f"ldprt.patch artifact: missing arrays {missing}")
        a = {k: np.asarray(arrays[k]) for k in need}
        r = a["heights"].shape[0] if a["heights"].ndim == 2 else -1
        t = r * r
        shapes = {"heights": (r, r), "axes": (t, None, 3), "coeffs": (t, None, None), "counts": (t,),
                  "stored": (t, 4), "fit_error": (t,), "albedo": (t, 3)}
        for k, want in shapes.items():
            got = a[k].shape
            if r < 1 or len(got) != len(want) or any(w is not None and w != g for w, g in zip(want, got)):
                raise ValueError(f"ldprt.patch artifact: {k!r} has shape {got}, expected {want} for {r} x {r} texels")
            if not np.all(np.isfinite(a[k])):
                raise ValueError(f"ldprt.patch artifact: {k!r} holds non-finite values")
        lobes = a["axes"].shape[1]
        if a["coeffs"].shape[1] != lobes or np.any(a["counts"] < 0) or np.any(a["counts"] > lobes):
            raise ValueError(f"ldprt.patch artifact: lobe counts outside 0..{lobes}")
        if np.any(a["albedo"] < 0):
            raise ValueError("ldprt.patch artifact: 'albedo' holds negative values")
        return cls(a["heights"].astype(np.float32), a["axes"].astype(np.float32), a["coeffs"].astype(np.float32),
                   a["counts"].astype(np.int32), a["stored"].astype(np.float32), a["fit_error"].astype(np.float32),
                   a["albedo"].astype(np.float32))

    def flattened(self) -> "PatchModel":
        """The same patch without relief: every texel's transfer the clamped cosine about +z
        (stored DC and linear band, one lobe along +z for the rest), its albedo kept."""
        from ...basis import sh

        order, texels = self.order, self.counts.size
        cosine = sh.zh_to_sh(np.array([0.0, 0.0, 1.0]), sh.clamped_cosine_zh(order, "zh"))
        coeffs = np.zeros((texels, 1, order), np.float32)
        coeffs[:, 0, 2:] = sh.clamped_cosine_zh(order)[2:]
        stored = np.zeros((texels, 4), np.float32)
        stored[:, : min(4, order * order)] = cosine[:4]
        axes = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (texels, 1, 1))
        return PatchModel(np.zeros_like(self.heights), axes, coeffs, np.ones(texels, np.int32), stored,
                          np.zeros(texels, np.float32), self.albedo.copy())

    def to_sh(self) -> np.ndarray:
        """Per-texel transfer reconstructed from the lobes, patch frame, (R*R, n*n) float64."""
        from ...basis import zh

        mask = np.arange(self.axes.shape[1])[None, :] < self.counts[:, None]
        out = zh.to_sh(self.axes.astype(np.float64), self.coeffs.astype(np.float64) * mask[:, :, None])
        k = min(4, self.order**2)
        out[:, :k] += self.stored[:, :k]
        return out


def bake_patch(heights, order: int, samples: int, lobes: int, target_error: float | None, tiles: int = 3,
               device=None, seed: int = 0, restarts: int = 2, albedo=None) -> tuple[PatchModel, dict]:
    """Trace the patch's transfer and fit it per texel (:func:`warpshade.methods.ldprt.fit_transfer`,
    lobe count per texel from ``target_error``, at most ``lobes``); ``albedo`` (R, R, 3) per texel
    (default ones). Returns (model, report)."""
    h = np.asarray(heights, np.float64)
    if h.ndim != 2 or h.shape[0] != h.shape[1]:
        raise ValueError(f"ldprt.patch: heights must be a square (R, R) array, got shape {h.shape}")
    if not np.all(np.isfinite(h)):
        raise ValueError(f"ldprt.patch: parameter 'heights' holds {int(np.sum(~np.isfinite(h)))} non-finite values "
                         "(NaN or inf); every texel needs a finite height")
    t = patch_transfer(h, order, samples, tiles, device, seed)
    fit = fit_transfer(t, lobes, target_error=target_error, restarts=restarts, seed=seed)
    tex = np.ones(h.shape + (3,)) if albedo is None else np.asarray(albedo, np.float64)
    if tex.shape != h.shape + (3,) or not np.all(np.isfinite(tex)) or np.any(tex < 0):
        raise ValueError(f"ldprt.patch: albedo must be finite, >= 0, shape {h.shape + (3,)}, got {tex.shape}")
    model = PatchModel(h.astype(np.float32), fit.axes, fit.coeffs, fit.counts, fit.stored, fit.fit_error,
                       tex.reshape(-1, 3).astype(np.float32))
    report = {"texels": int(h.size), "histogram": fit.histogram, "total_error": fit.total_error,
              "fit_seconds": fit.seconds, "mean_lobes": float(np.mean(fit.counts))}
    return model, report


def _subdivide(faces: np.ndarray, vertex_count: int, levels: int):
    """Midpoint subdivision ``levels`` times: (fine faces (F', 3), weights: scipy.sparse (V', V))
    with fine vertex = weights @ coarse vertices (edge midpoints shared between triangles)."""
    from scipy import sparse

    w = sparse.identity(vertex_count, format="csr")
    f = np.asarray(faces, np.int64)
    n = vertex_count
    for _ in range(int(levels)):
        edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        key = np.sort(edges, axis=1)
        uniq, inverse = np.unique(key, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        mid = n + inverse.reshape(3, -1).T  # (F, 3): midpoints of edges 01, 12, 20
        rows = np.repeat(np.arange(uniq.shape[0]), 2)
        half = sparse.csr_matrix((np.full(rows.size, 0.5), (rows, uniq.ravel())), shape=(uniq.shape[0], n))
        w = sparse.vstack([w, half @ w]).tocsr()
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        ab, bc, ca = mid[:, 0], mid[:, 1], mid[:, 2]
        f = np.concatenate([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1), np.stack([ca, bc, c], 1),
                            np.stack([ab, bc, ca], 1)])
        n += uniq.shape[0]
    return f.astype(np.int32), w


class PatchGeometry:
    """The displaced surface a patch describes: what the per-pixel ground truth is traced on.

    Each mesh of ``prims`` is subdivided ``levels`` times (midpoint; chosen, when None, so that
    a fine edge is at most one texel of the tiled patch in UV), and at every frame its fine
    vertices are the coarse surface interpolated (points, normals, UVs, albedo) and moved along
    the normal by ``(heights(uv * tiling) - mean height) * patch_size``, with ``patch_size`` the world length of
    one patch: the mesh's rest-pose world-to-UV scale ``sqrt(area / uv area)`` over ``tiling``.
    With ``albedo`` (R, R, 3) the fine vertices' albedo is multiplied by it (bilinear at their
    UVs). Other meshes are copied as they are at the frame. Seams in the UVs (split vertices) are not
    welded: a displaced seam may open.
    """

    def __init__(self, scene, heights, tiling: float, prims, levels: int | None = None, max_levels: int = 4,
                 albedo=None):
        self.scene = scene
        self.heights = np.asarray(heights, np.float64)
        self.albedo = None if albedo is None else np.asarray(albedo, np.float64).reshape(self.heights.shape + (3,))
        self.tiling = float(tiling)
        self.prims = list(prims)
        texel_uv = 1.0 / (self.tiling * self.heights.shape[0])
        rest = scene.points_at(float(scene.frames[0]))
        self._fine = {}
        for m in scene.meshes:
            if m.path not in self.prims:
                continue
            uv = np.asarray(m.uvs, np.float64)
            tri = np.asarray(m.faces, np.int64)
            e_uv = np.linalg.norm(uv[tri[:, 1]] - uv[tri[:, 0]], axis=1)
            lv = levels
            if lv is None:
                edge = float(np.median(e_uv)) if e_uv.size else 0.0
                lv = 0 if edge <= texel_uv else min(int(math.ceil(math.log2(edge / texel_uv))), int(max_levels))
            p = rest[m.vertex_offset : m.vertex_offset + m.vertex_count]
            area = 0.5 * np.linalg.norm(np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]]), axis=1).sum()
            d1, d2 = uv[tri[:, 1]] - uv[tri[:, 0]], uv[tri[:, 2]] - uv[tri[:, 0]]
            uv_area = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]).sum()
            scale = math.sqrt(area / uv_area) if uv_area > 0 else 0.0
            faces, w = _subdivide(m.faces, m.vertex_count, lv)
            fine_uv = w @ uv
            # about the patch's mean height: the transfer does not depend on a constant offset, and
            # the mean plane is the displaced surface closest to the undisplaced one (least parallax)
            rel = sample_heights(self.heights - self.heights.mean(), fine_uv * self.tiling)
            offset = rel * scale / self.tiling
            tint = np.ones((fine_uv.shape[0], 3))
            if self.albedo is not None:
                tint = np.stack([sample_heights(self.albedo[..., c], fine_uv * self.tiling) for c in range(3)], 1)
            self._fine[m.path] = {"faces": faces, "weights": w, "offset": offset, "levels": int(lv),
                                  "patch_size": scale / self.tiling, "tint": tint}

    @property
    def levels(self) -> dict:
        """Subdivision levels per displaced mesh."""
        return {k: v["levels"] for k, v in self._fine.items()}

    @property
    def patch_size(self) -> dict:
        """World length of one patch per displaced mesh."""
        return {k: v["patch_size"] for k, v in self._fine.items()}

    def scene_at(self, frame: float):
        """A static :class:`~warpshade.scene.Scene` of the displaced surface at ``frame`` (world
        space; the same mesh paths, lights and camera)."""
        from ...scene import Mesh, Scene

        sc = self.scene
        points = sc.points_at(float(frame))
        normals = sc.normals_at(float(frame))
        meshes = []
        for m in sc.meshes:
            sl = slice(m.vertex_offset, m.vertex_offset + m.vertex_count)
            p, albedo = points[sl], np.asarray(sc.albedo[sl], np.float64)
            fine = self._fine.get(m.path)
            if fine is None:
                meshes.append(Mesh(m.path, p, m.faces, albedo=albedo.astype(np.float32)))
                continue
            w = fine["weights"]
            n = w @ normals[sl]
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
            pts = w @ p + n * fine["offset"][:, None]
            meshes.append(Mesh(m.path, pts, fine["faces"], albedo=((w @ albedo) * fine["tint"]).astype(np.float32)))
        return Scene.from_meshes(meshes, frames=[float(frame)], lights=sc.lights, camera=sc.camera, up_axis=sc.up_axis)


def patch_prims(scene, prims: str) -> list:
    """The meshes that carry the patch: ``prims`` (comma-separated mesh paths), or every mesh with
    UVs when empty.

    Raises:
        ValueError: an unknown path, a named mesh without UVs, or no mesh with UVs at all.
    """
    meshes = {m.path: m for m in scene.meshes}
    names = [p.strip() for p in (prims or "").split(",") if p.strip()]
    if not names:
        names = [m.path for m in scene.meshes if m.uvs is not None]
        if not names:
            raise ValueError(f"parameter 'prims': no mesh of {scene.source or 'the scene'} has UVs (primvars:st); "
                             "a patch is mapped by UV")
        return names
    for n in names:
        if n not in meshes:
            raise ValueError(f"parameter 'prims': no mesh {n!r} in the scene (meshes: {sorted(meshes)})")
        if meshes[n].uvs is None:
            raise ValueError(f"parameter 'prims': mesh {n!r} has no UVs (primvars:st); a patch is mapped by UV")
        if not np.all(np.isfinite(meshes[n].uvs)):
            raise ValueError(f"parameter 'prims': mesh {n!r} has non-finite UVs")
    return names


def interpolate_at_hits(gbuffer, values) -> np.ndarray:
    """Per-vertex ``values`` (V, 3) interpolated with the barycentrics of a G-buffer's hits
    (Warp's ``(u, v, 1 - u - v)`` over ``faces[t, 0..2]``), (N, 3) float32, 0 for misses."""
    hit = gbuffer.hit.numpy().astype(bool)
    face = gbuffer.face.numpy()
    bary = gbuffer.bary.numpy().astype(np.float64)
    faces = gbuffer.faces.numpy()
    vals = np.asarray(values, np.float64)
    out = np.zeros((hit.size, 3), np.float32)
    tri = faces[face[hit]]
    w = np.stack([bary[hit, 0], bary[hit, 1], 1.0 - bary[hit, 0] - bary[hit, 1]], 1)
    out[hit] = np.einsum("pk,pkc->pc", w, vals[tri])
    return out
