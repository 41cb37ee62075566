"""Per-pixel ground truth: glossy (and diffuse) reference radiance at a camera's primary hits.

:func:`reference_image` shades the surface seen through every pixel of a pinhole camera with the
Monte Carlo estimator of :mod:`._estimator`, so that a method's image can be measured against
ground truth pixel by pixel, including materials whose parameters vary across a surface
(textures). For the hit ``p`` of a pixel's ray, with shading normal ``n`` and the view
``v = normalize(eye - p)``::

    L(p) = c(p) * integral b_alpha(p)(v, s) L_i(s) V(s) max(0, n.s) ds        ("specular")
         + rho(p) / pi * integral L_i(s) V(s) max(0, n.s) ds                   ("diffuse")

with ``b`` a BRDF of :mod:`warpshade.scene._materials` whose microfacet roughness ``alpha(p)``
may be given per pixel, ``c(p)`` the RGB specular colour per pixel (default 1: the BRDF's own
``specular`` scale is inside ``b``), ``rho(p)`` the diffuse albedo per pixel (default: the mesh
albedo interpolated at the hit), ``L_i`` the environment plus analytic lights and ``V``
ray-traced visibility. The specular part is :class:`~._glossy.GlossyReferenceShader`'s estimator
and the diffuse part :class:`~._shading.ReferenceShader`'s, both evaluated by
:meth:`~._estimator.MonteCarloShader.shade_points` at the hit points.

Primary hits come from :func:`warpshade.render.render_gbuffer` (the renderer's own ray cast:
shading normals interpolated from the frame's vertex normals with the hit's barycentrics,
normalised and flipped toward the camera), at ``supersample`` x ``supersample`` rays per pixel
(pixel ``(row, col)`` of the ray grid looks through ``(col + 0.5, row + 0.5)`` of that finer
image plane). Per-pixel parameters are given at that ray resolution: flat arrays of
``ray_count = (height * supersample) * (width * supersample)`` rows in row-major order (row 0 at
the top), or image-shaped ``(height * supersample, width * supersample[, 3])``;
:func:`pixel_hits` returns the hits (points, normals, UVs, triangles, barycentrics) a caller
evaluates its textures at. Values at rays that miss are ignored.

Sub-pixel results are box-filtered (a Warp kernel, :func:`box_filter_f64` is its float64
reference): the pixel's radiance is the mean over its rays (a miss contributes 0, so a partly
covered pixel is darkened by its coverage, as :func:`warpshade.render.render` does without an
environment) and its standard error ``sqrt(sum se_k^2) / supersample^2`` (independent rays).
The two parts use independent random streams (seed ``seed`` for the specular part,
``seed + 1`` for the diffuse one), so the total's standard error is the root sum of squares.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .._wp import resolve_device, wp
from ..io._images import write_exr
from ..render import camera_for, interpolate_vertex_values, render_gbuffer, tonemap, write_png
from ._glossy import GLOSSY_METHODS, GlossyReferenceShader
from ._shading import METHODS, ReferenceShader
from ._svbrdf_warp import surface_texels

__all__ = [
    "PARTS",
    "box_filter_f64",
]

wp.set_module_options({"enable_backward": False})

#: The terms :func:`reference_image` can include, in the order they are summed.
PARTS = ("specular", "diffuse")
#: Offset of the diffuse part's seed from the specular part's (independent random streams).
DIFFUSE_SEED_OFFSET = 1

_CALLER = "reference.reference_image"


@wp.kernel
def _scatter_kernel(receivers: wp.array(dtype=wp.int32), values: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec3)):
    """``out[receivers[i]] = values[i]`` (shaded hits back into the full ray grid)."""
    i = wp.tid()
    out[receivers[i]] = values[i]


@wp.kernel
def _box_filter_kernel(
    src: wp.array(dtype=wp.vec3),
    factor: int,
    width: int,
    root_sum_square: int,
    dst: wp.array(dtype=wp.vec3),
):
    """One output pixel from its ``factor`` x ``factor`` rays (row-major grids of ``width`` and
    ``width * factor`` columns): the mean, or with ``root_sum_square`` the standard error of the
    mean of independent estimates with standard errors ``src`` (``sqrt(sum src^2) / factor^2``)."""
    row, col = wp.tid()
    acc = wp.vec3(0.0)
    src_width = width * factor
    for a in range(factor):
        for b in range(factor):
            x = src[(row * factor + a) * src_width + col * factor + b]
            if root_sum_square != 0:
                acc += wp.cw_mul(x, x)
            else:
                acc += x
    scale = 1.0 / float(factor * factor)
    if root_sum_square != 0:
        acc = wp.vec3(wp.sqrt(acc[0]), wp.sqrt(acc[1]), wp.sqrt(acc[2]))
    dst[row * width + col] = acc * scale


@wp.kernel
def _coverage_kernel(hit: wp.array(dtype=wp.int32), factor: int, width: int, dst: wp.array(dtype=wp.float32)):
    """Fraction of the pixel's ``factor`` x ``factor`` rays that hit geometry."""
    row, col = wp.tid()
    count = int(0)
    src_width = width * factor
    for a in range(factor):
        for b in range(factor):
            count += hit[(row * factor + a) * src_width + col * factor + b]
    dst[row * width + col] = float(count) / float(factor * factor)


