"""The Monte Carlo estimator behind both references: outgoing radiance of a receiver with a BRDF.

For a receiver at ``p`` with unit normal ``n``, an RGB tint ``t`` (per receiver) and a BRDF ``b``
of :mod:`warpshade.scene._materials` (the same model for every receiver; evaluated by
:mod:`warpshade.scene._materials_warp`; a microfacet model's roughness may be given per receiver,
which shades a spatially varying material exactly), the outgoing radiance towards the unit view
direction ``v`` is::

    L_o(p, v) = t * integral b(v, s) L_i(s) V(s) max(0, n . s) ds

where ``L_i`` is the environment radiance (bilinear lat-long lookup, :mod:`..scene.lighting_warp`)
plus the analytic lights, and ``V(s)`` is ray-traced against every triangle of the frame
(``wp.mesh_query_ray_anyhit`` from ``p + offset * n``, :mod:`warpshade.geometry._bvh`). With an
``eye`` the view is ``v = normalize(eye - p)`` and ``L_o = 0`` where the eye is below the
receiver's horizon; without one (a view-independent BRDF such as Lambert's) ``v = n``.

Estimators of the environment term (per sample point), in the order of the kernel's ``method``:

* BRDF sampling (0): one direction from the BRDF lobe (:func:`~..scene.materials_warp.brdf_sample`,
  pdf ``p_b``); estimate ``t L b max(0, n.s) V / p_b``.
* light sampling (1): one direction from the environment's luminance distribution (pdf
  ``p_env``); estimate ``t L b max(0, n.s) V / p_env``.
* MIS (2): one direction from each, combined with the balance heuristic
  (``f / (p_b + p_env)`` for each), i.e. two rays per sample point.

Analytic lights, added to every iteration: a :class:`~..scene.lighting.DistantLight` with
``angle_deg == 0`` is a delta light (one deterministic shadow ray, no variance:
``t b(v, l) E max(0, n.l) V(l)``); with ``angle_deg > 0`` it is a uniform disc whose direction is
sampled uniformly in its cone (estimate ``t b E max(0, n.s) V(s)``). A
:class:`~..scene.lighting.SphereLight` is sampled uniformly inside the cone it subtends
(solid angle ``Omega``; estimate ``t b L_e max(0, n.s) V(s) Omega``), the shadow ray stopping
at the sphere; a receiver inside the sphere sees it in every direction, estimated by BRDF
sampling without rays (``t L_e b max(0, n.s) / p_b``). Sphere lights are not part of the BVH
(they cast no shadows on the environment).

Indirect light (``bounces = k > 0``): every sample point also carries one path of up to ``k``
diffuse bounces off the scene's triangles. Its first direction is drawn from the receiver's BRDF
lobe (throughput ``t b cos / p_b``, i.e. ``rho`` for a Lambert receiver); a path goes on only
where its closest hit is a front face (a back face or a miss ends it: the light that escapes is
the direct part's, counted above), so the direct and the indirect parts split the hemisphere
between them. At each hit ``q`` (albedo ``rho_q`` and shading normal ``n_q`` interpolated from
the vertices by barycentrics, shadow rays from ``q + offset * n_geometric``) the throughput is
multiplied by ``rho_q`` and next-event estimation adds the lights for the Lambert BRDF about
``n_q`` with the strategies above -- the delta lights deterministically, one point of the
environment (BRDF, light or MIS sampling with the balance heuristic, as the receiver's
``method``) and of the area lights -- and before the last bounce a cosine-sampled continuation
(``b cos / p_cos = 1``) leaves ``q``. Sphere lights are not geometry: paths pass through them.
The next-event estimates of every vertex are the same functions as the receiver's direct part,
so a diffuse and a glossy receiver share one estimator.

A texture of eq.-13 materials (``SVBRDFMaterial``) gives each receiver the BRDF of its texel (per
vertex at its UV, per point from ``texels``), evaluated and sampled by :mod:`._svbrdf_warp`.
A tabulated BRDF is shaded one table channel per pass (:func:`~..scene.materials_warp.upload_brdf_passes`,
same random streams) summed with RGB weights: channel ``c`` of a colour table is its own pass.

Sampling is randomised quasi-Monte Carlo: the 2-D sample points of every strategy are an R2
low-discrepancy set (the additive recurrence of the plastic number) under a random
Cranley-Patterson shift, which stratifies the lobe and the environment's CDF (penumbrae
converge faster than with independent samples) and stays unbiased. ``samples`` is the number of
environment rays per receiver, split into ``K`` = :data:`REPLICATES` independently shifted
replicates of ``samples / K`` points (``samples / 2K`` for MIS, which casts two rays per
point). The reported standard error is ``sqrt(var / K)`` with ``var`` the unbiased variance of
the ``K`` replicate estimates (Welford's running update): the standard deviation of the
returned mean, per channel. Shifts come from a counter-based hash of ``(seed, receiver,
replicate)``, so results are reproducible and independent across seeds. The paths' first
directions are one more randomly shifted R2 set; their later dimensions (next-event and
continuation at each bounce) are independent uniforms from a counter-based generator seeded per
``(replicate, point)``. These numbers are drawn after the direct part's, whose stream is the
same for every ``bounces``: with ``bounces = 0`` the results are bit-identical to the direct-only
estimator, and with the same seed each path is extended, not redrawn, by one more bounce (so
the radiance never decreases with ``bounces``).
"""

