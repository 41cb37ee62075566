"""The frame BVH: any-hit rays against a float64 brute-force oracle, refit, and the ray offset
on thin geometry."""

import numpy as np
import pytest
import trimesh

from warpshade._wp import wp
from warpshade.geometry._bvh import (
    RAY_OFFSET_FLOAT32_GUARD,
    RAY_OFFSET_RELATIVE,
    Visibility,
    ray_offset,
    trace_occlusion_f64,
)

# Random rays may graze a shared edge or vertex, where a float32 watertight test and the float64
# Moller-Trumbore test can legitimately disagree; with 4000 random rays we expect none, and
# allow 2 per thousand.
MAX_EDGE_DISAGREEMENT = 2e-3

# Elevation (radians) kept away from the tangent plane when testing thin geometry, so that a ray
# toward a parallel sheet 10 offsets away hits it well inside its extent.
MIN_ELEVATION = np.radians(2.0)


def _scene_mesh():
    sphere = trimesh.creation.icosphere(2, radius=0.6)
    box = trimesh.creation.box(extents=(0.5, 0.8, 0.3))
    box.apply_translation((1.0, 0.2, -0.1))
    mesh = trimesh.util.concatenate([sphere, box])
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


def _grid(n, size, z, flip=False):
    """A flat n x n vertex grid of side ``size`` at height z (normal +z, or -z when flipped)."""
    xs = np.linspace(-size / 2, size / 2, n)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    points = np.stack([gx.ravel(), gy.ravel(), np.full(n * n, z)], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    if flip:
        faces = faces[:, ::-1]
    return points, faces


def _hemisphere_dirs(count, upward, rng):
    """Random unit directions with |elevation| >= MIN_ELEVATION, above (+z) or below the plane."""
    d = rng.normal(size=(count * 3, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    keep = d[:, 2] > np.sin(MIN_ELEVATION) if upward else d[:, 2] < -np.sin(MIN_ELEVATION)
    return d[keep][:count]


def _interior(points, size, margin):
    return np.where((np.abs(points[:, 0]) < size / 2 - margin) & (np.abs(points[:, 1]) < size / 2 - margin))[0]


def _occluded_from(bvh, receivers, normal, dirs):
    """Occlusion of every (receiver, direction) pair, origins offset along ``normal``."""
    origins = np.repeat(receivers + bvh.offset * np.asarray(normal), len(dirs), axis=0)
    directions = np.tile(dirs, (len(receivers), 1))
    return bvh.occluded(origins, directions).numpy().astype(bool)


def test_anyhit_matches_float64_brute_force(device, rng):
    points, faces = _scene_mesh()
    bvh = Visibility(points, faces, device=device)
    origins = rng.uniform(-2.0, 2.0, size=(4000, 3))
    targets = points[rng.integers(0, len(points), 4000)] + rng.normal(scale=0.3, size=(4000, 3))
    dirs = np.where(rng.uniform(size=(4000, 1)) < 0.5, targets - origins, rng.normal(size=(4000, 3)))
    got = bvh.occluded(origins, dirs).numpy().astype(bool)
    ref = trace_occlusion_f64(points, faces, origins, dirs)
    assert 0.1 < ref.mean() < 0.9  # a meaningful mix of hits and misses
    assert np.mean(got != ref) <= MAX_EDGE_DISAGREEMENT


def test_max_distance_limits_hits(device):
    points, faces = _grid(3, 2.0, 1.0)
    bvh = Visibility(points, faces, device=device)
    up = np.array([[0.0, 0.0, 1.0]] * 2)
    origins = np.zeros((2, 3))
    hit = bvh.occluded(origins, up, max_distance=0.99).numpy()
    hit_far = bvh.occluded(origins, up, max_distance=1.01).numpy()
    assert hit.tolist() == [0, 0] and hit_far.tolist() == [1, 1]
    closest = bvh.closest_hits(np.array([[0.3, -0.2, 0.0], [0.0, 0.0, 2.0]]), np.array([[0, 0, 1.0], [0, 0, 1.0]]))
    np.testing.assert_allclose(closest["distance"], [1.0, -1.0], atol=1e-6)
    np.testing.assert_allclose(closest["cosine"][0] ** 2, 1.0, atol=1e-6)
    assert closest["face"][0] >= 0 and closest["face"][1] == -1


def test_refit_in_place_matches_rebuild(device, rng):
    points, faces = _scene_mesh()
    bvh = Visibility(points, faces, device=device)
    buffer_ptr, mesh_id = bvh.points.ptr, bvh.id
    moved = points + 0.3 * np.sin(3.0 * points[:, [1, 2, 0]])  # same topology, new shape
    bvh.update(moved)
    assert bvh.points.ptr == buffer_ptr and bvh.id == mesh_id  # refit, no reallocation
    fresh = Visibility(moved, faces, device=device, offset=bvh.offset)
    origins = rng.uniform(-2.0, 2.0, size=(3000, 3))
    dirs = rng.normal(size=(3000, 3))
    np.testing.assert_array_equal(bvh.occluded(origins, dirs).numpy(), fresh.occluded(origins, dirs).numpy())
    # device-side update path gives the same BVH
    bvh.update(wp.array(points.astype(np.float32), dtype=wp.vec3, device=device))
    again = Visibility(points, faces, device=device)
    np.testing.assert_array_equal(bvh.occluded(origins, dirs).numpy(), again.occluded(origins, dirs).numpy())


def test_topology_change_needs_rebuild(device):
    points, faces = _scene_mesh()
    bvh = Visibility(points, faces, device=device)
    with pytest.raises(ValueError, match="rebuild"):
        bvh.update(points[:-1])
    grid_p, grid_f = _grid(4, 1.0, 0.0)
    bvh.rebuild(grid_p, grid_f)
    assert bvh.vertex_count == 16 and bvh.triangle_count == 18


def test_bad_input_is_reported(device):
    points, faces = _scene_mesh()
    with pytest.raises(ValueError, match="faces index"):
        Visibility(points, faces + len(points), device=device)
    bad = points.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        Visibility(bad, faces, device=device)
    with pytest.raises(ValueError, match="triangle_count"):
        Visibility(points, np.zeros((0, 3), int), device=device)


def test_ray_offset_is_scene_scaled():
    points, _ = _scene_mesh()
    diag = np.linalg.norm(points.max(0) - points.min(0))
    assert ray_offset(points) == pytest.approx(RAY_OFFSET_RELATIVE * diag)
    assert ray_offset(points * 1000.0) == pytest.approx(1000.0 * ray_offset(points))
    # far from the origin the float32 guard takes over
    far = points + 1.0e5
    assert ray_offset(far) == pytest.approx(RAY_OFFSET_FLOAT32_GUARD * np.abs(far).max())


def test_thin_slab_sees_its_open_hemisphere(device, rng):
    """Both faces of a slab 7 offsets thick: no self-hits above, own surface blocks below."""
    size, thickness = 1.0, 1.0e-3
    top_p, top_f = _grid(11, size, thickness / 2)
    bot_p, bot_f = _grid(11, size, -thickness / 2, flip=True)
    points = np.concatenate([top_p, bot_p])
    faces = np.concatenate([top_f, bot_f + len(top_p)])
    bvh = Visibility(points, faces, device=device)
    assert thickness > 5 * bvh.offset  # the slab is thin, but resolved
    inner = _interior(top_p, size, 0.2)
    up, down = _hemisphere_dirs(200, True, rng), _hemisphere_dirs(200, False, rng)
    assert not _occluded_from(bvh, top_p[inner], (0, 0, 1), up).any()
    assert _occluded_from(bvh, top_p[inner], (0, 0, 1), down).all()
    assert not _occluded_from(bvh, bot_p[inner], (0, 0, -1), down).any()
    assert _occluded_from(bvh, bot_p[inner], (0, 0, -1), up).all()


def test_close_parallel_sheets_shadow_each_other(device, rng):
    """Two sheets 10 offsets apart occlude each other; closer than the offset they leak."""
    size = 1.0
    lower_p, lower_f = _grid(11, size, 0.0)
    probe = Visibility(*_grid(11, size, 0.0), device=device)  # same diagonal as the pair
    gap = 10.0 * probe.offset
    upper_p, upper_f = _grid(11, size, gap)
    points = np.concatenate([lower_p, upper_p])
    faces = np.concatenate([lower_f, upper_f + len(lower_p)])
    bvh = Visibility(points, faces, device=device)
    inner = _interior(lower_p, size, 0.2)
    up = _hemisphere_dirs(200, True, rng)
    assert _occluded_from(bvh, lower_p[inner], (0, 0, 1), up).all()
    assert not _occluded_from(bvh, upper_p[inner], (0, 0, 1), up).any()
    # Documented limit: a sheet closer than the offset is skipped (light leaks through it).
    leak_p = np.concatenate([lower_p, lower_p + (0, 0, 0.5 * bvh.offset)])
    leaky = Visibility(leak_p, faces, device=device, offset=bvh.offset)
    assert not _occluded_from(leaky, lower_p[inner], (0, 0, 1), up).any()


def test_offset_prevents_self_intersection(device, rng):
    """On a tilted sheet, rays leaving the surface without an offset hit their own triangles."""
    from scipy.spatial.transform import Rotation

    points, faces = _grid(11, 1.0, 0.0)
    rot = Rotation.from_euler("xyz", [0.37, -0.61, 0.2]).as_matrix()
    tilted = points @ rot.T + (0.3, 0.2, 0.1)
    normal = rot[:, 2]
    up = _hemisphere_dirs(200, True, rng) @ rot.T
    inner = _interior(points, 1.0, 0.2)
    acne = Visibility(tilted, faces, device=device, offset=1e-30)
    assert _occluded_from(acne, tilted[inner], normal, up).mean() > 0.5
    clean = Visibility(tilted, faces, device=device)
    assert not _occluded_from(clean, tilted[inner], normal, up).any()
