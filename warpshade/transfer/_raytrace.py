"""Ray-traced SH visibility, diffuse transfer and ambient occlusion per receiver vertex.

Definitions (per receiver vertex with position ``p``, unit normal ``n``; ``s`` a unit direction;
``V(s)`` = 1 when the ray from ``p + offset * n`` toward ``s`` hits no triangle of the frame,
else 0 -- see :mod:`warpshade.geometry._bvh` for the offset)::

    visibility[i]        v_i = integral V(s) y_i(s') ds                   (full sphere)
    transfer[i]          t_i = integral V(s) max(0, n . s) y_i(s') ds     (no albedo, no 1/pi)
    ambient_occlusion    a   = (1 / pi) integral V(s) max(0, n . s) ds    (1 = unoccluded)

with ``s' = s`` for ``space="world"`` and ``s' = F s`` for ``space="local"``, ``F`` the
per-vertex tangent frame of :mod:`warpshade.geometry._frames` (rows tangent, bitangent, normal).
For a diffuse surface of albedo ``rho`` lit by distant radiance with SH coefficients ``L`` (in
the same space), the outgoing radiance is ``rho / pi * dot(L, t)``; ``a = 2 t_0 / sqrt(pi)``.

Estimator: the integrals are sums over a spherical Fibonacci set of ``samples`` points, rotated
by a uniformly random rotation per vertex (Shoemake's quaternion from a counter-based RNG
seeded with ``(seed, vertex index)``), each with weight ``4 pi / samples``. The rotation
depends on the vertex and the seed only, never on the frame, so a vertex sees the same sample
directions in every frame (temporally stable noise), and the estimate is unbiased over the
random rotation. :func:`sample_rays` returns exactly these rays for external checks.

On the CPU device a launch runs on one thread; :class:`TransferTracer` splits the receivers
into chunks launched from a small thread pool (:func:`warpshade._wp.launch_parallel`).

Ray backends (:mod:`warpshade.geometry._embree`): with ``rays="embree"`` (or
``WARPSHADE_RAYS=embree``) on the CPU, :class:`TransferTracer` generates the same rays in batches
(:func:`sample_rays`' kernel), traces them with Embree and accumulates the same sums from the
answers; Warp's in-kernel any-hit is the default and the only path on CUDA and inside a capture.
"""

import functools
import math
from dataclasses import dataclass

import numpy as np

from .._wp import cpu_workers, launch_parallel, resolve_device, wp
from ..basis import quadrature, sh
from ..basis.sh_warp import MAX_KERNEL_ORDER, SHTables, sh_kernels
from ..geometry._bvh import RAY_MAX_DISTANCE, Visibility
from ..geometry._embree import EmbreeOcclusion, ray_backend
from ..geometry._frames import TangentFrames

__all__ = [
    "CHUNK_MIN_RAYS",
    "random_rotation",
    "receiver_indices",
]

wp.set_module_options({"enable_backward": False})

#: Frames a transfer vector can be expressed in.
SPACES = ("world", "local")

#: Rays per launch of a bake that shows progress (a few tenths of a second on one CPU core).
PROGRESS_BATCH_RAYS = 1 << 22

#: Below this many rays per call a single launch is used even with several workers: the thread
#: pool costs ~0.5 ms per call, ~3% of the ~20 ms such a batch takes on one CPU core.
CHUNK_MIN_RAYS = 65536

#: Rays per batch handed to the Embree backend (32 MiB of origins and directions).
EMBREE_BATCH_RAYS = 1 << 20

_RAY_MAX = wp.constant(RAY_MAX_DISTANCE)


@wp.func
def random_rotation(seed: int, vertex: int) -> wp.mat33:
    """Uniform random rotation of a vertex's sample set (Shoemake 1992), from ``(seed, vertex)``."""
    state = wp.rand_init(seed, vertex)
    u1 = wp.randf(state)
    u2 = wp.randf(state)
    u3 = wp.randf(state)
    a = wp.sqrt(1.0 - u1)
    b = wp.sqrt(u1)
    q = wp.quat(a * wp.sin(2.0 * wp.pi * u2), a * wp.cos(2.0 * wp.pi * u2), b * wp.sin(2.0 * wp.pi * u3), b * wp.cos(2.0 * wp.pi * u3))
    return wp.quat_to_matrix(q)


