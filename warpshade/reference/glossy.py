"""Monte Carlo ground truth for glossy receivers: outgoing radiance towards a viewer.

For a receiver at ``p`` with unit normal ``n``, seen from ``eye`` (``v = normalize(eye - p)``)
and a BRDF ``b`` of :mod:`warpshade.scene.materials` (the same for every receiver), the
reference is::

    L_o(p, v) = c * integral b(v, s) L_i(s) V(s) max(0, n . s) ds

with ``c`` an RGB colour (the ``specular`` colour of the glossy stages), ``L_i`` the environment
plus analytic lights and ``V`` ray-traced visibility, as in :mod:`.shading`. ``L_o = 0`` where the
viewer is below the receiver's horizon.

Environment estimators: ``"brdf"`` samples the BRDF lobe (:func:`~warpshade.scene.materials_warp.brdf_sample`),
``"light"`` the environment's luminance distribution, ``"mis"`` one direction from each, combined
with the balance heuristic (two rays per sample point). Analytic lights: delta distant lights
are evaluated exactly (one shadow ray); disc distant lights and sphere lights are sampled
uniformly in the cone they subtend (estimate ``b L cos V Omega``); a receiver inside a sphere
light sees it everywhere (estimated by BRDF sampling, no rays). Randomised QMC replicates and
standard errors exactly as :func:`warpshade.reference.shade`.
"""

from __future__ import annotations

import numpy as np

from .._wp import resolve_device, wp
from ..geometry.bvh import Visibility
from ..scene.materials_warp import BRDFParams, brdf_eval, brdf_pdf, brdf_sample, upload_brdf
from ..scene.lighting_warp import EnvironmentMap, env_pdf, env_radiance, env_sample
from ..transfer.raytrace import CHUNK_MIN_RAYS, default_workers, launch_chunked, receiver_indices
from .shading import _R2_A1, _R2_A2, _RAY_MAX, AnalyticLights, ShadingResult, _cone_dir, _r2, _sampling_plan, upload_lighting

__all__ = ["GLOSSY_METHODS", "GlossyReferenceShader", "shade_glossy"]

wp.set_module_options({"enable_backward": False})

#: Environment estimators, in the order of the kernel's ``method`` argument.
GLOSSY_METHODS = ("brdf", "light", "mis")


