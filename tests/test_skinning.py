"""Linear-blend skinning and rigid transform kernels against float64 mirrors."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from warpshade._wp import wp
from warpshade.geometry._skinning import (
    launch_transform_normals,
    launch_transform_points,
    skin_points,
    skin_points_f64,
)
from warpshade.scene import SkinBinding

#: float32 kernels: a few rounding steps of magnitude ~ scene size (points ~1, translations ~3).
ATOL_FLOAT32 = 5e-6


def _row_transform(rng, scale=1.0):
    m = np.eye(4)
    m[:3, :3] = Rotation.random(random_state=rng).as_matrix().T * scale
    m[3, :3] = rng.uniform(-3.0, 3.0, 3)
    return m


@pytest.fixture
def skin_case(rng):
    vertex_count, joint_count, influences = 400, 7, 3
    points = rng.uniform(-1.0, 1.0, (vertex_count, 3))
    idx = rng.integers(0, joint_count, (vertex_count, influences)).astype(np.int32)
    w = rng.uniform(0.0, 1.0, (vertex_count, influences))
    w /= w.sum(axis=1, keepdims=True)
    bind = _row_transform(rng)
    skin = SkinBinding(skeleton=0, joint_indices=idx, joint_weights=w.astype(np.float32), geom_bind_transform=bind)
    xfs = np.stack([_row_transform(rng, scale=rng.uniform(0.8, 1.2)) for _ in range(joint_count)])
    return points, skin, xfs


def test_reference_matches_per_vertex_formula(skin_case):
    points, skin, xfs = skin_case
    out = skin_points_f64(points, skin, xfs)
    # The definition, one vertex at a time: sum_k w_k [p, 1] @ bind @ X_jk.
    for v in (0, 17, 399):
        hom = np.append(points[v], 1.0) @ skin.geom_bind_transform
        expected = sum(float(skin.joint_weights[v, k]) * (hom @ xfs[skin.joint_indices[v, k]]) for k in range(3))
        np.testing.assert_allclose(out[v], expected[:3], rtol=1e-6)


def test_equal_joint_transforms_act_rigidly(skin_case, rng):
    points, skin, _ = skin_case
    rigid = _row_transform(rng)
    xfs = np.repeat(rigid[None], 7, axis=0)
    expected = (points @ skin.geom_bind_transform[:3, :3] + skin.geom_bind_transform[3, :3]) @ rigid[:3, :3] + rigid[3, :3]
    np.testing.assert_allclose(skin_points_f64(points, skin, xfs), expected, rtol=1e-6, atol=1e-6)


def test_warp_skinning_matches_reference(skin_case, device, rng):
    points, skin, xfs = skin_case
    post = _row_transform(rng)
    got = skin_points(points, skin, xfs, post_transform=post, device=device)
    ref = skin_points_f64(points, skin, xfs)
    ref = ref @ post[:3, :3] + post[3, :3]
    np.testing.assert_allclose(got, ref, atol=ATOL_FLOAT32 * 4)


def test_rigid_point_and_normal_kernels(device, rng):
    xf = _row_transform(rng, scale=1.0)
    xf[:3, :3] = xf[:3, :3] @ np.diag([0.5, 2.0, 1.0])  # non-uniform scale: normals need inverse transpose
    pts = rng.uniform(-1, 1, (50, 3))
    nrm = rng.normal(size=(50, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    src = wp.array(np.concatenate([pts, pts]).astype(np.float32), dtype=wp.vec3, device=device)
    out = wp.zeros(60, dtype=wp.vec3, device=device)
    launch_transform_points(src, 50, 50, xf, out, 10)  # second copy into rows 10..59
    got = out.numpy()
    np.testing.assert_array_equal(got[:10], 0.0)
    np.testing.assert_allclose(got[10:], pts @ xf[:3, :3] + xf[3, :3], atol=ATOL_FLOAT32 * 4)
    nout = wp.zeros(50, dtype=wp.vec3, device=device)
    launch_transform_normals(wp.array(nrm.astype(np.float32), dtype=wp.vec3, device=device), xf, nout)
    expected = nrm @ np.linalg.inv(xf[:3, :3]).T
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(nout.numpy(), expected, atol=ATOL_FLOAT32)
    # transformed normals stay perpendicular to transformed tangent vectors
    tangent = np.cross(nrm, rng.normal(size=(50, 3)))
    assert np.abs(np.sum((tangent @ xf[:3, :3]) * nout.numpy(), axis=1)).max() < 1e-5 * np.linalg.norm(tangent, axis=1).max() * 4