def box_filter_f64(values, width: int, height: int, factor: int, root_sum_square: bool = False) -> np.ndarray:
    """Float64 mirror of the box filter: (ray_count, 3) at ``factor`` times the resolution ->
    (height, width, 3): the mean over each pixel's rays, or ``sqrt(sum x^2) / factor^2``."""
    x = np.asarray(values, np.float64).reshape(height, factor, width, factor, 3)
    if root_sum_square:
        return np.sqrt((x * x).sum(axis=(1, 3))) / factor**2
    return x.mean(axis=(1, 3))


@dataclass
class PixelHits:
    """The primary hits of a camera's rays (host copies), at the ray resolution.

    Every array has one row per ray, ``ray_count = ray_height * ray_width`` rows, row-major
    (row 0 at the top); ``ray_width = width * supersample``, ``ray_height = height * supersample``.

    Attributes:
        width, height: output image size in pixels; supersample: rays per pixel along each axis.
        hit: whether the ray hit a triangle, (ray_count,) bool.
        points: world hit positions, (ray_count, 3) float32 (0 for misses).
        normals: unit shading normals facing the camera (vertex normals interpolated with the
            barycentrics, two-sided), (ray_count, 3) float32, world (0 for misses).
        directions: unit ray directions, (ray_count, 3) float32, world.
        triangles: hit triangle (row of ``scene.faces``), (ray_count,) int32, -1 for misses.
        barycentrics: weights of the triangle's corners ``scene.faces[t, 0..2]``, (ray_count, 3)
            float32 (Warp's ``(u, v, 1 - u - v)``; 0 for misses).
        uvs: texture coordinates interpolated from the meshes' per-vertex UVs, (ray_count, 2)
            float32, or None when no mesh has UVs; uv_valid: (ray_count,) bool, hits on a mesh
            with UVs (the UVs of other hits are 0).
        camera: the :class:`~warpshade.scene.Camera` the rays left; gbuffer: the device
            :class:`~warpshade.render.GBuffer` (its ``hit``, ``position``, ``normal``, ``face``,
            ``bary``, ``direction`` arrays).
    """

    width: int
    height: int
    supersample: int
    hit: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    directions: np.ndarray
    triangles: np.ndarray
    barycentrics: np.ndarray
    uvs: np.ndarray | None
    uv_valid: np.ndarray
    camera: object
    gbuffer: object

    @property
    def ray_width(self) -> int:
        return self.width * self.supersample

    @property
    def ray_height(self) -> int:
        return self.height * self.supersample

    @property
    def ray_count(self) -> int:
        return self.ray_width * self.ray_height


