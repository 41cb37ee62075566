"""Per-pixel images of a run: stages that shade G-buffers (:class:`._protocols.PixelStage`), their materials
from the meshes' textures at every pixel, linear EXR + PNG per frame, and the error of each image
against the per-pixel ray-traced reference (:func:`warpshade.reference._pixels.reference_image`).

* :func:`pixel_stage` -- the run's stage that shades pixels (``sg.shade``), or None;
* :func:`pixel_materials` -- albedo, specular colour and roughness at every hit: the meshes'
  UsdPreviewSurface textures sampled at the interpolated UVs (Warp), the stage's per-vertex
  materials interpolated elsewhere, the same rule the stage applies at the vertices;
* :func:`render_frame` -- one frame: step the run to it, cast the G-buffer, shade, box-filter;
  returns a :class:`PixelImage` with the time of each step;
* :func:`write_pixel_images` -- ``<graph>_px_<frame>.png`` and ``.exr`` per frame;
* :func:`measure_pixels` -- relative RMS over covered pixels against the per-pixel reference (the
  stage's own reference BRDF, eye and colour, the per-pixel roughness and colours), its noise, and
  ``<graph>_px_<frame>_vs_reference.png``.
"""

from __future__ import annotations

import time
import weakref
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._wp import wp
from ._outputs import pixel_comparison_name, pixel_image_names, preview_frames
from ._pictures import ERROR_COLORMAP, ERROR_LIMIT, luminance, run_exposure, write_panels
from ._protocols import PixelStage, ground_truth_model

#: The primary-ray BVH of each run without one of its own (built once, refit per frame).
_BVHS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()

__all__ = ["PixelImage", "exposure_for", "measure_pixels", "pixel_bvh", "pixel_materials", "pixel_stage", "pixel_stage_of",
           "render_frame", "write_pixel_images"]


def pixel_stage(runtime):
    """The stage of the run that shades pixels (a :class:`~warpshade.measure._protocols.PixelStage`):
    the output's, else the first such stage; None when there is none."""
    spec = getattr(runtime, "spec", None)
    return pixel_stage_of(runtime.stages, spec.output if spec is not None else None)


def pixel_stage_of(stages, output: str | None = None):
    """:func:`pixel_stage` among ``stages`` (built, not necessarily set up: e.g. those of
    :meth:`warpshade.graph.GraphSpec.build`, to plan a run's files before any work), whose output
    port is ``output`` ("stage.port")."""
    out_name = output.split(".")[0] if output else None
    stages = list(stages)
    for st in ([s for s in stages if s.name == out_name] + stages):
        if isinstance(st, PixelStage):
            return st
    return None


@dataclass
class PixelImage:
    """A per-pixel rendering of one frame.

    Attributes:
        linear: radiance (H, W, 3) float32, linear RGB (0 where no geometry).
        coverage: fraction of each pixel's rays that hit geometry (H, W) float32.
        frame: the time code; camera: the camera used.
        seconds: time of each step of the frame: ``gbuffer``, ``materials``, ``shade``, ``total``.
        materials: the per-ray material arrays used (albedo, specular, roughness) or None.
    """

    linear: np.ndarray
    coverage: np.ndarray
    frame: float
    camera: object
    seconds: dict = field(default_factory=dict)
    materials: dict | None = None


def _mesh_of_triangle(scene) -> np.ndarray:
    starts = []
    for k, m in enumerate(scene.meshes):
        starts.append(np.full(m.triangle_count, k, np.int32))
    return np.concatenate(starts) if starts else np.zeros(0, np.int32)