from __future__ import annotations

import numpy as np

from .._wp import cpu_workers, launch_parallel, resolve_device, wp
from ..geometry._bvh import RAY_MAX_DISTANCE, Visibility
from ..geometry._frames import onb_tangent
from ..scene._lighting import DistantLight, Environment, SphereLight
from ..scene._lighting_warp import EnvironmentMap, disabled_environment, env_pdf, env_radiance, env_sample, upload_environment
from ..scene._materials import Lambert
from ..scene._materials_warp import (ANISOTROPIC_MODELS, BRDF_MODELS, BRDFParams, brdf_with_roughness, brdf_with_tangent,
                                    check_roughness, upload_brdf)
from ..transfer._interreflection import check_albedo, check_bounces, hit_corners, hit_weights, interpolate_vec3
from ..transfer._raytrace import CHUNK_MIN_RAYS, receiver_indices
from ._result import ShadingResult
from ._svbrdf_warp import (brdf_with_texel, check_texels, surface_brdf_eval, surface_brdf_pdf, surface_brdf_sample, surface_texels,
                          upload_surface_passes)

__all__ = [
    "ESTIMATOR_VERSION",
    "REPLICATES",
    "AnalyticLights",
    "DeviceLighting",
    "DiffuseSurfaces",
    "MonteCarloShader",
    "strategy_index",
]

wp.set_module_options({"enable_backward": False})

#: Independent randomised-QMC replicates per receiver (the standard error is their spread).
REPLICATES = 16
#: Bumped whenever the estimator's results change beyond float32 rounding (its random streams or
#: strategies), so cached ground truth is recomputed.
ESTIMATOR_VERSION = 2

_RAY_MAX = wp.constant(RAY_MAX_DISTANCE)


@wp.struct
class AnalyticLights:
    """Distant and sphere lights on the device (arrays may be empty).

    Fields:
        distant_direction: unit direction toward each distant light, (D,) vec3, world.
        distant_irradiance: RGB irradiance, (D,) vec3.
        distant_cos_half: cosine of the disc half-angle, (D,); 1 for a delta light.
        sphere_position: centres, (S,) vec3, world; sphere_radius: (S,); sphere_radiance: (S,) vec3.
    """

    distant_direction: wp.array(dtype=wp.vec3)
    distant_irradiance: wp.array(dtype=wp.vec3)
    distant_cos_half: wp.array(dtype=float)
    sphere_position: wp.array(dtype=wp.vec3)
    sphere_radius: wp.array(dtype=float)
    sphere_radiance: wp.array(dtype=wp.vec3)


class DeviceLighting:
    """Lighting uploaded for the reference kernel.

    Attributes:
        environment: :class:`~warpshade.scene._lighting_warp.EnvironmentMap` (disabled if none).
        lights: :class:`AnalyticLights`.
        has_environment: whether an environment was given.
        has_area_lights: whether any light needs sampling (disc distant lights, sphere lights).
    """

    def __init__(self, environment, lights, has_environment, has_area_lights):
        self.environment = environment
        self.lights = lights
        self.has_environment = has_environment
        self.has_area_lights = has_area_lights


def _split_lighting(lighting):
    items = [lighting] if isinstance(lighting, (Environment, DistantLight, SphereLight)) else list(lighting)
    envs, distant, spheres = [], [], []
    for item in items:
        if isinstance(item, Environment):
            envs.append(item)
        elif isinstance(item, DistantLight):
            distant.append(item)
        elif isinstance(item, SphereLight):
            spheres.append(item)
        else:
            raise ValueError(f"reference lighting: unsupported light of type {type(item).__name__}")
    if len(envs) > 1:
        paths = ", ".join(str(e.path or "<array>") for e in envs)
        raise ValueError(f"reference lighting: at most one Environment is supported, got {len(envs)} ({paths})")
    return (envs[0] if envs else None), distant, spheres


def upload_lighting(lighting, device=None) -> DeviceLighting:
    """Upload a list of lights (at most one Environment) for the reference shaders."""
    dev = resolve_device(device)
    env, distant, spheres = _split_lighting(lighting)
    lights = AnalyticLights()

    def vecs(rows):
        return wp.array(np.asarray(rows, np.float32).reshape(-1, 3), dtype=wp.vec3, device=dev)

    def floats(vals):
        return wp.array(np.asarray(vals, np.float32).reshape(-1), dtype=float, device=dev)

    lights.distant_direction = vecs([d.direction for d in distant])
    lights.distant_irradiance = vecs([d.irradiance for d in distant])
    lights.distant_cos_half = floats([np.cos(np.radians(d.angle_deg) / 2.0) if d.angle_deg > 0 else 1.0 for d in distant])
    lights.sphere_position = vecs([s.position for s in spheres])
    lights.sphere_radius = floats([s.radius for s in spheres])
    lights.sphere_radiance = vecs([s.radiance for s in spheres])
    env_map = upload_environment(env, dev) if env is not None else disabled_environment(dev)
    area = any(d.angle_deg > 0 for d in distant) or bool(spheres)
    return DeviceLighting(env_map, lights, env is not None, area)


