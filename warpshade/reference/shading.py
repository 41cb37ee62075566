"""Monte Carlo ground truth: outgoing radiance of diffuse receivers under distant and area light.

For a receiver at ``p`` with unit normal ``n`` and albedo ``rho`` (per RGB channel) the
outgoing radiance (the same in every direction for a Lambertian surface) is::

    L_o = rho / pi * integral L_i(s) V(s) max(0, n . s) ds

where ``L_i`` is the environment radiance (bilinear lat-long lookup, :mod:`..scene.lighting_warp`)
plus the analytic lights, and ``V(s)`` is ray-traced against every triangle of the frame
(``wp.mesh_query_ray_anyhit`` from ``p + offset * n``, :mod:`warpshade.geometry.bvh`).

Estimators of the environment term (per sample point):

* ``"cosine"``: one direction from the cosine-weighted hemisphere of ``n``; estimate
  ``rho * L(s) V(s)`` (pdf ``cos / pi``). Exact (zero variance) under a constant, unoccluded sky.
* ``"light"``: one direction from the environment's luminance distribution (pdf ``p_env``);
  estimate ``rho / pi * L V max(0, n.s) / p_env``.
* ``"mis"``: one direction from each, combined with the balance heuristic
  (``f / (p_cos + p_env)`` for each), i.e. two rays per sample point.

Analytic lights, added to every iteration: a :class:`~..scene.lighting.DistantLight` with
``angle_deg == 0`` is a delta light (one deterministic shadow ray, no variance:
``rho / pi * E max(0, n.l) V(l)``); with ``angle_deg > 0`` it is a uniform disc whose direction is
sampled uniformly in its cone (estimate ``rho / pi * E max(0, n.s) V(s)``). A
:class:`~..scene.lighting.SphereLight` is sampled uniformly inside the cone it subtends
(solid angle ``Omega``; estimate ``rho / pi * L_e max(0, n.s) V(s) Omega``), the shadow ray stopping
at the sphere; a receiver inside the sphere gets ``rho * L_e`` unshadowed. Sphere lights are
not part of the BVH (they cast no shadows on the environment).

Sampling is randomised quasi-Monte Carlo: the 2-D sample points of every strategy are an R2
low-discrepancy set (the additive recurrence of the plastic number) under a random
Cranley-Patterson shift, which stratifies the hemisphere and the environment's CDF (penumbrae
converge faster than with independent samples) and stays unbiased. ``samples`` is the number of
environment rays per receiver, split into ``K`` = :data:`REPLICATES` independently shifted
replicates of ``samples / K`` points (``samples / 2K`` for "mis", which casts two rays per
point). The reported standard error is ``sqrt(var / K)`` with ``var`` the unbiased variance of
the ``K`` replicate estimates (Welford's running update): the standard deviation of the
returned mean, per channel. Shifts come from a counter-based hash of ``(seed, receiver,
replicate)``, so results are reproducible and independent across seeds.
"""

import numpy as np

from .._wp import resolve_device, wp
from ..geometry.bvh import RAY_MAX_DISTANCE, Visibility
from ..geometry.frames import onb_tangent
from ..scene.lighting import DistantLight, Environment, SphereLight
from ..scene.lighting_warp import EnvironmentMap, disabled_environment, env_pdf, env_radiance, env_sample, upload_environment
from ..transfer.raytrace import CHUNK_MIN_RAYS, default_workers, launch_chunked, receiver_indices

__all__ = [
    "ESTIMATOR_VERSION",
    "METHODS",
    "REPLICATES",
    "AnalyticLights",
    "DeviceLighting",
    "upload_lighting",
    "ShadingResult",
    "ReferenceShader",
    "shade",
]

wp.set_module_options({"enable_backward": False})

