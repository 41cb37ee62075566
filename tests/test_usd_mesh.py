"""USD mesh loading: triangulation, normals, UVs, albedo, animation, instancing, bad input.

Every case is a small .usda written into tmp_path; the expected values are worked out by hand
from the file text (the oracle), never from the loader.
"""

import hashlib
import os
import warnings

import numpy as np
import pytest

from warpshade.io import load_scene, load_usd, resolve_scene_path
from warpshade.io._usd_mesh import ZERO_AREA_RELATIVE

#: Values pass through USD float32 attributes; compare at float32 resolution.
ATOL_FLOAT32_IO = 1e-6
#: PointInstancer orientations are quath (half precision, 11-bit significand): ~5e-4 per unit.
ATOL_HALF_QUATERNION = 1e-3


def _write(tmp_path, text, name="scene.usda", up="Z", header_extra=""):
    path = tmp_path / name
    path.write_text(f'#usda 1.0\n(\n    upAxis = "{up}"\n{header_extra})\n' + text)
    return str(path)


QUAD_AND_PENTAGON = """
def Mesh "Poly"
{
    int[] faceVertexCounts = [4, 5]
    int[] faceVertexIndices = [0, 1, 2, 3, 1, 4, 5, 6, 2]
    point3f[] points = [(0,0,0), (1,0,0), (1,1,0), (0,1,0), (2,0,0), (2.5,0.5,0), (2,1,0)]
    %s
}
"""


def test_fan_triangulation_and_default_albedo(tmp_path):
    scene = load_usd(_write(tmp_path, QUAD_AND_PENTAGON % ""))
    mesh = scene.meshes[0]
    # quad -> 2 triangles, pentagon -> 3, fanned from each polygon's first corner
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 6], [1, 6, 2]])
    assert mesh.animation == "static" and scene.frames.tolist() == [0.0] and scene.up_axis == "Z"
    np.testing.assert_allclose(mesh.albedo, 0.8)
    assert mesh.normals is None and mesh.uvs is None
    # all triangles counter-clockwise seen from +Z
    p = mesh.points[mesh.faces]
    assert np.all(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 2] > 0)


CONCAVE = """
def Mesh "Concave"
{
    int[] faceVertexCounts = [6, 4, 4]
    int[] faceVertexIndices = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13]
    point3f[] points = [(2,1,0), (1,1,0), (1,2,0), (0,2,0), (0,0,0), (2,0,0),
                        (4,2.5,0), (3,0,0), (5,0,0), (4,1,0),
                        (6,0,0), (7,0,0), (7,1,0), (6,1,0)]
    %s
}
"""
#: shoelace areas of the L-hexagon (reflex corner (1,1)), the dart (reflex corner (4,1)) and the square
CONCAVE_AREAS = (3.0, 0.5 * abs((3 * 0 - 5 * 0) + (5 * 1 - 4 * 0) + (4 * 2.5 - 4 * 1) + (4 * 0 - 3 * 2.5)), 1.0)


@pytest.mark.parametrize("orientation", ["", 'uniform token orientation = "leftHanded"'])
def test_concave_polygons_are_ear_clipped(tmp_path, orientation):
    mesh = load_usd(_write(tmp_path, CONCAVE % orientation)).meshes[0]
    assert mesh.faces.shape == (4 + 2 + 2, 3)
    p = mesh.points[mesh.faces]
    cross_z = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 2]
    # every triangle keeps the polygon's winding: counter-clockwise seen from +Z, reversed for a
    # left-handed mesh (whose outward side is then -Z)
    sign = -1.0 if orientation else 1.0
    # (the cases are meaningful: a fan from each concave polygon's first corner folds over)
    for start, k in ((0, 6), (6, 4)):
        q = mesh.points[start:start + k]
        fan = np.cross(q[1:-1] - q[0], q[2:] - q[0])[:, 2]
        assert np.any(fan < 0)
    assert np.all(sign * cross_z > 0)
    # triangles tile each polygon exactly: their areas sum to the polygon's shoelace area (a fan
    # from the first corner of the L or the dart would overlap or leave it)
    areas = 0.5 * sign * cross_z
    np.testing.assert_allclose([areas[:4].sum(), areas[4:6].sum(), areas[6:].sum()], CONCAVE_AREAS, rtol=1e-6)
    # the convex square keeps its fan
    fan = np.array([[10, 11, 12], [10, 12, 13]])
    np.testing.assert_array_equal(mesh.faces[6:], fan[:, [0, 2, 1]] if orientation else fan)