@wp.func
def _cone_dir(axis: wp.vec3, cos_half: float, u1: float, u2: float) -> wp.vec3:
    """Uniform direction in the cone of half-angle acos(cos_half) about a unit axis."""
    z = 1.0 - u1 * (1.0 - cos_half)
    r = wp.sqrt(wp.max(0.0, 1.0 - z * z))
    phi = 2.0 * wp.pi * u2
    t = onb_tangent(axis)
    b = wp.cross(axis, t)
    return wp.normalize(r * wp.cos(phi) * t + r * wp.sin(phi) * b + z * axis)


#: Additive recurrence of the plastic number (the "R2" sequence): a 2-D low-discrepancy set for
#: any point count; randomly shifted (Cranley-Patterson) it gives unbiased stratified estimates.
_R2_A1 = wp.constant(0.7548776662466927)
_R2_A2 = wp.constant(0.5698402909980532)


@wp.func
def _r2(j: int, shift: float, a: float) -> float:
    x = float(j) * a + shift
    return x - wp.floor(x)


@wp.func
def _delta_lights(mesh_id: wp.uint64, origin: wp.vec3, n: wp.vec3, v: wp.vec3, brdf: BRDFParams, lights: AnalyticLights) -> wp.vec3:
    """Delta distant lights at a shading point: ``sum b(v, l) E max(0, n.l) V(l)`` (no variance)."""
    fixed = wp.vec3(0.0)
    for k in range(lights.distant_direction.shape[0]):
        if lights.distant_cos_half[k] >= 1.0:
            l = lights.distant_direction[k]
            c = wp.dot(n, l)
            if c > 0.0:
                if not wp.mesh_query_ray_anyhit(mesh_id, origin, l, _RAY_MAX):
                    fixed += (surface_brdf_eval(brdf, n, v, l) * c) * lights.distant_irradiance[k]
    return fixed


@wp.func
def _sampled_lights(
    acc: wp.vec3,
    mesh_id: wp.uint64,
    origin: wp.vec3,
    n: wp.vec3,
    v: wp.vec3,
    brdf: BRDFParams,
    env: EnvironmentMap,
    lights: AnalyticLights,
    method: int,
    point_count: int,
    shift_brdf: wp.vec2,
    shift_env: wp.vec4,
    shift_area: wp.vec2,
) -> wp.vec3:
    """``acc`` plus the environment, disc and sphere lights at a shading point, summed over
    the sample points ``j = 0 .. point_count - 1``.

    The points are the R2 set under the given Cranley-Patterson shifts (``point_count = 1``
    with uniformly random shifts is one independent uniform sample); strategies as in the module
    docstring (``method`` 0 / 1 / 2 = BRDF / light / MIS). No tint: the caller applies it.
    """
    for j in range(point_count):
        if env.enabled != 0:
            if method != 1:
                d = surface_brdf_sample(brdf, n, v, _r2(j, shift_brdf[0], _R2_A1), _r2(j, shift_brdf[1], _R2_A2))
                f = surface_brdf_eval(brdf, n, v, d) * wp.max(wp.dot(n, d), 0.0)
                pdf_b = surface_brdf_pdf(brdf, n, v, d)
                if f > 0.0 and pdf_b > 0.0:
                    if not wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX):
                        denom = pdf_b
                        if method == 2:
                            denom = pdf_b + env_pdf(env, d)
                        acc += env_radiance(env, d) * (f / denom)
            if method != 0:
                s = env_sample(
                    env,
                    _r2(j, shift_env[0], _R2_A1),
                    _r2(j, shift_env[1], _R2_A2),
                    _r2(j, shift_env[2], _R2_A1),
                    _r2(j, shift_env[3], _R2_A2),
                )
                d = wp.vec3(s[0], s[1], s[2])
                f = surface_brdf_eval(brdf, n, v, d) * wp.max(wp.dot(n, d), 0.0)
                if f > 0.0 and s[3] > 0.0:
                    if not wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX):
                        denom = s[3]
                        if method == 2:
                            denom = s[3] + surface_brdf_pdf(brdf, n, v, d)
                        acc += env_radiance(env, d) * (f / denom)
        for k in range(lights.distant_direction.shape[0]):
            cos_half = lights.distant_cos_half[k]
            if cos_half < 1.0:
                # a per-light offset decorrelates the lights' point sets
                u1 = _r2(j, shift_area[0] + 0.318 * float(k), _R2_A1)
                u2 = _r2(j, shift_area[1] + 0.618 * float(k), _R2_A2)
                d = _cone_dir(lights.distant_direction[k], cos_half, u1, u2)
                c = wp.dot(n, d)
                if c > 0.0:
                    if not wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX):
                        acc += lights.distant_irradiance[k] * (surface_brdf_eval(brdf, n, v, d) * c)
        for k in range(lights.sphere_position.shape[0]):
            to_centre = lights.sphere_position[k] - origin
            dist = wp.length(to_centre)
            radius = lights.sphere_radius[k]
            u1 = _r2(j, shift_area[0] + 0.414 * float(k + 1), _R2_A1)
            u2 = _r2(j, shift_area[1] + 0.732 * float(k + 1), _R2_A2)
            if dist <= radius:
                d = surface_brdf_sample(brdf, n, v, u1, u2)
                pdf_b = surface_brdf_pdf(brdf, n, v, d)
                if pdf_b > 0.0:
                    acc += lights.sphere_radiance[k] * (surface_brdf_eval(brdf, n, v, d) * wp.max(wp.dot(n, d), 0.0) / pdf_b)
            else:
                axis = to_centre / dist
                sin_a = radius / dist
                cos_a = wp.sqrt(wp.max(0.0, 1.0 - sin_a * sin_a))
                d = _cone_dir(axis, cos_a, u1, u2)
                c = wp.dot(n, d)
                if c > 0.0:
                    # distance to the near intersection with the light sphere
                    b = wp.dot(to_centre, d)
                    disc = b * b - (dist * dist - radius * radius)
                    t_hit = b - wp.sqrt(wp.max(disc, 0.0))
                    if not wp.mesh_query_ray_anyhit(mesh_id, origin, d, t_hit):
                        solid = 2.0 * wp.pi * (1.0 - cos_a)
                        acc += lights.sphere_radiance[k] * (surface_brdf_eval(brdf, n, v, d) * c * solid)
    return acc


