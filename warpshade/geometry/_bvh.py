"""One Warp BVH (``wp.Mesh``) over all triangles of a frame, and shadow-ray queries on it.

:class:`Visibility` owns a ``wp.Mesh`` built over every triangle of the scene (all meshes
concatenated in scene order, the indexing of ``Scene.faces``). Per frame it is *refit* in
place (:meth:`Visibility.update`): the points are copied into the mesh's own point buffer and
the bounding-volume hierarchy is refit without reallocating, which is what deforming, skinned
and rigidly moving meshes need because their topology never changes. :meth:`Visibility.rebuild`
builds a new hierarchy and is only needed when the triangle list itself changes.

Ray-origin offset (self-intersection). A shadow ray leaving a surface point ``p`` must not hit
the triangles that contain ``p``. Rays start at ``p + offset * n``: the receiver point pushed
along its unit normal ``n`` by a distance scaled to the scene,

    ``offset = max(RAY_OFFSET_RELATIVE * diagonal, RAY_OFFSET_FLOAT32_GUARD * max|p|)``,

with ``diagonal`` the length of the bounding-box diagonal of the points the BVH was built
from and ``max|p|`` their largest absolute coordinate (float32 positions far from the origin
need a larger offset than their spread alone suggests). Consequences, tested on thin geometry
in ``tests/test_bvh.py``:

* surfaces further than ``offset`` from the receiver are resolved: two parallel sheets a few
  offsets apart shadow each other, and both faces of a slab a few offsets thick see their own
  open hemisphere unoccluded;
* a surface closer than ``offset`` above the receiver is skipped (its light leaks through), so
  geometry thinner than ``offset`` (1e-4 of the scene diagonal by default) is not resolved;
* rays into the hemisphere below ``n`` start on the normal side too, so they cross the
  receiver's own surface and count as occluded: on closed or sheet-like geometry the full-sphere
  visibility is ~0 below the surface, except at open boundaries where the surface ends.

The offset is fixed when the BVH is built (or given explicitly), not recomputed by
:meth:`Visibility.update`, so it does not jitter from frame to frame.

Shadow rays use ``wp.mesh_query_ray_anyhit`` (any intersection, no closest-hit search). Bulk
rays outside a recorded frame can go to Embree instead (:mod:`warpshade.geometry._embree`).
"""

import numpy as np

from .._wp import resolve_device, wp

__all__ = [
    "RAY_OFFSET_RELATIVE",
    "RAY_OFFSET_FLOAT32_GUARD",
    "RAY_MAX_DISTANCE",
    "ray_offset",
    "Visibility",
    "offset_origin",
    "trace_occlusion_f64",
]

wp.set_module_options({"enable_backward": False})

#: Ray-origin offset as a fraction of the scene's bounding-box diagonal. 1e-4 keeps acne away on
#: float32 geometry of up to ~1e4 triangles per diagonal while resolving gaps of a few 1e-4.
RAY_OFFSET_RELATIVE = 1.0e-4

#: Lower bound of the offset relative to the largest absolute coordinate: 64 float32 ulps
#: (2**-23 * 64), so positions far from the origin still clear their own triangle.
RAY_OFFSET_FLOAT32_GUARD = 64.0 * 2.0**-23

#: ``max_t`` of shadow rays toward distant light (environment, distant lights), scene units.
RAY_MAX_DISTANCE = 1.0e30