@dataclass
class PixelReference:
    """A per-pixel reference image (NumPy, host memory).

    Attributes:
        radiance: outgoing radiance toward the eye, (height, width, 3) float32, linear RGB (the
            sum of the included parts; 0 where no ray hit).
        stderr: its Monte Carlo standard error, (height, width, 3) float32.
        mask: pixels whose every ray hit geometry, (height, width) bool.
        coverage: fraction of each pixel's rays that hit, (height, width) float32.
        specular, specular_stderr: the glossy part and its standard error, (height, width, 3)
            float32, or None when not included; diffuse, diffuse_stderr: the same for the diffuse part.
        hits: the :class:`PixelHits` that were shaded.
        eye: the viewer, (3,) float64, world; frame: the time code; samples, method, seed: how
            it was computed; include: the parts summed; brdf: the BRDF's description.
    """

    radiance: np.ndarray
    stderr: np.ndarray
    mask: np.ndarray
    coverage: np.ndarray
    specular: np.ndarray | None
    specular_stderr: np.ndarray | None
    diffuse: np.ndarray | None
    diffuse_stderr: np.ndarray | None
    hits: PixelHits
    eye: np.ndarray
    frame: float
    samples: int
    method: str
    seed: int
    include: tuple
    brdf: dict

    def save(self, path_stem, exposure: float = 0.0, mode: str = "srgb") -> dict:
        """Write ``<stem>.png`` (tone-mapped, uncovered parts of pixels in the neutral grey) and
        ``<stem>.exr`` (linear radiance, float32), plus ``<stem>-specular.exr`` and
        ``<stem>-diffuse.exr`` when both parts are included; every file atomically.

        Args:
            path_stem: path without extension; its directory must exist.
            exposure: stops for the PNG; mode: "srgb" or "reinhard" (:func:`warpshade.render.tonemap`).

        Returns:
            ``{"png": Path, "exr": Path, ...}`` of the files written.
        """
        stem = Path(path_stem)
        if not stem.parent.is_dir():
            raise ValueError(f"PixelReference.save: directory {stem.parent} does not exist")
        height, width = self.coverage.shape
        dev = wp.get_device("cpu")
        linear = wp.array(self.radiance.reshape(-1, 3), dtype=wp.vec3, device=dev)
        grey = wp.array((1.0 - self.coverage).reshape(-1).astype(np.float32), dtype=wp.float32, device=dev)
        paths = {"png": write_png(stem.with_name(stem.name + ".png"), tonemap(linear, grey, width, height, exposure, mode))}
        paths["exr"] = stem.with_name(stem.name + ".exr")
        write_exr(paths["exr"], self.radiance)
        if self.specular is not None and self.diffuse is not None:
            for part in PARTS:
                paths[part] = stem.with_name(f"{stem.name}-{part}.exr")
                write_exr(paths[part], getattr(self, part))
        return paths


def _frame_camera(scene, frame, camera, width, height):
    if camera is not None:
        return camera
    cam = camera_for(scene, frame, aspect=width / height)
    if getattr(cam, "moving", False):
        cam = replace(cam, position=cam.position_at(scene.frame_index(frame)), positions=None)
    return cam


def _scene_uvs(scene):
    """Per-vertex UVs of every mesh padded to vec3 rows (V, 3) and a per-vertex validity flag,
    or (None, None) when no mesh has UVs."""
    if all(m.uvs is None for m in scene.meshes):
        return None, None
    rows = np.zeros((scene.vertex_count, 3), np.float32)
    valid = np.zeros((scene.vertex_count, 3), np.float32)
    for m in scene.meshes:
        if m.uvs is not None:
            uv = np.asarray(m.uvs, np.float32).reshape(m.vertex_count, 2)
            rows[m.vertex_offset:m.vertex_offset + m.vertex_count, :2] = uv
            valid[m.vertex_offset:m.vertex_offset + m.vertex_count] = 1.0
    return rows, valid


def _check_size(width, height, supersample, caller):
    for name, value in (("width", width), ("height", height), ("supersample", supersample)):
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < 1:
            raise ValueError(f"{caller}: {name} must be a positive integer, got {value!r}")


def _hits_from_gbuffer(scene, gb, camera, width, height, supersample) -> PixelHits:
    hit = gb.hit.numpy().astype(bool)
    bary_uv = gb.bary.numpy().astype(np.float32)
    bary = np.zeros((gb.pixel_count, 3), np.float32)
    bary[hit, 0], bary[hit, 1] = bary_uv[hit, 0], bary_uv[hit, 1]
    bary[hit, 2] = 1.0 - bary_uv[hit, 0] - bary_uv[hit, 1]
    uv_rows, uv_flags = _scene_uvs(scene)
    uvs, uv_valid = None, np.zeros(gb.pixel_count, bool)
    if uv_rows is not None:
        uvs = interpolate_vertex_values(gb, uv_rows).numpy()[:, :2].copy()
        # a flag interpolated over a triangle is exactly 1 inside a mesh with UVs, 0 elsewhere
        uv_valid = hit & (interpolate_vertex_values(gb, uv_flags).numpy()[:, 0] > 0.5)
        uvs[~uv_valid] = 0.0
    return PixelHits(
        width=width, height=height, supersample=supersample, hit=hit, points=gb.position.numpy().copy(),
        normals=gb.normal.numpy().copy(), directions=gb.direction.numpy().copy(), triangles=gb.face.numpy().copy(),
        barycentrics=bary, uvs=uvs, uv_valid=uv_valid, camera=camera, gbuffer=gb,
    )


