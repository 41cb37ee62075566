"""Optional Embree backend for bulk shadow rays on the CPU, and the choice of ray backend.

Work outside a recorded frame -- transfer bakes, visibility training data -- traces millions of
explicit shadow rays. On the CPU those can go to Embree through the ``embreex`` package (the
binding trimesh uses; ``pip install 'warpshade[embree]'``) instead of Warp's
``wp.mesh_query_ray_anyhit``. Warp stays the default and is the only backend on CUDA devices
and inside recorded frames.

Choosing: :func:`ray_backend` resolves a requested name (an argument, else the environment
variable ``WARPSHADE_RAYS``, else ``"warp"``). ``"embree"`` on a CUDA device, or without
``embreex`` installed, falls back to ``"warp"`` with one line on stderr saying why (once per
process and reason).

Same answers: :class:`EmbreeOcclusion` answers the query of
:meth:`warpshade.geometry._bvh.Visibility.occluded` (a hit at ``0 <= t < max_distance`` along the
normalised direction, origins already offset) on the same float32 triangles. The two tracers
use different watertight triangle tests, so rays that graze an edge or a vertex can differ;
``tests/test_ray_backends.py`` bounds the disagreeing fraction by
:data:`BACKEND_DISAGREEMENT_TOLERANCE`.

Both cores: ``embreex`` traces one ray at a time and holds the interpreter lock, so a thread pool
does not help. A large batch (:data:`EMBREE_PARALLEL_MIN_RAYS` rays or more) is split over
spawned worker processes (:func:`warpshade._wp.cpu_workers` of them) that read the triangles and
the rays from shared memory and write their answers there; each keeps its Embree scene until the
points change.
"""

from __future__ import annotations

import itertools
import os
import sys
import threading
from multiprocessing import shared_memory

import numpy as np

from .._wp import cpu_workers, resolve_device
from ._bvh import RAY_MAX_DISTANCE

__all__ = [
    "RAY_BACKENDS",
    "RAYS_ENV",
    "BACKEND_DISAGREEMENT_TOLERANCE",
    "EMBREE_PARALLEL_MIN_RAYS",
    "embree_available",
    "ray_backend",
    "EmbreeOcclusion",
]

#: Names :func:`ray_backend` accepts.
RAY_BACKENDS = ("warp", "embree")

#: Environment variable that picks the bulk ray backend when no argument does.
RAYS_ENV = "WARPSHADE_RAYS"

#: Largest fraction of shadow rays on which Embree and Warp may disagree: both use watertight
#: float32 triangle tests, but different ones, so rays through an edge or a vertex (to float32
#: rounding) can flip. Measured: 0 of 2**20 rays on each bundled scene and on Warp's nonuniform
#: mesh; 3 to 6 of 46080 on a box standing flush on a ground slab (rays grazing the contact edge).
BACKEND_DISAGREEMENT_TOLERANCE = 1.0e-3

#: Below this many rays a batch is traced in this process (a round trip to the workers and the
#: copies into shared memory cost about a millisecond).
EMBREE_PARALLEL_MIN_RAYS = 1 << 17

_said: set[str] = set()


def _say_once(line: str) -> None:
    if line not in _said:
        _said.add(line)
        print(line, file=sys.stderr)


def embree_available() -> bool:
    """True when ``embreex`` can be imported."""
    try:
        import embreex.mesh_construction  # noqa: F401
        import embreex.rtcore_scene  # noqa: F401
    except ImportError:
        return False
    return True


def ray_backend(requested: str | None = None, device=None) -> str:
    """The bulk ray backend to use: ``"warp"`` or ``"embree"``.

    Args:
        requested: a name of :data:`RAY_BACKENDS`; None reads ``$WARPSHADE_RAYS`` (default
            ``"warp"``).
        device: the Warp device the work runs on (None = Warp's default); Embree serves only the
            CPU.

    Returns:
        ``"embree"`` when asked for, on the CPU, with ``embreex`` installed; else ``"warp"``
        (falling back with one line on stderr).

    Raises:
        ValueError: an unknown backend name.
    """
    name = requested if requested is not None else os.environ.get(RAYS_ENV, "") or "warp"
    name = str(name).strip().lower()
    if name not in RAY_BACKENDS:
        source = "rays" if requested is not None else RAYS_ENV
        raise ValueError(f"{source} must be one of {RAY_BACKENDS}, got {name!r}")
    if name == "warp":
        return name
    dev = resolve_device(device)
    if not dev.is_cpu:
        _say_once(f"warpshade: the Embree ray backend serves the CPU only; tracing with Warp on {dev}")
        return "warp"
    if not embree_available():
        _say_once("warpshade: embreex is not installed (pip install 'warpshade[embree]'); tracing with Warp")
        return "warp"
    return name


