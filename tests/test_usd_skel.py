"""UsdSkel loading: the Warp skinning kernel against UsdSkel's own skinning, joint angles, bad skins.

The oracle for skinning is ``UsdSkel.BakeSkinning`` run by USD itself on a temporary copy of the
bundled scene (the bundled file is never written).
"""

import os
import shutil

import numpy as np
import pytest

from warpshade.io import bundled_asset_directory, load_usd
from warpshade.usd_assets.generator import figure

#: Issue 3 asks the Warp skinning to agree with UsdSkel to 1e-4 of the model's size; float32
#: skinning of a ~2 m figure is good to ~1e-7 of its size, so this bound has a wide margin.
SKIN_RTOL_MODEL = 1e-4
#: The float64 mirror against USD's own (float32-stored) baked points.
SKIN_RTOL_REFERENCE = 1e-6
#: The generator rounds quaternion components to 1e-4 before writing them, so recovered joint
#: angles differ from the authored rotation vectors by up to a few 1e-4 rad.
ANGLE_ATOL = 1e-3

FRAMES = [0.0, 13.0, 29.0, 44.0, 59.0]


def _baked_world_points(tmp_path, name, root_path, mesh_path, frames):
    """USD's own skinning: BakeSkinning on a temp copy, read back in world space."""
    from pxr import Gf, Usd, UsdGeom, UsdSkel

    src = os.path.join(bundled_asset_directory(), f"{name}.usda")
    shutil.copy(src, tmp_path / f"{name}.usda")
    shutil.copy(os.path.join(bundled_asset_directory(), "sky.hdr"), tmp_path / "sky.hdr")
    stage = Usd.Stage.Open(str(tmp_path / f"{name}.usda"))
    assert UsdSkel.BakeSkinning(UsdSkel.Root(stage.GetPrimAtPath(root_path)), Gf.Interval(min(frames), max(frames)))
    prim = stage.GetPrimAtPath(mesh_path)
    out = {}
    for f in frames:
        local = np.array(UsdGeom.Mesh(prim).GetPointsAttr().Get(f), dtype=np.float64)
        xf = np.array(UsdGeom.XformCache(f).GetLocalToWorldTransform(prim))
        out[f] = local @ xf[:3, :3] + xf[3, :3]
    return out


@pytest.mark.parametrize(
    "name, root_path, mesh_path",
    [("figure", "/World/Figure", "/World/Figure/Body"), ("bend", "/World/Bend", "/World/Bend/Tube")],
)
def test_warp_skinning_agrees_with_usdskel(tmp_path, device, name, root_path, mesh_path):
    scene = load_usd(f"bundled:{name}")
    mesh = next(m for m in scene.meshes if m.path == mesh_path)
    assert mesh.animation == "skinned"
    sl = slice(mesh.vertex_offset, mesh.vertex_offset + mesh.vertex_count)
    baked = _baked_world_points(tmp_path, name, root_path, mesh_path, FRAMES)
    size = np.linalg.norm(np.ptp(baked[FRAMES[0]], axis=0))
    worst = 0.0
    for f in FRAMES:
        warp_pts = scene.evaluate(f, device=device).points.numpy()[sl]
        ref_pts = scene.points_at(f)[sl]
        worst = max(worst, np.abs(warp_pts - baked[f]).max() / size)
        assert np.abs(ref_pts - baked[f]).max() <= SKIN_RTOL_REFERENCE * size
    assert worst <= SKIN_RTOL_MODEL
    # the animation really moves the mesh, so the agreement is not trivial
    assert np.abs(baked[FRAMES[2]] - baked[FRAMES[0]]).max() > 0.1 * size


def test_figure_skeleton_structure_and_joint_angles():
    scene = load_usd("bundled:figure")
    skel = scene.skeletons[0]
    assert skel.joint_count == len(figure.FIGURE_JOINTS) >= 10
    assert [n.rsplit("/", 1)[-1] for n in skel.joint_names] == [j[0] for j in figure.FIGURE_JOINTS]
    names = [j[0] for j in figure.FIGURE_JOINTS]
    expected_parents = [-1 if p is None else names.index(p) for _, p, _ in figure.FIGURE_JOINTS]
    np.testing.assert_array_equal(skel.parents, expected_parents)
    assert skel.local_transforms.shape[0] == len(scene.frames) >= 60
    for f in (0, 7, 22, 45):
        np.testing.assert_allclose(skel.joint_angles(f), figure.figure_joint_rotations(f), atol=ANGLE_ATOL)
    # the root of the figure stands where the SkelRoot puts it
    np.testing.assert_allclose(skel.skel_to_world[0][3, :3], figure.FIGURE_ROOT_TRANSLATE, atol=1e-9)