def pixel_hits(scene, frame, camera=None, width: int = 160, height: int = 120, supersample: int = 1, device=None) -> PixelHits:
    """The primary hits of a camera at one frame: what per-pixel textures are evaluated at.

    Args:
        scene: the :class:`~warpshade.scene.Scene`; frame: a time code of ``scene.frames``.
        camera: a :class:`~warpshade.scene.Camera` (default: the scene's, at this frame when it
            moves, else a 3/4 framing of the bounds).
        width, height: image size in pixels; supersample: rays per pixel along each axis.
        device: Warp device (None = Warp's default).

    Returns:
        :class:`PixelHits` at the ray resolution (``height * supersample`` x ``width * supersample``).
    """
    from ..geometry._bvh import Visibility

    _check_size(width, height, supersample, "reference.pixel_hits")
    dev = resolve_device(device)
    camera = _frame_camera(scene, frame, camera, width, height)
    state = scene.evaluate(frame, device=dev)
    bvh = Visibility.from_scene(scene, device=dev)
    bvh.update(state.points)
    gb = render_gbuffer(bvh, state.normals, camera, width * supersample, height * supersample)
    return _hits_from_gbuffer(scene, gb, camera, width, height, supersample)


def _per_ray(values, ray_height, ray_width, channels, name, hit):
    """Validate a per-ray parameter: (ray_count[, 3]) or (ray_height, ray_width[, 3]); finite and
    >= 0 at the hits (misses are ignored and set to 0). Returns float32 (ray_count[, channels])."""
    count = ray_height * ray_width
    arr = values.numpy() if isinstance(values, wp.array) else np.asarray(values)
    tail = () if channels == 1 else (channels,)
    if arr.shape not in ((count, *tail), (ray_height, ray_width, *tail)):
        allowed = f"({count}, 3) or ({ray_height}, {ray_width}, 3)" if tail else f"({count},) or ({ray_height}, {ray_width})"
        raise ValueError(f"{_CALLER}: {name} must have shape {allowed} (one row per ray: height * supersample by "
                         f"width * supersample), got {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{_CALLER}: {name} must be numeric, got dtype {arr.dtype}")
    arr = np.array(arr, dtype=np.float32).reshape(count, *tail)
    seen = arr[hit]
    bad = ~(np.isfinite(seen) & (seen >= 0.0))
    if np.any(bad):
        raise ValueError(f"{_CALLER}: {name} must be finite and >= 0 at every ray that hits; {int(bad.sum())} values are not")
    arr[~hit] = 0.0
    return arr


def _check_include(include):
    parts = (include,) if isinstance(include, str) else tuple(include)
    if not parts or any(p not in PARTS for p in parts) or len(set(parts)) != len(parts):
        raise ValueError(f"{_CALLER}: include must be a non-empty selection of {PARTS} without repeats, got {include!r}")
    return tuple(p for p in PARTS if p in parts)


