"""Per-vertex tangent frames: Warp kernel vs float64 mirror, rotation with the surface,
temporal coherence, and the degenerate-case fallback."""

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from warpshade._wp import wp
from warpshade.geometry._frames import DEGENERATE_STRETCH, TangentFrames, frame_rule, tangent_frames_f64
from warpshade.geometry._normals import vertex_normals_f64

from tolerances import ATOL_FLOAT32

# Orthonormality of float32 frames (three normalised/cross-product rows).
ORTHO_FLOAT32 = 1e-5


def _frames(tf, points, normals, device):
    p = wp.array(np.asarray(points, np.float32), dtype=wp.vec3, device=device)
    n = wp.array(np.asarray(normals, np.float32), dtype=wp.vec3, device=device)
    return tf.compute(p, n).numpy().astype(np.float64)


def _bend(points, amount):
    """Roll a z = 0 sheet onto a cylinder of radius 1/amount (turning x by amount * x radians)
    and shear it in y: a smooth, non-rigid deformation, the identity at amount 0."""
    x, y = points[:, 0], points[:, 1]
    if amount == 0.0:
        return points.copy()
    return np.stack([np.sin(amount * x) / amount, y + 0.1 * amount * x * x, (1.0 - np.cos(amount * x)) / amount], 1)


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(2)
    return np.asarray(m.vertices), np.asarray(m.faces)


@pytest.fixture(scope="module")
def sheet():
    """An open 2 x 1 sheet in the z = 0 plane, 21 x 11 vertices, slightly irregular."""
    gx, gy = np.meshgrid(np.linspace(-1, 1, 21), np.linspace(-0.5, 0.5, 11), indexing="ij")
    jitter = 0.02 * np.sin(7.0 * gx + 3.0 * gy)
    points = np.stack([gx.ravel() + jitter.ravel(), gy.ravel() - jitter.ravel(), np.zeros(gx.size)], 1)
    idx = np.arange(gx.size).reshape(gx.shape)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return points, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def _check_orthonormal(frames, normals):
    gram = np.einsum("vij,vkj->vik", frames, frames)
    assert np.abs(gram - np.eye(3)).max() < ORTHO_FLOAT32
    assert np.abs(np.linalg.det(frames) - 1.0).max() < ORTHO_FLOAT32  # right-handed
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    assert np.abs(frames[:, 2] - n).max() < ORTHO_FLOAT32  # third row is the vertex normal


def test_kernel_matches_reference(device, sphere, rng):
    points, faces = sphere
    tf = TangentFrames(points, faces, device=device)
    moved = points + 0.15 * np.sin(2.0 * points[:, [2, 0, 1]]) + 0.01 * rng.normal(size=points.shape)
    normals = vertex_normals_f64(moved, faces)
    got = _frames(tf, moved, normals, device)
    ref = tangent_frames_f64(moved, normals, tf.rule)
    np.testing.assert_allclose(got, ref, atol=ATOL_FLOAT32)
    _check_orthonormal(got, normals)


def test_rigid_motion_rotates_frames_exactly(device, sphere):
    points, faces = sphere
    tf = TangentFrames(points, faces, device=device)
    rot = Rotation.from_euler("zyx", [0.7, -1.1, 2.3]).as_matrix()
    normals = vertex_normals_f64(points, faces)
    before = tangent_frames_f64(points, normals, tf.rule)
    after = _frames(tf, points @ rot.T + (3.0, -1.0, 2.0), normals @ rot.T, device)
    # rows are world vectors: every row turns with the surface, F' = F R^T
    np.testing.assert_allclose(after, before @ rot.T, atol=ATOL_FLOAT32)


