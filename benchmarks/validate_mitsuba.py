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

4. With ``--glossy beckmann ggx`` (instead of parts 1-3): the GLOSSY per-pixel reference
   (:func:`warpshade.reference.reference_image`, specular part only, ``--supersample`` rays per
   pixel) against Mitsuba's ``direct`` integrator with a ``twosided`` ``roughconductor`` of the
   same distribution. The material varies over the surfaces: a per-vertex roughness (alpha in
   [0.12, 0.45], a smooth function of the rest position) and a per-vertex specular colour (the
   albedo) are Mitsuba ``mesh_attribute`` textures (``alpha``, ``specular_reflectance``),
   interpolated at the hit by barycentrics; ours gets the same vertex values interpolated at each
   ray's hit (:func:`warpshade.reference.pixel_hits`) as per-ray ``roughness`` / ``specular``.
   Parameter mapping: our ``Microfacet.roughness`` IS Mitsuba's ``alpha`` (both are the slope
   parameter of D: Beckmann ``exp(-tan^2/alpha^2) / (pi alpha^2 cos^4)``, GGX
   ``alpha^2 / (pi cos^4 (alpha^2 + tan^2)^2)``), and both use the separable Smith masking with
   the same Lambda (GGX exact, Beckmann the same rational fit). Fresnel is factored out: ours has
   ``f0 = 1`` (Schlick gives exactly 1) and Mitsuba's conductor ``material = "none"`` (a 100 %
   reflector), so the two BSDFs are the same function; the report measures it in isolation
   (``bsdf_isolation``: Mitsuba's ``bsdf.eval`` against our float64 ``Microfacet.evaluate`` times
   the cosine on random direction pairs) and, for information, what keeping a Fresnel term
   would cost (``fresnel_if_kept``: Schlick with ``f0 = ((eta - 1) / (eta + 1))^2`` against the
   exact unpolarised Fresnel factor of a conductor with ``eta = 1.5, k = 0``, which is what
   Mitsuba would evaluate). Lighting: the scene's environment built as in part 2 (plus its delta
   distant lights); with ``--point-light`` also a second image lit only by a point light, ours a
   :class:`~warpshade.scene.SphereLight` of radius ``POINT_LIGHT_RELATIVE_RADIUS`` (1 %) times
   its distance to the scene centre and radiance ``L_e``, Mitsuba a ``point`` emitter of intensity
   ``I = L_e pi r^2`` (a uniform sphere's irradiance is exactly ``pi L_e (r/d)^2 cos``, so the
   two differ only by the lobe's average over the sphere's small cone). The light sits opposite
   the camera (mirrored in the ground) so its highlight is in view. Reported per scene,
   distribution and light as in part 2: relative RMS over eroded covered pixels, the part of it
   the two estimators' noise explains, and the mean difference. Scenes: ``--scene`` or the
   bundled ``blockers.usda``, plus ``sunlit.usda`` when it exists. Writes
   ``mitsuba-glossy-<date>-<device>.json`` and one PNG per case (ours | Mitsuba | 4x |difference|).

Usage::

    python benchmarks/validate_mitsuba.py            # bundled blockers scene (array scene if absent)
    python benchmarks/validate_mitsuba.py --quick    # small and fast (used by the tests)
    python benchmarks/validate_mitsuba.py --bounces 1  # one diffuse bounce vs Mitsuba's path (depth 3)
    python benchmarks/validate_mitsuba.py --glossy beckmann ggx --point-light  # glossy per-pixel reference

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

#: Smoke profile (tests/test_benchmarks.py): skipped where Mitsuba 3 is not installed
#: (pip install -e '.[validate]').
PROFILE = {"requires": ["mitsuba"]}

ROOT = Path(__file__).resolve().parents[1]

from warpshade._fileio import write_json_atomic  # noqa: E402
from warpshade._wp import resolve_device, wp  # noqa: E402
from warpshade.geometry._bvh import RAY_MAX_DISTANCE, Visibility  # noqa: E402
from warpshade.io import bundled_asset_directory  # noqa: E402
from warpshade.reference import ReferenceShader, pixel_hits, reference_image  # noqa: E402
from warpshade.render import camera_for, interpolate_vertex_values, render, write_png  # noqa: E402
from warpshade.render import tonemap_f64
from warpshade.scene import DistantLight, Environment, SphereLight, _materials as materials  # noqa: E402
from warpshade.transfer import sample_rays  # noqa: E402

