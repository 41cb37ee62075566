"""Interreflected diffuse transfer: per-vertex, per-channel SH transfer with k diffuse bounces.

For a receiver vertex ``v`` with position ``p``, unit normal ``n`` and RGB albedo ``rho_v``, lit
by distant radiance with world-frame SH coefficients ``L_c`` per channel ``c``, the outgoing
radiance is ``L_o(v) = rho_v,c / pi * dot(L_c, t_v,c)``. The transfer after ``b`` bounces is
(Sloan et al. 2002, interreflected transfer)::

    t^(0)_v,c = t0_v = integral V(s) max(0, n . s) y(s) ds            (the direct transfer)
    t^(b)_v,c = t0_v + integral_{occluded s} (rho_q,c / pi) t^(b-1)_q,c max(0, n . s) ds

with ``q`` the closest hit of the ray from ``p + offset * n`` toward ``s``. The hit's albedo
``rho_q`` and transfer ``t^(b-1)_q`` are the barycentric interpolations of its triangle's vertex
values. Only the front face of a triangle (the side its counter-clockwise normal points to, the
side vertex normals point to) reflects: a ray that hits a back face contributes nothing -- the
direction counts as occluded and dark, as inside a closed object. No albedo and no ``1 / pi``
are folded into ``t`` (the same convention as the direct transfer), so ``k = 0`` is the direct
transfer broadcast to the three channels, exactly.

Estimator: the integrals are sums over the same per-vertex randomly rotated spherical Fibonacci
rays as the direct transfer (:mod:`warpshade.transfer._raytrace`; weight ``4 pi / samples``), and
only rays above the receiver's horizon are traced (the cosine vanishes below). Every bounce
gathers the previous bounce's transfer of the whole mesh at the hit points (``wp.mesh_query_ray``,
closest hit: face and barycentrics), so bounces ``1 .. k - 1`` are computed at every vertex and
the last one at the receivers only. Because a vertex reuses its rays at every bounce, a path
that returns to a vertex (``v -> q -> v``) sees the same rays twice; the bias this correlation
adds is of the order of the squared quadrature error and vanishes as ``samples`` grows.

Limits: the transfer is per vertex, and a hit reads its triangle's vertex values linearly, while
a path tracer evaluates the hit point itself; the difference is O(h^2) where the radiance is
smooth. A vertex that lies on another surface (an unwelded contact line, a plate resting on
another) starts its rays on that surface and is mostly self-occluded: its dark transfer is then
interpolated across its triangles, an O(h) darkening near contact lines that the path-traced
reference (:func:`warpshade.reference.shade` with ``bounces``) does not have.

Energy: with albedo below 1 the bounce increments shrink geometrically
(``|t^(b+1) - t^(b)| <= rho_max * c * |t^(b) - t^(b-1)|``, ``c = (4 / S) sum max(0, n . s)``
the cosine quadrature of the rays, ~1), so ``t^(k)`` converges as ``k`` grows; with albedo 1 in
a closed scene it grows at most linearly in ``k`` and stays finite.
"""

import functools

import numpy as np

from .._wp import launch_parallel, wp
from ..basis.sh_warp import sh_kernels
from ..geometry._bvh import RAY_MAX_DISTANCE, Visibility
from ._raytrace import CHUNK_MIN_RAYS, PROGRESS_BATCH_RAYS, TransferTracer, random_rotation, receiver_indices

__all__ = [
    "check_albedo",
    "check_bounces",
    "hit_corners",
    "hit_weights",
    "interpolate_vec3",
]

wp.set_module_options({"enable_backward": False})

#: Most diffuse bounces a transfer bake or a reference path may ask for (64 bounces of albedo
#: 0.9 leave 0.1% of the energy of the series; beyond that the request is a mistake).
MAX_BOUNCES = 64

_RAY_MAX = wp.constant(RAY_MAX_DISTANCE)


def check_bounces(bounces, caller: str) -> int:
    """``bounces`` as an int in ``0..MAX_BOUNCES`` (ValueError naming ``caller`` otherwise)."""
    if isinstance(bounces, bool) or not isinstance(bounces, (int, np.integer)) or not 0 <= int(bounces) <= MAX_BOUNCES:
        raise ValueError(f"{caller}: bounces must be an integer in 0..{MAX_BOUNCES}, got {bounces!r}")
    return int(bounces)