def test_left_handed_orientation_and_holes(tmp_path):
    scene = load_usd(_write(tmp_path, QUAD_AND_PENTAGON % 'uniform token orientation = "leftHanded"\n    int[] holeIndices = [1]'))
    mesh = scene.meshes[0]
    np.testing.assert_array_equal(mesh.faces, [[0, 2, 1], [0, 3, 2]])


def test_normals_interpolations(tmp_path):
    # faceVarying: vertex 1 is shared by both polygons with normals (0,0,1) and (1,0,0); the
    # quad has area 1 and the pentagon area 1.25 + ... -> area-weighted average.
    text = QUAD_AND_PENTAGON % (
        "normal3f[] normals = [(0,0,1),(0,0,1),(0,0,1),(0,0,1),(1,0,0),(1,0,0),(1,0,0),(1,0,0),(1,0,0)] "
        '(interpolation = "faceVarying")'
    )
    mesh = load_usd(_write(tmp_path, text)).meshes[0]
    quad_area = 1.0
    pent = np.array([[1, 0], [2, 0], [2.5, 0.5], [2, 1], [1, 1]])
    pent_area = 0.5 * abs(np.dot(pent[:, 0], np.roll(pent[:, 1], -1)) - np.dot(pent[:, 1], np.roll(pent[:, 0], -1)))
    shared = np.array([pent_area, 0.0, quad_area])
    shared /= np.linalg.norm(shared)
    np.testing.assert_allclose(mesh.normals[1], shared, atol=ATOL_FLOAT32_IO)
    np.testing.assert_allclose(mesh.normals[0], [0, 0, 1], atol=ATOL_FLOAT32_IO)
    np.testing.assert_allclose(mesh.normals[4], [1, 0, 0], atol=ATOL_FLOAT32_IO)

    text = QUAD_AND_PENTAGON % 'normal3f[] primvars:normals = [(0,0,1),(0,1,0)] (interpolation = "uniform")'
    mesh = load_usd(_write(tmp_path, text, "uniform.usda")).meshes[0]
    np.testing.assert_allclose(mesh.normals[3], [0, 0, 1], atol=ATOL_FLOAT32_IO)
    np.testing.assert_allclose(mesh.normals[5], [0, 1, 0], atol=ATOL_FLOAT32_IO)


def test_uvs_and_display_color(tmp_path):
    text = QUAD_AND_PENTAGON % (
        "texCoord2f[] primvars:st = [(0,0),(1,0),(1,1),(0,1),(0.5,0),(1,0),(1,0.5),(1,1),(0.5,1)] "
        '(interpolation = "faceVarying")\n'
        'color3f[] primvars:displayColor = [(1,0,0),(0,0,1)] (interpolation = "uniform")'
    )
    mesh = load_usd(_write(tmp_path, text)).meshes[0]
    # vertex 1 has corners st (1,0) in the quad and (0.5,0) in the pentagon: plain average
    np.testing.assert_allclose(mesh.uvs[1], [0.75, 0.0], atol=ATOL_FLOAT32_IO)
    np.testing.assert_allclose(mesh.uvs[3], [0.0, 1.0], atol=ATOL_FLOAT32_IO)
    np.testing.assert_allclose(mesh.albedo[0], [1, 0, 0])
    np.testing.assert_allclose(mesh.albedo[5], [0, 0, 1])


MATERIAL = """
def Material "Mat"
{
    token outputs:surface.connect = </Mat/Surface.outputs:surface>
    def Shader "Surface"
    {
        uniform token info:id = "UsdPreviewSurface"
        %s
        token outputs:surface
    }
}
def Mesh "Tri" (prepend apiSchemas = ["MaterialBindingAPI"])
{
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
    point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]
    color3f[] primvars:displayColor = [(0.1, 0.2, 0.3)]
    rel material:binding = </Mat>
}
"""