@wp.func
def _blocked(mesh_id: wp.uint64, origin: wp.vec3, d: wp.vec3, occluded: wp.array2d(dtype=wp.int32), row: int, s: int):
    """Whether ray ``s`` of a receiver is blocked: the answer in ``occluded[row, s]`` when it is
    not empty (traced by another backend), else Warp's any-hit query."""
    if occluded.shape[0] > 0:
        return occluded[row, s] != 0
    return wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX)


@wp.kernel
def _sample_rays_kernel(
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    receivers: wp.array(dtype=wp.int32),
    samples: wp.array(dtype=wp.vec3),
    seed: int,
    offset: float,
    origins: wp.array2d(dtype=wp.vec3),
    directions: wp.array2d(dtype=wp.vec3),
):
    r, s = wp.tid()
    v = receivers[r]
    rot = random_rotation(seed, v)
    origins[r, s] = points[v] + offset * normals[v]
    directions[r, s] = rot * samples[s]


@wp.kernel
def _receiver_rays_kernel(
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    receivers: wp.array(dtype=wp.int32),
    receiver_start: int,
    batch_start: int,
    samples: wp.array(dtype=wp.vec3),
    seed: int,
    offset: float,
    origins: wp.array2d(dtype=wp.vec3),
    directions: wp.array2d(dtype=wp.vec3),
):
    """The rays of :func:`_sample_rays_kernel` for receiver ``receiver_start + tid``, written to
    row ``receiver_start + tid - batch_start`` (one thread per receiver, for chunked launches)."""
    r = receiver_start + wp.tid()
    v = receivers[r]
    rot = random_rotation(seed, v)
    origin = points[v] + offset * normals[v]
    for s in range(samples.shape[0]):
        origins[r - batch_start, s] = origin
        directions[r - batch_start, s] = rot * samples[s]


@wp.kernel
def _visible_count_kernel(
    mesh_id: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    receivers: wp.array(dtype=wp.int32),
    receiver_start: int,
    samples: wp.array(dtype=wp.vec3),
    seed: int,
    offset: float,
    visible: wp.array(dtype=wp.int32),
):
    r = receiver_start + wp.tid()
    v = receivers[r]
    rot = random_rotation(seed, v)
    origin = points[v] + offset * normals[v]
    count = int(0)
    for s in range(samples.shape[0]):
        if not wp.mesh_query_ray_anyhit(mesh_id, origin, rot * samples[s], _RAY_MAX):
            count += 1
    visible[r] = count


