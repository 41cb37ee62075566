"""Area-weighted vertex normals of triangle meshes, on Warp with a float64 NumPy reference."""

import numpy as np

from .._wp import resolve_device, wp

__all__ = ["vertex_normals", "vertex_normals_f64", "vertex_normal_sums_f64", "compute_vertex_normals"]

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