def test_frames_change_smoothly_over_a_deformation(sheet):
    """Per-step frame change shrinks in proportion to the step (no flips or jumps)."""
    points, faces = sheet
    rule = frame_rule(points, faces)

    def frames_at(amount):
        moved = _bend(points, amount)
        return tangent_frames_f64(moved, vertex_normals_f64(moved, faces), rule)

    steps = np.linspace(0.0, 1.5, 16)
    change = [np.abs(frames_at(b) - frames_at(a)).max() for a, b in zip(steps[:-1], steps[1:])]
    half = [np.abs(frames_at(a + (b - a) / 2) - frames_at(a)).max() for a, b in zip(steps[:-1], steps[1:])]
    step = steps[1] - steps[0]
    # Lipschitz in the deformation parameter: halving the step halves the change (within 20%).
    ratio = np.asarray(change) / np.asarray(half)
    assert np.all((ratio > 1.6) & (ratio < 2.4))
    # The surface turns by at most step * max|x| ~ step radians per step; frames follow it with
    # no more than 1.5x that change per matrix entry (the shear adds a little).
    assert max(change) < 1.5 * step


def test_degenerate_neighbourhoods_never_nan(device):
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.5, 0.5, 0.0], [5, 5, 5]], float)
    faces = np.array([[0, 1, 4], [1, 3, 4], [3, 2, 4], [2, 0, 4]])  # vertex 5 is isolated
    tf = TangentFrames(points, faces, device=device)
    normals = vertex_normals_f64(points, faces)
    rest = _frames(tf, points, normals, device)
    _check_orthonormal(rest, normals)
    # Collapse the whole mesh to one point: every edge has zero length.
    collapsed = np.repeat(points[4:5], len(points), axis=0)
    zero_normals = np.zeros_like(points)
    got = _frames(tf, collapsed, zero_normals, device)
    assert np.all(np.isfinite(got))
    # zero normals fall back to the rest normals; zero edges to the rest tangents
    np.testing.assert_allclose(got, tangent_frames_f64(points, normals, tf.rule), atol=ATOL_FLOAT32)
    np.testing.assert_allclose(got, tangent_frames_f64(collapsed, zero_normals, tf.rule), atol=ATOL_FLOAT32)
    # A normal opposite to the rest normal (the transport's singular case) stays finite.
    flipped = _frames(tf, collapsed, -normals, device)
    _check_orthonormal(flipped, -normals)


def test_fallback_blend_is_continuous(device):
    """Shrinking the one-ring through DEGENERATE_STRETCH moves the tangent continuously."""
    ring = np.array([[np.cos(a), np.sin(a), 0.0] for a in np.linspace(0, 2 * np.pi, 7)[:-1]])
    points = np.concatenate([[[0.0, 0.0, 0.0]], ring])
    faces = np.array([[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)])
    tf = TangentFrames(points, faces, device=device)
    normals = vertex_normals_f64(points, faces)
    twist = Rotation.from_rotvec([0.0, 0.0, 0.9]).as_matrix()  # rotate the ring about the normal

    def tangent(scale):
        moved = points.copy()
        moved[1:] = scale * ring @ twist.T
        return tangent_frames_f64(moved, normals, tf.rule)[0, 0]

    eps = 1e-4
    # the centre's |t_raw| equals the scale times its rest value (>= 1): scan across the threshold
    rest_len = np.linalg.norm((tf.rule.weights[:, None] * (points[tf.rule.neighbours] - points[0]))[: tf.rule.offsets[1]].sum(0))
    s0 = DEGENERATE_STRETCH / rest_len
    for s in (s0, 0.5 * s0):
        assert np.linalg.norm(tangent(s * (1 + eps)) - tangent(s * (1 - eps))) < 1e-3
    # far above the threshold the tangent is the twisted edge rule; at zero the rest tangent
    np.testing.assert_allclose(tangent(1.0), twist @ tf.rule.rest_tangents[0], atol=1e-12)
    np.testing.assert_allclose(tangent(0.0), tf.rule.rest_tangents[0], atol=1e-12)
    kernel = _frames(tf, points, normals, device)[0, 0]
    np.testing.assert_allclose(kernel, tf.rule.rest_tangents[0], atol=ATOL_FLOAT32)


def test_frame_rule_rejects_bad_faces(sphere):
    points, faces = sphere
    with pytest.raises(ValueError, match="faces index"):
        frame_rule(points, faces + len(points))