@functools.lru_cache(maxsize=None)
def _transfer_kernel(order: int):
    """The per-receiver transfer kernel specialised to an SH order (cached per order).

    A receiver's rays are ``w_s = R d_s`` (``R`` its random rotation, ``d_s`` the tracer's fixed
    set), seen in its SH frame as ``M d_s`` (``M = R``, or ``F R`` in the tangent frame). SH
    rotation commutes with evaluation, ``y(M d) = D(M) y(d)``, so the sums run over the set's
    own SH (``basis``, (samples, order^2), computed once per tracer) and are turned by ``D(M)``
    once per receiver (``sh_rotate`` with ``tables``) instead of evaluating SH per ray."""
    bundle = sh_kernels(order)
    N = bundle.coeff_count
    vec_t = bundle.vec
    sh_load, sh_rotate = bundle.load, bundle.rotate
    INV_PI = 1.0 / math.pi

    @wp.kernel(enable_backward=False, module="unique")
    def transfer_kernel(
        mesh_id: wp.uint64,
        points: wp.array(dtype=wp.vec3),
        normals: wp.array(dtype=wp.vec3),
        frames: wp.array(dtype=wp.mat33),
        use_local: int,
        open_below: int,
        receivers: wp.array(dtype=wp.int32),
        receiver_start: int,
        samples: wp.array(dtype=wp.vec3),
        basis: wp.array2d(dtype=wp.float32),
        tables: SHTables,
        seed: int,
        offset: float,
        visibility: wp.array2d(dtype=wp.float32),
        transfer: wp.array2d(dtype=wp.float32),
        ambient_occlusion: wp.array(dtype=wp.float32),
        occluded: wp.array2d(dtype=wp.int32),
        occluded_start: int,
    ):
        r = receiver_start + wp.tid()
        v = receivers[r]
        n = normals[v]
        origin = points[v] + offset * n
        rot = random_rotation(seed, v)
        to_set = rot  # y(to_set d_s): the SH of ray s in the receiver's frame
        if use_local != 0:
            to_set = frames[v] * rot
        acc_v = vec_t()
        acc_t = vec_t()
        acc_ao = float(0.0)
        for s in range(samples.shape[0]):
            d = rot * samples[s]
            c = wp.dot(n, d)
            if open_below != 0 and c <= 0.0:
                acc_v += sh_load(basis, s)  # below the horizon counts as visible (no ray)
            elif not _blocked(mesh_id, origin, d, occluded, r - occluded_start, s):
                y = sh_load(basis, s)
                acc_v += y
                if c > 0.0:
                    acc_t += c * y
                    acc_ao += c
        acc_v = sh_rotate(acc_v, to_set, tables)
        acc_t = sh_rotate(acc_t, to_set, tables)
        weight = 4.0 * wp.pi / float(samples.shape[0])
        for i in range(N):
            visibility[r, i] = acc_v[i] * weight
            transfer[r, i] = acc_t[i] * weight
        ambient_occlusion[r] = acc_ao * weight * float(INV_PI)

    return transfer_kernel


@dataclass
class TransferResult:
    """Transfer quantities of the receivers of one frame (NumPy, host memory).

    Attributes:
        visibility: SH of V(s), shape (receiver_count, order**2), float32, ``space`` frame.
        transfer: SH of V(s) max(0, n.s), shape (receiver_count, order**2), float32, ``space``
            frame; outgoing radiance = albedo / pi * dot(L, transfer).
        ambient_occlusion: shape (receiver_count,), float32 in [0, 1].
        vertices: receiver vertex indices (rows of the arrays above), shape (receiver_count,), int64.
        order, samples, space, frame, seed, offset: how it was computed.
        transfer_rgb: interreflected transfer per RGB channel after ``bounces`` diffuse bounces
            (:mod:`warpshade.transfer._interreflection`), shape (receiver_count, 3, order**2),
            float32, world frame, no albedo and no 1/pi: outgoing radiance in channel c =
            albedo_c / pi * dot(L_c, transfer_rgb[:, c]). None when ``bounces`` is 0 (then
            :meth:`per_channel` is ``transfer`` broadcast to the channels).
        bounces: diffuse bounces in ``transfer_rgb`` (0: none computed).
    """

    visibility: np.ndarray
    transfer: np.ndarray
    ambient_occlusion: np.ndarray
    vertices: np.ndarray
    order: int
    samples: int
    space: str
    frame: float
    seed: int
    offset: float
    transfer_rgb: np.ndarray | None = None
    bounces: int = 0

    def per_channel(self) -> np.ndarray:
        """Transfer per RGB channel, shape (receiver_count, 3, order**2), float32: ``transfer_rgb``,
        or the direct ``transfer`` broadcast to three channels (a read-only view) without bounces."""
        if self.transfer_rgb is not None:
            return self.transfer_rgb
        return np.broadcast_to(self.transfer[:, None, :], (self.transfer.shape[0], 3, self.transfer.shape[1]))