SKEL_FILE = """#usda 1.0
(
    upAxis = "Z"
    startTimeCode = 0
    endTimeCode = 2
)
def SkelRoot "Root"
{
    def Skeleton "Skel"
    {
        uniform token[] joints = ["A", "A/B"]
        uniform matrix4d[] bindTransforms = [((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,0,1)), ((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,1,1))]
        uniform matrix4d[] restTransforms = [((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,0,1)), ((1,0,0,0),(0,1,0,0),(0,0,1,0),(0,0,1,1))]
    }
    def Mesh "Skin" (prepend apiSchemas = ["SkelBindingAPI"])
    {
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0,0,0), (1,0,0), (0,0,2)]
        rel skel:skeleton = </Root/Skel>
        %s
    }
}
"""


def _skel_file(tmp_path, binding, name="skin.usda"):
    path = tmp_path / name
    path.write_text(SKEL_FILE % binding)
    return str(path)


def test_valid_small_skin_remaps_joint_order(tmp_path):
    binding = (
        'uniform token[] skel:joints = ["A/B", "A"]\n'
        'int[] primvars:skel:jointIndices = [1, 1, 0] (elementSize = 1\n interpolation = "vertex")\n'
        'float[] primvars:skel:jointWeights = [1, 1, 1] (elementSize = 1\n interpolation = "vertex")'
    )
    scene = load_usd(_skel_file(tmp_path, binding))
    mesh = scene.meshes[0]
    # skin order ["A/B", "A"] -> skeleton order: index 1 (A) -> 0, index 0 (A/B) -> 1
    np.testing.assert_array_equal(mesh.skin.joint_indices[:, 0], [0, 0, 1])
    # no animation: points at rest, the world equals the authored points
    np.testing.assert_allclose(scene.points_at(1.0), mesh.points, atol=1e-12)


def test_constant_skinning_is_broadcast(tmp_path):
    binding = (
        'int[] primvars:skel:jointIndices = [1, 0] (elementSize = 2\n interpolation = "constant")\n'
        'float[] primvars:skel:jointWeights = [3, 1] (elementSize = 2\n interpolation = "constant")'
    )
    mesh = load_usd(_skel_file(tmp_path, binding)).meshes[0]
    np.testing.assert_array_equal(mesh.skin.joint_indices, [[1, 0]] * 3)
    np.testing.assert_allclose(mesh.skin.joint_weights, [[0.75, 0.25]] * 3)  # renormalised


def test_joint_indices_out_of_range(tmp_path):
    binding = (
        'int[] primvars:skel:jointIndices = [0, 1, 2] (elementSize = 1\n interpolation = "vertex")\n'
        'float[] primvars:skel:jointWeights = [1, 1, 1] (elementSize = 1\n interpolation = "vertex")'
    )
    with pytest.raises(ValueError, match="/Root/Skin.*jointIndices 0..2 out of range for 2 joints"):
        load_usd(_skel_file(tmp_path, binding))


def test_skin_joints_not_in_skeleton(tmp_path):
    binding = (
        'uniform token[] skel:joints = ["A", "A/Missing"]\n'
        'int[] primvars:skel:jointIndices = [0, 1, 1] (elementSize = 1\n interpolation = "vertex")\n'
        'float[] primvars:skel:jointWeights = [1, 1, 1] (elementSize = 1\n interpolation = "vertex")'
    )
    with pytest.raises(ValueError, match="/Root/Skin.*not in skeleton /Root/Skel: A/Missing"):
        load_usd(_skel_file(tmp_path, binding))


def test_bad_weights_and_counts(tmp_path):
    zero = (
        'int[] primvars:skel:jointIndices = [0, 1, 1] (elementSize = 1\n interpolation = "vertex")\n'
        'float[] primvars:skel:jointWeights = [1, 0, 1] (elementSize = 1\n interpolation = "vertex")'
    )
    with pytest.raises(ValueError, match="/Root/Skin.*1 point\\(s\\) have all-zero joint weights"):
        load_usd(_skel_file(tmp_path, zero))
    short = (
        'int[] primvars:skel:jointIndices = [0, 1] (elementSize = 1\n interpolation = "vertex")\n'
        'float[] primvars:skel:jointWeights = [1, 1] (elementSize = 1\n interpolation = "vertex")'
    )
    with pytest.raises(ValueError, match="/Root/Skin.*2 jointIndices for 3 points"):
        load_usd(_skel_file(tmp_path, short, "short.usda"))