def ray_offset(points) -> float:
    """Scene-scaled ray-origin offset for the given points (see module docstring).

    Args:
        points: vertex positions, shape (vertex_count, 3), any float dtype, world space.

    Returns:
        The offset distance in scene units (> 0 for any non-empty point set).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if p.shape[0] == 0:
        raise ValueError("ray_offset: no points")
    if not np.all(np.isfinite(p)):
        raise ValueError("ray_offset: points contain NaN or infinite values")
    diagonal = float(np.linalg.norm(p.max(axis=0) - p.min(axis=0)))
    magnitude = float(np.abs(p).max())
    offset = max(RAY_OFFSET_RELATIVE * diagonal, RAY_OFFSET_FLOAT32_GUARD * magnitude)
    # A single point (zero diagonal) at the origin still needs a positive offset.
    return offset if offset > 0.0 else RAY_OFFSET_RELATIVE


@wp.func
def offset_origin(point: wp.vec3, normal: wp.vec3, offset: float) -> wp.vec3:
    """Ray origin for a receiver: ``point + offset * normal`` (normal is unit length)."""
    return point + offset * normal


@wp.kernel
def _occlusion_kernel(
    mesh_id: wp.uint64,
    origins: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    max_distance: float,
    occluded: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    d = wp.normalize(directions[i])
    occluded[i] = wp.where(wp.mesh_query_ray_anyhit(mesh_id, origins[i], d, max_distance), 1, 0)


@wp.kernel
def _closest_hit_kernel(
    mesh_id: wp.uint64,
    origins: wp.array(dtype=wp.vec3),
    directions: wp.array(dtype=wp.vec3),
    max_distance: float,
    distance: wp.array(dtype=wp.float32),
    face: wp.array(dtype=wp.int32),
    bary: wp.array(dtype=wp.vec2),
    cosine: wp.array(dtype=wp.float32),
):
    i = wp.tid()
    d = wp.normalize(directions[i])
    q = wp.mesh_query_ray(mesh_id, origins[i], d, max_distance)
    if q.result:
        distance[i] = q.t
        face[i] = q.face
        bary[i] = wp.vec2(q.u, q.v)
        cosine[i] = wp.dot(d, q.normal)
    else:
        distance[i] = -1.0
        face[i] = -1
        bary[i] = wp.vec2(0.0)
        cosine[i] = 0.0


def _as_vec3_array(values, device, name: str):
    """Return a wp.array(vec3) on ``device`` (copying NumPy input, keeping Warp input as is)."""
    if isinstance(values, wp.array):
        if values.dtype != wp.vec3:
            raise ValueError(f"{name}: expected a wp.array of vec3, got dtype {values.dtype}")
        if values.device != device:
            raise ValueError(f"{name}: array is on {values.device}, the BVH is on {device}")
        return values
    arr = np.asarray(values, dtype=np.float32).reshape(-1, 3)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    return wp.array(arr, dtype=wp.vec3, device=device)


class Visibility:
    """A Warp BVH over all triangles of one frame, refit in place per frame.

    Attributes:
        device: the Warp device everything lives on.
        points: the BVH's own point buffer, wp.array(vec3), shape (vertex_count,), world space.
        faces: triangle indices, shape (triangle_count, 3), int32 (NumPy copy).
        mesh: the ``wp.Mesh``; pass ``mesh.id`` (also :attr:`id`) to kernels.
        offset: ray-origin offset in scene units (see module docstring).
    """

    def __init__(self, points, faces, device=None, offset: float | None = None, bvh_constructor: str | None = None,
                 bvh_leaf_size: int | None = None):
        """Build the BVH.

        Args:
            points: world-space vertex positions, shape (vertex_count, 3) (NumPy or wp vec3).
            faces: triangles, shape (triangle_count, 3), integer indices into ``points``.
            device: Warp device (None = Warp's default).
            offset: ray-origin offset in scene units; default :func:`ray_offset` of ``points``.
            bvh_constructor: passed to ``wp.Mesh`` ("sah", "median", "lbvh"; None = Warp's default).
            bvh_leaf_size: triangles per BVH leaf, passed to ``wp.Mesh`` (None = Warp's default,
                4 for SAH). ``benchmarks/bench_rays.py`` sweeps it: no leaf size beats the default
                on the bundled scenes by more than the run-to-run noise on the CPU.
        """
        self.device = resolve_device(device)
        self._bvh_constructor = bvh_constructor
        self._bvh_leaf_size = bvh_leaf_size
        self._build(points, faces)
        host = self.points.numpy()
        self.offset = float(ray_offset(host) if offset is None else offset)
        if not self.offset > 0.0:
            raise ValueError(f"Visibility: offset must be > 0, got {offset!r}")

    def _build(self, points, faces) -> None:
        f = np.asarray(faces)
        if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
            raise ValueError(f"Visibility: faces must have shape (triangle_count > 0, 3), got {f.shape}")
        src = _as_vec3_array(points, self.device, "Visibility points")
        vertex_count = src.shape[0]
        if f.min() < 0 or f.max() >= vertex_count:
            raise ValueError(
                f"Visibility: faces index vertices {int(f.min())}..{int(f.max())} but there are {vertex_count} points"
            )
        self.faces = f.astype(np.int32)
        self.points = wp.empty(vertex_count, dtype=wp.vec3, device=self.device)
        wp.copy(self.points, src)
        self._indices = wp.array(self.faces.reshape(-1), dtype=wp.int32, device=self.device)
        kwargs = {} if self._bvh_constructor is None else {"bvh_constructor": self._bvh_constructor}
        if self._bvh_leaf_size is not None:
            kwargs["bvh_leaf_size"] = int(self._bvh_leaf_size)
        self.mesh = wp.Mesh(points=self.points, indices=self._indices, **kwargs)

    @classmethod
    def over(cls, points: wp.array, faces, offset: float | None = None) -> "Visibility":
        """A BVH whose point buffer *is* ``points`` (shared, not copied).

        For per-frame loops whose points are written in place by kernels (a
        :class:`~warpshade.scene._state.FrameState`): call :meth:`refit` after they change (a
        capture-safe launch). The offset is computed from the points' current values.

        Args:
            points: wp.array(vec3), (vertex_count,), world space, on the BVH's device.
            faces: triangles, (triangle_count, 3), indices into ``points``.
            offset: ray-origin offset in scene units (default :func:`ray_offset`).
        """
        if not isinstance(points, wp.array) or points.dtype != wp.vec3:
            raise ValueError("Visibility.over: points must be a wp.array(dtype=wp.vec3)")
        self = cls.__new__(cls)
        self.device = points.device
        self._bvh_constructor = None
        self._bvh_leaf_size = None
        f = np.asarray(faces)
        if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
            raise ValueError(f"Visibility.over: faces must have shape (triangle_count > 0, 3), got {f.shape}")
        if f.min() < 0 or f.max() >= points.shape[0]:
            raise ValueError(f"Visibility.over: faces index vertices {int(f.min())}..{int(f.max())} "
                             f"but there are {points.shape[0]} points")
        self.faces = f.astype(np.int32)
        self.points = points
        self._indices = wp.array(self.faces.reshape(-1), dtype=wp.int32, device=self.device)
        self.mesh = wp.Mesh(points=self.points, indices=self._indices)
        self.offset = float(ray_offset(points.numpy()) if offset is None else offset)
        return self

    def refit(self) -> None:
        """Refit the hierarchy to the current point buffer (capture-safe)."""
        self.mesh.refit()

    @classmethod
    def from_scene(cls, scene, frame=None, device=None, offset: float | None = None) -> "Visibility":
        """BVH over all triangles of ``scene`` at time code ``frame`` (default: first frame)."""
        frame = scene.frames[0] if frame is None else frame
        return cls(scene.points_at(frame), scene.faces, device=device, offset=offset)

    @property
    def id(self):
        """The ``wp.Mesh`` id to pass to kernels (``wp.uint64``)."""
        return self.mesh.id

    @property
    def vertex_count(self) -> int:
        return int(self.points.shape[0])

    @property
    def triangle_count(self) -> int:
        return int(self.faces.shape[0])

    def update(self, points) -> None:
        """Move the vertices (same topology) and refit the BVH in place; no reallocation.

        Args:
            points: new world-space positions, shape (vertex_count, 3): a wp.array(vec3) on the
                BVH's device (copied on device) or a NumPy array (uploaded).
        """
        if isinstance(points, wp.array):
            src = _as_vec3_array(points, self.device, "Visibility.update points")
            if src.shape[0] != self.vertex_count:
                raise ValueError(
                    f"Visibility.update: got {src.shape[0]} points for a BVH of {self.vertex_count}; "
                    "use rebuild() when the topology changes"
                )
            wp.copy(self.points, src)
        else:
            arr = np.asarray(points, dtype=np.float32).reshape(-1, 3)
            if arr.shape[0] != self.vertex_count:
                raise ValueError(
                    f"Visibility.update: got {arr.shape[0]} points for a BVH of {self.vertex_count}; "
                    "use rebuild() when the topology changes"
                )
            if not np.all(np.isfinite(arr)):
                raise ValueError("Visibility.update: points contain NaN or infinite values")
            self.points.assign(arr)
        self.mesh.refit()

    def rebuild(self, points, faces, offset: float | None = None) -> None:
        """Build a new BVH for new topology (new point count or triangle list).

        The offset is kept unless ``offset`` is given.
        """
        self._build(points, faces)
        if offset is not None:
            self.offset = float(offset)

    def occluded(self, origins, directions, max_distance: float = RAY_MAX_DISTANCE, out=None):
        """Any-hit test of explicit rays against the BVH.

        Args:
            origins: ray origins, shape (ray_count, 3), world space (already offset).
            directions: ray directions, shape (ray_count, 3) (normalised in the kernel).
            max_distance: hits further than this (scene units) are ignored.
            out: optional preallocated wp.array(int32) of shape (ray_count,).

        Returns:
            wp.array(int32), shape (ray_count,): 1 where the ray hits a triangle, else 0.
        """
        o = _as_vec3_array(origins, self.device, "occluded origins")
        d = _as_vec3_array(directions, self.device, "occluded directions")
        if o.shape[0] != d.shape[0]:
            raise ValueError(f"occluded: {o.shape[0]} origins but {d.shape[0]} directions")
        if out is None:
            out = wp.empty(o.shape[0], dtype=wp.int32, device=self.device)
        if o.shape[0] > 0:
            wp.launch(
                _occlusion_kernel,
                dim=o.shape[0],
                inputs=[self.mesh.id, o, d, float(max_distance), out],
                device=self.device,
            )
        return out

    def closest_hits(self, origins, directions, max_distance: float = RAY_MAX_DISTANCE) -> dict:
        """Closest hit of explicit rays (for diagnostics: which triangle, where, how grazing).

        Args:
            origins, directions: rays, shape (ray_count, 3), world space.
            max_distance: hits further than this are ignored.

        Returns:
            dict of NumPy arrays of length ray_count: ``distance`` (float32, -1 for a miss),
            ``face`` (int32, -1 for a miss), ``bary`` ((ray_count, 2) Warp barycentrics u, v of
            ``u p0 + v p1 + (1 - u - v) p2``), ``cosine`` (float32, ray direction . face normal).
        """
        o = _as_vec3_array(origins, self.device, "closest_hits origins")
        d = _as_vec3_array(directions, self.device, "closest_hits directions")
        if o.shape[0] != d.shape[0]:
            raise ValueError(f"closest_hits: {o.shape[0]} origins but {d.shape[0]} directions")
        count = o.shape[0]
        distance = wp.empty(count, dtype=wp.float32, device=self.device)
        face = wp.empty(count, dtype=wp.int32, device=self.device)
        bary = wp.empty(count, dtype=wp.vec2, device=self.device)
        cosine = wp.empty(count, dtype=wp.float32, device=self.device)
        if count:
            wp.launch(
                _closest_hit_kernel,
                dim=count,
                inputs=[self.mesh.id, o, d, float(max_distance), distance, face, bary, cosine],
                device=self.device,
            )
        return {"distance": distance.numpy(), "face": face.numpy(), "bary": bary.numpy(), "cosine": cosine.numpy()}


def trace_occlusion_f64(points, faces, origins, directions, max_distance: float = np.inf) -> np.ndarray:
    """Float64 brute-force any-hit test (Moller-Trumbore against every triangle), for tests.

    Args:
        points: (V, 3) positions; faces: (F, 3) indices; origins, directions: (R, 3).
        max_distance: hits at ``t >= max_distance`` (in units of the normalised direction) are ignored.

    Returns:
        bool array (R,): True where some triangle is hit at ``0 < t < max_distance``. Cost is
        O(R * F) memory-chunked; meant for tiny cases only.
    """
    p = np.asarray(points, np.float64)
    f = np.asarray(faces, np.int64)
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    v0, v1, v2 = p[f[:, 0]], p[f[:, 1]], p[f[:, 2]]
    e1, e2 = v1 - v0, v2 - v0
    hit = np.zeros(o.shape[0], dtype=bool)
    chunk = max(1, 2_000_000 // max(1, f.shape[0]))
    for start in range(0, o.shape[0], chunk):
        oc = o[start : start + chunk, None, :]
        dc = d[start : start + chunk, None, :]
        pvec = np.cross(dc, e2[None])
        det = np.sum(e1[None] * pvec, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            tvec = oc - v0[None]
            u = np.sum(tvec * pvec, axis=-1) * inv
            qvec = np.cross(tvec, e1[None])
            v = np.sum(dc * qvec, axis=-1) * inv
            t = np.sum(e2[None] * qvec, axis=-1) * inv
        ok = (np.abs(det) > 1e-300) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t < max_distance)
        hit[start : start + chunk] = ok.any(axis=1)
    return hit