def _tangent_rays(scene, state, gb, tangents, count):
    """Per-ray tangent directions (wp.array(vec3), (count,)) of ``reference_image``'s ``tangents``."""
    dev = gb.hit.device
    if isinstance(tangents, str):
        if tangents != "uv":
            raise ValueError(f"{_CALLER}: tangents must be 'uv', 3 floats or one row per ray, got {tangents!r}")
        from ..geometry._uv_tangents import UVTangents

        if all(m.uvs is None for m in scene.meshes):
            raise ValueError(f"{_CALLER}: tangents = 'uv' needs UVs, and no mesh of {scene.source or '<arrays>'} has them")
        per_vertex = wp.zeros(scene.vertex_count, dtype=wp.vec3, device=dev)
        UVTangents.from_scene(scene, dev).compute(state.points, state.normals, per_vertex)
        rays = interpolate_vertex_values(gb, per_vertex).numpy()
        # misses (and tangents that cancel over a triangle) take +x: projected, or the normal's basis, in the kernel
        rays[~(np.linalg.norm(rays, axis=1) > 0.0)] = (1.0, 0.0, 0.0)
        return wp.array(rays, dtype=wp.vec3, device=dev)
    arr = np.asarray(tangents, np.float64)
    if arr.shape == (3,):
        arr = np.broadcast_to(arr, (count, 3))
    if arr.shape != (count, 3) or not np.all(np.isfinite(arr)) or np.any(np.linalg.norm(arr, axis=-1) == 0.0):
        raise ValueError(f"{_CALLER}: tangents must be 'uv', 3 finite floats or ({count}, 3) finite nonzero rows, "
                         f"got shape {arr.shape}")
    return wp.array(np.ascontiguousarray(arr, np.float32), dtype=wp.vec3, device=dev)


