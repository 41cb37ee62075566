"""Cross-check the ray-traced ground truth against Mitsuba 3 (needs the ``validate`` extra).

Two comparisons on the same scene, frame and lighting:

1. Visibility from the SAME rays: the exact shadow rays of :func:`warpshade.transfer.sample_rays`
   (per-vertex randomly rotated Fibonacci sets, origins offset along the normal) are traced by
   our ``wp.Mesh`` any-hit kernel and by Mitsuba's ``scene.ray_test`` (llvm_ad_rgb, Embree).
   Reported: rays that disagree, the per-vertex visible-fraction difference, and for each
   disagreeing ray why it is ambiguous (its hit lies on a triangle edge/vertex, the ray grazes
   the hit triangle's plane, or the hit is within two offsets of the origin).
2. An image: our reference shading evaluated per pixel (:class:`warpshade.reference.ReferenceShader`
   at the camera's primary hits, ``--supersample`` x ``--supersample`` sub-pixel rays) against
   Mitsuba's ``direct`` integrator (emitter + BSDF sampling with MIS, one bounce, box pixel
   filter) with a two-sided diffuse BSDF whose reflectance is the same per-vertex albedo and an
   ``envmap`` emitter built from the same lat-long image. Mitsuba's envmap puts texel rows at
   ``theta = k pi / (rows - 1)`` (ours: texel centres) and runs azimuth the other way round, so
   the image is resampled to 2H+1 rows (exact for our bilinear map) and mirrored, and its
   ``to_world`` is ours times a fixed rotation; the mapping error is measured and reported.
   Reported: relative RMS over pixels fully covered by geometry (eroded by one pixel), and the
   part of it explained by the two estimators' noise.
3. With ``--bounces K``: the same image with K diffuse bounces of indirect light, our
   ``ReferenceShader(..., bounces=K)`` at the primary hits against Mitsuba's ``path`` integrator
   at ``max_depth = K + 2`` (Mitsuba counts the camera segment: ``max_depth = 1`` shows emitters
   only, ``2`` is direct lighting, each further unit one more bounce; ``rr_depth`` is set beyond
   ``max_depth`` so no path is cut by Russian roulette). ``--bounces 0`` is the control: the
   ``path`` integrator at depth 2 against our direct-only reference. The image space
   comparison is kept because it puts Mitsuba's own path construction (its BSDF sampling,
   emitter sampling and MIS at every vertex, shading normals, interpolated vertex colours) against
   ours with nothing shared but the scene; per-vertex estimates would need our own loop around
   Mitsuba's ray queries. As a control the report also gives our direct-only image against
   Mitsuba's K bounces (``direct_only_vs_mitsuba``): the difference the bounces make. Both sides reflect with shading normals interpolated from the same vertex
   normals and albedo interpolated from the same vertex colours. Mitsuba's BSDF is two-sided and
   ours reflects only front faces: on closed meshes over a ground plane (the bundled scenes) no
   path from a front face reaches a back face, so the two agree there.

Usage::

    python benchmarks/validate_mitsuba.py            # bundled blockers scene (array scene if absent)
    python benchmarks/validate_mitsuba.py --quick    # small and fast (used by the tests)
    python benchmarks/validate_mitsuba.py --bounces 1  # one diffuse bounce vs Mitsuba's path (depth 3)

Writes ``mitsuba-<date>-<scene>.json`` (``-bounces<K>`` appended with ``--bounces``) and a
side-by-side PNG (ours | Mitsuba | 4x |difference|) into ``--out`` (default benchmarks/results).
"""

from __future__ import annotations

import argparse
import datetime
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from warpshade._fileio import write_json_atomic  # noqa: E402
from warpshade._wp import resolve_device, wp  # noqa: E402
from warpshade.geometry.bvh import RAY_MAX_DISTANCE, Visibility  # noqa: E402
from warpshade.reference import ReferenceShader  # noqa: E402
from warpshade.render import camera_for, interpolate_vertex_values, render, write_png  # noqa: E402
from warpshade.render.image import tonemap_reference  # noqa: E402
from warpshade.scene import DistantLight, Environment, SphereLight  # noqa: E402
from warpshade.transfer import sample_rays  # noqa: E402