def test_material_diffuse_color_wins_over_display_color(tmp_path):
    mesh = load_usd(_write(tmp_path, MATERIAL % "color3f inputs:diffuseColor = (0.5, 0.25, 0.125)")).meshes[0]
    np.testing.assert_allclose(mesh.albedo, np.tile([0.5, 0.25, 0.125], (3, 1)))
    # UsdPreviewSurface without an authored diffuseColor: the spec's fallback 0.18
    mesh = load_usd(_write(tmp_path, MATERIAL % "", "fallback.usda")).meshes[0]
    np.testing.assert_allclose(mesh.albedo, 0.18, atol=ATOL_FLOAT32_IO)


ANIMATED = """
def Xform "Mover"
{
    double3 xformOp:translate.timeSamples = { 1: (0, 0, 0), 3: (2, 0, 0) }
    uniform token[] xformOpOrder = ["xformOp:translate"]
    def Mesh "Box"
    {
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]
    }
}
def Mesh "Wave"
{
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
    point3f[] points.timeSamples = { 1: [(0,0,0), (1,0,0), (0,1,0)], 3: [(0,0,2), (1,0,0), (0,1,0)] }
}
def Mesh "Still"
{
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
    point3f[] points = [(5,0,0), (6,0,0), (5,1,0)]
}
"""


def test_animation_kinds_frames_and_fps(tmp_path):
    path = _write(tmp_path, ANIMATED, header_extra="    startTimeCode = 1\n    endTimeCode = 3\n    timeCodesPerSecond = 30\n")
    scene = load_usd(path)
    assert scene.frames.tolist() == [1.0, 2.0, 3.0] and scene.fps == 30.0
    kinds = {m.path: m.animation for m in scene.meshes}
    assert kinds == {"/Mover/Box": "rigid", "/Wave": "deforming", "/Still": "static"}
    box = scene.meshes[0]
    np.testing.assert_allclose(box.transforms[:, 3, :3], [[0, 0, 0], [1, 0, 0], [2, 0, 0]])  # linear interpolation
    wave = scene.points_at(2.0)[3:6]
    np.testing.assert_allclose(wave[0], [0, 0, 1])  # held/interpolated point samples
    assert not scene.is_static


def test_unranged_stage_is_sampled_at_its_time_samples(tmp_path):
    # no startTimeCode/endTimeCode: the union of the translate's and the points' samples, 1 and 3
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene = load_usd(_write(tmp_path, ANIMATED))
    assert scene.frames.tolist() == [1.0, 3.0]
    assert {m.path: m.animation for m in scene.meshes} == {"/Mover/Box": "rigid", "/Wave": "deforming", "/Still": "static"}
    np.testing.assert_allclose(scene.meshes[0].transforms[:, 3, :3], [[0, 0, 0], [2, 0, 0]])
    np.testing.assert_allclose(scene.points_at(3.0)[3], [0, 0, 2])


def test_purpose_and_visibility_are_skipped_and_implicit_prims_tessellated(tmp_path):
    tri = 'int[] faceVertexCounts = [3]\nint[] faceVertexIndices = [0, 1, 2]\npoint3f[] points = [(0,0,0), (1,0,0), (0,1,0)]'
    text = f"""
def Mesh "Shown" {{
{tri}
}}
def Mesh "Guide" {{
{tri}
    uniform token purpose = "guide"
}}
def Xform "Hidden" {{
    token visibility = "invisible"
    def Mesh "Child" {{
{tri}
    }}
}}
def Sphere "Ball" {{
}}
"""
    scene = load_usd(_write(tmp_path, text))
    assert [m.path for m in scene.meshes] == ["/Shown", "/Ball"] and scene.meshes[1].implicit == ("Sphere", {"radius": 1.0})
    assert dict(scene.skipped) == {"/Guide": "purpose guide", "/Hidden": "invisible"}


