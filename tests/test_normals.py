"""Area-weighted vertex normals: the vertex-parallel gather (what the scene evaluation runs per
frame) against the float64 reference and against the face-parallel atomic sums."""

import numpy as np
import pytest
import trimesh

from warpshade._wp import wp
from warpshade.geometry.normals import (GATHER_CHUNK_MIN, compute_vertex_normals, gather_vertex_normals,
                                        vertex_face_adjacency, vertex_normals_f64)

from tolerances import ATOL_FLOAT32


@pytest.fixture(scope="module")
def bumpy_sphere():
    """An icosphere with more vertices than one CPU chunk, moved off the sphere, plus a
    degenerate triangle (two equal corners) and a vertex on no triangle."""
    m = trimesh.creation.icosphere(5)
    rng = np.random.default_rng(3)
    points = np.asarray(m.vertices) * (1.0 + 0.1 * rng.standard_normal((len(m.vertices), 1)))
    faces = np.asarray(m.faces)
    assert points.shape[0] > 2 * GATHER_CHUNK_MIN  # the chunked path runs
    isolated = np.array([[5.0, 5.0, 5.0]])
    points = np.concatenate([points, isolated])
    faces = np.concatenate([faces, [[0, 0, 1]]])
    return points, faces


def _device_arrays(points, faces, device):
    return (wp.array(points.astype(np.float32), dtype=wp.vec3, device=device),
            wp.array(faces.astype(np.int32), dtype=wp.int32, device=device))


def test_gather_matches_float64_and_fallback(device, bumpy_sphere):
    points, faces = bumpy_sphere
    p, _ = _device_arrays(points, faces, device)
    out = wp.zeros(points.shape[0], dtype=wp.vec3, device=device)
    gather_vertex_normals(p, vertex_face_adjacency(faces, 0, points.shape[0], device), out)
    got = out.numpy()
    ref = vertex_normals_f64(points, faces)
    assert np.abs(got - ref).max() < ATOL_FLOAT32
    assert np.array_equal(got[-1], [0.0, 0.0, 1.0])  # on no triangle


def test_gather_is_the_atomic_sum_bit_for_bit_on_cpu(bumpy_sphere):
    # the CPU's face-parallel launch adds in face order; the gather keeps that order per vertex
    points, faces = bumpy_sphere
    p, f = _device_arrays(points, faces, "cpu")
    atomic = wp.zeros(points.shape[0], dtype=wp.vec3, device="cpu")
    compute_vertex_normals(p, f, atomic)
    gathered = wp.zeros(points.shape[0], dtype=wp.vec3, device="cpu")
    gather_vertex_normals(p, vertex_face_adjacency(faces, 0, points.shape[0], "cpu"), gathered)
    assert np.array_equal(gathered.numpy(), atomic.numpy())


def test_gather_writes_only_its_vertex_range(device):
    # two meshes in one point array: the second one's normals only, the first one's untouched
    a = trimesh.creation.icosphere(1)
    b = trimesh.creation.box()
    na = len(a.vertices)
    points = np.concatenate([a.vertices, np.asarray(b.vertices) + 3.0])
    faces_b = np.asarray(b.faces) + na
    p = wp.array(points.astype(np.float32), dtype=wp.vec3, device=device)
    sentinel = np.full((points.shape[0], 3), 7.0, np.float32)
    out = wp.array(sentinel, dtype=wp.vec3, device=device)
    gather_vertex_normals(p, vertex_face_adjacency(faces_b, na, len(b.vertices), device), out)
    got = out.numpy()
    assert np.array_equal(got[:na], sentinel[:na])
    ref = vertex_normals_f64(np.asarray(b.vertices) + 3.0, np.asarray(b.faces))
    assert np.abs(got[na:] - ref).max() < ATOL_FLOAT32


def test_adjacency_refuses_faces_outside_the_range():
    with pytest.raises(ValueError, match="outside 4..7"):
        vertex_face_adjacency(np.array([[4, 5, 8]]), 4, 4, "cpu")
    with pytest.raises(ValueError, match=r"\(F, 3\)"):
        vertex_face_adjacency(np.array([4, 5, 6]), 4, 4, "cpu")