def _check_args(order, samples, space):
    if not isinstance(order, (int, np.integer)) or not 1 <= int(order) <= MAX_KERNEL_ORDER:
        raise ValueError(f"transfer: order must be an integer in 1..{MAX_KERNEL_ORDER}, got {order!r}")
    if not isinstance(samples, (int, np.integer)) or int(samples) < 1:
        raise ValueError(f"transfer: samples must be a positive integer, got {samples!r}")
    if space not in SPACES:
        raise ValueError(f"transfer: space must be one of {SPACES}, got {space!r}")


def receiver_indices(vertices, vertex_count: int) -> np.ndarray:
    """Validated receiver vertex indices (int64); None means every vertex."""
    if vertices is None:
        return np.arange(vertex_count, dtype=np.int64)
    idx = np.asarray(vertices).reshape(-1)
    if idx.size and not np.issubdtype(idx.dtype, np.integer):
        raise ValueError(f"receiver vertices must be integer indices, got dtype {idx.dtype}")
    idx = idx.astype(np.int64)
    if idx.size and (idx.min() < 0 or idx.max() >= vertex_count):
        raise ValueError(f"receiver vertices index {int(idx.min())}..{int(idx.max())} outside 0..{vertex_count - 1}")
    return idx


class TransferTracer:
    """Per-frame transfer on the device with preallocated outputs and an in-place BVH refit.

    Build once per scene and settings, then call :meth:`trace` (a time code) or
    :meth:`trace_state` (points and normals already on the device) every frame. Outputs are
    overwritten in place.

    Attributes:
        bvh: the :class:`~warpshade.geometry._bvh.Visibility` (wp.Mesh) refit per frame.
        tangent_frames: :class:`~warpshade.geometry._frames.TangentFrames` for ``space="local"``.
        receivers: receiver vertex indices, wp.array(int32), shape (receiver_count,).
        visibility_sh, transfer_sh: wp.array2d(float32), shape (receiver_count, order**2).
        ambient_occlusion: wp.array(float32), shape (receiver_count,).
        rays: the shadow-ray backend, ``"warp"`` or ``"embree"`` (the ``rays`` argument, else
            ``$WARPSHADE_RAYS``; :func:`~warpshade.geometry._embree.ray_backend`).
    """

    def __init__(
        self,
        scene,
        order: int,
        samples: int,
        space: str = "world",
        vertices=None,
        device=None,
        seed: int = 0,
        workers: int | None = None,
        chunks: int | None = None,
        offset: float | None = None,
        chunk_min_rays: int = CHUNK_MIN_RAYS,
        below_horizon: str = "traced",
        bvh: Visibility | None = None,
        progress: bool = False,
        rays: str | None = None,
    ):
        _check_args(order, samples, space)
        if below_horizon not in ("traced", "visible"):
            raise ValueError(f"transfer: below_horizon must be 'traced' or 'visible', got {below_horizon!r}")
        self.below_horizon = below_horizon
        self.progress = bool(progress)
        self.scene = scene
        self.order = int(order)
        self.samples = int(samples)
        self.space = space
        self.seed = int(seed)
        self.device = resolve_device(device)
        self.workers = (cpu_workers() if self.device.is_cpu else 1) if workers is None else max(1, int(workers))
        self.chunks = chunks
        # a BVH of its own (refit by trace_state), or one kept current by others (launch)
        self.bvh = Visibility.from_scene(scene, device=self.device, offset=offset) if bvh is None else bvh
        self.chunk_min_rays = int(chunk_min_rays)
        self.tangent_frames = TangentFrames.from_scene(scene, device=self.device) if space == "local" else None
        self._no_frames = wp.empty(0, dtype=wp.mat33, device=self.device)
        self.vertices = receiver_indices(vertices, scene.vertex_count)
        self.receivers = wp.array(self.vertices.astype(np.int32), dtype=wp.int32, device=self.device)
        directions = quadrature.fibonacci(self.samples).directions
        self.sample_directions = wp.array(directions.astype(np.float32), dtype=wp.vec3, device=self.device)
        # the set's own SH, turned per receiver in the kernel (float64, then rounded once)
        self._sample_basis = wp.array(sh.basis(directions, self.order).astype(np.float32), dtype=wp.float32,
                                      device=self.device)
        self._sh_tables = sh_kernels(self.order).tables(self.device)
        count = self.receiver_count
        n2 = self.order * self.order
        self.visibility_sh = wp.zeros((count, n2), dtype=wp.float32, device=self.device)
        self.transfer_sh = wp.zeros((count, n2), dtype=wp.float32, device=self.device)
        self.ambient_occlusion = wp.zeros(count, dtype=wp.float32, device=self.device)
        self._kernel = _transfer_kernel(self.order)
        self.frame = None
        # bulk shadow rays: Warp's any-hit in the kernel, or Embree on the CPU (module docstring)
        self.rays = ray_backend(rays, self.device)
        self._embree = None
        self._no_occluded = wp.empty((0, 0), dtype=wp.int32, device=self.device)

    @property
    def receiver_count(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def offset(self) -> float:
        return self.bvh.offset

    def trace_state(self, points, normals) -> None:
        """Refit the BVH to ``points`` and fill the outputs.

        Args:
            points: world positions of all scene vertices, wp.array(vec3) on the tracer's device.
            normals: unit world normals, wp.array(vec3), same shape.
        """
        self.bvh.update(points)
        self.launch(points, normals)

    def launch(self, points, normals) -> None:
        """Fill the outputs against the BVH as it is (no refit): kernel launches on fixed
        buffers only, for a recorded frame whose BVH is refit before (a FrameState's).

        Args:
            points, normals: the frame's vertex positions and unit normals, wp.array(vec3).
        """
        frames = self._no_frames
        if self.tangent_frames is not None:
            frames = self.tangent_frames.compute(points, normals)
        use_local = 1 if self.space == "local" else 0
        mesh_id = self.bvh.id

        embree = self.rays == "embree" and not self.device.is_capturing
        if embree:
            if self._embree is None:
                self._embree = EmbreeOcclusion(self.bvh.points.numpy(), self.bvh.faces)
            else:
                self._embree.update(self.bvh.points.numpy())

        def run(lo, count):
            """Receivers ``lo .. lo + count``: their rays traced by Embree first, or in the kernel."""
            occluded, occluded_start = self._no_occluded, 0
            if embree:
                occluded, occluded_start = self._embree_batch(points, normals, lo, count), lo

            def inputs(start, stop):
                return [
                    mesh_id, points, normals, frames, use_local, 1 if self.below_horizon == "visible" else 0,
                    self.receivers, lo + start, self.sample_directions, self._sample_basis, self._sh_tables, self.seed,
                    self.bvh.offset,
                    self.visibility_sh, self.transfer_sh, self.ambient_occlusion, occluded, occluded_start,
                ]

            launch_parallel(self._kernel, count, inputs, self.device, self._launch_workers(), chunks=self.chunks)

        # batches of about PROGRESS_BATCH_RAYS rays, so a long bake shows it is moving; batches of
        # EMBREE_BATCH_RAYS rays for Embree (their rays are held in memory)
        batch_rays = min(PROGRESS_BATCH_RAYS, EMBREE_BATCH_RAYS) if embree else PROGRESS_BATCH_RAYS
        batch = max(1, min(self.receiver_count, batch_rays // max(self.samples, 1)))
        if not self.progress or self.device.is_capturing:
            if not embree:
                run(0, self.receiver_count)
                return
            for lo in range(0, self.receiver_count, batch):
                run(lo, min(batch, self.receiver_count - lo))
            return
        from ..tasks import progress_bar

        with progress_bar(total=self.receiver_count, desc=f"ray tracing {self.samples} rays per vertex", unit="vertex",
                  leave=False) as bar:
            for lo in range(0, self.receiver_count, batch):
                count = min(batch, self.receiver_count - lo)
                run(lo, count)
                wp.synchronize_device(self.device)
                bar.update(count)

    def _embree_batch(self, points, normals, lo: int, count: int):
        """Embree's answers for the rays of receivers ``lo .. lo + count``, wp.array2d(int32),
        shape (count, samples), 1 = blocked (the rays of :func:`sample_rays`)."""
        origins = wp.empty((count, self.samples), dtype=wp.vec3, device=self.device)
        directions = wp.empty((count, self.samples), dtype=wp.vec3, device=self.device)
        launch_parallel(_receiver_rays_kernel, count, lambda start, stop: [
            points, normals, self.receivers, lo + start, lo, self.sample_directions, self.seed, self.bvh.offset,
            origins, directions], self.device, self._launch_workers(), chunks=self.chunks)
        hits = self._embree.occluded(origins.numpy().reshape(-1, 3), directions.numpy().reshape(-1, 3),
                                     unit_directions=True)
        return wp.array(hits.reshape(count, self.samples), dtype=wp.int32, device=self.device)

    def _launch_workers(self) -> int:
        return self.workers if self.receiver_count * self.samples >= self.chunk_min_rays else 1

    def trace(self, frame) -> None:
        """Evaluate the scene at time code ``frame`` on the device and fill the outputs."""
        state = self.scene.evaluate(frame, device=self.device)
        self.trace_state(state.points, state.normals)
        self.frame = float(state.frame)

    def visible_fraction(self, points, normals) -> np.ndarray:
        """Fraction of unoccluded sample rays per receiver (the same rays as the transfer).

        The BVH is *not* refit here; call after :meth:`trace_state` (or :meth:`trace`).

        Returns:
            float64 array, shape (receiver_count,).
        """
        visible = wp.zeros(self.receiver_count, dtype=wp.int32, device=self.device)

        def inputs(start, stop):
            return [self.bvh.id, points, normals, self.receivers, start, self.sample_directions, self.seed, self.bvh.offset, visible]

        launch_parallel(_visible_count_kernel, self.receiver_count, inputs, self.device, self._launch_workers(), chunks=self.chunks)
        return visible.numpy().astype(np.float64) / self.samples

    def result(self) -> TransferResult:
        """Copy the current outputs to host memory."""
        return TransferResult(
            visibility=self.visibility_sh.numpy().copy(),
            transfer=self.transfer_sh.numpy().copy(),
            ambient_occlusion=self.ambient_occlusion.numpy().copy(),
            vertices=self.vertices.copy(),
            order=self.order,
            samples=self.samples,
            space=self.space,
            frame=self.frame,
            seed=self.seed,
            offset=self.bvh.offset,
        )


def sample_rays(scene, frame, samples: int, vertices=None, device=None, seed: int = 0, offset: float | None = None):
    """The exact rays :func:`warpshade.transfer.compute` traces (for cross-checks against other ray tracers).

    Returns:
        ``(origins, directions)``, float32 NumPy arrays of shape (receiver_count, samples, 3),
        world space; origins are already offset along the normal, directions are unit length.
    """
    _check_args(1, samples, "world")
    dev = resolve_device(device)
    state = scene.evaluate(frame, device=dev)
    idx = receiver_indices(vertices, scene.vertex_count)
    if offset is None:
        offset = Visibility.from_scene(scene, device=dev).offset
    receivers = wp.array(idx.astype(np.int32), dtype=wp.int32, device=dev)
    dirs = wp.array(quadrature.fibonacci(int(samples)).directions.astype(np.float32), dtype=wp.vec3, device=dev)
    origins = wp.empty((idx.shape[0], int(samples)), dtype=wp.vec3, device=dev)
    directions = wp.empty((idx.shape[0], int(samples)), dtype=wp.vec3, device=dev)
    if idx.shape[0]:
        wp.launch(
            _sample_rays_kernel,
            dim=(idx.shape[0], int(samples)),
            inputs=[state.points, state.normals, receivers, dirs, int(seed), float(offset), origins, directions],
            device=dev,
        )
    return origins.numpy().reshape(-1, int(samples), 3), directions.numpy().reshape(-1, int(samples), 3)