DEFAULT_SCENE = Path(bundled_asset_directory()) / "blockers.usda"
# A disagreeing ray counts as "on an edge" when its hit's smallest barycentric is below this.
EDGE_BARYCENTRIC = 1e-4
# ... as "grazing" when |cos| between the ray and the hit triangle's normal is below this.
GRAZING_COSINE = 1e-3
# Maps Mitsuba's envmap frame (y up, azimuth atan2(x, -z), mirrored image) to our map frame.
_MITSUBA_TO_MAP = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
SUNLIT_SCENE = Path(bundled_asset_directory()) / "sunlit.usda"
# Glossy part: the per-vertex roughness spans this range (smooth in the rest position).
GLOSSY_ALPHA_RANGE = (0.12, 0.45)
# The sphere light standing in for Mitsuba's point light: radius / distance to the scene centre.
# Two errors pull opposite ways: the lobe's average over the light's cone (grows as r^2) and
# float32 rounding of its solid angle 2 pi (1 - cos a) in our estimator (grows as 1 / r^2; 1 - cos a
# rounds to 0 below r/d ~ 3e-4). Measured on blockers (ggx, 80 x 60, away from edges, relative
# RMS): r/d = 0.005: 0.0012 (mean +0.18 %: rounding), 0.01: 0.00055 (noise 0.00035), 0.02:
# 0.0012, 0.04: 0.0041.
POINT_LIGHT_RELATIVE_RADIUS = 0.01
# The point light's irradiance on a surface at the scene centre facing it.
POINT_LIGHT_IRRADIANCE = 4.0
# Schlick and the exact Fresnel factor of this real index (the informational comparison).
FRESNEL_ETA = 1.5
# Glossy part: a pixel is "on an edge" (silhouette, hard shadow, sharp highlight) when the range
# of our luminance over its 3x3 neighbourhood exceeds this fraction of the image's RMS; there the
# fixed sub-pixel grid of ours and Mitsuba's random box-filter positions integrate the pixel
# differently (an error that shrinks with --supersample, not Monte Carlo noise).
EDGE_RELATIVE_RANGE = 0.25


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
        from warpshade.io import load_usd

        p = Path(path) if path is not None else DEFAULT_SCENE
        return load_usd(str(p)), p.stem
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


# ---- part 4: the glossy per-pixel reference -------------------------------------------------------


def glossy_vertex_material(scene):
    """Per-vertex roughness (V,) in GLOSSY_ALPHA_RANGE and specular colour (V, 3) of the glossy check."""
    rest = scene.points_at(scene.frames[0])
    lo, hi = scene.bounds(scene.frames[0])
    u = (rest - lo) / np.maximum(hi - lo, 1e-9)
    wave = 0.5 + 0.5 * np.sin(2.0 * np.pi * u[:, 0]) * np.cos(2.0 * np.pi * u[:, 1] + 1.3 * u[:, 2])
    alpha = GLOSSY_ALPHA_RANGE[0] + (GLOSSY_ALPHA_RANGE[1] - GLOSSY_ALPHA_RANGE[0]) * wave
    return alpha.astype(np.float32), scene.albedo.astype(np.float32)