@wp.struct
class DiffuseSurfaces:
    """What a diffuse bounce needs of the scene's triangles (indexed like the BVH's).

    Fields:
        indices: triangle vertex indices, flat (3 F,), int32 (the ``wp.Mesh``'s own).
        normals: unit vertex normals of the frame, (V,) vec3, world (interpolated: shading normal).
        albedo: per-vertex RGB albedo, (V,) vec3 (interpolated by barycentrics).
        lambert: the Lambert BRDF of albedo 1 (the albedo is applied by the path's throughput).
    """

    indices: wp.array(dtype=wp.int32)
    normals: wp.array(dtype=wp.vec3)
    albedo: wp.array(dtype=wp.vec3)
    lambert: BRDFParams


@wp.func
def _indirect_path(
    acc: wp.vec3,
    mesh_id: wp.uint64,
    surfaces: DiffuseSurfaces,
    origin: wp.vec3,
    n: wp.vec3,
    v: wp.vec3,
    brdf: BRDFParams,
    env: EnvironmentMap,
    lights: AnalyticLights,
    method: int,
    bounces: int,
    offset: float,
    u1: float,
    u2: float,
    path_seed: int,
    j: int,
) -> wp.vec3:
    """``acc`` plus one path of up to ``bounces`` diffuse bounces leaving a shading point.

    The first direction is drawn from the shading point's BRDF lobe with the uniforms (u1, u2)
    (weight ``b cos / p_b``); its closest hit ``q`` continues the path only on a front face
    (a back face or a miss ends it: escaping light is the direct part's). At each vertex ``q``:
    the throughput takes ``q``'s interpolated albedo, next-event estimation adds the lights with
    :func:`_delta_lights` and one :func:`_sampled_lights` point (independent uniforms from
    ``(path_seed, j)``) for the Lambert BRDF about the interpolated shading normal, and, before
    the last bounce, a cosine-sampled continuation (weight ``b cos / p_cos = 1``) goes on.
    """
    d = surface_brdf_sample(brdf, n, v, u1, u2)
    f = surface_brdf_eval(brdf, n, v, d) * wp.max(wp.dot(n, d), 0.0)
    pdf = surface_brdf_pdf(brdf, n, v, d)
    if f <= 0.0 or pdf <= 0.0:
        return acc
    throughput = wp.vec3(f / pdf)
    state = wp.rand_init(path_seed, j)
    o = origin
    for bounce in range(bounces):
        q = wp.mesh_query_ray(mesh_id, o, d, _RAY_MAX)
        if not q.result or q.sign <= 0.0:
            break
        corners = hit_corners(surfaces.indices, q.face)
        weights = hit_weights(q.u, q.v)
        throughput = wp.cw_mul(throughput, interpolate_vec3(surfaces.albedo, corners, weights))
        if wp.max(throughput) <= 0.0:
            break
        ns = interpolate_vec3(surfaces.normals, corners, weights)
        length = wp.length(ns)
        if length > 1.0e-12:
            ns = ns / length
        else:
            ns = q.normal  # vertex normals cancel (a fold): the face's own
        # shadow rays leave the front side of the hit triangle (its geometric normal)
        o = o + q.t * d + offset * q.normal
        shift_brdf = wp.vec2(wp.randf(state), wp.randf(state))
        shift_env = wp.vec4(wp.randf(state), wp.randf(state), wp.randf(state), wp.randf(state))
        shift_area = wp.vec2(wp.randf(state), wp.randf(state))
        light = _delta_lights(mesh_id, o, ns, ns, surfaces.lambert, lights)
        light = _sampled_lights(light, mesh_id, o, ns, ns, surfaces.lambert, env, lights, method, 1, shift_brdf, shift_env, shift_area)
        acc += wp.cw_mul(throughput, light)
        if bounce + 1 < bounces:
            d = surface_brdf_sample(surfaces.lambert, ns, ns, wp.randf(state), wp.randf(state))
            f = surface_brdf_eval(surfaces.lambert, ns, ns, d) * wp.max(wp.dot(ns, d), 0.0)
            pdf = surface_brdf_pdf(surfaces.lambert, ns, ns, d)
            if f <= 0.0 or pdf <= 0.0:
                break
            throughput = throughput * (f / pdf)
    return acc