def pixel_materials(stage, scene, gbuffer, textures: bool = True) -> dict:
    """Materials at every ray of a G-buffer: ``albedo`` (N, 3), ``specular`` (N, 3) (the stage's
    specular colour times the texture's), ``roughness`` (N,), float32 host arrays. Meshes without
    textures (or ``textures`` false) take the stage's per-vertex materials interpolated."""
    from ..scene._textures import sample_surface_warp

    dev = gbuffer.device
    out = stage.pixel_materials(gbuffer)
    if not textures:
        return out
    textured = [(k, m) for k, m in enumerate(scene.meshes) if getattr(m, "surface", None) is not None and m.uvs is not None]
    if not textured:
        return out
    hit = gbuffer.hit.numpy().astype(bool)
    face = gbuffer.face.numpy()
    bary = gbuffer.bary.numpy().astype(np.float64)
    faces = scene.faces
    mesh_of = _mesh_of_triangle(scene)
    specular_rgb = np.asarray(stage.params["specular"], np.float64).reshape(3)
    for k, m in textured:
        rows = np.nonzero(hit & (mesh_of[np.maximum(face, 0)] == k))[0]
        if rows.size == 0:
            continue
        tri = faces[face[rows]] - m.vertex_offset
        w = np.stack([bary[rows, 0], bary[rows, 1], 1.0 - bary[rows, 0] - bary[rows, 1]], -1)
        uv = np.einsum("pk,pkc->pc", w, m.uvs[tri])
        vals = sample_surface_warp(m.surface, uv, dev)
        out["albedo"][rows] = vals["diffuse"]
        out["roughness"][rows] = vals["roughness"]
        out["specular"][rows] = vals["specular"] * specular_rgb[None]
    return out


def pixel_bvh(runtime):
    """The BVH the run's primary rays are cast against: the frame state's when the run keeps one,
    else one built once per run (refit to the frame by :func:`render_frame`)."""
    from ..geometry._bvh import Visibility

    if runtime.state.bvh is not None:
        return runtime.state.bvh
    bvh = _BVHS.get(runtime)
    if bvh is None:
        bvh = _BVHS[runtime] = Visibility.from_scene(runtime.scene, device=runtime.device)
    return bvh


def render_frame(runtime, frame, width: int = 640, height: int = 480, supersample: int = 1, textures: bool | None = None,
                 stage=None, camera=None) -> PixelImage:
    """Step the run to ``frame`` and shade every pixel with its pixel stage (module docstring);
    ``textures`` (default: the stage's ``textures`` parameter) samples the meshes' textures per pixel."""
    from ..render import camera_for, render_gbuffer

    st = stage if stage is not None else pixel_stage(runtime)
    if st is None:
        raise ValueError(f"graph {runtime.spec.name!r}: no stage of this run shades pixels")
    if width < 1 or height < 1 or supersample < 1:
        raise ValueError(f"pixels: image size and supersample must be positive, got {width}x{height} x{supersample}")
    if textures is None:
        textures = bool(st.params.get("textures", False))
    t0 = time.perf_counter()
    runtime.step(float(frame))
    state = runtime.state
    cam = camera if camera is not None else camera_for(runtime.scene, float(frame), aspect=width / height)
    bvh = pixel_bvh(runtime)
    bvh.update(state.points)
    ss = int(supersample)
    t1 = time.perf_counter()
    gb = render_gbuffer(bvh, state.normals, cam, width * ss, height * ss)
    wp.synchronize_device(runtime.device)
    t2 = time.perf_counter()
    mats = pixel_materials(st, runtime.scene, gb, textures) if textures else None
    t3 = time.perf_counter()
    colour = st.render_pixels(gb, **(mats or {}))
    if mats is None:  # what was shaded: the per-vertex materials interpolated
        mats = st.pixel_materials(gb)
    wp.synchronize_device(runtime.device)
    t4 = time.perf_counter()
    rgb = colour.numpy().reshape(height * ss, width * ss, 3)
    hit = gb.hit.numpy().reshape(height * ss, width * ss).astype(np.float32)
    linear = rgb.reshape(height, ss, width, ss, 3).mean(axis=(1, 3)).astype(np.float32)
    coverage = hit.reshape(height, ss, width, ss).mean(axis=(1, 3)).astype(np.float32)
    seconds = {"step": t1 - t0, "gbuffer": t2 - t1, "materials": t3 - t2, "shade": t4 - t3, "total": t4 - t1}
    return PixelImage(linear, coverage, float(frame), cam, seconds, mats)