def bsdf_isolation(distribution, alphas=(0.12, 0.3, 0.45), count=1500, seed=0):
    """Mitsuba's roughconductor (material none) against our Microfacet(f0=1) times the cosine,
    on random direction pairs above the horizon: max |difference| relative to the largest value,
    and relative where the value exceeds 1e-3 of it."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    rng = np.random.default_rng(seed)
    out = {}
    for alpha in alphas:
        bsdf = mi.load_dict({"type": "roughconductor", "distribution": distribution, "alpha": float(alpha), "material": "none"})
        wi = rng.normal(size=(count, 3))
        wo = rng.normal(size=(count, 3))
        wi /= np.linalg.norm(wi, axis=1, keepdims=True)
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
        ours = materials.Microfacet(float(alpha), distribution, f0=1.0).evaluate(wi, wo) * wo[:, 2]
        ctx = mi.BSDFContext()
        theirs = np.empty(count)
        for k in range(count):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*wi[k])
            si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
            theirs[k] = np.array(bsdf.eval(ctx, si, mi.Vector3f(*wo[k])))[0]
        big = ours > 1e-3 * ours.max()
        out[f"alpha={alpha:g}"] = {
            "max_abs_difference_relative_to_max": float(np.abs(theirs - ours).max() / ours.max()),
            "max_relative_difference_where_significant": float((np.abs(theirs - ours)[big] / ours[big]).max()),
        }
    return out


def fresnel_if_kept(eta=FRESNEL_ETA):
    """Schlick's approximation against the exact unpolarised Fresnel factor of a conductor with
    index eta + 0i (Mitsuba's ``fresnel_conductor``), over the incidence cosine."""
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    f0 = ((eta - 1.0) / (eta + 1.0)) ** 2
    cos = np.linspace(1e-3, 1.0, 1000)
    exact = np.array([float(mi.fresnel_conductor(mi.Float(c), dr.scalar.Complex2f(eta, 0.0))) for c in cos])
    schlick = f0 + (1.0 - f0) * (1.0 - cos) ** 5
    rel = np.abs(schlick - exact) / exact
    return {"eta": eta, "f0": f0, "max_relative_difference": float(rel.max()),
            "max_relative_difference_cos_above_0.2": float(rel[cos > 0.2].max()),
            "cos_at_max": float(cos[np.argmax(rel)])}


def point_light_for(scene, frame, camera):
    """A point above the scene opposite the camera (mirrored in the ground) and its intensity:
    (position (3,), intensity I (scalar, W/sr per channel), sphere radius r, sphere radiance L_e)."""
    lo, hi = scene.bounds(frame)
    centre = 0.5 * (lo + hi)
    up = np.array([0.0, 0.0, 1.0]) if scene.up_axis == "Z" else np.array([0.0, 1.0, 0.0])
    offset = np.asarray(camera.position, np.float64) - centre
    height = float(offset @ up)
    position = centre - (offset - height * up) * 0.8 + up * max(height, 0.5 * float(np.linalg.norm(hi - lo)))
    distance = float(np.linalg.norm(position - centre))
    intensity = POINT_LIGHT_IRRADIANCE * distance**2
    radius = POINT_LIGHT_RELATIVE_RADIUS * distance
    return position, intensity, radius, intensity / (np.pi * radius**2)


def our_glossy_image(scene, frame, distribution, lighting, camera, width, height, supersample, samples, device, seed):
    alpha_v, spec_v = glossy_vertex_material(scene)
    hits = pixel_hits(scene, frame, camera, width, height, supersample, device)
    h = hits.hit
    corners = scene.faces[hits.triangles[h]]
    rough = np.full(hits.ray_count, float(np.mean(alpha_v)), np.float32)
    rough[h] = np.einsum("ik,ik->i", hits.barycentrics[h], alpha_v[corners])
    spec = np.zeros((hits.ray_count, 3), np.float32)
    spec[h] = np.einsum("ik,ikj->ij", hits.barycentrics[h], spec_v[corners])
    brdf = materials.Microfacet(float(np.mean(alpha_v)), distribution, f0=1.0)
    t0 = time.perf_counter()
    ref = reference_image(scene, frame, brdf, camera=camera, width=width, height=height, samples=samples,
                          supersample=supersample, lighting=lighting, roughness=rough, specular=spec,
                          include=("specular",), seed=seed, device=device)
    return ref, time.perf_counter() - t0


def mitsuba_glossy_image(scene, frame, distribution, env, delta_lights, point, camera, width, height, spp, seed):
    """Two Mitsuba renders of the glossy scene; ``point`` = (position, intensity) or None."""
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    alpha_v, spec_v = glossy_vertex_material(scene)
    points = scene.points_at(frame).astype(np.float32)
    normals = scene.evaluate(frame, device="cpu").normals.numpy()
    mesh = mi.Mesh("scene", len(points), len(scene.faces), has_vertex_normals=True)
    mesh.add_attribute("vertex_roughness", 1, alpha_v.astype(np.float32).ravel().tolist())
    mesh.add_attribute("vertex_specular", 3, spec_v.astype(np.float32).ravel().tolist())
    params = mi.traverse(mesh)
    params["vertex_positions"] = points.ravel()
    params["faces"] = scene.faces.astype(np.uint32).ravel()
    params["vertex_normals"] = normals.astype(np.float32).ravel()
    params.update()
    mesh.set_bsdf(mi.load_dict({"type": "twosided", "bsdf": {
        "type": "roughconductor", "distribution": distribution, "material": "none",
        "alpha": {"type": "mesh_attribute", "name": "vertex_roughness"},
        "specular_reflectance": {"type": "mesh_attribute", "name": "vertex_specular"},
    }}))
    desc = {
        "type": "scene",
        "mesh": mesh,
        "integrator": mitsuba_integrator(None),
        "sensor": {
            "type": "perspective",
            "fov": float(camera.vertical_fov),
            "fov_axis": "y",
            "to_world": mi.ScalarTransform4f().look_at(origin=[float(x) for x in camera.position], target=[float(x) for x in camera.target], up=[float(x) for x in camera.up]),
            "film": {"type": "hdrfilm", "width": width, "height": height, "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": spp},
        },
    }
    if env:
        bitmap, to_world = mitsuba_envmap_bitmap(env[0])
        desc["env"] = {"type": "envmap", "bitmap": mi.Bitmap(bitmap), "to_world": mi.ScalarTransform4f(to_world.tolist())}
    for k, light in enumerate(delta_lights):
        desc[f"sun{k}"] = {"type": "directional", "direction": [float(-x) for x in light.direction], "irradiance": {"type": "rgb", "value": [float(x) for x in light.irradiance]}}
    if point is not None:
        desc["point"] = {"type": "point", "position": [float(x) for x in point[0]], "intensity": {"type": "rgb", "value": [float(point[1])] * 3}}
    mscene = mi.load_dict(desc)
    t0 = time.perf_counter()
    images = [np.array(mi.render(mscene, seed=seed + s)) for s in range(2)]
    return images, time.perf_counter() - t0


def edge_free_stats(ours, our_var, theirs, mask):
    """Relative RMS and its noise expectation over the covered pixels away from edges
    (:data:`EDGE_RELATIVE_RANGE`), normalised like :func:`compare_images`."""
    from scipy.ndimage import maximum_filter, minimum_filter

    lum = ours.sum(axis=-1)
    scale_lum = np.sqrt(np.mean(lum[mask] ** 2))
    edge = (maximum_filter(lum, size=3) - minimum_filter(lum, size=3)) > EDGE_RELATIVE_RANGE * scale_lum
    keep = mask & ~edge
    mi_mean = 0.5 * (theirs[0] + theirs[1])
    scale = np.sqrt(np.mean(mi_mean[mask] ** 2))
    diff = ours[keep] - mi_mean[keep]
    noise = 0.25 * np.mean((theirs[0][keep] - theirs[1][keep]) ** 2) + np.mean(our_var[keep])
    return {"pixels": int(keep.sum()), "relative_rms": float(np.sqrt(np.mean(diff**2)) / scale),
            "relative_rms_expected_from_noise": float(np.sqrt(noise) / scale),
            "relative_mean_difference": float(np.mean(diff) / np.mean(mi_mean[keep]))}


def glossy_scenes(path):
    if path is not None:
        return [load_scene(path)]
    scenes = [load_scene(None)]
    if SUNLIT_SCENE.exists():
        scenes.append(load_scene(str(SUNLIT_SCENE)))
    return scenes


def run_glossy(args, mi, dev):
    """Part 4 (module docstring): every scene x distribution x light; returns the report."""
    from warpshade.render import tonemap_f64 as tonemap_np

    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    date = datetime.date.today().isoformat()
    device_name = "cpu" if dev.is_cpu else "cuda"
    stem = f"mitsuba-glossy-{date}-{device_name}" + ("-quick" if args.quick else "")
    report = {
        "date": date, "device": str(dev), "mitsuba_version": mi.__version__, "quick": args.quick,
        "settings": {"width": args.width, "height": args.height, "supersample": args.supersample,
                     "shade_samples": args.shade_samples, "mitsuba_spp_per_render": args.spp, "mitsuba_renders": 2,
                     "alpha_range": list(GLOSSY_ALPHA_RANGE), "fresnel": "factored out (f0 = 1 / material none)",
                     "point_light_relative_radius": POINT_LIGHT_RELATIVE_RADIUS},
        "bsdf_isolation": {d: bsdf_isolation(d, count=300 if args.quick else 1500) for d in args.glossy},
        "fresnel_if_kept": fresnel_if_kept(),
        "cases": [],
    }
    for scene, scene_name in glossy_scenes(args.scene):
        frame = float(scene.frames[0] if args.frame is None else scene.frames[scene.frame_index(args.frame)])
        env, delta, excluded = split_lighting(scene.lights)
        if not env and not delta:
            env = [Environment.sky(64, 128)]
        camera = camera_for(scene, frame, aspect=args.width / args.height)
        lights = [("environment", env + delta, None)]
        if args.point_light:
            position, intensity, radius, radiance = point_light_for(scene, frame, camera)
            lights.append(("point", [SphereLight(position, radius, np.full(3, radiance))], (position, intensity)))
        for distribution in args.glossy:
            for light_name, lighting, point in lights:
                ours, our_seconds = our_glossy_image(scene, frame, distribution, lighting, camera, args.width, args.height,
                                                     args.supersample, args.shade_samples, dev, args.seed)
                use_env = env if point is None else []
                use_delta = delta if point is None else []
                theirs, mi_seconds = mitsuba_glossy_image(scene, frame, distribution, use_env, use_delta, point, camera,
                                                          args.width, args.height, args.spp, args.seed)
                our_var = ours.stderr.astype(np.float64) ** 2
                stats, mi_mean, mask = compare_images(ours.radiance, our_var, theirs, ours.coverage)
                stats["away_from_edges"] = edge_free_stats(ours.radiance, our_var, theirs, mask)
                name = f"{stem}-{scene_name}-{distribution}-{light_name}"
                diff = np.abs(ours.radiance - mi_mean) * 4.0
                grey = 1.0 - ours.coverage
                panels = [tonemap_np(ours.radiance, grey), tonemap_np(mi_mean, None), tonemap_np(diff, grey)]
                png = write_png(out_dir / f"{name}.png", np.concatenate(panels, axis=1))
                stats.update({"scene": scene_name, "frame": frame, "distribution": distribution, "light": light_name,
                              "our_seconds": our_seconds, "mitsuba_seconds": mi_seconds, "png": png.name,
                              "excluded_lights": excluded if point is None else []})
                if point is not None:
                    stats["point_light"] = {"position": [float(x) for x in point[0]], "intensity": float(point[1]),
                                            "sphere_radius": float(lighting[0].radius), "sphere_radiance": float(lighting[0].radiance[0])}
                report["cases"].append(stats)
                print(f"[{scene_name} {distribution} {light_name}] relative RMS {stats['relative_rms']:.4f} over "
                      f"{stats['pixels_compared']} pixels (noise alone {stats['relative_rms_expected_from_noise']:.4f}; "
                      f"mean difference {stats['relative_mean_difference']:+.4f}); away from edges {stats['away_from_edges']['relative_rms']:.4f} "
                      f"(noise {stats['away_from_edges']['relative_rms_expected_from_noise']:.4f}); ours {our_seconds:.1f} s, "
                      f"Mitsuba {mi_seconds:.1f} s")
    report["command"] = "python benchmarks/validate_mitsuba.py " + " ".join(args.argv)
    path = write_json_atomic(out_dir / f"{stem}.json", report)
    print(f"wrote {path}")
    return report


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
    parser.add_argument("--glossy", nargs="+", choices=("beckmann", "ggx"), default=None, metavar="DISTRIBUTION",
                        help="cross-check the glossy per-pixel reference (part 4) with these microfacet distributions "
                             "instead of parts 1-3")
    parser.add_argument("--point-light", action="store_true", help="with --glossy: also an image lit by a point light")
    parser.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = parser.parse_args(argv)
    args.argv = list(argv if argv is not None else sys.argv[1:])
    if args.point_light and not args.glossy:
        parser.error("--point-light needs --glossy")
    if args.bounces is not None and args.bounces < 0:
        parser.error(f"--bounces must be >= 0, got {args.bounces}")
    bounces = args.bounces or 0
    if args.quick and args.out is None:
        parser.error("--quick writes only into --out DIR (never benchmarks/results)")
    args.out = args.out or str(ROOT / "benchmarks" / "results")
    if args.quick:
        args.samples, args.receivers = 64, args.receivers or 300
        args.width, args.height, args.supersample, args.shade_samples, args.spp = 64, 48, 2, 64, 64

    try:
        import mitsuba as mi
    except ImportError:
        print("mitsuba is not installed: pip install -e '.[validate]'")
        return 2

    dev = resolve_device(args.device)
    if args.glossy:
        run_glossy(args, mi, dev)
        return 0
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
    panels = [ours.image, tonemap_f64(mi_mean, None, exposure), tonemap_f64(diff, None, exposure)]
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
