"""Area-weighted vertex normals of triangle meshes, on Warp with a float64 NumPy reference.

Two ways to fill them on the device, with the same float32 sums:

* :func:`compute_vertex_normals` -- face-parallel: every triangle adds its normal to its three
  vertices (atomic adds), then every vertex is normalised;
* :func:`vertex_face_adjacency` once, then :func:`gather_vertex_normals` per frame --
  the triangles' normals, then every vertex sums those of its triangles (in face order, as the
  face-parallel sums on the CPU: the same float32 result) and normalises; no atomics, both
  launches split over the CPU cores (:func:`~warpshade._wp.launch_parallel`).
"""

from dataclasses import dataclass

import numpy as np

from .._wp import launch_parallel, resolve_device, wp

__all__ = ["vertex_normals", "vertex_normals_f64", "vertex_normal_sums_f64", "compute_vertex_normals", "VertexFaces",
           "vertex_face_adjacency", "gather_vertex_normals"]

#: Vertices per CPU chunk below which :func:`gather_vertex_normals` is one launch.
GATHER_CHUNK_MIN = 4096

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _accumulate_face_normals(
    points: wp.array(dtype=wp.vec3),
    faces: wp.array2d(dtype=wp.int32),
    normals: wp.array(dtype=wp.vec3),
):
    f = wp.tid()
    i0 = faces[f, 0]
    i1 = faces[f, 1]
    i2 = faces[f, 2]
    # The unnormalised cross product is twice the area times the unit face normal.
    n = wp.cross(points[i1] - points[i0], points[i2] - points[i0])
    wp.atomic_add(normals, i0, n)
    wp.atomic_add(normals, i1, n)
    wp.atomic_add(normals, i2, n)


@wp.kernel
def _normalise_or_fallback(normals: wp.array(dtype=wp.vec3), fallback: wp.vec3):
    i = wp.tid()
    n = normals[i]
    length = wp.length(n)
    if length > 1.0e-30:
        normals[i] = n / length
    else:
        # Isolated vertex or a fan of degenerate triangles: a fixed, finite normal.
        normals[i] = fallback


@wp.kernel
def _zero_selected(normals: wp.array(dtype=wp.vec3), vertices: wp.array(dtype=wp.int32)):
    normals[vertices[wp.tid()]] = wp.vec3(0.0)


@wp.kernel
def _normalise_selected(normals: wp.array(dtype=wp.vec3), vertices: wp.array(dtype=wp.int32), fallback: wp.vec3):
    i = vertices[wp.tid()]
    n = normals[i]
    length = wp.length(n)
    if length > 1.0e-30:
        normals[i] = n / length
    else:
        normals[i] = fallback


def compute_vertex_normals(points: wp.array, faces: wp.array, normals: wp.array, vertices: wp.array | None = None) -> None:
    """Fill ``normals`` with area-weighted unit vertex normals, in place, on the arrays' device.

    Args:
        points: vertex positions, wp.array(dtype=vec3), shape (vertex_count,).
        faces: triangle indices, wp.array2d(dtype=int32), shape (triangle_count, 3).
        normals: output, wp.array(dtype=vec3), shape (vertex_count,). Vertices touched by no
            non-degenerate triangle get (0, 0, 1).
        vertices: optional wp.array(int32) of the only vertices to (re)compute; ``faces`` must
            then be the triangles that touch them and no other vertex (e.g. the moving meshes of
            a scene, whose static meshes keep their normals). Capture-safe: launches only.
    """
    device = points.device
    fallback = wp.vec3(0.0, 0.0, 1.0)
    if vertices is None:
        normals.zero_()
    elif vertices.shape[0] > 0:
        wp.launch(_zero_selected, dim=vertices.shape[0], inputs=[normals, vertices], device=device)
    if faces.shape[0] > 0:
        wp.launch(_accumulate_face_normals, dim=faces.shape[0], inputs=[points, faces, normals], device=device)
    if vertices is None:
        if normals.shape[0] > 0:
            wp.launch(_normalise_or_fallback, dim=normals.shape[0], inputs=[normals, fallback], device=device)
    elif vertices.shape[0] > 0:
        wp.launch(_normalise_selected, dim=vertices.shape[0], inputs=[normals, vertices, fallback], device=device)


@wp.kernel
def _face_normals_kernel(points: wp.array(dtype=wp.vec3), faces: wp.array2d(dtype=wp.int32), chunk: int,
                         out: wp.array(dtype=wp.vec3)):
    f = wp.tid() + chunk
    i0 = faces[f, 0]
    i1 = faces[f, 1]
    i2 = faces[f, 2]
    out[f] = wp.cross(points[i1] - points[i0], points[i2] - points[i0])


@wp.kernel
def _gather_normals_kernel(face_normals: wp.array(dtype=wp.vec3), start: wp.array(dtype=wp.int32),
                           incident: wp.array(dtype=wp.int32), first: int, chunk: int, fallback: wp.vec3,
                           normals: wp.array(dtype=wp.vec3)):
    v = wp.tid() + chunk
    n = wp.vec3(0.0)
    for j in range(start[v], start[v + 1]):
        n = n + face_normals[incident[j]]
    length = wp.length(n)
    if length > 1.0e-30:
        normals[first + v] = n / length
    else:
        normals[first + v] = fallback