def exposure_for(linear: np.ndarray) -> float:
    """Exposure in stops mapping the 99th percentile of the luminance of (N, 3) radiance to 0.9."""
    lum = linear @ np.array([0.2126, 0.7152, 0.0722])
    lum = lum[lum > 0]
    p99 = float(np.percentile(lum, 99)) if lum.size else 1.0
    return float(np.log2(0.9 / p99)) if p99 > 0 else 0.0


def write_pixel_images(runtime, out_dir, frames=None, width: int = 640, height: int = 480, supersample: int = 1,
                       textures: bool | None = None, exposure: float | None = None) -> list:
    """``<graph>_px_<frame>.png`` (tone-mapped at the run's one exposure,
    :func:`~warpshade.measure._pictures.run_exposure`, or one for these images when the run
    recorded no frame) and ``.exr`` (linear) for the pixel stage of the run; returns the paths
    (empty without such a stage)."""
    from ..io._images import write_exr
    from ..render import write_png
    from ..render._image import tonemap_f64

    if pixel_stage(runtime) is None:
        return []
    rec = sorted(runtime.results)
    if frames is None:
        frames = preview_frames(rec) if rec else [float(runtime.scene.frames[0])]
    images = [render_frame(runtime, f, width, height, supersample, textures) for f in frames]
    if exposure is None:
        exposure = (run_exposure(runtime) if runtime.results
                    else exposure_for(np.concatenate([im.linear.reshape(-1, 3) for im in images])))
    paths = []
    for im in images:
        png, exr = (Path(out_dir) / name for name in pixel_image_names(runtime.spec.name, im.frame))
        write_png(png, tonemap_f64(im.linear, exposure=exposure))
        write_exr(exr, im.linear)
        paths += [png, exr]
    return paths


def _error_image(linear, reference, mask):
    """The error panel of a per-pixel strip: ``(Y_method - Y_ref) / mean Y_ref`` over the covered
    pixels ``mask`` on :data:`~warpshade.measure._pictures.ERROR_COLORMAP` (``+-ERROR_LIMIT`` at its
    ends), the neutral grey elsewhere. Returns (uint8 sRGB image (H, W, 3), the errors of the
    covered pixels)."""
    import matplotlib

    from ..render._image import GREY_BACKGROUND

    y_est, y_ref = luminance(linear), luminance(reference)
    scale = float(np.mean(y_ref[mask])) if mask.any() else 0.0
    err = (y_est - y_ref) / scale if scale > 0 else np.zeros_like(y_ref)
    t = np.clip(0.5 + 0.5 * np.nan_to_num(err, nan=0.0) / ERROR_LIMIT, 0.0, 1.0)
    rgb = np.where(mask[..., None], matplotlib.colormaps[ERROR_COLORMAP](t)[..., :3], GREY_BACKGROUND)
    return np.clip(np.floor(rgb * 255.0 + 0.5), 0, 255).astype(np.uint8), err[mask]