def test_instancing_is_flattened(tmp_path):
    text = """
def Xform "Proto"
{
    def Mesh "M"
    {
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]
    }
}
def Xform "A" (
    instanceable = true
    references = </Proto>
)
{
    double3 xformOp:translate = (10, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def Xform "B" (
    instanceable = true
    references = </Proto>
)
{
    double3 xformOp:translate = (0, 20, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def PointInstancer "Scatter"
{
    rel prototypes = </Scatter/Protos/Tri>
    int[] protoIndices = [0, 0]
    point3f[] positions = [(0, 0, 5), (0, 0, 7)]
    quath[] orientations = [(1, 0, 0, 0), (0.70710677, 0, 0, 0.70710677)]
    double3 xformOp:translate = (100, 0, 0)
    uniform token[] xformOpOrder = ["xformOp:translate"]
    def Xform "Protos"
    {
        def Xform "Tri"
        {
            double3 xformOp:translate = (0, 0, 1)
            uniform token[] xformOpOrder = ["xformOp:translate"]
            def Mesh "M"
            {
                int[] faceVertexCounts = [3]
                int[] faceVertexIndices = [0, 1, 2]
                point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]
            }
        }
    }
}
"""
    scene = load_usd(_write(tmp_path, text))
    by_path = {m.path: m for m in scene.meshes}
    assert set(by_path) == {"/Proto/M", "/A/M", "/B/M", "/Scatter/instance_0/M", "/Scatter/instance_1/M"}
    pts = scene.points_at(0.0)
    np.testing.assert_allclose(pts[by_path["/A/M"].vertex_offset + 1], [11, 0, 0])
    np.testing.assert_allclose(pts[by_path["/B/M"].vertex_offset + 2], [0, 21, 0])
    # instance 0: proto translate (0,0,1), then instance (0,0,5), then instancer (100,0,0)
    np.testing.assert_allclose(pts[by_path["/Scatter/instance_0/M"].vertex_offset + 1], [101, 0, 6], atol=1e-6)
    # instance 1 is turned 90 degrees about +Z: the point (1,0,0) goes to (0,1,0)
    np.testing.assert_allclose(pts[by_path["/Scatter/instance_1/M"].vertex_offset + 1], [100, 1, 8], atol=ATOL_HALF_QUATERNION)


CAMERA = """
def Camera "Cam"
{
    float focalLength = 50
    float verticalAperture = 24
    float focusDistance = 4
    double3 xformOp:translate = (0, 0, 4)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
def Mesh "Tri"
{
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
    point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]
}
"""


def test_camera(tmp_path):
    cam = load_usd(_write(tmp_path, CAMERA, up="Y")).camera
    assert cam.path == "/Cam"
    np.testing.assert_allclose(cam.position, [0, 0, 4])
    np.testing.assert_allclose(cam.target, [0, 0, 0], atol=1e-9)  # looks down its -Z
    np.testing.assert_allclose(cam.up, [0, 1, 0], atol=1e-9)
    assert cam.vertical_fov == pytest.approx(np.degrees(2 * np.arctan(12 / 50)), rel=1e-6)


# ---- bad input ------------------------------------------------------------------------------
def _tri_mesh(points="[(0,0,0), (1,0,0), (0,1,0)]", indices="[0, 1, 2]", counts="[3]", name="Bad"):
    return f'def Mesh "{name}" {{\n int[] faceVertexCounts = {counts}\n int[] faceVertexIndices = {indices}\n point3f[] points = {points}\n}}\n'


def test_missing_file_and_unknown_specs(tmp_path):
    with pytest.raises(FileNotFoundError, match="absent.usda"):
        load_usd(tmp_path / "absent.usda")
    with pytest.raises(FileNotFoundError, match="no_such_model.*available: .*bunny"):
        resolve_scene_path("warp-example:no_such_model")
    junk = tmp_path / "junk.usda"
    junk.write_text("this is not usd")
    with pytest.raises(ValueError, match="junk.usda"):
        load_usd(junk)


def test_no_meshes(tmp_path):
    with pytest.raises(ValueError, match="empty.usda.*no .*Mesh"):
        load_usd(_write(tmp_path, 'def Xform "Nothing" {}\n', "empty.usda"))