#: Environment estimators, in the order of the kernel's ``method`` argument.
METHODS = ("cosine", "light", "mis")

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
    """Lighting uploaded for the reference kernels.

    Attributes:
        environment: :class:`~warpshade.scene.lighting_warp.EnvironmentMap` (disabled if none).
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
    """Upload a list of lights (at most one Environment) for :class:`ReferenceShader`."""
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
def _frame_dir(axis: wp.vec3, x: float, y: float, z: float) -> wp.vec3:
    t = onb_tangent(axis)
    b = wp.cross(axis, t)
    return wp.normalize(x * t + y * b + z * axis)


@wp.func
def _cosine_dir(n: wp.vec3, u1: float, u2: float) -> wp.vec3:
    r = wp.sqrt(u1)
    phi = 2.0 * wp.pi * u2
    return _frame_dir(n, r * wp.cos(phi), r * wp.sin(phi), wp.sqrt(wp.max(0.0, 1.0 - u1)))


@wp.func
def _cone_dir(axis: wp.vec3, cos_half: float, u1: float, u2: float) -> wp.vec3:
    z = 1.0 - u1 * (1.0 - cos_half)
    r = wp.sqrt(wp.max(0.0, 1.0 - z * z))
    phi = 2.0 * wp.pi * u2
    return _frame_dir(axis, r * wp.cos(phi), r * wp.sin(phi), z)


#: Additive recurrence of the plastic number (the "R2" sequence): a 2-D low-discrepancy set for
#: any point count; randomly shifted (Cranley-Patterson) it gives unbiased stratified estimates.
_R2_A1 = wp.constant(0.7548776662466927)
_R2_A2 = wp.constant(0.5698402909980532)


@wp.func
def _r2(j: int, shift: float, a: float) -> float:
    x = float(j) * a + shift
    return x - wp.floor(x)


@wp.kernel
def _shade_kernel(
    mesh_id: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    albedo: wp.array(dtype=wp.vec3),
    receivers: wp.array(dtype=wp.int32),
    receiver_start: int,
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
    v = receivers[r]
    p = points[v]
    n = normals[v]
    rho = albedo[v]
    origin = p + offset * n
    base = int(wp.rand_init(seed, v))

    # Delta distant lights: deterministic, no variance.
    fixed = wp.vec3(0.0)
    for k in range(lights.distant_direction.shape[0]):
        if lights.distant_cos_half[k] >= 1.0:
            l = lights.distant_direction[k]
            c = wp.dot(n, l)
            if c > 0.0:
                if not wp.mesh_query_ray_anyhit(mesh_id, origin, l, _RAY_MAX):
                    fixed += c * lights.distant_irradiance[k]

    mean = wp.vec3(0.0)
    m2 = wp.vec3(0.0)
    for rep in range(replicates):
        # one independent randomised-QMC estimate per replicate: random shifts of the R2 set
        state = wp.rand_init(base, rep)
        s_cos1 = wp.randf(state)
        s_cos2 = wp.randf(state)
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
                    d = _cosine_dir(n, _r2(j, s_cos1, _R2_A1), _r2(j, s_cos2, _R2_A2))
                    if not wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX):
                        if method == 0:
                            acc += env_radiance(env, d)
                        else:
                            c = wp.max(wp.dot(n, d), 0.0)
                            acc += env_radiance(env, d) * (c / wp.pi) / (c / wp.pi + env_pdf(env, d))
                if method != 0:
                    s = env_sample(
                        env, _r2(j, s_env1, _R2_A1), _r2(j, s_env2, _R2_A2), _r2(j, s_env3, _R2_A1), _r2(j, s_env4, _R2_A2)
                    )
                    d = wp.vec3(s[0], s[1], s[2])
                    c = wp.dot(n, d)
                    if c > 0.0 and s[3] > 0.0:
                        if not wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX):
                            denom = s[3]
                            if method == 2:
                                denom = s[3] + c / wp.pi
                            acc += env_radiance(env, d) * (c / wp.pi) / denom
            for k in range(lights.distant_direction.shape[0]):
                cos_half = lights.distant_cos_half[k]
                if cos_half < 1.0:
                    # a per-light offset decorrelates the lights' point sets
                    u1 = _r2(j, s_area1 + 0.318 * float(k), _R2_A1)
                    u2 = _r2(j, s_area2 + 0.618 * float(k), _R2_A2)
                    d = _cone_dir(lights.distant_direction[k], cos_half, u1, u2)
                    c = wp.dot(n, d)
                    if c > 0.0:
                        if not wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX):
                            acc += lights.distant_irradiance[k] * (c / wp.pi)
            for k in range(lights.sphere_position.shape[0]):
                to_centre = lights.sphere_position[k] - origin
                dist = wp.length(to_centre)
                radius = lights.sphere_radius[k]
                u1 = _r2(j, s_area1 + 0.414 * float(k + 1), _R2_A1)
                u2 = _r2(j, s_area2 + 0.732 * float(k + 1), _R2_A2)
                if dist <= radius:
                    acc += lights.sphere_radiance[k]
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
                            acc += lights.sphere_radiance[k] * (c * solid / wp.pi)
        x = wp.cw_mul(rho, acc) / float(points_per_replicate)
        delta = x - mean
        mean += delta / float(rep + 1)
        m2 += wp.cw_mul(delta, x - mean)

    radiance[r] = mean + wp.cw_mul(rho, fixed) / wp.pi
    if replicates > 1:
        var = m2 / float((replicates - 1) * replicates)
        stderr[r] = wp.vec3(wp.sqrt(wp.max(var[0], 0.0)), wp.sqrt(wp.max(var[1], 0.0)), wp.sqrt(wp.max(var[2], 0.0)))
    else:
        stderr[r] = wp.vec3(0.0)


class ShadingResult:
    """Reference shading of the receivers of one frame (NumPy, host memory).

    Attributes:
        radiance: outgoing radiance, shape (receiver_count, 3), float32, linear RGB.
        stderr: its Monte Carlo standard error, shape (receiver_count, 3), float32.
        vertices: receiver vertex indices (rows), shape (receiver_count,), int64.
        samples, method, frame, seed: how it was computed.
    """

    def __init__(self, radiance, stderr, vertices, samples, method, frame, seed):
        self.radiance = radiance
        self.stderr = stderr
        self.vertices = vertices
        self.samples = samples
        self.method = method
        self.frame = frame
        self.seed = seed

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self.radiance, dtype=dtype)

    def __repr__(self) -> str:
        return f"ShadingResult(receivers={self.radiance.shape[0]}, samples={self.samples}, method={self.method!r})"


#: Independent randomised-QMC replicates per receiver (the standard error is their spread).
REPLICATES = 16
#: Bumped whenever the estimator changes, so cached ground truth is recomputed.
ESTIMATOR_VERSION = 2


def _sampling_plan(samples: int, method: str, has_environment: bool) -> tuple[int, int]:
    """(replicates, points per replicate) for ``samples`` environment rays per receiver."""
    if method not in METHODS:
        raise ValueError(f"reference.shade: method must be one of {METHODS}, got {method!r}")
    if not isinstance(samples, (int, np.integer)) or samples < 2:
        raise ValueError(f"reference.shade: samples must be an integer >= 2, got {samples!r}")
    per_point = 2 if (method == "mis" and has_environment) else 1
    count = int(samples) // per_point
    if count < 2:
        raise ValueError(f"reference.shade: method 'mis' needs samples >= 4, got {samples}")
    replicates = min(REPLICATES, count)
    return replicates, max(1, count // replicates)


class ReferenceShader:
    """Per-frame reference shading with an in-place BVH refit and uploaded lighting.

    Build once (scene, lighting, samples, method), then call :meth:`shade` (a time code) or
    :meth:`shade_state` (device points and normals) every frame; :meth:`shade_points` shades
    arbitrary receivers such as camera hit points against the current BVH.

    Attributes:
        bvh: :class:`~warpshade.geometry.bvh.Visibility` of the scene (refit per frame).
        lighting: :class:`DeviceLighting`.
        radiance, stderr: per-vertex outputs, wp.array(vec3), shape (receiver_count,).
    """

    def __init__(self, scene, lighting=None, samples: int = 256, method: str = "mis", device=None, seed: int = 0, vertices=None, workers=None, offset=None):
        self.scene = scene
        self.device = resolve_device(device)
        self.lighting = upload_lighting(scene.lights if lighting is None else lighting, self.device)
        self.method = method
        self.replicates, self.points_per_replicate = _sampling_plan(samples, method, self.lighting.has_environment)
        self.samples = int(samples)
        if not (self.lighting.has_environment or self.lighting.has_area_lights):
            self.replicates, self.points_per_replicate = 1, 1  # only delta lights: nothing to sample
        self.seed = int(seed)
        self.workers = default_workers(self.device) if workers is None else max(1, int(workers))
        self.bvh = Visibility.from_scene(scene, device=self.device, offset=offset)
        self.vertices = receiver_indices(vertices, scene.vertex_count)
        self.receivers = wp.array(self.vertices.astype(np.int32), dtype=wp.int32, device=self.device)
        self.albedo = wp.array(np.asarray(scene.albedo, np.float32).reshape(-1, 3), dtype=wp.vec3, device=self.device)
        self.radiance = wp.zeros(self.vertices.shape[0], dtype=wp.vec3, device=self.device)
        self.stderr = wp.zeros(self.vertices.shape[0], dtype=wp.vec3, device=self.device)
        self.frame = None

    def shade_points(self, points, normals, albedo, receivers, radiance, stderr, seed=None) -> None:
        """Shade arbitrary receivers (e.g. camera hit points) against the current BVH.

        Args:
            points, normals: receiver positions and unit normals, wp.array(vec3), world space.
            albedo: wp.array(vec3), same length.
            receivers: wp.array(int32) of indices into the three arrays above.
            radiance, stderr: outputs, wp.array(vec3), shape (len(receivers),).
            seed: random seed (default: the shader's seed).
        """
        lighting = self.lighting
        method = METHODS.index(self.method)
        seed = self.seed if seed is None else int(seed)

        def inputs(start):
            return [
                self.bvh.id, points, normals, albedo, receivers, start, lighting.environment, lighting.lights,
                method, self.replicates, self.points_per_replicate, seed, self.bvh.offset, radiance, stderr,
            ]

        rays = receivers.shape[0] * self.replicates * self.points_per_replicate * (2 if self.method == "mis" else 1)
        workers = self.workers if rays >= CHUNK_MIN_RAYS else 1
        launch_chunked(_shade_kernel, receivers.shape[0], inputs, self.device, workers)

    def shade_state(self, points, normals) -> None:
        """Refit the BVH to ``points`` and shade the receiver vertices into the outputs."""
        self.bvh.update(points)
        self.shade_points(points, normals, self.albedo, self.receivers, self.radiance, self.stderr)

    def shade(self, frame) -> ShadingResult:
        """Evaluate the scene at ``frame``, shade and return host copies."""
        state = self.scene.evaluate(frame, device=self.device)
        self.shade_state(state.points, state.normals)
        self.frame = float(state.frame)
        return self.result()

    def result(self) -> ShadingResult:
        return ShadingResult(
            self.radiance.numpy().copy(), self.stderr.numpy().copy(), self.vertices.copy(), self.samples, self.method, self.frame, self.seed
        )


def shade(scene, frame, lighting=None, samples: int = 256, device=None, method: str = "mis", seed: int = 0, vertices=None, workers=None) -> ShadingResult:
    """Ray-traced ground-truth radiance of every (or the selected) vertex at one frame.

    Args:
        scene: :class:`~warpshade.scene.Scene`; albedo is ``scene.albedo``.
        frame: time code (one of ``scene.frames``).
        lighting: a list of lights (at most one :class:`Environment`, any number of
            :class:`DistantLight` / :class:`SphereLight`), a single light, or None for ``scene.lights``.
        samples: environment rays per receiver (see module docstring), >= 2 (>= 4 for "mis").
        device: Warp device (None = Warp's default).
        method: "cosine", "light" (environment importance sampling) or "mis".
        seed: random seed.
        vertices: receiver vertex indices (default every vertex).
        workers: CPU launch threads (default: every core on the CPU device).

    Returns:
        :class:`ShadingResult`: ``radiance`` and ``stderr``, shape (receiver_count, 3), float32,
        linear RGB; ``numpy.asarray(result)`` is the radiance.
    """
    return ReferenceShader(scene, lighting, samples, method, device, seed, vertices, workers).shade(frame)