@wp.kernel
def _estimator_kernel(
    mesh_id: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    tint: wp.array(dtype=wp.vec3),
    receivers: wp.array(dtype=wp.int32),
    receiver_start: int,
    brdf_uniform: BRDFParams,
    roughness: wp.array(dtype=float),
    tangents: wp.array(dtype=wp.vec3),
    texels: wp.array(dtype=wp.int32),
    has_eye: int,
    eye: wp.vec3,
    env: EnvironmentMap,
    lights: AnalyticLights,
    method: int,
    replicates: int,
    points_per_replicate: int,
    bounces: int,
    surfaces: DiffuseSurfaces,
    seed: int,
    offset: float,
    radiance: wp.array(dtype=wp.vec3),
    stderr: wp.array(dtype=wp.vec3),
):
    """Radiance and standard error of receivers ``receiver_start + tid`` (module docstring).

    ``points``, ``normals`` (unit), ``tint`` and -- when it is not empty -- ``roughness`` (the
    microfacet alpha replacing ``brdf_uniform.roughness``) are indexed by ``receivers[r]``; with
    an empty ``roughness`` every receiver has ``brdf_uniform`` unchanged; a non-empty ``tangents``
    gives each receiver the tangent direction of the anisotropic models (world), a non-empty
    ``texels`` its SVBRDF texel (:func:`~._svbrdf_warp.brdf_with_texel`); ``has_eye`` 0
    evaluates the BRDF with ``v = n`` (``eye`` unused); ``method`` 0 / 1 / 2 = BRDF / light / MIS
    sampling; ``bounces`` > 0 adds one path of that many diffuse bounces per sample point over
    ``surfaces``; ``offset`` (world units) lifts shadow-ray origins along ``n``. Writes
    ``radiance[r]`` and ``stderr[r]`` (linear RGB).
    """
    r = receiver_start + wp.tid()
    vi = receivers[r]
    p = points[vi]
    n = normals[vi]
    v = n  # a view-independent BRDF is evaluated with the viewer on the normal
    if has_eye != 0:
        to_eye = eye - p
        dist_eye = wp.length(to_eye)
        if dist_eye <= 0.0 or wp.dot(n, to_eye) <= 0.0:
            radiance[r] = wp.vec3(0.0)
            stderr[r] = wp.vec3(0.0)
            return
        v = to_eye / dist_eye
    t = tint[vi]
    alpha = brdf_uniform.roughness
    if roughness.shape[0] > 0:
        alpha = roughness[vi]
    brdf = brdf_with_roughness(brdf_uniform, alpha)
    if tangents.shape[0] > 0:
        brdf = brdf_with_tangent(brdf, tangents[vi])
    if texels.shape[0] > 0:
        brdf = brdf_with_texel(brdf, texels[vi])
    origin = p + offset * n
    base = int(wp.rand_init(seed, vi))

    # Delta distant lights: deterministic, no variance.
    fixed = _delta_lights(mesh_id, origin, n, v, brdf, lights)

    mean = wp.vec3(0.0)
    m2 = wp.vec3(0.0)
    for rep in range(replicates):
        # one independent randomised-QMC estimate per replicate: random shifts of the R2 set
        state = wp.rand_init(base, rep)
        s_b1 = wp.randf(state)
        s_b2 = wp.randf(state)
        s_env1 = wp.randf(state)
        s_env2 = wp.randf(state)
        s_env3 = wp.randf(state)
        s_env4 = wp.randf(state)
        s_area1 = wp.randf(state)
        s_area2 = wp.randf(state)
        shift_brdf = wp.vec2(s_b1, s_b2)
        shift_env = wp.vec4(s_env1, s_env2, s_env3, s_env4)
        shift_area = wp.vec2(s_area1, s_area2)
        # the paths' numbers come after the direct part's, whose stream is unchanged
        s_path1 = wp.randf(state)
        s_path2 = wp.randf(state)
        path_seed = wp.randi(state)
        acc = _sampled_lights(wp.vec3(0.0), mesh_id, origin, n, v, brdf, env, lights, method, points_per_replicate,
                              shift_brdf, shift_env, shift_area)
        if bounces > 0:
            indirect = wp.vec3(0.0)
            for j in range(points_per_replicate):
                indirect = _indirect_path(indirect, mesh_id, surfaces, origin, n, v, brdf, env, lights, method, bounces,
                                          offset, _r2(j, s_path1, _R2_A1), _r2(j, s_path2, _R2_A2), path_seed, j)
            acc = acc + indirect
        x = wp.cw_mul(t, acc) / float(points_per_replicate)
        delta = x - mean
        mean += delta / float(rep + 1)
        m2 += wp.cw_mul(delta, x - mean)

    radiance[r] = mean + wp.cw_mul(t, fixed)
    if replicates > 1:
        var = m2 / float((replicates - 1) * replicates)
        stderr[r] = wp.vec3(wp.sqrt(wp.max(var[0], 0.0)), wp.sqrt(wp.max(var[1], 0.0)), wp.sqrt(wp.max(var[2], 0.0)))
    else:
        stderr[r] = wp.vec3(0.0)


@wp.kernel
def _add_pass_kernel(radiance: wp.array(dtype=wp.vec3), stderr: wp.array(dtype=wp.vec3), weights: wp.vec3,
                     out_radiance: wp.array(dtype=wp.vec3), out_stderr: wp.array(dtype=wp.vec3)):
    """Add one pass times its RGB weights; standard errors add (an upper bound for shared streams)."""
    i = wp.tid()
    out_radiance[i] = out_radiance[i] + wp.cw_mul(weights, radiance[i])
    out_stderr[i] = out_stderr[i] + wp.cw_mul(weights, stderr[i])