DEFAULT_SCENE = ROOT / "usd_assets" / "blockers.usda"
# A disagreeing ray counts as "on an edge" when its hit's smallest barycentric is below this.
EDGE_BARYCENTRIC = 1e-4
# ... as "grazing" when |cos| between the ray and the hit triangle's normal is below this.
GRAZING_COSINE = 1e-3
# Maps Mitsuba's envmap frame (y up, azimuth atan2(x, -z), mirrored image) to our map frame.
_MITSUBA_TO_MAP = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def array_scene():
    import trimesh

    from warpshade.scene import Mesh, Scene

    ground = trimesh.creation.box(extents=(6.0, 6.0, 0.05))
    ground = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(ground.vertices, ground.faces, 0.25))
    ball = trimesh.creation.icosphere(3, radius=0.6)
    ball.apply_translation((0.0, 0.0, 0.9))
    box = trimesh.creation.box(extents=(0.8, 0.5, 0.6))
    box.apply_translation((1.2, -0.8, 0.35))
    meshes = [
        Mesh("ground", ground.vertices, ground.faces, albedo=(0.7, 0.7, 0.7)),
        Mesh("ball", ball.vertices, ball.faces, albedo=(0.8, 0.3, 0.2)),
        Mesh("box", box.vertices, box.faces, albedo=(0.2, 0.5, 0.8)),
    ]
    return Scene.from_meshes(meshes, lights=[Environment.sky(64, 128)])


def load_scene(path):
    if path is not None or DEFAULT_SCENE.exists():
        import warpshade

        p = Path(path) if path is not None else DEFAULT_SCENE
        return warpshade.load_usd(str(p)), p.stem
    return array_scene(), "arrays"


def mitsuba_envmap_bitmap(env: Environment) -> tuple[np.ndarray, np.ndarray]:
    """Mitsuba envmap image (2H+1 rows, mirrored) and its 4x4 to_world for our Environment."""
    h = env.height
    v = np.arange(2 * h + 1) / 2.0 - 0.5  # our continuous row coordinate at theta = k pi / (2H)
    r0 = np.clip(np.floor(v), 0, h - 1).astype(int)
    r1 = np.clip(np.floor(v) + 1, 0, h - 1).astype(int)
    f = (v - np.floor(v))[:, None, None]
    rows = (1.0 - f) * env.image[r0].astype(np.float64) + f * env.image[r1].astype(np.float64)
    to_world = np.eye(4)
    to_world[:3, :3] = env.to_world @ _MITSUBA_TO_MAP
    return np.ascontiguousarray(rows[:, ::-1], dtype=np.float32), to_world


def split_lighting(lights):
    env = [light for light in lights if isinstance(light, Environment)]
    delta = [light for light in lights if isinstance(light, DistantLight) and light.angle_deg == 0.0]
    excluded = [type(light).__name__ + ("" if light.path is None else f" {light.path}") for light in lights if isinstance(light, SphereLight) or (isinstance(light, DistantLight) and light.angle_deg > 0.0)]
    return env[:1], delta, excluded


# ---- part 1: visibility on the same rays ------------------------------------------------------