def reference_image(scene, frame, brdf, camera=None, width: int = 160, height: int = 120, samples: int = 256,
                    supersample: int = 1, eye=None, lighting=None, roughness=None, specular=None, albedo=None,
                    include=PARTS, seed: int = 0, device=None, workers=None, method: str = "mis",
                    tangents=None) -> PixelReference:
    """Per-pixel ray-traced reference of the surface a camera sees (module docstring).

    Args:
        scene: the :class:`~warpshade.scene.Scene`; frame: a time code of ``scene.frames``.
        brdf: the :class:`~warpshade.scene._materials.BRDF` of the specular part (every surface; a
            texture of eq.-13 materials, ``SVBRDFMaterial``, is looked up at each hit's UV).
        camera: a :class:`~warpshade.scene.Camera` (default: the scene's, at this frame when it
            moves, else a 3/4 framing of the bounds).
        width, height: image size in pixels; supersample: rays per pixel along each axis.
        samples: environment rays per receiver and part (>= 2; >= 4 for "mis").
        eye: the viewer of the glossy term, 3 floats, world (default: the camera position).
        lighting: lights (default ``scene.lights``): at most one Environment, any number of
            DistantLight / SphereLight.
        roughness: microfacet alpha per ray, (ray_count,) or (ray_height, ray_width) float, in
            (0, 2] (GGX / Beckmann only); None: ``brdf.roughness``.
        specular: RGB specular colour per ray, (ray_count, 3) or (ray_height, ray_width, 3),
            >= 0; None: 1 (the BRDF's ``specular`` scale alone).
        albedo: RGB diffuse albedo per ray, same shapes, >= 0; None: the mesh albedo interpolated
            at the hit.
        include: the parts to sum, a selection of :data:`PARTS` ("specular", "diffuse").
        seed: random seed (the diffuse part uses ``seed + 1``).
        device: Warp device (None = Warp's default); workers: CPU launch threads.
        method: environment estimator, "brdf", "light" or "mis" (for the diffuse part the
            same strategy: "cosine", "light" or "mis").
        tangents: the tangent direction of an anisotropic BRDF (``ward``, ``ashikhmin-shirley``,
            ``beckmann-anisotropic``) at every hit: ``"uv"`` (the direction of increasing u of the
            meshes' UVs, :mod:`warpshade.geometry._uv_tangents`, interpolated at the hit), one
            world direction (3 floats), or one per ray (ray_count, 3); projected on each hit's
            tangent plane. None: the BRDF's own frame about each normal (isotropic BRDFs).

    Returns:
        :class:`PixelReference` with (height, width) images.

    Raises:
        ValueError: naming the parameter: a bad size, per-ray array shape or value, ``include``,
            ``method`` or ``samples``; a ``roughness`` for a BRDF without one.
    """
    _check_size(width, height, supersample, _CALLER)
    parts = _check_include(include)
    if method not in GLOSSY_METHODS:
        raise ValueError(f"{_CALLER}: method must be one of {GLOSSY_METHODS}, got {method!r}")
    dev = resolve_device(device)
    camera = _frame_camera(scene, frame, camera, width, height)
    eye = np.asarray(camera.position if eye is None else eye, np.float64).reshape(-1)
    glossy = GlossyReferenceShader(scene, brdf, eye, lighting, samples, method, device=dev, seed=seed, vertices=[0],
                                   workers=workers)
    state = scene.evaluate(frame, device=dev)
    glossy.update(state.points, state.normals)
    ray_width, ray_height = width * supersample, height * supersample
    gb = render_gbuffer(glossy.bvh, state.normals, camera, ray_width, ray_height)
    hits = _hits_from_gbuffer(scene, gb, camera, width, height, supersample)
    count = gb.pixel_count

    tint = None if specular is None else _per_ray(specular, ray_height, ray_width, 3, "specular", hits.hit)
    rough = None
    if roughness is not None:
        rough = _per_ray(roughness, ray_height, ray_width, 1, "roughness", hits.hit)
        rough[~hits.hit] = glossy.brdf.roughness  # never read (misses are not shaded), but valid
        rough = glossy.upload_roughness(rough, count, "roughness")
    diffuse_albedo = None if albedo is None else _per_ray(albedo, ray_height, ray_width, 3, "albedo", hits.hit)

    tangent_rays = None if tangents is None else _tangent_rays(scene, state, gb, tangents, count)

    receivers_np = np.nonzero(hits.hit)[0].astype(np.int32)
    receivers = wp.array(receivers_np, dtype=wp.int32, device=dev)

    def shade(shader, tint_rays, part_seed, roughness_rays=None, tangent_rays=None, texel_rays=None):
        out_r = wp.zeros(receivers.shape[0], dtype=wp.vec3, device=dev)
        out_s = wp.zeros(receivers.shape[0], dtype=wp.vec3, device=dev)
        if receivers.shape[0] > 0:
            shader.shade_points(gb.position, gb.normal, tint_rays, receivers, out_r, out_s, seed=part_seed,
                                roughness=roughness_rays, tangents=tangent_rays, texels=texel_rays)
        images = []
        for values, rss in ((out_r, 0), (out_s, 1)):
            full = wp.zeros(count, dtype=wp.vec3, device=dev)
            if receivers.shape[0] > 0:
                wp.launch(_scatter_kernel, dim=receivers.shape[0], inputs=[receivers, values, full], device=dev)
            pixel = wp.empty(width * height, dtype=wp.vec3, device=dev)
            wp.launch(_box_filter_kernel, dim=(height, width), inputs=[full, supersample, width, rss, pixel], device=dev)
            images.append(pixel.numpy().reshape(height, width, 3))
        return images

    results = {}
    if "specular" in parts:
        tint_rays = wp.array(np.ones((count, 3), np.float32) if tint is None else tint, dtype=wp.vec3, device=dev)
        results["specular"] = shade(glossy, tint_rays, int(seed), rough, tangent_rays, surface_texels(brdf, scene, dev, gb))
    if "diffuse" in parts:
        diffuse = ReferenceShader(scene, lighting, samples, METHODS[GLOSSY_METHODS.index(method)], dev, int(seed) + DIFFUSE_SEED_OFFSET,
                                  vertices=[0], workers=workers)
        diffuse.update(state.points, state.normals)
        if diffuse_albedo is None:
            tint_rays = interpolate_vertex_values(gb, scene.albedo)
        else:
            tint_rays = wp.array(diffuse_albedo, dtype=wp.vec3, device=dev)
        results["diffuse"] = shade(diffuse, tint_rays, int(seed) + DIFFUSE_SEED_OFFSET)

    radiance = sum(results[p][0].astype(np.float64) for p in parts)
    stderr = np.sqrt(sum(results[p][1].astype(np.float64) ** 2 for p in parts))
    coverage = wp.empty(width * height, dtype=wp.float32, device=dev)
    wp.launch(_coverage_kernel, dim=(height, width), inputs=[gb.hit, supersample, width, coverage], device=dev)
    coverage = coverage.numpy().reshape(height, width)
    spec = results.get("specular", (None, None))
    diff = results.get("diffuse", (None, None))
    return PixelReference(
        radiance=radiance.astype(np.float32), stderr=stderr.astype(np.float32), mask=coverage >= 1.0, coverage=coverage,
        specular=spec[0], specular_stderr=spec[1], diffuse=diff[0], diffuse_stderr=diff[1], hits=hits, eye=eye,
        frame=float(frame), samples=int(samples), method=method, seed=int(seed), include=parts, brdf=brdf.describe(),
    )