def test_non_finite_points(tmp_path):
    with pytest.raises(ValueError, match="/Bad.*NaN or infinite.*point 1"):
        load_usd(_write(tmp_path, _tri_mesh(points="[(0,0,0), (nan,0,0), (0,1,0)]")))
    with pytest.raises(ValueError, match="/Bad.*NaN or infinite"):
        load_usd(_write(tmp_path, _tri_mesh(points="[(0,0,0), (inf,0,0), (0,1,0)]"), "inf.usda"))


def test_face_indices_out_of_range_and_bad_counts(tmp_path):
    with pytest.raises(ValueError, match="/Bad.*out of range for 3 points"):
        load_usd(_write(tmp_path, _tri_mesh(indices="[0, 1, 3]")))
    with pytest.raises(ValueError, match="/Bad.*sum to 4 but there are 3"):
        load_usd(_write(tmp_path, _tri_mesh(counts="[4]"), "counts.usda"))
    with pytest.raises(ValueError, match="/Bad.*face 0 has 2 vertices"):
        load_usd(_write(tmp_path, _tri_mesh(counts="[2, 1]"), "two.usda"))


def test_zero_area_faces_are_dropped_with_a_warning(tmp_path):
    text = _tri_mesh(
        points="[(0,0,0), (1,0,0), (0,1,0), (2,0,0)]",
        indices="[0, 1, 2, 0, 1, 3, 1, 1, 2]",
        counts="[3, 3, 3]",
    )
    with pytest.warns(UserWarning, match="/Bad.*dropped 2 zero-area triangle"):
        scene = load_usd(_write(tmp_path, text))
    assert scene.meshes[0].dropped_face_count == 2 and scene.dropped_face_count == 2
    np.testing.assert_array_equal(scene.faces, [[0, 1, 2]])
    # a genuine sliver far above the threshold is kept
    eps = 10 * ZERO_AREA_RELATIVE**0.5
    sliver = _tri_mesh(points=f"[(0,0,0), (1,0,0), (0.5,{eps},0)]", name="Sliver")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_usd(_write(tmp_path, sliver, "sliver.usda")).meshes[0].triangle_count == 1


def test_loading_never_writes_to_inputs(tmp_path):
    path = _write(tmp_path, ANIMATED, header_extra="    startTimeCode = 1\n    endTimeCode = 3\n")
    before = {p: (os.stat(p).st_mtime_ns, hashlib.sha256(open(p, "rb").read()).hexdigest()) for p in [path]}
    listing = sorted(os.listdir(tmp_path))
    load_usd(path)
    assert sorted(os.listdir(tmp_path)) == listing
    assert {p: (os.stat(p).st_mtime_ns, hashlib.sha256(open(p, "rb").read()).hexdigest()) for p in [path]} == before


# ---- Warp's example assets ------------------------------------------------------------------
@pytest.mark.parametrize("name, vertices, triangles", [("bunny", 6102, 12200), ("bear", 1986, 3968)])
def test_warp_examples_load_with_ground_and_sky(name, vertices, triangles):
    plain = load_usd(f"warp-example:{name}")
    mesh = plain.meshes[0]
    assert (mesh.vertex_count, mesh.triangle_count) == (vertices, triangles)
    assert plain.up_axis == "Y" and len(plain.frames) == 1 and mesh.normals is not None
    # smooth faceVarying normals become per-vertex normals that agree with the geometry
    from warpshade.geometry._normals import vertex_normals_f64

    area_weighted = vertex_normals_f64(mesh.points, mesh.faces)
    assert np.median(np.sum(area_weighted * mesh.normals, axis=1)) > 0.99

    scene = load_scene(f"warp-example:{name}", ground_plane=True)
    assert len(scene.meshes) == 2 and len(scene.lights) == 1
    ground = scene.meshes[1]
    assert ground.vertex_count == 40 * 40
    lo = mesh.points.min(axis=0)
    np.testing.assert_allclose(ground.points[:, 1], lo[1])  # on the floor of the Y-up model