def mitsuba_ray_scene(mi, points, faces):
    mesh = mi.Mesh("scene", len(points), len(faces), has_vertex_normals=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = np.asarray(points, np.float32).ravel()
    params["faces"] = np.asarray(faces, np.uint32).ravel()
    params.update()
    return mi.load_dict({"type": "scene", "mesh": mesh})


def compare_visibility(scene, frame, samples, receivers, device, seed):
    import drjit as dr
    import mitsuba as mi

    origins, dirs = sample_rays(scene, frame, samples, vertices=receivers, device=device, seed=seed)
    shape = origins.shape[:2]
    o, d = origins.reshape(-1, 3), dirs.reshape(-1, 3)
    bvh = Visibility.from_scene(scene, device=device)
    bvh.update(scene.points_at(frame))
    t0 = time.perf_counter()
    ours = bvh.occluded(o, d).numpy().astype(bool)
    warp_seconds = time.perf_counter() - t0
    points = scene.points_at(frame).astype(np.float32)
    try:
        mi.set_variant("llvm_ad_rgb")
        variant = "llvm_ad_rgb"
    except Exception:
        mi.set_variant("scalar_rgb")
        variant = "scalar_rgb"
    mscene = mitsuba_ray_scene(mi, points, scene.faces)
    t0 = time.perf_counter()
    if variant == "llvm_ad_rgb":
        ray = mi.Ray3f(mi.Point3f(o[:, 0], o[:, 1], o[:, 2]), mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))
        ray.maxt = RAY_MAX_DISTANCE
        theirs = np.asarray(scene_ray_test(dr, mscene, ray)).astype(bool)
    else:
        theirs = np.array([bool(mscene.ray_test(mi.Ray3f(mi.Point3f(*o[i]), mi.Vector3f(*d[i])))) for i in range(len(o))])
    mitsuba_seconds = time.perf_counter() - t0
    differ = np.nonzero(ours != theirs)[0]
    # why do they differ? closest hits from both sides
    ours_hit = bvh.closest_hits(o[differ], d[differ])
    kinds = {"edge_or_vertex": 0, "grazing": 0, "near_origin": 0, "unexplained": 0}
    examples = []
    mi_t = np.full(len(differ), -1.0)
    mi_bary = np.zeros((len(differ), 2))
    if len(differ) and variant == "llvm_ad_rgb":
        sub = mi.Ray3f(mi.Point3f(o[differ, 0], o[differ, 1], o[differ, 2]), mi.Vector3f(d[differ, 0], d[differ, 1], d[differ, 2]))
        pi = mscene.ray_intersect_preliminary(sub)
        valid = np.asarray(pi.is_valid()).astype(bool)
        mi_t = np.where(valid, np.asarray(pi.t), -1.0)
        mi_bary = np.stack([np.asarray(pi.prim_uv[0]), np.asarray(pi.prim_uv[1])], 1)
    for k, ray_index in enumerate(differ):
        if ours[ray_index]:
            u, v = ours_hit["bary"][k]
            bary = np.array([u, v, 1.0 - u - v])
            t, cos = float(ours_hit["distance"][k]), float(ours_hit["cosine"][k])
        else:
            u, v = mi_bary[k]
            bary = np.array([1.0 - u - v, u, v])
            t, cos = float(mi_t[k]), float("nan")
        if bary.min() < EDGE_BARYCENTRIC:
            kind = "edge_or_vertex"
        elif np.isfinite(cos) and abs(cos) < GRAZING_COSINE:
            kind = "grazing"
        elif 0.0 <= t < 2.0 * bvh.offset:
            kind = "near_origin"
        else:
            kind = "unexplained"
        kinds[kind] += 1
        if len(examples) < 8:
            examples.append({"ray": int(ray_index), "warp_hit": bool(ours[ray_index]), "mitsuba_hit": bool(theirs[ray_index]), "distance": t, "min_barycentric": float(bary.min()), "cosine": cos, "kind": kind})
    frac_ours = 1.0 - ours.reshape(shape).mean(1)
    frac_theirs = 1.0 - theirs.reshape(shape).mean(1)
    return {
        "variant": variant,
        "receivers": int(shape[0]),
        "samples": int(samples),
        "rays": int(len(o)),
        "rays_disagreeing": int(len(differ)),
        "fraction_disagreeing": float(len(differ) / len(o)),
        "disagreement_kinds": kinds,
        "examples": examples,
        "vertices_with_any_disagreement": int(np.sum(frac_ours != frac_theirs)),
        "visible_fraction_max_abs_difference": float(np.abs(frac_ours - frac_theirs).max()),
        "visible_fraction_mean": float(frac_ours.mean()),
        "offset": bvh.offset,
        "warp_seconds": warp_seconds,
        "mitsuba_seconds": mitsuba_seconds,
    }