def strategy_index(method: str, methods: tuple[str, ...], caller: str) -> int:
    """The kernel's ``method`` code (0 BRDF, 1 light, 2 MIS sampling) of ``method`` in ``methods``."""
    if method not in methods:
        raise ValueError(f"{caller}: method must be one of {methods}, got {method!r}")
    return methods.index(method)


def _sampling_plan(samples: int, strategy: int, has_environment: bool, caller: str) -> tuple[int, int]:
    """(replicates, points per replicate) for ``samples`` environment rays per receiver."""
    if not isinstance(samples, (int, np.integer)) or samples < 2:
        raise ValueError(f"{caller}: samples must be an integer >= 2, got {samples!r}")
    per_point = 2 if (strategy == 2 and has_environment) else 1
    count = int(samples) // per_point
    if count < 2:
        raise ValueError(f"{caller}: method 'mis' needs samples >= 4, got {samples}")
    replicates = min(REPLICATES, count)
    return replicates, max(1, count // replicates)


def _vec3(value, name: str, caller: str) -> wp.vec3:
    arr = np.asarray(value, np.float64).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{caller}: {name} must be three finite numbers, got {value!r}")
    return wp.vec3(*[float(x) for x in arr])


class MonteCarloShader:
    """Per-frame reference shading with one BRDF: BVH refit in place, lighting and BRDF uploaded once.

    Build once, then call :meth:`shade` (a time code) or :meth:`shade_state` (device points and
    normals) every frame; :meth:`shade_points` shades arbitrary receivers such as camera hit
    points against the current BVH.

    Args:
        scene: the :class:`~warpshade.scene.Scene`.
        brdf: a :class:`~warpshade.scene._materials.BRDF` applied to every receiver (an SVBRDF: per texel).
        tint: per-vertex RGB factor ``t``, array-like of shape (vertex_count, 3).
        method: estimator name, one of ``methods`` (BRDF, light and MIS sampling, in that order).
        methods: the caller's names of the three estimators.
        caller: the public function named in error messages.
        eye: viewer position, 3 floats, world; None for a view-independent BRDF (``v = n``).
        lighting: lights (default ``scene.lights``): at most one Environment, any number of
            DistantLight / SphereLight.
        samples: environment rays per receiver, >= 2 (>= 4 for MIS).
        device: Warp device (None = Warp's default).
        seed: random seed.
        vertices: receiver vertex indices (default every vertex).
        workers: CPU launch threads (default: every core on the CPU device).
        offset: shadow-ray origin offset along the normal, world units (default: the BVH's).
        bounces: diffuse bounces of the indirect light, 0..MAX_BOUNCES (0 = direct light only);
            the surfaces reflect with the Lambert BRDF of ``scene.albedo`` (front faces only).
        roughness: per-vertex microfacet alpha overriding ``brdf.roughness`` (GGX / Beckmann only),
            shape (vertex_count,), values in (0, 2]; None (default) shades every vertex with
            ``brdf`` unchanged. Used by :meth:`shade_state`; :meth:`shade_points` takes its own.
        tangents: the tangent direction of an anisotropic BRDF per vertex for :meth:`shade_state`:
            ``"uv"`` (the meshes' UV tangents of each frame, :mod:`warpshade.geometry._uv_tangents`),
            3 floats (one world direction) or (vertex_count, 3); None: the BRDF's own (+x).

    Attributes:
        bvh: :class:`~warpshade.geometry._bvh.Visibility` of the scene (refit per frame).
        lighting: :class:`DeviceLighting`.
        surfaces: :class:`DiffuseSurfaces` the paths bounce off (vertex normals of the frame
            last given to :meth:`update`, ``scene.albedo``).
        brdf: the uploaded :class:`~warpshade.scene._materials_warp.BRDFParams` (of the first pass).
        passes: ``(BRDFParams, RGB weights)`` per shading pass: one for an analytic BRDF, one per
            table channel for a tabulated one (:func:`~warpshade.scene._materials_warp.upload_brdf_passes`).
        tint: per-vertex tint, wp.array(vec3), shape (vertex_count,).
        roughness: per-vertex alpha, wp.array(float), shape (vertex_count,), or empty (uniform).
        texels: an SVBRDF's texel per vertex (flat index), wp.array(int32), or None (other BRDFs).
        radiance, stderr: per-receiver outputs, wp.array(vec3), shape (receiver_count,).
    """

    def __init__(self, scene, brdf, tint, method: str, methods: tuple[str, ...], caller: str, eye=None, lighting=None,
                 samples: int = 256, device=None, seed: int = 0, vertices=None, workers=None, offset=None,
                 bounces: int = 0, roughness=None, tangents=None):
        self.caller = caller
        self.strategy = strategy_index(method, methods, caller)
        self.bounces = check_bounces(bounces, caller)
        self.method = method
        self.scene = scene
        self.device = resolve_device(device)
        self.passes = upload_surface_passes(brdf, self.device, caller, roughness, tangents)
        self.brdf = self.passes[0][0]
        self.has_eye = 0 if eye is None else 1
        self.eye = wp.vec3(0.0) if eye is None else _vec3(eye, "eye", caller)
        self.lighting = upload_lighting(scene.lights if lighting is None else lighting, self.device)
        self.replicates, self.points_per_replicate = _sampling_plan(samples, self.strategy, self.lighting.has_environment, caller)
        if not (self.lighting.has_environment or self.lighting.has_area_lights):
            self.replicates, self.points_per_replicate = 1, 1  # only delta lights: nothing to sample
        self.samples = int(samples)
        self.seed = int(seed)
        self.workers = (cpu_workers() if self.device.is_cpu else 1) if workers is None else max(1, int(workers))
        self.bvh = Visibility.from_scene(scene, device=self.device, offset=offset)
        self.vertices = receiver_indices(vertices, scene.vertex_count)
        self.receivers = wp.array(self.vertices.astype(np.int32), dtype=wp.int32, device=self.device)
        tint = np.broadcast_to(np.asarray(tint, np.float32).reshape(-1, 3), (scene.vertex_count, 3))
        self.tint = wp.array(np.ascontiguousarray(tint), dtype=wp.vec3, device=self.device)
        self._no_roughness = wp.zeros(0, dtype=float, device=self.device)
        self._no_tangents = wp.zeros(0, dtype=wp.vec3, device=self.device)
        self.texels = surface_texels(brdf, scene, self.device)
        self.roughness = self._no_roughness if roughness is None else self.upload_roughness(roughness, scene.vertex_count, "roughness")
        self._uv_tangents = None
        self.tangents = None
        if isinstance(tangents, str):
            from ..geometry._uv_tangents import UVTangents

            if tangents != "uv" or all(m.uvs is None for m in scene.meshes):
                raise ValueError(f"{caller}: tangents must be 'uv' (on a scene with UVs), 3 floats or (vertex_count, 3) rows, "
                                 f"got {tangents!r}")
            self.upload_tangents(np.ones((1, 3)), 1)  # refuses an isotropic BRDF
            self._uv_tangents = UVTangents.from_scene(scene, self.device)
            self.tangents = wp.zeros(scene.vertex_count, dtype=wp.vec3, device=self.device)
        elif tangents is not None:
            arr = np.asarray(tangents, np.float64)
            arr = np.broadcast_to(arr, (scene.vertex_count, 3)) if arr.shape == (3,) else arr
            self.tangents = self.upload_tangents(arr, scene.vertex_count)
        self.radiance = wp.zeros(self.vertices.shape[0], dtype=wp.vec3, device=self.device)
        self.stderr = wp.zeros(self.vertices.shape[0], dtype=wp.vec3, device=self.device)
        self.surfaces = DiffuseSurfaces()
        self.surfaces.indices = self.bvh.mesh.indices
        self.surfaces.normals = wp.zeros(scene.vertex_count, dtype=wp.vec3, device=self.device)
        albedo = check_albedo(scene.albedo, scene.vertex_count, caller) if self.bounces > 0 else scene.albedo
        self.surfaces.albedo = wp.array(albedo, dtype=wp.vec3, device=self.device)
        self.surfaces.lambert = upload_brdf(Lambert(1.0))
        self._has_surface_normals = False
        self.frame = None

    def update(self, points, normals) -> None:
        """Refit the BVH to the frame's ``points`` and keep its vertex ``normals`` for the bounces.

        Args:
            points, normals: positions and unit normals of every scene vertex, wp.array(vec3),
                shape (vertex_count,), world space.
        """
        self.bvh.update(points)
        if self.bounces > 0:
            wp.copy(self.surfaces.normals, normals)
            self._has_surface_normals = True

    def upload_roughness(self, values, count: int, name: str = "roughness"):
        """Validate per-point microfacet alpha (:func:`~warpshade.scene._materials_warp.check_roughness`)
        and return it as wp.array(float) of shape (count,) on the shader's device.

        Raises:
            ValueError: naming ``name``: the BRDF has no roughness, the shape is not (count,), or
                a value is not finite or outside (0, 2].
        """
        arr = check_roughness(values, count, self.brdf, name, self.caller)
        if isinstance(values, wp.array) and values.dtype == wp.float32 and values.device == self.device:
            return values
        return wp.array(arr, dtype=float, device=self.device)

    def upload_tangents(self, values, count: int, name: str = "tangents"):
        """Validate per-point tangent directions (finite, nonzero, shape (count, 3)) for an
        anisotropic BRDF and return them as wp.array(vec3) on the shader's device.

        Raises:
            ValueError: naming ``name``: the BRDF is isotropic, a bad shape or a bad value.
        """
        if self.brdf.model not in ANISOTROPIC_MODELS:
            raise ValueError(f"{self.caller}: {name} orient an anisotropic BRDF, but the BRDF is "
                             f"{BRDF_MODELS[self.brdf.model]!r}")
        arr = values.numpy() if isinstance(values, wp.array) else np.asarray(values, np.float64)
        if arr.shape != (count, 3):
            raise ValueError(f"{self.caller}: {name} must have shape ({count}, 3), got {arr.shape}")
        if not np.all(np.isfinite(arr)) or np.any(np.linalg.norm(arr, axis=1) == 0.0):
            raise ValueError(f"{self.caller}: {name} must be finite and nonzero")
        if isinstance(values, wp.array) and values.dtype == wp.vec3 and values.device == self.device:
            return values
        return wp.array(np.ascontiguousarray(arr, np.float32), dtype=wp.vec3, device=self.device)

    def shade_points(self, points, normals, tint, receivers, radiance, stderr, seed=None, roughness=None,
                     tangents=None, texels=None) -> None:
        """Shade arbitrary receivers (e.g. camera hit points) against the current BVH.

        With ``bounces > 0`` the paths bounce off the scene as last set by :meth:`update` (or
        :meth:`shade_state`), which must have been called.

        Args:
            points, normals: receiver positions and unit normals, wp.array(vec3), world space.
            tint: per-point RGB factor (the albedo of a diffuse receiver, the specular colour of
                a glossy one), wp.array(vec3), same length.
            receivers: wp.array(int32) of indices into the three arrays above.
            radiance, stderr: outputs, wp.array(vec3), shape (len(receivers),).
            seed: random seed (default: the shader's seed).
            roughness: per-point microfacet alpha overriding the BRDF's (GGX / Beckmann only),
                wp.array(float) or array-like indexed like ``points``, values in (0, 2]
                (validated on the host); None (default): the BRDF's own for every point, with
                results bit-identical to a shader without per-point parameters.
            tangents: per-point tangent directions of an anisotropic BRDF (ward,
                ashikhmin-shirley, beckmann-anisotropic), wp.array(vec3) indexed like ``points``,
                world (projected on each normal's tangent plane in the kernel); None: the BRDF's
                own tangent (+x) for every point.
            texels: an SVBRDF's texel per point (flat index, int, indexed like ``points``; required
                for it, refused otherwise): :func:`~._svbrdf_warp.check_texels`.

        Raises:
            ValueError: a bad ``roughness``, ``tangents`` or ``texels`` (named), or ``bounces > 0`` before :meth:`update`.
        """
        lit = self.lighting
        seed = self.seed if seed is None else int(seed)
        if self.bounces > 0 and not self._has_surface_normals:
            raise ValueError("shade_points with bounces > 0 needs the frame's vertex normals: call update(points, normals) first")
        tex = check_texels(self.brdf, texels, points.shape[0], self.device, self.caller, roughness, tangents)
        if roughness is None:
            rough = self._no_roughness
        elif roughness is self.roughness and roughness.shape[0] == points.shape[0]:
            rough = roughness  # the per-vertex array, validated when the shader was built
        else:
            rough = self.upload_roughness(roughness, points.shape[0], "roughness")
        tang = self._no_tangents if tangents is None else self.upload_tangents(tangents, points.shape[0])

        rays = receivers.shape[0] * self.replicates * self.points_per_replicate * (2 if self.strategy == 2 else 1)
        rays *= 1 + 2 * self.bounces  # each bounce: a continuation ray and the next-event rays
        workers = self.workers if rays >= CHUNK_MIN_RAYS else 1

        def launch(brdf, out_radiance, out_stderr):
            def inputs(start, stop):
                return [
                    self.bvh.id, points, normals, tint, receivers, start, brdf, rough, tang, tex, self.has_eye, self.eye,
                    lit.environment, lit.lights, self.strategy, self.replicates, self.points_per_replicate, self.bounces,
                    self.surfaces, seed, self.bvh.offset, out_radiance, out_stderr,
                ]

            launch_parallel(_estimator_kernel, receivers.shape[0], inputs, self.device, workers)

        if len(self.passes) == 1 and np.all(self.passes[0][1] == 1.0):
            launch(self.brdf, radiance, stderr)
            return
        # one pass per table channel, summed with its RGB weights (module docstring)
        pass_r = wp.empty(radiance.shape[0], dtype=wp.vec3, device=self.device)
        pass_s = wp.empty(radiance.shape[0], dtype=wp.vec3, device=self.device)
        radiance.zero_()
        stderr.zero_()
        for params, weights in self.passes:
            launch(params, pass_r, pass_s)
            wp.launch(_add_pass_kernel, dim=radiance.shape[0], inputs=[pass_r, pass_s, wp.vec3(*[float(w) for w in weights])],
                      outputs=[radiance, stderr], device=self.device)

    def shade_state(self, points, normals) -> None:
        """Refit the BVH to ``points`` and shade the receiver vertices into the outputs.

        Args:
            points, normals: the frame's vertex positions and unit normals, wp.array(vec3),
                shape (vertex_count,), world space.
        """
        self.update(points, normals)
        roughness = self.roughness if self.roughness.shape[0] > 0 else None
        if self._uv_tangents is not None:
            self._uv_tangents.compute(points, normals, self.tangents)
        self.shade_points(points, normals, self.tint, self.receivers, self.radiance, self.stderr, roughness=roughness,
                          tangents=self.tangents, texels=self.texels)

    def shade(self, frame) -> ShadingResult:
        """Evaluate the scene at ``frame`` (a time code), shade and return host copies."""
        state = self.scene.evaluate(frame, device=self.device)
        self.shade_state(state.points, state.normals)
        self.frame = float(state.frame)
        return self.result()

    def result(self) -> ShadingResult:
        """Host copies of the last shading (:class:`ShadingResult`)."""
        return ShadingResult(
            self.radiance.numpy().copy(), self.stderr.numpy().copy(), self.vertices.copy(), self.samples, self.method, self.frame,
            self.seed, self.bounces,
        )
