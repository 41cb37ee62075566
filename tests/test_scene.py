"""Scene.evaluate (Warp, float32) against the float64 mirror, ground planes, validation."""

import numpy as np
import pytest

from warpshade._wp import resolve_device
from warpshade.io import load_scene, load_usd
from warpshade.scene import FrameEvaluator, Mesh, Scene, SkinBinding, Skeleton, ground_plane

#: float32 positions of scenes a few metres across: a few ulps of the largest coordinate.
POINT_RTOL_SIZE = 1e-6
#: Normals are unit vectors recomputed from float32 points: errors grow with 1/(edge length)
#: of the smallest triangles (~1 cm on the bundled meshes), so compare at 1e-4.
NORMAL_ATOL = 1e-4


@pytest.fixture(scope="module")
def bundled():
    return {name: load_usd(f"bundled:{name}") for name in ("blockers", "figure", "cloth", "bend")}


@pytest.mark.parametrize("name", ["blockers", "figure", "cloth", "bend"])
def test_evaluate_matches_reference(bundled, device, name):
    scene = bundled[name]
    size = np.linalg.norm(np.subtract(*scene.bounds_over_frames()[::-1]))
    for frame in (scene.frames[0], scene.frames[len(scene.frames) // 2], scene.frames[-1]):
        state = scene.evaluate(frame, device=device)
        assert state.points.shape == (scene.vertex_count,) and state.normals.shape == (scene.vertex_count,)
        np.testing.assert_allclose(state.points.numpy(), scene.points_at(frame), atol=POINT_RTOL_SIZE * size)
        np.testing.assert_allclose(state.normals.numpy(), scene.normals_at(frame), atol=NORMAL_ATOL)
        assert state.frame == frame and scene.frames[state.frame_index] == frame


def test_evaluate_uses_authored_normals_for_static_meshes(device):
    scene = load_usd("warp-example:bunny")
    mesh = scene.meshes[0]
    state = scene.evaluate(0.0, device=device)
    np.testing.assert_allclose(state.normals.numpy(), mesh.normals, atol=NORMAL_ATOL)


def test_static_arrays_are_cached_per_device(bundled, device):
    scene = bundled["bend"]
    dev = resolve_device(device)
    scene.evaluate(0.0, device=device)
    cached = scene._device_cache[str(dev)]
    a = scene.evaluate(10.0, device=device)
    assert scene._device_cache[str(a.device)] is cached
    assert FrameEvaluator(scene, dev)._data is cached, "every evaluator of a device shares the static arrays"
    b = scene.evaluate(10.0, device=device)
    c = scene.evaluate(20.0, device=device)
    np.testing.assert_array_equal(a.points.numpy(), b.points.numpy())
    assert not np.array_equal(a.points.numpy(), c.points.numpy()), "evaluate() returns snapshots, not shared buffers"


def test_ground_plane_mesh_faces_up():
    for up, axis in (("Z", 2), ("Y", 1)):
        plane = ground_plane(np.array([-1.0, -2.0, 0.5]), np.array([1.0, 2.0, 3.0]), up, resolution=5)
        assert plane.vertex_count == 25 and plane.triangle_count == 32
        p = plane.points[plane.faces]
        n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        assert np.all(n[:, axis] > 0) and np.allclose(np.delete(n, axis, axis=1), 0.0)
        assert np.allclose(plane.points[:, axis], [0.5, -2.0, 0.5][axis])


def test_with_ground_plane_keeps_meshes_and_adds_a_floor():
    scene = load_scene("warp-example:bear", ground_plane=True, ground_resolution=12)
    bear, plane = scene.meshes
    assert plane.vertex_count == 144 and plane.vertex_offset == bear.vertex_count
    assert np.isclose(plane.points[:, 1].max(), bear.points[:, 1].min())
    extent = np.ptp(plane.points, axis=0)
    assert extent[0] == pytest.approx(extent[2]) and extent[0] >= 3.0 * np.ptp(bear.points[:, [0, 2]], axis=0).max() - 1e-9


def _two_joint_skeleton(frames=1):
    eye = np.repeat(np.eye(4)[None], 2, axis=0)
    return Skeleton("/Skel", ["A", "A/B"], np.array([-1, 0]), eye, eye, np.repeat(eye[None], frames, axis=0), np.eye(4)[None])


def test_scene_validation_names_the_mesh():
    tri = dict(points=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], faces=[[0, 1, 2]])
    bad_skin = SkinBinding(0, np.array([[0], [1], [2]], np.int32), np.ones((3, 1), np.float32))
    with pytest.raises(ValueError, match="mesh /Skinned: joint indices 0..2 do not match skeleton /Skel with 2 joints"):
        Scene([Mesh("/Skinned", animation="skinned", skin=bad_skin, **tri)], skeletons=[_two_joint_skeleton()])
    with pytest.raises(ValueError, match="mesh /Tri: face indices must lie in 0..2"):
        Scene([Mesh("/Tri", points=tri["points"], faces=[[0, 1, 3]])])
    with pytest.raises(ValueError, match="contains no meshes"):
        Scene([])
    scene = Scene([Mesh("/Tri", **tri)], frames=[1.0, 2.0])
    with pytest.raises(ValueError, match="frame 1.5 is not one of the sampled time codes"):
        scene.frame_index(1.5)