def _build_scene(points: np.ndarray, faces: np.ndarray):
    from embreex.mesh_construction import TriangleMesh
    from embreex.rtcore_scene import EmbreeScene

    scene = EmbreeScene()
    TriangleMesh(scene, points, faces)
    return scene


def _trace(scene, origins, directions, max_distance: float) -> np.ndarray:
    """int32 (ray_count,): 1 where the ray hits, else 0 (directions are unit length)."""
    hit = scene.run(origins, directions, dists=float(max_distance), query="OCCLUDED")
    return (np.asarray(hit) != -1).astype(np.int32)


# ---- worker processes -----------------------------------------------------------------------
_worker_scene: dict = {"key": None, "scene": None}


def _attach(name: str) -> shared_memory.SharedMemory:
    # spawned workers share the creating process's resource tracker, which holds one entry per
    # block: the creator unlinks it, a worker only closes its view
    return shared_memory.SharedMemory(name=name)


def _worker_trace(geometry: tuple, key: tuple, rays: tuple, lo: int, hi: int, max_distance: float) -> None:
    """Trace rays ``lo .. hi`` of a batch in a worker process (all arrays in shared memory)."""
    geometry_name, vertex_count, triangle_count = geometry
    if _worker_scene["key"] != key:
        shm = _attach(geometry_name)
        try:
            buf = shm.buf
            points = np.ndarray((vertex_count, 3), np.float32, buf).copy()
            faces = np.ndarray((triangle_count, 3), np.int32, buf, offset=vertex_count * 12).copy()
            del buf
        finally:
            shm.close()
        _worker_scene["scene"], _worker_scene["key"] = None, None
        _worker_scene["scene"] = _build_scene(points, faces)
        _worker_scene["key"] = key
    rays_name, count = rays
    shm = _attach(rays_name)
    try:
        buf = shm.buf
        origins = np.ndarray((count, 3), np.float32, buf)
        directions = np.ndarray((count, 3), np.float32, buf, offset=count * 12)
        out = np.ndarray((count,), np.int32, buf, offset=count * 24)
        out[lo:hi] = _trace(_worker_scene["scene"], np.ascontiguousarray(origins[lo:hi]),
                            np.ascontiguousarray(directions[lo:hi]), max_distance)
        del origins, directions, out, buf
    finally:
        shm.close()


_pool_lock = threading.Lock()
_pools: dict = {}
_keys = itertools.count()


def _shutdown_pools() -> None:
    with _pool_lock:
        for pool in _pools.values():
            pool.shutdown(wait=True, cancel_futures=True)
        _pools.clear()


def _process_pool(workers: int):
    import atexit
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with _pool_lock:
        if not _pools:
            atexit.register(_shutdown_pools)  # before the interpreter tears the pool's modules down
        if workers not in _pools:
            # spawned, never forked: a forked child of a process running Warp threads can deadlock
            _pools[workers] = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"))
        return _pools[workers]