def scene_ray_test(dr, mscene, ray):
    hit = mscene.ray_test(ray)
    dr.eval(hit)
    return hit


# ---- part 2: images -----------------------------------------------------------------------------


def our_image(scene, frame, lighting, camera, width, height, supersample, samples, device, seed, bounces=0):
    dev = resolve_device(device)
    shader = ReferenceShader(scene, lighting, samples, "mis", dev, seed, bounces=bounces)
    state = scene.evaluate(frame, device=dev)
    shader.update(state.points, state.normals)  # the frame the paths bounce off
    albedo = scene.albedo
    noise = {}

    def shade(gb):
        hit = np.nonzero(gb.hit.numpy())[0]
        receivers = wp.array(hit.astype(np.int32), dtype=wp.int32, device=dev)
        radiance = wp.zeros(len(hit), dtype=wp.vec3, device=dev)
        stderr = wp.zeros(len(hit), dtype=wp.vec3, device=dev)
        pixel_albedo = interpolate_vertex_values(gb, albedo)
        shader.shade_points(gb.position, gb.normal, pixel_albedo, receivers, radiance, stderr)
        out = np.zeros((gb.pixel_count, 3), np.float32)
        out[hit] = radiance.numpy()
        var = np.zeros((gb.pixel_count, 3))
        var[hit] = stderr.numpy().astype(np.float64) ** 2
        ss = supersample
        noise["pixel_variance"] = var.reshape(height, ss, width, ss, 3).sum(axis=(1, 3)) / ss**4
        return out

    t0 = time.perf_counter()
    res = render(scene, frame, shade=shade, camera=camera, width=width, height=height, environment=lighting[0] if lighting and isinstance(lighting[0], Environment) else None, supersample=supersample, device=dev, bvh=shader.bvh, state=state)
    return res, noise["pixel_variance"], time.perf_counter() - t0


def mitsuba_integrator(bounces):
    """Mitsuba integrator: ``direct`` without ``--bounces``, else ``path`` at ``max_depth = K + 2``."""
    if bounces is None:
        return {"type": "direct", "hide_emitters": False}
    return {"type": "path", "max_depth": int(bounces) + 2, "rr_depth": int(bounces) + 3, "hide_emitters": False}


