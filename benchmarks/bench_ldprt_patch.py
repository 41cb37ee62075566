"""LDPRT texture patches per pixel (Sloan, Luna, Snyder 2005, Sec. 5): error against the displaced geometry.

On the bundled deforming cloth (``stages/cloth_ldprt_patch.toml``: a tileable 32^2 weave patch,
ZH lobes per texel from a 5% budget, tiled 4x over the UVs), through the stage-graph runtime on
the CPU, per pixel from a camera framing the cloth, at frames 0 and 30 (the cloth moves between):

* ``patch``: ``ldprt.patch_shade`` (lobes rotated into the deformed UV tangent frame per pixel,
  the texel found by marching the view ray through the heights: ``parallax = true``);
* ``patch without parallax``: the same with ``parallax = false`` (the texel at the pixel's UV, the
  paper's look-up);
* ``undisplaced, unshadowed``: the same stage with ``detail = "none"`` (the smooth surface, no
  patch: what the surface looks like without it, shaded the same way);
* ``undisplaced, ray traced``: ground truth of the smooth cloth with the patch's albedo (the best
  any shading of the surface without the relief can do);

each measured against the ground truth ray traced on the displaced geometry (the cloth
subdivided to about one edge per patch texel and moved along its normals by the patch heights:
:class:`warpshade.methods.ldprt._patch.PatchGeometry`), over the pixels of the cloth, as relative
RMS (``sqrt(mean |d|^2) / sqrt(mean |ref|^2)`` over RGB) with the part the reference's own noise
explains, over all those pixels and over those at least two pixels inside the cloth's outline
(``*_interior``: without the silhouettes, where the displaced outline differs from the smooth
one). Also: the patch's precompute time and lobe histogram, the per-pixel shading time.
``--scene-camera`` measures through the scene's camera (as ``--validate`` does) instead.

Writes ``ldprt-patch-<date>-cpu[-scene-camera].json`` and ``.png`` (patch | displaced reference | undisplaced |
the two error maps, frame 30) into ``--out`` (default ``benchmarks/results``).

Usage::

    python benchmarks/bench_ldprt_patch.py [--width 160] [--spp 256] [--supersample 2] [--out DIR]
    python benchmarks/bench_ldprt_patch.py --texture warpshade/usd_assets/sunlit_ground_diffuse.png
    python benchmarks/bench_ldprt_patch.py --quick --out /tmp/patch   # smoke profile (8^2 patch, 32x24)
"""

from __future__ import annotations

import argparse
import copy
import json
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DATE = "2026-12-02"
GRAPH = ROOT / "stages" / "cloth_ldprt_patch.toml"
#: A camera framing the cloth (the scene's shows the whole ground).
CAMERA = {"position": (0.9, -1.2, 3.3), "target": (0.0, 0.0, 0.8), "up": (0.0, 0.0, 1.0), "vertical_fov": 40.0}
#: Seeds of the two ground truths (independent streams).
SEED_DISPLACED, SEED_SMOOTH = 11, 23


def _spec(quick: bool, tiling: float | None, texture: str | None = None):
    from warpshade.graph import load

    spec = copy.deepcopy(load(GRAPH))
    patch, shade = spec.stages
    if texture is not None:  # heights (and albedo) from an image, the paper's way
        patch.params.update({"shape": "texture", "texture": str(Path(texture).resolve())})
    if quick:
        patch.params.update({"resolution": 8, "samples": 32, "lobes": 2})
    if tiling is not None:
        shade.params["tiling"] = float(tiling)
    return spec


def _smooth_albedo(scene, frame, camera, width, height, ss, shade):
    """Albedo per ray on the smooth surface: the surface's times the patch's at the UVs (ones for
    the procedural patches), so the smooth ground truth differs from the displaced one only in
    the relief."""
    from warpshade.methods.ldprt._patch import sample_heights
    from warpshade.reference import pixel_hits

    hits = pixel_hits(scene, frame, camera, width, height, ss, device="cpu")
    tri = scene.faces[np.maximum(hits.triangles, 0)]
    albedo = np.einsum("pk,pkc->pc", hits.barycentrics.astype(np.float64), np.asarray(scene.albedo, np.float64)[tri])
    owner = np.concatenate([np.full(m.triangle_count, k) for k, m in enumerate(scene.meshes)])
    on = hits.hit & np.array([m.path in shade.prims for m in scene.meshes])[owner[np.maximum(hits.triangles, 0)]]
    r = shade.patch.resolution
    tex = shade.patch.albedo.reshape(r, r, 3).astype(np.float64)
    uv = hits.uvs[on].astype(np.float64) * float(shade.params["tiling"])
    albedo[on] *= np.stack([sample_heights(tex[..., c], uv) for c in range(3)], 1)
    albedo[~hits.hit] = 0.0
    return albedo.astype(np.float32)