@wp.kernel
def _glossy_kernel(
    mesh_id: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    receivers: wp.array(dtype=wp.int32),
    receiver_start: int,
    eye: wp.vec3,
    color: wp.vec3,
    brdf: BRDFParams,
    env: EnvironmentMap,
    lights: AnalyticLights,
    method: int,
    replicates: int,
    points_per_replicate: int,
    seed: int,
    offset: float,
    radiance: wp.array(dtype=wp.vec3),
    stderr: wp.array(dtype=wp.vec3),
):
    r = receiver_start + wp.tid()
    vi = receivers[r]
    p = points[vi]
    n = normals[vi]
    to_eye = eye - p
    dist_eye = wp.length(to_eye)
    if dist_eye <= 0.0 or wp.dot(n, to_eye) <= 0.0:
        radiance[r] = wp.vec3(0.0)
        stderr[r] = wp.vec3(0.0)
        return
    v = to_eye / dist_eye
    origin = p + offset * n
    base = int(wp.rand_init(seed, vi))

    fixed = wp.vec3(0.0)
    for k in range(lights.distant_direction.shape[0]):
        if lights.distant_cos_half[k] >= 1.0:
            l = lights.distant_direction[k]
            c = wp.dot(n, l)
            if c > 0.0:
                if not wp.mesh_query_ray_anyhit(mesh_id, origin, l, _RAY_MAX):
                    fixed += (brdf_eval(brdf, n, v, l) * c) * lights.distant_irradiance[k]

    mean = wp.vec3(0.0)
    m2 = wp.vec3(0.0)
    for rep in range(replicates):
        state = wp.rand_init(base, rep)
        s_b1 = wp.randf(state)
        s_b2 = wp.randf(state)
        s_env1 = wp.randf(state)
        s_env2 = wp.randf(state)
        s_env3 = wp.randf(state)
        s_env4 = wp.randf(state)
        s_area1 = wp.randf(state)
        s_area2 = wp.randf(state)
        acc = wp.vec3(0.0)
        for j in range(points_per_replicate):
            if env.enabled != 0:
                if method != 1:
                    d = brdf_sample(brdf, n, v, _r2(j, s_b1, _R2_A1), _r2(j, s_b2, _R2_A2))
                    f = brdf_eval(brdf, n, v, d) * wp.max(wp.dot(n, d), 0.0)
                    pdf_b = brdf_pdf(brdf, n, v, d)
                    if f > 0.0 and pdf_b > 0.0:
                        if not wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX):
                            denom = pdf_b
                            if method == 2:
                                denom = pdf_b + env_pdf(env, d)
                            acc += env_radiance(env, d) * (f / denom)
                if method != 0:
                    s = env_sample(
                        env, _r2(j, s_env1, _R2_A1), _r2(j, s_env2, _R2_A2), _r2(j, s_env3, _R2_A1), _r2(j, s_env4, _R2_A2)
                    )
                    d = wp.vec3(s[0], s[1], s[2])
                    f = brdf_eval(brdf, n, v, d) * wp.max(wp.dot(n, d), 0.0)
                    if f > 0.0 and s[3] > 0.0:
                        if not wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX):
                            denom = s[3]
                            if method == 2:
                                denom = s[3] + brdf_pdf(brdf, n, v, d)
                            acc += env_radiance(env, d) * (f / denom)
            for k in range(lights.distant_direction.shape[0]):
                cos_half = lights.distant_cos_half[k]
                if cos_half < 1.0:
                    u1 = _r2(j, s_area1 + 0.318 * float(k), _R2_A1)
                    u2 = _r2(j, s_area2 + 0.618 * float(k), _R2_A2)
                    d = _cone_dir(lights.distant_direction[k], cos_half, u1, u2)
                    c = wp.dot(n, d)
                    if c > 0.0:
                        if not wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX):
                            acc += lights.distant_irradiance[k] * (brdf_eval(brdf, n, v, d) * c)
            for k in range(lights.sphere_position.shape[0]):
                to_centre = lights.sphere_position[k] - origin
                dist = wp.length(to_centre)
                radius = lights.sphere_radius[k]
                u1 = _r2(j, s_area1 + 0.414 * float(k + 1), _R2_A1)
                u2 = _r2(j, s_area2 + 0.732 * float(k + 1), _R2_A2)
                if dist <= radius:
                    d = brdf_sample(brdf, n, v, u1, u2)
                    pdf_b = brdf_pdf(brdf, n, v, d)
                    if pdf_b > 0.0:
                        acc += lights.sphere_radiance[k] * (brdf_eval(brdf, n, v, d) * wp.max(wp.dot(n, d), 0.0) / pdf_b)
                else:
                    axis = to_centre / dist
                    sin_a = radius / dist
                    cos_a = wp.sqrt(wp.max(0.0, 1.0 - sin_a * sin_a))
                    d = _cone_dir(axis, cos_a, u1, u2)
                    c = wp.dot(n, d)
                    if c > 0.0:
                        b = wp.dot(to_centre, d)
                        disc = b * b - (dist * dist - radius * radius)
                        t_hit = b - wp.sqrt(wp.max(disc, 0.0))
                        if not wp.mesh_query_ray_anyhit(mesh_id, origin, d, t_hit):
                            solid = 2.0 * wp.pi * (1.0 - cos_a)
                            acc += lights.sphere_radiance[k] * (brdf_eval(brdf, n, v, d) * c * solid)
        x = wp.cw_mul(color, acc) / float(points_per_replicate)
        delta = x - mean
        mean += delta / float(rep + 1)
        m2 += wp.cw_mul(delta, x - mean)

    radiance[r] = mean + wp.cw_mul(color, fixed)
    if replicates > 1:
        var = m2 / float((replicates - 1) * replicates)
        stderr[r] = wp.vec3(wp.sqrt(wp.max(var[0], 0.0)), wp.sqrt(wp.max(var[1], 0.0)), wp.sqrt(wp.max(var[2], 0.0)))
    else:
        stderr[r] = wp.vec3(0.0)


def _vec3(value, name: str) -> wp.vec3:
    arr = np.asarray(value, np.float64).reshape(-1)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"reference.shade_glossy: {name} must be three finite numbers, got {value!r}")
    return wp.vec3(*[float(x) for x in arr])