def check_albedo(albedo, vertex_count: int, caller: str) -> np.ndarray:
    """Per-vertex RGB albedo, shape (vertex_count, 3), float32, finite and >= 0.

    Args:
        albedo: array-like of shape (vertex_count, 3) or (3,) (one colour for every vertex).
    """
    a = np.asarray(albedo, dtype=np.float64)
    if a.shape == (3,):
        a = np.broadcast_to(a, (vertex_count, 3))
    if a.shape != (vertex_count, 3):
        raise ValueError(f"{caller}: albedo must have shape ({vertex_count}, 3) or (3,), got {a.shape}")
    if not np.all(np.isfinite(a)) or np.any(a < 0.0):
        raise ValueError(f"{caller}: albedo must be finite and >= 0")
    return np.ascontiguousarray(a, dtype=np.float32)


@wp.func
def hit_corners(indices: wp.array(dtype=wp.int32), face: int) -> wp.vec3i:
    """Vertex indices of triangle ``face`` of a ``wp.Mesh`` (its flat ``indices`` array)."""
    return wp.vec3i(indices[3 * face], indices[3 * face + 1], indices[3 * face + 2])


@wp.func
def hit_weights(u: float, v: float) -> wp.vec3:
    """Weights of a hit's three corners from ``wp.mesh_query_ray``'s barycentrics
    (``hit = u p0 + v p1 + (1 - u - v) p2``), clamped so that a sliver never extrapolates."""
    b0 = wp.clamp(u, 0.0, 1.0)
    b1 = wp.clamp(v, 0.0, 1.0 - b0)
    return wp.vec3(b0, b1, 1.0 - b0 - b1)


@wp.func
def interpolate_vec3(values: wp.array(dtype=wp.vec3), corners: wp.vec3i, weights: wp.vec3) -> wp.vec3:
    """``sum_k weights[k] * values[corners[k]]``: a per-vertex quantity at a hit point."""
    return weights[0] * values[corners[0]] + weights[1] * values[corners[1]] + weights[2] * values[corners[2]]


@functools.lru_cache(maxsize=None)
def _bounce_kernel(order: int):
    """One gather bounce, specialised to an SH order (cached per order)."""
    sh = sh_kernels(order)
    vec_t = sh.vec
    sh_load = sh.load
    sh_store = sh.store

    @wp.kernel(enable_backward=False, module="unique")
    def bounce_kernel(
        mesh_id: wp.uint64,
        indices: wp.array(dtype=wp.int32),
        points: wp.array(dtype=wp.vec3),
        normals: wp.array(dtype=wp.vec3),
        albedo: wp.array(dtype=wp.vec3),
        receivers: wp.array(dtype=wp.int32),
        receiver_start: int,
        samples: wp.array(dtype=wp.vec3),
        seed: int,
        offset: float,
        direct: wp.array2d(dtype=wp.float32),
        previous: wp.array2d(dtype=wp.float32),
        out: wp.array2d(dtype=wp.float32),
    ):
        # direct: (V, C) by vertex; previous: (3 V, C), row 3 v + c; out: (3 R, C), row 3 r + c
        r = receiver_start + wp.tid()
        v = receivers[r]
        n = normals[v]
        origin = points[v] + offset * n
        rot = random_rotation(seed, v)
        acc_r = vec_t()
        acc_g = vec_t()
        acc_b = vec_t()
        for s in range(samples.shape[0]):
            d = rot * samples[s]
            c = wp.dot(n, d)
            if c > 0.0:
                q = wp.mesh_query_ray(mesh_id, origin, d, _RAY_MAX)
                if q.result and q.sign > 0.0:
                    corners = hit_corners(indices, q.face)
                    weights = hit_weights(q.u, q.v)
                    rho = c * interpolate_vec3(albedo, corners, weights)
                    i0 = 3 * corners[0]
                    i1 = 3 * corners[1]
                    i2 = 3 * corners[2]
                    b0 = weights[0]
                    b1 = weights[1]
                    b2 = weights[2]
                    if rho[0] != 0.0:
                        acc_r += rho[0] * (b0 * sh_load(previous, i0) + b1 * sh_load(previous, i1) + b2 * sh_load(previous, i2))
                    if rho[1] != 0.0:
                        acc_g += rho[1] * (b0 * sh_load(previous, i0 + 1) + b1 * sh_load(previous, i1 + 1) + b2 * sh_load(previous, i2 + 1))
                    if rho[2] != 0.0:
                        acc_b += rho[2] * (b0 * sh_load(previous, i0 + 2) + b1 * sh_load(previous, i1 + 2) + b2 * sh_load(previous, i2 + 2))
        # (4 pi / S) per ray times the 1 / pi of the hit's Lambert BRDF
        weight = 4.0 / float(samples.shape[0])
        t0 = sh_load(direct, v)
        sh_store(out, 3 * r, t0 + weight * acc_r)
        sh_store(out, 3 * r + 1, t0 + weight * acc_g)
        sh_store(out, 3 * r + 2, t0 + weight * acc_b)

    return bounce_kernel