@dataclass
class VertexFaces:
    """The triangles around each vertex of a range ``first .. first + count`` of a point array
    (compressed rows, device arrays).

    Attributes:
        faces: the triangles, (F, 3) int32 indices into the point array.
        start: (count + 1,) int32; the triangles of vertex ``first + v`` are
            ``incident[start[v] : start[v + 1]]``, in increasing order (a triangle that names a
            vertex twice is listed twice, as it adds twice).
        incident: (3 F,) int32 rows of ``faces``.
        face_normals: (F,) vec3 scratch: the unnormalised normals of the triangles.
        first, count: the vertex range.
    """

    faces: wp.array
    start: wp.array
    incident: wp.array
    face_normals: wp.array
    first: int
    count: int


def vertex_face_adjacency(faces, first: int, count: int, device=None) -> VertexFaces:
    """The :class:`VertexFaces` of triangles ``faces`` (F, 3) (indices into a point array) over
    vertices ``first .. first + count``.

    Raises:
        ValueError: ``faces`` is not (F, 3), or names a vertex outside the range.
    """
    dev = resolve_device(device)
    f = np.asarray(faces, np.int64)
    if f.ndim != 2 or f.shape[1] != 3:
        raise ValueError(f"vertex_face_adjacency: faces must be (F, 3) vertex indices, got shape {f.shape}")
    if f.size and (f.min() < first or f.max() >= first + count):
        raise ValueError(f"vertex_face_adjacency: faces name vertices {int(f.min())}..{int(f.max())}, outside "
                         f"{first}..{first + count - 1}")
    corner_vertex = f.reshape(-1) - first  # corner c of face k at 3 k + c: face-major, so a stable sort keeps face order
    order = np.argsort(corner_vertex, kind="stable")
    incident = (order // 3).astype(np.int32)
    start = np.zeros(count + 1, np.int64)
    np.cumsum(np.bincount(corner_vertex, minlength=count), out=start[1:])
    return VertexFaces(wp.array(f.astype(np.int32), dtype=wp.int32, device=dev),
                       wp.array(start.astype(np.int32), dtype=wp.int32, device=dev),
                       wp.array(incident, dtype=wp.int32, device=dev), wp.zeros(f.shape[0], dtype=wp.vec3, device=dev),
                       int(first), int(count))


def gather_vertex_normals(points: wp.array, adjacency: VertexFaces, normals: wp.array) -> None:
    """Fill ``normals[first : first + count]`` of ``adjacency``'s vertices with area-weighted
    unit normals of ``points`` (vertices on no non-degenerate triangle: (0, 0, 1)); the same
    float32 sums as :func:`compute_vertex_normals` over the same triangles. Launches only
    (capture-safe); split over the CPU cores on the CPU."""
    a = adjacency
    fallback = wp.vec3(0.0, 0.0, 1.0)
    dev = points.device
    launch_parallel(_face_normals_kernel, a.faces.shape[0], lambda s, e: [points, a.faces, s, a.face_normals], dev,
                    min_count=GATHER_CHUNK_MIN)
    launch_parallel(_gather_normals_kernel, a.count,
                    lambda s, e: [a.face_normals, a.start, a.incident, a.first, s, fallback, normals], dev,
                    min_count=GATHER_CHUNK_MIN)


def vertex_normal_sums_f64(points, faces) -> np.ndarray:
    """Unnormalised area-weighted normal sums (twice the incident areas times the face
    normals), float64, shape (vertex_count, 3); :func:`vertex_normals_f64` normalises them."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    n = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    acc = np.zeros_like(p)
    for k in range(3):
        np.add.at(acc, f[:, k], n)
    return acc


def vertex_normals(points, faces, device=None) -> np.ndarray:
    """Area-weighted unit vertex normals (float32 Warp kernel), shape (vertex_count, 3)."""
    dev = resolve_device(device)
    pts = wp.array(np.asarray(points, dtype=np.float32).reshape(-1, 3), dtype=wp.vec3, device=dev)
    fcs = wp.array(np.asarray(faces, dtype=np.int32).reshape(-1, 3), dtype=wp.int32, device=dev)
    out = wp.empty(pts.shape[0], dtype=wp.vec3, device=dev)
    compute_vertex_normals(pts, fcs, out)
    return out.numpy()


def vertex_normals_f64(points, faces) -> np.ndarray:
    """Float64 NumPy reference of :func:`vertex_normals`."""
    acc = vertex_normal_sums_f64(points, faces)
    length = np.linalg.norm(acc, axis=1, keepdims=True)
    out = np.tile([0.0, 0.0, 1.0], (acc.shape[0], 1))
    ok = length[:, 0] > 1e-30
    out[ok] = acc[ok] / length[ok]
    return out