def _rel(est, ref, mask):
    d, r = (est - ref)[mask], ref[mask]
    return float(np.sqrt(np.mean(d * d)) / np.sqrt(np.mean(r * r)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smoke profile: 8^2 patch, 32 x 24 pixels, 8 spp, one frame")
    ap.add_argument("--width", type=int, default=160, help="image width (height: 3/4 of it)")
    ap.add_argument("--spp", type=int, default=256, help="ground-truth rays per pixel ray")
    ap.add_argument("--supersample", type=int, default=2, help="rays per pixel along each axis (box-filtered)")
    ap.add_argument("--tiling", type=float, default=None, help="patch repeats per UV unit (default: the graph's)")
    ap.add_argument("--frames", default="0,30", help="frames measured, comma-separated")
    ap.add_argument("--texture", default=None, help="an albedo image (tileable) whose luminance is the height and "
                    "which is the patch's albedo, instead of the graph's weave (results file: -texture)")
    ap.add_argument("--scene-camera", action="store_true", help="measure through the scene's camera (as --validate "
                    "does: the cloth seen at about 20 degrees above its plane) instead of the framing camera")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = ap.parse_args(argv)
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy import ndimage

    from warpshade.measure._pixels import render_frame
    from warpshade.measure._pictures import ERROR_LIMIT
    from warpshade.reference import reference_image
    from warpshade.render import tonemap_f64
    from warpshade.scene import Camera
    from warpshade.scene._materials import Lambert

    quick = args.quick
    width = 32 if quick else int(args.width)
    height = width * 3 // 4
    spp = 8 if quick else int(args.spp)
    ss = 1 if quick else int(args.supersample)
    frames = [0.0] if quick else [float(f) for f in args.frames.split(",")]
    out = Path(args.out) if args.out else ROOT / "benchmarks" / "results"
    out.mkdir(parents=True, exist_ok=True)
    stem = (f"ldprt-patch-{DATE}-cpu" + ("-texture" if args.texture else "") + ("-scene-camera" if args.scene_camera else "")
            + ("-quick" if quick else ""))

    spec = _spec(quick, args.tiling, args.texture)
    t0 = time.perf_counter()
    rt = spec.compile(device="cpu", progress=not quick)
    compile_s = time.perf_counter() - t0
    shade = next(s for s in rt.stages if s.type_name == "ldprt.patch_shade")
    patch_stage = next(s for s in rt.stages if s.type_name == "ldprt.patch")
    camera = Camera(position=np.array(CAMERA["position"]), target=np.array(CAMERA["target"]),
                    up=np.array(CAMERA["up"]), vertical_fov=CAMERA["vertical_fov"])
    if args.scene_camera:
        from warpshade.render import camera_for

        camera = camera_for(rt.scene, frames[0], aspect=width / height)
    rows, panels = {}, None
    for f in frames:
        print(f"frame {f:g}: shading", flush=True)
        rt.set_parameter("shade", "parallax", False)
        im_lookup = render_frame(rt, f, width, height, ss, camera=camera)
        rt.set_parameter("shade", "parallax", True)
        im = render_frame(rt, f, width, height, ss, camera=camera)
        shade = next(s for s in rt.stages if s.type_name == "ldprt.patch_shade")
        model = shade.pixel_reference_model()
        rt.set_parameter("shade", "detail", "none")
        im_flat = render_frame(rt, f, width, height, ss, camera=camera)
        rt.set_parameter("shade", "detail", "patch")
        lights = rt.lighting.lights_at(f)
        t1 = time.perf_counter()
        geometry = model["geometry"](f)
        build_s = time.perf_counter() - t1
        print(f"frame {f:g}: ground truth on the displaced cloth ({geometry.triangle_count:,} triangles)", flush=True)
        t1 = time.perf_counter()
        ref = reference_image(geometry, f, Lambert(), camera=camera, width=width, height=height, samples=spp,
                              supersample=ss, lighting=lights, include=("diffuse",), seed=SEED_DISPLACED, device="cpu")
        ref_s = time.perf_counter() - t1
        print(f"frame {f:g}: ground truth on the smooth cloth", flush=True)
        smooth = reference_image(rt.scene, f, Lambert(), camera=camera, width=width, height=height, samples=spp,
                                 supersample=ss, lighting=lights, include=("diffuse",), seed=SEED_SMOOTH, device="cpu",
                                 albedo=_smooth_albedo(rt.scene, f, camera, width, height, ss, shade))
        owner = np.concatenate([np.full(m.triangle_count, k) for k, m in enumerate(geometry.meshes)])
        keep = np.array([m.path in model["prims"] for m in geometry.meshes])
        tri = ref.hits.triangles
        on = (ref.hits.hit & (tri >= 0) & keep[owner[np.maximum(tri, 0)]]).reshape(height, ss, width, ss).all(axis=(1, 3))
        mask = on & ref.mask & (im.coverage >= 1.0) & smooth.mask
        # pixels at least two pixels inside the cloth's outline: what silhouettes leave
        interior = ndimage.binary_erosion(mask, iterations=2)
        denom = float(np.sqrt(np.mean(ref.radiance[mask] ** 2)))
        noise = float(np.sqrt(np.mean(ref.stderr[mask] ** 2)) / denom)
        noise_smooth = float(np.sqrt(np.mean(smooth.stderr[mask] ** 2)) / denom)
        rows[f"{f:g}"] = {
            "pixels": int(mask.sum()),
            "patch": _rel(im.linear, ref.radiance, mask),
            "patch_without_parallax": _rel(im_lookup.linear, ref.radiance, mask),
            "undisplaced_unshadowed": _rel(im_flat.linear, ref.radiance, mask),
            "undisplaced_ray_traced": _rel(smooth.radiance, ref.radiance, mask),
            "interior_pixels": int(interior.sum()),
            "patch_interior": _rel(im.linear, ref.radiance, interior),
            "patch_without_parallax_interior": _rel(im_lookup.linear, ref.radiance, interior),
            "undisplaced_unshadowed_interior": _rel(im_flat.linear, ref.radiance, interior),
            "reference_noise": noise,
            "undisplaced_ray_traced_noise": noise_smooth,
            "shade_s": im.seconds["shade"],
            "gbuffer_s": im.seconds["gbuffer"],
            "displaced_mesh_s": build_s,
            "reference_s": ref_s,
            "displaced_triangles": int(geometry.triangle_count),
        }
        print(f"frame {f:g}: {rows[f'{f:g}']}", flush=True)
        panels = (f, im.linear, ref.radiance, im_flat.linear, smooth.radiance, mask)
    report = {
        "graph": str(GRAPH.relative_to(ROOT)), "date": DATE, "machine": platform.processor() or platform.machine(),
        "quick": quick, "width": width, "height": height, "supersample": ss, "spp": spp,
        "camera": "scene" if args.scene_camera else CAMERA,
        "frames": rows, "patch": {**patch_stage.params, "report": getattr(patch_stage, "report", None)},
        "shade": dict(shade.params), "diagnostics": shade.diagnostics(), "compile_and_precompute_s": compile_s,
        "metric": "relative RMS over the cloth's fully covered pixels vs ground truth on the displaced fine mesh",
    }
    (out / f"{stem}.json").write_text(json.dumps(report, indent=2, default=str))
    f, lin, ref_rad, flat, smooth_rad, mask = panels
    lum = np.array([0.2126, 0.7152, 0.0722])
    exposure = float(np.log2(0.9 / max(np.percentile((ref_rad[mask] @ lum), 99), 1e-12))) if mask.any() else 0.0
    scale = float(np.mean((ref_rad @ lum)[mask])) if mask.any() else 1.0

    def err(img):
        e = ((img - ref_rad) @ lum) / scale
        return np.where(mask, e, np.nan)

    r = rows[f"{f:g}"]
    fig, axes = plt.subplots(1, 5, figsize=(17, 3.4))
    for ax, img, title in ((axes[0], lin, f"LDPRT patch, per pixel (parallax)\nrel RMS {r['patch']:.3f} "
                                          f"(without parallax {r['patch_without_parallax']:.3f})"),
                           (axes[1], ref_rad, f"ray traced, displaced geometry\n{spp} spp (noise {r['reference_noise']:.3f})"),
                           (axes[2], flat, f"undisplaced (unshadowed)\nrel RMS {r['undisplaced_unshadowed']:.3f}")):
        ax.imshow(tonemap_f64(img, exposure=exposure))
        ax.set_title(title, fontsize=9)
    cmap = plt.get_cmap("RdBu_r").copy()
    cmap.set_bad((0.5, 0.5, 0.5))
    for ax, img, title in ((axes[3], err(lin), "error: patch"), (axes[4], err(flat), "error: undisplaced")):
        h = ax.imshow(img, cmap=cmap, vmin=-ERROR_LIMIT, vmax=ERROR_LIMIT)
        ax.set_title(f"{title}\n(Y - Y_ref) / mean Y_ref", fontsize=9)
    for ax in axes:
        ax.set_axis_off()
    fig.colorbar(h, ax=axes[3:], fraction=0.03)
    shape = patch_stage.params["shape"]
    fig.suptitle(f"cloth, frame {f:g}: {shape} patch tiled {shade.params['tiling']:g}x, {width}x{height} px x{ss}^2", fontsize=10)
    fig.savefig(out / f"{stem}.png", dpi=110, bbox_inches="tight")
    print(f"wrote {out / (stem + '.json')} and .png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