class EmbreeOcclusion:
    """Any-hit shadow rays against one frame's triangles with Embree (``embreex``), on the CPU.

    The same query as :meth:`warpshade.geometry._bvh.Visibility.occluded`, on host arrays.

    Args:
        points: vertex positions, shape (vertex_count, 3), world space (cast to float32).
        faces: triangles, shape (triangle_count, 3), integer indices into ``points``.
        workers: processes a large batch is split over (default :func:`warpshade._wp.cpu_workers`,
            or 1 inside a worker process, whose parent already spreads the work; 1 traces
            everything in this process).

    Raises:
        ImportError: ``embreex`` is not installed (use :func:`ray_backend` to fall back).
    """

    def __init__(self, points, faces, workers: int | None = None):
        if not embree_available():
            raise ImportError("EmbreeOcclusion needs embreex: pip install 'warpshade[embree]'")
        f = np.ascontiguousarray(np.asarray(faces), dtype=np.int32)
        if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
            raise ValueError(f"EmbreeOcclusion: faces must have shape (triangle_count > 0, 3), got {f.shape}")
        self.faces = f
        if workers is None:
            import multiprocessing

            workers = 1 if multiprocessing.parent_process() is not None else cpu_workers()
        self.workers = max(1, int(workers))
        self._geometry = None
        self._scene = None
        self.update(points)

    def update(self, points) -> None:
        """New vertex positions (same topology): the next query builds a new Embree scene.

        Args:
            points: shape (vertex_count, 3), world space.
        """
        p = np.ascontiguousarray(np.asarray(points, dtype=np.float32).reshape(-1, 3))
        if self.faces.min() < 0 or self.faces.max() >= p.shape[0]:
            raise ValueError(f"EmbreeOcclusion: faces index vertices {int(self.faces.min())}..{int(self.faces.max())} "
                             f"but there are {p.shape[0]} points")
        if not np.all(np.isfinite(p)):
            raise ValueError("EmbreeOcclusion: points contain NaN or infinite values")
        self.points = p
        self._scene = None
        self._key = (os.getpid(), next(_keys))
        self._release_geometry()

    def _local_scene(self):
        if self._scene is None:
            self._scene = _build_scene(self.points, self.faces)
        return self._scene

    def _shared_geometry(self) -> tuple:
        if self._geometry is None:
            size = self.points.nbytes + self.faces.nbytes
            shm = shared_memory.SharedMemory(create=True, size=size)
            np.ndarray(self.points.shape, np.float32, shm.buf)[:] = self.points
            np.ndarray(self.faces.shape, np.int32, shm.buf, offset=self.points.nbytes)[:] = self.faces
            self._geometry = shm
        return (self._geometry.name, int(self.points.shape[0]), int(self.faces.shape[0]))

    def _release_geometry(self) -> None:
        if self._geometry is not None:
            self._geometry.close()
            self._geometry.unlink()
            self._geometry = None

    def occluded(self, origins, directions, max_distance: float = RAY_MAX_DISTANCE, out=None,
                 unit_directions: bool = False) -> np.ndarray:
        """Any-hit test of explicit rays: the arguments and answer of
        :meth:`warpshade.geometry._bvh.Visibility.occluded` (origins already offset, directions
        normalised here unless ``unit_directions`` says they are unit length), with NumPy arrays:
        an int32 array (ray_count,), 1 where the ray hits a triangle, else 0.
        """
        o = np.ascontiguousarray(np.asarray(origins, dtype=np.float32).reshape(-1, 3))
        d = np.ascontiguousarray(np.asarray(directions, dtype=np.float32).reshape(-1, 3))
        if o.shape[0] != d.shape[0]:
            raise ValueError(f"occluded: {o.shape[0]} origins but {d.shape[0]} directions")
        if not unit_directions:
            length = np.sqrt(np.einsum("ij,ij->i", d, d))
            d = d / np.where(length > 0.0, length, 1.0)[:, None]
        count = o.shape[0]
        result = np.empty(count, np.int32) if out is None else out
        if count == 0:
            return result
        if self.workers <= 1 or count < EMBREE_PARALLEL_MIN_RAYS:
            result[:] = _trace(self._local_scene(), o, d, max_distance)
            return result
        self._trace_parallel(o, d, float(max_distance), result)
        return result

    def _trace_parallel(self, o: np.ndarray, d: np.ndarray, max_distance: float, result: np.ndarray) -> None:
        count = o.shape[0]
        geometry = self._shared_geometry()
        shm = shared_memory.SharedMemory(create=True, size=count * 28)
        try:
            buf = shm.buf
            np.ndarray((count, 3), np.float32, buf)[:] = o
            np.ndarray((count, 3), np.float32, buf, offset=count * 12)[:] = d
            # a few slices per worker balance rays of unequal cost
            bounds = np.linspace(0, count, 4 * self.workers + 1).astype(np.int64)
            pool = _process_pool(self.workers)
            jobs = [pool.submit(_worker_trace, geometry, self._key, (shm.name, count), int(lo), int(hi), max_distance)
                    for lo, hi in zip(bounds[:-1], bounds[1:]) if hi > lo]
            for job in jobs:
                job.result()
            result[:] = np.ndarray((count,), np.int32, buf, offset=count * 24)
            del buf
        finally:
            shm.close()
            shm.unlink()

    def close(self) -> None:
        """Free the shared copy of the triangles (the workers stay for the next batch)."""
        self._release_geometry()
        self._scene = None

    def __del__(self):
        try:
            self._release_geometry()
        except Exception:
            pass
