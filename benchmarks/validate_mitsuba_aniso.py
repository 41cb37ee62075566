"""Cross-check the per-pixel glossy reference's ANISOTROPIC BRDFs against Mitsuba 3 (needs the
``validate`` extra).

Scene: a 4 m ground grid and a ball above it (an icosphere, for a shadow), both with planar UVs
``(u, v) = R (x, y)`` turned by ``UV_TURN_DEG`` so that the tangent (the direction of increasing
u) is neither an axis of the grid nor of the camera, lit by the procedural sky
(``Environment.sky``) and, with ``--point-light``, by a point light. Material: the anisotropic
Beckmann microfacet BRDF, ours :class:`warpshade.scene._materials.AnisotropicMicrofacet`
(``roughness`` a_x along the tangent, ``roughness_y`` a_y along the bitangent; Smith masking with
the projected roughness and the rational Lambda; ``f0 = 1``: Schlick gives 1) evaluated by
:func:`warpshade.reference.reference_image` with ``tangents = "uv"``; Mitsuba's ``twosided``
``roughconductor`` with ``distribution = "beckmann"``, ``alpha_u = a_x``, ``alpha_v = a_y``,
``material = "none"`` (a 100 % reflector), whose shading frame's tangent is the mesh's
``dp/du`` projected on the shading normal, as ours. On a plane both tangents are exact and
equal; on the ball ours is the per-vertex average of ``dp/du`` interpolated, Mitsuba's the
triangle's own, so the ball's pixels are reported apart.

Reported (JSON): the BSDFs in isolation (Mitsuba's ``bsdf.eval`` against our float64
``AnisotropicMicrofacet.evaluate`` times the cosine, random direction pairs in the local frame),
and per light: the relative RMS of the two images over covered pixels (eroded by one) and over
the ground's pixels, the part the two estimators' noise explains, the mean difference. PNG:
ours | Mitsuba | 4x |difference|.

Usage::

    python benchmarks/validate_mitsuba_aniso.py --point-light
    python benchmarks/validate_mitsuba_aniso.py --quick --out /tmp/x

Writes ``mitsuba-aniso-<date>-<device>[-quick].json`` and ``...-<light>.png`` into ``--out``
(default benchmarks/results).
"""

from __future__ import annotations

import argparse
import datetime
import sys
import time
from pathlib import Path

import numpy as np

from validate_mitsuba import compare_images, edge_free_stats, mitsuba_envmap_bitmap, point_light_for

from warpshade._fileio import write_json_atomic
from warpshade._wp import resolve_device
from warpshade.reference import reference_image
from warpshade.render import tonemap_f64, write_png
from warpshade.scene import Camera, Environment, Mesh, Scene, SphereLight, _materials as materials

#: Smoke profile (tests/test_benchmarks.py): skipped where Mitsuba 3 is not installed
#: (pip install -e '.[validate]').
PROFILE = {"requires": ["mitsuba"]}

ROOT = Path(__file__).resolve().parents[1]
#: Slope parameters along the tangent and the bitangent.
ALPHA_U, ALPHA_V = 0.08, 0.35
#: The UVs' turn about the up axis (degrees): the tangent is this far from +x.
UV_TURN_DEG = 30.0
#: The camera: the ball, its shadow and the stretched highlight fill the frame.
CAMERA_EYE, CAMERA_TARGET, CAMERA_FOV_DEG = (2.6, -2.8, 2.0), (0.1, 0.1, 0.3), 45.0


def aniso_scene():
    """(scene, per-vertex UVs (V, 2)): the ground grid and the ball, planar UVs turned by UV_TURN_DEG."""
    import trimesh

    c = np.linspace(-2.0, 2.0, 21)
    gx, gy = np.meshgrid(c, c, indexing="ij")
    ground = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    idx = np.arange(gx.size).reshape(gx.shape)
    a, b, d, e = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    ground_faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, e], 1)])
    ball = trimesh.creation.icosphere(3, radius=0.45)
    ball.apply_translation((0.3, 0.2, 0.75))
    turn = np.radians(UV_TURN_DEG)
    rot = np.array([[np.cos(turn), np.sin(turn)], [-np.sin(turn), np.cos(turn)]])  # u grows along (cos, sin)

    def planar(p):
        return (p[:, :2] @ rot.T) * 0.25 + 0.5

    meshes = [Mesh("ground", ground, ground_faces, uvs=planar(ground)),
              Mesh("ball", ball.vertices, ball.faces, uvs=planar(np.asarray(ball.vertices)))]
    scene = Scene.from_meshes(meshes)
    return scene, np.concatenate([m.uvs for m in meshes])