def measure_pixels(runtime, out_dir, frames, width: int = 160, height: int = 120, samples: int = 256, supersample: int = 1,
                   textures: bool | None = None, seed: int = 0, exposure: float | None = None) -> dict:
    """Per-pixel error of the pixel stage against the per-pixel glossy reference, per frame.

    Each frame's ``<graph>_px_<frame>_vs_reference.png`` shows method | reference | error with
    titles and the error's colour bar (:func:`~warpshade.measure._pictures.write_panels`), at one
    ``exposure`` (stops; default the run's, :func:`~warpshade.measure._pictures.run_exposure`).

    The reference has the stage's per-pixel reference BRDF, eye and colour
    (:func:`~warpshade.measure._protocols.ground_truth_model` with ``per_pixel``), the frame's
    lights, and the per-pixel roughness and specular colour the method shaded with; the error is the relative RMS over fully covered pixels (``sqrt(mean |d|^2) / sqrt(mean |ref|^2)``
    over RGB), with the part explained by the reference's own noise.

    Returns:
        ``{"frames": {frame: {"rel_rms", "noise", "pixels", "image"}}, "width", "height", "samples"}``.
    """
    from ..reference._pixels import reference_image
    from ..render._image import tonemap_f64

    st = pixel_stage(runtime)
    if st is None:
        raise ValueError(f"graph {runtime.spec.name!r}: no stage of this run shades pixels")
    report = {"width": width, "height": height, "samples": samples, "supersample": supersample, "frames": {}}
    for f in frames:
        im = render_frame(runtime, f, width, height, supersample, textures)
        model = ground_truth_model(st, runtime.state.materials, runtime.state.eye.numpy()[0], per_pixel=True)
        if model is not None and "geometry" in model:
            ref, mask = _geometry_reference(runtime, model, im, float(f), width, height, samples, supersample, seed)
        else:
            brdf = model["brdf"]
            mats = im.materials
            uses_roughness = hasattr(brdf, "roughness")
            ref = reference_image(runtime.scene, float(f), brdf, camera=im.camera, width=width, height=height,
                                  samples=samples, supersample=supersample, eye=model["eye"],
                                  lighting=runtime.lighting.lights_at(float(f)),
                                  roughness=mats["roughness"] if uses_roughness else None, specular=mats["specular"],
                                  include=("specular",), seed=seed, device=runtime.device, tangents=model.get("tangents"))
            mask = ref.mask & (im.coverage >= 1.0)
        d = (im.linear - ref.radiance)[mask]
        r = ref.radiance[mask]
        denom = float(np.sqrt(np.mean(r * r))) if r.size else 0.0
        rel = float(np.sqrt(np.mean(d * d)) / denom) if denom > 0 else float("nan")
        noise = float(np.sqrt(np.mean(ref.stderr[mask] ** 2)) / denom) if denom > 0 else float("nan")
        path = Path(out_dir) / pixel_comparison_name(runtime.spec.name, f)
        if exposure is None:
            exposure = run_exposure(runtime) if runtime.results else exposure_for(ref.radiance.reshape(-1, 3))
        error_image, err = _error_image(im.linear, ref.radiance, mask)
        titles = [f"method: {runtime.spec.name}, per pixel\nrel RMS {rel:.3f} (reference noise {noise:.3f})",
                  f"reference: ray traced, {samples} spp",
                  f"error\nmin {np.min(err, initial=0.0):+.2f}, max {np.max(err, initial=0.0):+.2f}"]
        write_panels(path, [tonemap_f64(im.linear, exposure=exposure), tonemap_f64(ref.radiance, exposure=exposure),
                            error_image], titles, ERROR_LIMIT, f"frame {float(f):g}, {width}x{height} pixels")
        report["frames"][float(f)] = {"rel_rms": rel, "noise": noise, "pixels": int(mask.sum()), "image": str(path)}
    return report


def _geometry_reference(runtime, model, im, frame, width, height, samples, supersample, seed):
    """The diffuse ground truth of a pixel stage whose surface detail is geometry the run does not
    have (an LDPRT patch: ``model["geometry"](frame)`` is the displaced fine mesh's scene), traced
    through the method's camera; the mask keeps fully covered pixels of both images whose reference
    hit lies on one of ``model["prims"]`` (all meshes when absent). Returns (reference, mask)."""
    from ..reference._pixels import reference_image
    from ..scene._materials import Lambert

    scene = model["geometry"](frame)
    ref = reference_image(scene, frame, Lambert(), camera=im.camera, width=width, height=height, samples=samples,
                          supersample=supersample, lighting=runtime.lighting.lights_at(frame),
                          include=tuple(model.get("include", ("diffuse",))), seed=seed, device=runtime.device)
    mask = ref.mask & (im.coverage >= 1.0)
    prims = model.get("prims")
    if prims:
        owner = _mesh_of_triangle(scene)
        keep = np.array([m.path in prims for m in scene.meshes])
        tri = ref.hits.triangles
        on = ref.hits.hit & (tri >= 0) & keep[owner[np.maximum(tri, 0)]]
        ss = int(supersample)
        mask &= on.reshape(height, ss, width, ss).all(axis=(1, 3))
    return ref, mask