def mitsuba_image(scene, frame, env, delta_lights, camera, width, height, spp, seed, bounces=None):
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    points = scene.points_at(frame).astype(np.float32)
    normals = scene.evaluate(frame, device="cpu").normals.numpy()
    mesh = mi.Mesh("scene", len(points), len(scene.faces), has_vertex_normals=True)
    mesh.add_attribute("vertex_color", 3, scene.albedo.astype(np.float32).ravel().tolist())
    params = mi.traverse(mesh)
    params["vertex_positions"] = points.ravel()
    params["faces"] = scene.faces.astype(np.uint32).ravel()
    params["vertex_normals"] = normals.astype(np.float32).ravel()
    params.update()
    mesh.set_bsdf(mi.load_dict({"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": {"type": "mesh_attribute", "name": "vertex_color"}}}))
    desc = {
        "type": "scene",
        "mesh": mesh,
        "integrator": mitsuba_integrator(bounces),
        "sensor": {
            "type": "perspective",
            "fov": float(camera.vertical_fov),
            "fov_axis": "y",
            "to_world": mi.ScalarTransform4f().look_at(origin=[float(x) for x in camera.position], target=[float(x) for x in camera.target], up=[float(x) for x in camera.up]),
            "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": spp},
        },
    }
    mapping_error = None
    if env:
        bitmap, to_world = mitsuba_envmap_bitmap(env[0])
        desc["env"] = {"type": "envmap", "bitmap": mi.Bitmap(bitmap), "to_world": mi.ScalarTransform4f(to_world.tolist())}
    for k, light in enumerate(delta_lights):
        desc[f"sun{k}"] = {"type": "directional", "direction": [float(-x) for x in light.direction], "irradiance": {"type": "rgb", "value": [float(x) for x in light.irradiance]}}
    mscene = mi.load_dict(desc)
    if env:
        rng = np.random.default_rng(0)
        dirs = rng.normal(size=(256, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        emitter = mscene.environment()
        values = []
        for d in dirs:
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*(-d))
            values.append(np.array(emitter.eval(si)))
        ref = env[0].radiance(dirs)
        mapping_error = float(np.abs(np.array(values) - ref).max() / max(np.abs(ref).max(), 1e-30))
    t0 = time.perf_counter()
    images = [np.array(mi.render(mscene, seed=seed + s)) for s in range(2)]
    return images, mapping_error, time.perf_counter() - t0


def compare_images(ours, our_var, theirs, coverage):
    from scipy.ndimage import binary_erosion

    mask = binary_erosion(coverage >= 1.0, iterations=1)
    mi_mean = 0.5 * (theirs[0] + theirs[1])
    diff = ours[mask] - mi_mean[mask]
    scale = np.sqrt(np.mean(mi_mean[mask] ** 2))
    rel_rms = float(np.sqrt(np.mean(diff**2)) / scale)
    mi_noise_var = 0.25 * np.mean((theirs[0][mask] - theirs[1][mask]) ** 2)  # variance of the mean of two renders
    ours_noise_var = float(np.mean(our_var[mask]))
    return {
        "pixels_compared": int(mask.sum()),
        "relative_rms": rel_rms,
        "relative_rms_expected_from_noise": float(np.sqrt(mi_noise_var + ours_noise_var) / scale),
        "relative_noise_ours": float(np.sqrt(ours_noise_var) / scale),
        "relative_noise_mitsuba_two_renders": float(np.sqrt(mi_noise_var) / scale),
        "relative_mean_difference": float(np.mean(diff) / np.mean(mi_mean[mask])),
    }, mi_mean, mask


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scene", default=None)
    parser.add_argument("--frame", type=float, default=None, help="time code (default: the first)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--samples", type=int, default=256, help="rays per receiver for the visibility comparison")
    parser.add_argument("--receivers", type=int, default=None, help="receiver count (default: every vertex)")
    parser.add_argument("--width", type=int, default=240)
    parser.add_argument("--height", type=int, default=180)
    parser.add_argument("--supersample", type=int, default=3)
    parser.add_argument("--shade-samples", type=int, default=256, help="our reference samples per sub-pixel ray")
    parser.add_argument("--spp", type=int, default=512, help="Mitsuba samples per pixel (per render; two renders)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="small settings for a fast check")
    parser.add_argument("--bounces", type=int, default=None, metavar="K",
                        help="compare K diffuse bounces with Mitsuba's path integrator (max_depth K + 2); "
                             "default: direct light against Mitsuba's direct integrator")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    if args.bounces is not None and args.bounces < 0:
        parser.error(f"--bounces must be >= 0, got {args.bounces}")
    bounces = args.bounces or 0
    if args.quick:
        args.samples, args.receivers = 64, args.receivers or 300
        args.width, args.height, args.supersample, args.shade_samples, args.spp = 64, 48, 2, 64, 64

    try:
        import mitsuba as mi
    except ImportError:
        print("mitsuba is not installed: pip install -e '.[validate]'")
        return 2

    dev = resolve_device(args.device)
    scene, scene_name = load_scene(args.scene)
    frame = float(scene.frames[0] if args.frame is None else scene.frames[scene.frame_index(args.frame)])
    rng = np.random.default_rng(args.seed)
    receivers = None if args.receivers is None else np.sort(rng.choice(scene.vertex_count, min(args.receivers, scene.vertex_count), replace=False))

    visibility = compare_visibility(scene, frame, args.samples, receivers, dev, args.seed)
    print(f"[{scene_name} frame {frame:g}] visibility on the same rays ({visibility['variant']}): "
          f"{visibility['rays_disagreeing']} of {visibility['rays']} rays disagree "
          f"({visibility['disagreement_kinds']}); max |visible fraction difference| = "
          f"{visibility['visible_fraction_max_abs_difference']:.2e} over {visibility['receivers']} receivers")

    env, delta, excluded = split_lighting(scene.lights)
    lighting = env + delta
    if not lighting:
        env = [Environment.sky(64, 128)]
        lighting = env
    camera = camera_for(scene, frame, aspect=args.width / args.height)
    ours, our_var, our_seconds = our_image(scene, frame, lighting, camera, args.width, args.height, args.supersample, args.shade_samples, dev, args.seed, bounces)
    theirs, mapping_error, mi_seconds = mitsuba_image(scene, frame, env, delta, camera, args.width, args.height, args.spp, args.seed, args.bounces)
    image_stats, mi_mean, mask = compare_images(ours.linear, our_var, theirs, ours.coverage)
    image_stats.update({
        "width": args.width, "height": args.height, "supersample": args.supersample, "shade_samples": args.shade_samples,
        "mitsuba_spp_per_render": args.spp, "mitsuba_renders": 2, "envmap_mapping_max_relative_error": mapping_error,
        "our_seconds": our_seconds, "mitsuba_seconds": mi_seconds, "excluded_lights": excluded,
        "bounces": bounces, "mitsuba_integrator": mitsuba_integrator(args.bounces),
    })
    if bounces > 0:
        # control: our direct light alone against Mitsuba's K bounces shows what the bounces weigh
        direct, direct_var, _ = our_image(scene, frame, lighting, camera, args.width, args.height, args.supersample, args.shade_samples, dev, args.seed)
        direct_stats, _, _ = compare_images(direct.linear, direct_var, theirs, ours.coverage)
        image_stats["direct_only_vs_mitsuba"] = {k: direct_stats[k] for k in ("relative_rms", "relative_mean_difference")}
    print(f"image {args.width}x{args.height}, {bounces} bounces: relative RMS {image_stats['relative_rms']:.4f} over {image_stats['pixels_compared']} pixels "
          f"(noise alone would give {image_stats['relative_rms_expected_from_noise']:.4f}; mean difference "
          f"{image_stats['relative_mean_difference']:+.4f}); envmap mapping error {mapping_error}")
    if bounces > 0:
        control = image_stats["direct_only_vs_mitsuba"]
        print(f"control, our direct light only: relative RMS {control['relative_rms']:.4f}, mean difference "
              f"{control['relative_mean_difference']:+.4f}")

    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    date = datetime.date.today().isoformat()
    stem = f"mitsuba-{date}-{scene_name}" + ("" if args.bounces is None else f"-bounces{args.bounces}") + ("-quick" if args.quick else "")
    exposure = 0.0
    diff = np.abs(ours.linear - mi_mean) * 4.0
    panels = [ours.image, tonemap_reference(mi_mean, None, exposure), tonemap_reference(diff, None, exposure)]
    png = write_png(out_dir / f"{stem}.png", np.concatenate(panels, axis=1))
    report = {
        "date": date,
        "scene": scene_name,
        "frame": frame,
        "device": str(dev),
        "mitsuba_version": mi.__version__,
        "quick": args.quick,
        "visibility": visibility,
        "image": image_stats,
        "side_by_side_png": png.name,
        "command": "python benchmarks/validate_mitsuba.py " + " ".join(argv if argv is not None else sys.argv[1:]),
    }
    path = out_dir / f"{stem}.json"
    write_json_atomic(path, report)
    print(f"wrote {path} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