def _broadcast_rows(receivers, direct, out, device) -> None:
    """``out[3 r + c] = direct[receivers[r]]`` for the three channels c (the k = 0 transfer)."""
    if receivers.shape[0]:
        wp.launch(_broadcast_kernel, dim=(receivers.shape[0], direct.shape[1]), inputs=[receivers, direct, out], device=device)


@wp.kernel
def _broadcast_kernel(receivers: wp.array(dtype=wp.int32), direct: wp.array2d(dtype=wp.float32), out: wp.array2d(dtype=wp.float32)):
    """``out[3 r + c, i] = direct[receivers[r], i]`` for the three channels c."""
    r, i = wp.tid()
    x = direct[receivers[r], i]
    out[3 * r, i] = x
    out[3 * r + 1, i] = x
    out[3 * r + 2, i] = x


class InterreflectionTracer:
    """Per-frame interreflected transfer on the device (preallocated buffers, BVH refit in place).

    The direct transfer of every vertex is traced by an inner :class:`TransferTracer` (world
    frame), then ``bounces`` gather passes (module docstring) run over the whole mesh, the last
    over the receivers only.

    Args:
        scene: a :class:`~warpshade.scene.Scene`.
        order: SH order n (n*n coefficients), 1..MAX_KERNEL_ORDER.
        samples: rays per vertex (the direct transfer's randomly rotated Fibonacci set, reused
            by every bounce).
        bounces: diffuse bounces k, 0..:data:`MAX_BOUNCES` (0 = the direct transfer per channel).
        albedo: per-vertex RGB albedo of the reflecting surfaces, (vertex_count, 3) or (3,),
            linear, >= 0 (default ``scene.albedo``).
        vertices: receiver vertex indices (default every vertex).
        device, seed, workers, chunks, offset, chunk_min_rays, below_horizon, bvh, progress: as
            :class:`TransferTracer` (``below_horizon`` only changes the direct visibility).

    Attributes:
        direct: the inner :class:`TransferTracer` over every vertex (its ``transfer_sh`` is t0).
        albedo: wp.array(vec3), shape (vertex_count,).
        transfer_rgb: wp.array2d(float32), shape (3 * receiver_count, order**2); row ``3 r + c``
            is receiver ``r``'s transfer in channel ``c`` (world frame, no albedo, no 1/pi).
    """

    def __init__(self, scene, order: int, samples: int, bounces: int, albedo=None, vertices=None, device=None,
                 seed: int = 0, workers: int | None = None, chunks: int | None = None, offset: float | None = None,
                 chunk_min_rays: int = CHUNK_MIN_RAYS, below_horizon: str = "traced", bvh: Visibility | None = None,
                 progress: bool = False):
        self.bounces = check_bounces(bounces, "transfer")
        self.direct = TransferTracer(scene, order, samples, space="world", device=device, seed=seed, workers=workers,
                                     chunks=chunks, offset=offset, chunk_min_rays=chunk_min_rays,
                                     below_horizon=below_horizon, bvh=bvh, progress=progress)
        self.scene = scene
        self.device = self.direct.device
        self.order = self.direct.order
        self.samples = self.direct.samples
        self.seed = self.direct.seed
        self.progress = bool(progress)
        self.vertices = receiver_indices(vertices, scene.vertex_count)
        self.receivers = wp.array(self.vertices.astype(np.int32), dtype=wp.int32, device=self.device)
        rgb = check_albedo(scene.albedo if albedo is None else albedo, scene.vertex_count, "transfer")
        self.albedo = wp.array(rgb, dtype=wp.vec3, device=self.device)
        n2 = self.order * self.order
        count = scene.vertex_count
        # ping-pong buffers over every vertex for the bounces before the last
        self._buffers = [wp.zeros((3 * count, n2), dtype=wp.float32, device=self.device) for _ in range(2 if self.bounces > 1 else 1)]
        self.transfer_rgb = wp.zeros((3 * self.receiver_count, n2), dtype=wp.float32, device=self.device)
        self._kernel = _bounce_kernel(self.order)
        self.frame = None

    @property
    def receiver_count(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def bvh(self) -> Visibility:
        return self.direct.bvh

    @property
    def offset(self) -> float:
        return self.direct.offset

    def trace(self, frame) -> None:
        """Evaluate the scene at time code ``frame`` on the device and fill the outputs."""
        state = self.scene.evaluate(frame, device=self.device)
        self.trace_state(state.points, state.normals)
        self.frame = float(state.frame)

    def trace_state(self, points, normals) -> None:
        """Refit the BVH to ``points`` and fill the outputs.

        Args:
            points, normals: positions and unit normals of every scene vertex, wp.array(vec3).
        """
        self.bvh.update(points)
        self.launch(points, normals)

    def launch(self, points, normals) -> None:
        """Direct transfer, then the bounces, against the BVH as it is (no refit).

        Args:
            points, normals: the frame's vertex positions and unit normals, wp.array(vec3).
        """
        self.direct.launch(points, normals)
        direct = self.direct.transfer_sh
        every = self.direct.receivers
        if self.bounces == 0:
            _broadcast_rows(self.receivers, direct, self.transfer_rgb, self.device)
            return
        _broadcast_rows(every, direct, self._buffers[0], self.device)
        bar = None
        if self.progress and not self.device.is_capturing:
            from ..tasks import progress_bar

            bar = progress_bar(total=self.bounces, desc=f"{self.bounces} diffuse bounces, {self.samples} rays per vertex",
                       unit="bounce", leave=False)
        previous = self._buffers[0]
        for b in range(1, self.bounces + 1):
            last = b == self.bounces
            target = self.transfer_rgb if last else self._buffers[b % 2]
            receivers = self.receivers if last else every
            self._launch_bounce(points, normals, receivers, direct, previous, target)
            previous = target
            if bar is not None:
                wp.synchronize_device(self.device)
                bar.update(1)
        if bar is not None:
            bar.close()

    def _launch_bounce(self, points, normals, receivers, direct, previous, target) -> None:
        mesh = self.bvh.mesh
        count = receivers.shape[0]

        def inputs(start, stop):
            return [mesh.id, mesh.indices, points, normals, self.albedo, receivers, start, self.direct.sample_directions,
                    self.seed, self.offset, direct, previous, target]

        workers = self.direct.workers if count * self.samples >= self.direct.chunk_min_rays else 1
        if not self.progress or self.device.is_capturing:
            launch_parallel(self._kernel, count, inputs, self.device, workers, chunks=self.direct.chunks)
            return
        batch = max(1, min(count, PROGRESS_BATCH_RAYS // max(self.samples, 1)))
        for lo in range(0, count, batch):
            launch_parallel(self._kernel, min(batch, count - lo), lambda start, stop, lo=lo: inputs(lo + start, lo + stop),
                            self.device, workers, chunks=self.direct.chunks)

    def transfer_rgb_numpy(self) -> np.ndarray:
        """Host copy of :attr:`transfer_rgb`, shape (receiver_count, 3, order**2), float32."""
        return self.transfer_rgb.numpy().reshape(self.receiver_count, 3, -1).copy()

    def result(self):
        """Host copies: the direct quantities of the receivers plus ``transfer_rgb``
        (:class:`~warpshade.transfer._raytrace.TransferResult`)."""
        full = self.direct.result()
        rows = self.vertices
        full.visibility = full.visibility[rows]
        full.transfer = full.transfer[rows]
        full.ambient_occlusion = full.ambient_occlusion[rows]
        full.vertices = rows.copy()
        full.frame = self.frame
        full.transfer_rgb = self.transfer_rgb_numpy()
        full.bounces = self.bounces
        return full