def bsdf_isolation(count=1500, seed=0):
    """Mitsuba's anisotropic roughconductor against our AnisotropicMicrofacet times the cosine."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    rng = np.random.default_rng(seed)
    ours = materials.AnisotropicMicrofacet(ALPHA_U, ALPHA_V, f0=1.0)
    bsdf = mi.load_dict({"type": "roughconductor", "distribution": "beckmann", "alpha_u": ALPHA_U, "alpha_v": ALPHA_V,
                         "material": "none"})
    v = rng.normal(size=(count, 3))
    s = rng.normal(size=(count, 3))
    v[:, 2], s[:, 2] = np.abs(v[:, 2]) + 0.05, np.abs(s[:, 2]) + 0.05
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    theirs = np.zeros(count)
    for k in range(count):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*v[k])
        theirs[k] = float(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*s[k]))[0])
    mine = ours.evaluate(v, s) * s[:, 2]
    big = mine > 1e-3 * mine.max()
    rel = np.abs(theirs - mine) / np.maximum(np.abs(mine), 1e-30)
    return {"max_relative_difference_where_significant": float(rel[big].max()), "pairs": int(big.sum())}


def mitsuba_image(scene, uvs, env, point, camera, width, height, spp, seed):
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    points = scene.points_at(scene.frames[0]).astype(np.float32)
    normals = scene.evaluate(scene.frames[0], device="cpu").normals.numpy()
    mesh = mi.Mesh("scene", len(points), len(scene.faces), has_vertex_normals=True, has_vertex_texcoords=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = points.ravel()
    params["faces"] = scene.faces.astype(np.uint32).ravel()
    params["vertex_normals"] = normals.astype(np.float32).ravel()
    params["vertex_texcoords"] = uvs.astype(np.float32).ravel()
    params.update()
    mesh.set_bsdf(mi.load_dict({"type": "twosided", "bsdf": {
        "type": "roughconductor", "distribution": "beckmann", "material": "none", "alpha_u": ALPHA_U, "alpha_v": ALPHA_V}}))
    desc = {"type": "scene", "mesh": mesh, "integrator": {"type": "direct", "hide_emitters": False},
            "sensor": {"type": "perspective", "fov": float(camera.vertical_fov), "fov_axis": "y",
                       "to_world": mi.ScalarTransform4f().look_at(origin=[float(x) for x in camera.position],
                                                                  target=[float(x) for x in camera.target],
                                                                  up=[float(x) for x in camera.up]),
                       "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"},
                                "pixel_format": "rgb"},
                       "sampler": {"type": "independent", "sample_count": spp}}}
    if env is not None:
        bitmap, to_world = mitsuba_envmap_bitmap(env)
        desc["env"] = {"type": "envmap", "bitmap": mi.Bitmap(bitmap), "to_world": mi.ScalarTransform4f(to_world.tolist())}
    if point is not None:
        desc["point"] = {"type": "point", "position": [float(x) for x in point[0]],
                         "intensity": {"type": "rgb", "value": [float(point[1])] * 3}}
    mscene = mi.load_dict(desc)
    t0 = time.perf_counter()
    images = [np.array(mi.render(mscene, seed=seed + s)) for s in range(2)]
    return images, time.perf_counter() - t0


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--width", type=int, default=160)
    parser.add_argument("--height", type=int, default=120)
    parser.add_argument("--supersample", type=int, default=2)
    parser.add_argument("--shade-samples", type=int, default=256, help="our reference samples per sub-pixel ray")
    parser.add_argument("--spp", type=int, default=512, help="Mitsuba samples per pixel (per render; two renders)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--point-light", action="store_true", help="also an image lit by a point light")
    parser.add_argument("--quick", action="store_true", help="small settings for a fast check")
    parser.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = parser.parse_args(argv)
    if args.quick and args.out is None:
        parser.error("--quick writes only into --out DIR (never benchmarks/results)")
    args.out = args.out or str(ROOT / "benchmarks" / "results")
    if args.quick:
        args.width, args.height, args.supersample, args.shade_samples, args.spp = 48, 36, 1, 64, 64
    try:
        import mitsuba as mi
    except ImportError:
        print("mitsuba is not installed: pip install -e '.[validate]'")
        return 2
    dev = resolve_device(args.device)
    scene, uvs = aniso_scene()
    frame = float(scene.frames[0])
    camera = Camera(np.array(CAMERA_EYE), np.array(CAMERA_TARGET), np.array([0.0, 0.0, 1.0]), vertical_fov=CAMERA_FOV_DEG)
    env = Environment.sky(64, 128)
    lights = [("environment", [env], None)]
    if args.point_light:
        position, intensity, radius, radiance = point_light_for(scene, frame, camera)
        lights.append(("point", [SphereLight(position, radius, np.full(3, radiance))], (position, intensity)))
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    date = datetime.date.today().isoformat()
    stem = f"mitsuba-aniso-{date}-{'cpu' if dev.is_cpu else 'cuda'}" + ("-quick" if args.quick else "")
    report = {"date": date, "device": str(dev), "mitsuba_version": mi.__version__, "quick": args.quick,
              "material": {"ours": "AnisotropicMicrofacet(f0=1)", "mitsuba": "roughconductor beckmann, material none",
                           "alpha_u": ALPHA_U, "alpha_v": ALPHA_V, "uv_turn_deg": UV_TURN_DEG},
              "settings": {"width": args.width, "height": args.height, "supersample": args.supersample,
                           "shade_samples": args.shade_samples, "mitsuba_spp_per_render": args.spp, "mitsuba_renders": 2},
              "bsdf_isolation": bsdf_isolation(300 if args.quick else 1500), "cases": []}
    brdf = materials.AnisotropicMicrofacet(ALPHA_U, ALPHA_V, f0=1.0)
    ground_tris = np.arange(scene.triangle_count) < scene.meshes[0].triangle_count
    for name, lighting, point in lights:
        t0 = time.perf_counter()
        ours = reference_image(scene, frame, brdf, camera=camera, width=args.width, height=args.height,
                               samples=args.shade_samples, supersample=args.supersample, lighting=lighting,
                               include=("specular",), seed=args.seed, device=dev, tangents="uv")
        our_seconds = time.perf_counter() - t0
        theirs, mi_seconds = mitsuba_image(scene, uvs, env if point is None else None, point, camera, args.width,
                                           args.height, args.spp, args.seed)
        our_var = ours.stderr.astype(np.float64) ** 2
        stats, mi_mean, mask = compare_images(ours.radiance, our_var, theirs, ours.coverage)
        stats["away_from_edges"] = edge_free_stats(ours.radiance, our_var, theirs, mask)
        tri = ours.hits.triangles.reshape(args.height, args.supersample, args.width, args.supersample)
        on_ground = np.all((tri >= 0) & ground_tris[np.maximum(tri, 0)], axis=(1, 3))
        ground_stats, _, _ = compare_images(ours.radiance, our_var, theirs, ours.coverage * on_ground)
        stats["ground_only"] = {k: ground_stats[k] for k in ("pixels_compared", "relative_rms",
                                                             "relative_rms_expected_from_noise", "relative_mean_difference")}
        diff = np.abs(ours.radiance - mi_mean) * 4.0
        grey = 1.0 - ours.coverage
        png = write_png(out_dir / f"{stem}-{name}.png", np.concatenate(
            [tonemap_f64(ours.radiance, grey), tonemap_f64(mi_mean, None), tonemap_f64(diff, grey)], axis=1))
        stats.update({"light": name, "our_seconds": our_seconds, "mitsuba_seconds": mi_seconds, "png": png.name})
        report["cases"].append(stats)
        print(f"[{name}] relative RMS {stats['relative_rms']:.4f} over {stats['pixels_compared']} pixels (noise alone "
              f"{stats['relative_rms_expected_from_noise']:.4f}; mean difference {stats['relative_mean_difference']:+.4f}); "
              f"ground only {stats['ground_only']['relative_rms']:.4f} (noise "
              f"{stats['ground_only']['relative_rms_expected_from_noise']:.4f}); ours {our_seconds:.1f} s, Mitsuba {mi_seconds:.1f} s")
    report["command"] = "python benchmarks/validate_mitsuba_aniso.py " + " ".join(argv if argv is not None else sys.argv[1:])
    path = write_json_atomic(out_dir / f"{stem}.json", report)
    print(f"bsdf isolation: {report['bsdf_isolation']}")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