class GlossyReferenceShader:
    """Per-frame glossy reference shading (BVH refit in place, lighting and BRDF uploaded once).

    Args:
        scene: the :class:`~warpshade.scene.Scene`.
        brdf: a :class:`~warpshade.scene.materials.BRDF` applied to every receiver.
        eye: viewer position, world (default: the scene camera's position).
        lighting: lights (default ``scene.lights``); samples, method, seed, vertices, workers:
            as :class:`~warpshade.reference.ReferenceShader` (method: "brdf", "light", "mis").
        color: RGB factor of the result.
    """

    def __init__(self, scene, brdf, eye=None, lighting=None, samples: int = 256, method: str = "mis", color=(1.0, 1.0, 1.0),
                 device=None, seed: int = 0, vertices=None, workers=None):
        if method not in GLOSSY_METHODS:
            raise ValueError(f"reference.shade_glossy: method must be one of {GLOSSY_METHODS}, got {method!r}")
        if eye is None:
            if scene.camera is None:
                raise ValueError(f"reference.shade_glossy: scene {scene.source or '<arrays>'} has no camera; pass eye=")
            eye = scene.camera.position
        self.scene = scene
        self.device = resolve_device(device)
        self.brdf = upload_brdf(brdf)
        self.eye = _vec3(eye, "eye")
        self.color = _vec3(color, "color")
        self.lighting = upload_lighting(scene.lights if lighting is None else lighting, self.device)
        self.method = method
        # "mis" casts two rays per sample point, like the diffuse estimator's "mis"
        self.replicates, self.points_per_replicate = _sampling_plan(samples, "mis" if method == "mis" else "cosine",
                                                                     self.lighting.has_environment)
        if not (self.lighting.has_environment or self.lighting.has_area_lights):
            self.replicates, self.points_per_replicate = 1, 1
        self.samples = int(samples)
        self.seed = int(seed)
        self.workers = default_workers(self.device) if workers is None else max(1, int(workers))
        self.bvh = Visibility.from_scene(scene, device=self.device)
        self.vertices = receiver_indices(vertices, scene.vertex_count)
        self.receivers = wp.array(self.vertices.astype(np.int32), dtype=wp.int32, device=self.device)
        self.radiance = wp.zeros(self.vertices.shape[0], dtype=wp.vec3, device=self.device)
        self.stderr = wp.zeros(self.vertices.shape[0], dtype=wp.vec3, device=self.device)
        self.frame = None

    def shade_state(self, points, normals) -> None:
        """Refit the BVH to ``points`` and shade the receiver vertices into the outputs."""
        self.bvh.update(points)
        lit = self.lighting
        method = GLOSSY_METHODS.index(self.method)

        def inputs(start):
            return [self.bvh.id, points, normals, self.receivers, start, self.eye, self.color, self.brdf, lit.environment,
                    lit.lights, method, self.replicates, self.points_per_replicate, self.seed, self.bvh.offset,
                    self.radiance, self.stderr]

        rays = self.receivers.shape[0] * self.replicates * self.points_per_replicate * (2 if self.method == "mis" else 1)
        workers = self.workers if rays >= CHUNK_MIN_RAYS else 1
        launch_chunked(_glossy_kernel, self.receivers.shape[0], inputs, self.device, workers)

    def shade(self, frame) -> ShadingResult:
        """Evaluate the scene at ``frame``, shade and return host copies."""
        state = self.scene.evaluate(frame, device=self.device)
        self.shade_state(state.points, state.normals)
        self.frame = float(state.frame)
        return ShadingResult(self.radiance.numpy().copy(), self.stderr.numpy().copy(), self.vertices.copy(),
                             self.samples, self.method, self.frame, self.seed)


def shade_glossy(scene, frame, brdf, eye=None, lighting=None, samples: int = 256, color=(1.0, 1.0, 1.0), device=None,
                 method: str = "mis", seed: int = 0, vertices=None, workers=None) -> ShadingResult:
    """Ray-traced glossy radiance towards ``eye`` of every (or the selected) vertex at one frame.

    See the module docstring for the integral and the estimators; arguments as
    :class:`GlossyReferenceShader`. Returns a :class:`~warpshade.reference.ShadingResult`.
    """
    return GlossyReferenceShader(scene, brdf, eye, lighting, samples, method, color, device, seed, vertices,
                                 workers).shade(frame)
