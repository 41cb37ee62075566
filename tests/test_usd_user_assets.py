"""Scenes as users have them (issue 38, item 2; issue 39): stages without a time range sampled at
their own animation, static assets without ``frame_count``, ``warpshade run GRAPH --scene FILE``,
implicit prims tessellated, every skipped prim named, and ``warpshade info FILE | head``.

The exact cases are small stages written with their text into ``tmp_path``: the expected values
come from the file text and the UsdGeom schemas (analytic surfaces, areas and volumes), never from
the loader. Real assets are loaded from the installed packages (Warp's examples, Newton's
examples) and skipped when those are absent; nothing is copied into the repository.
"""

import json
import math
import os
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest

from warpshade import cli
from warpshade.graph import GraphError, extend_static_frames, load
from warpshade.graph._scene_inputs import scene_animation
from warpshade.io import load_usd
from warpshade.io._usd_implicit import IMPLICIT_TYPES, SEGMENTS, tessellate

ROOT = Path(__file__).resolve().parents[1]
#: Tessellated vertices are computed in float64 from sin/cos of exact angles: on the analytic
#: surface to a few ulps of the shape's size.
ON_SURFACE_RTOL = 1e-12
#: Shapes whose transform goes through USD's double-precision matrices, compared in world space.
WORLD_RTOL = 1e-9
#: At SEGMENTS = 32 (11.25 degree steps) inscribed polyhedra lose at most the sphere's 0.8 % of
#: area and 1.6 % of volume (every curved part uses the same angular step).
AREA_RTOL = 1e-2
VOLUME_RTOL = 2e-2
#: Doubling the segments divides those errors by about 4 (second order); 0.3 leaves a margin.
CONVERGENCE_RATIO = 0.3
#: Grids (cube faces, planes) are exact.
EXACT_RTOL = 1e-12


@pytest.fixture(autouse=True)
def _private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("WARPSHADE_CACHE", str(tmp_path_factory.getbasetemp() / "user-assets-cache"))


def _write(path: Path, body: str, header: str = "") -> Path:
    path.write_text(f'#usda 1.0\n(\n    upAxis = "Z"\n{header})\n' + textwrap.dedent(body))
    return path


TRIANGLE = """
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
"""


def _tri(name: str, points: str, extra: str = "") -> str:
    return f'def Mesh "{name}"\n{{{TRIANGLE}    {points}\n{extra}}}\n'


# ---- 1. time-sampled stages without startTimeCode/endTimeCode ------------------------------------
def test_time_sampled_points_without_a_range_are_read_at_their_samples(tmp_path, device):
    path = _write(tmp_path / "wave.usda", _tri(
        "Wave", "point3f[] points.timeSamples = { 0: [(0,0,0), (1,0,0), (0,1,0)], 0.5: [(0,0,1), (1,0,0), (0,1,0)], "
                "2.25: [(0,0,3), (1,0,0), (0,1,0)] }"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "loading time code 0 only" any more
        scene = load_usd(path)
    assert scene.frames.tolist() == [0.0, 0.5, 2.25], "fractional time samples stay fractional"
    mesh = scene.meshes[0]
    assert mesh.animation == "deforming" and mesh.point_samples.shape == (3, 3, 3)
    for frame, z in [(0.0, 0.0), (0.5, 1.0), (2.25, 3.0)]:
        np.testing.assert_allclose(scene.points_at(frame)[0], [0, 0, z])
        np.testing.assert_allclose(scene.evaluate(frame, device=device).points.numpy()[0], [0, 0, z], atol=1e-6)
    with pytest.raises(ValueError, match="frame 1 is not one of the sampled time codes"):
        scene.frame_index(1)


def test_the_union_of_points_xforms_and_lights_gives_the_frames(tmp_path):
    body = _tri("Wave", "point3f[] points.timeSamples = { 1: [(0,0,0), (1,0,0), (0,1,0)], 4: [(0,0,2), (1,0,0), (0,1,0)] }")
    body += """
    def Xform "Mover"
    {
        double3 xformOp:translate.timeSamples = { 2: (0, 0, 0), 6: (4, 0, 0) }
        uniform token[] xformOpOrder = ["xformOp:translate"]
    """ + _tri("Box", "point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]") + """
    }
    def DistantLight "Sun"
    {
        float xformOp:rotateX.timeSamples = { 3: 0, 7: 90 }
        uniform token[] xformOpOrder = ["xformOp:rotateX"]
    }
    def Mesh "Guide" (
    )
    {
        uniform token purpose = "guide"
        double3 xformOp:translate.timeSamples = { 100: (0, 0, 0), 200: (1, 0, 0) }
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    """
    scene = load_usd(_write(tmp_path / "union.usda", body))
    # points 1, 4; translate 2, 6; the light's rotateX 3, 7; a guide prim's samples do not count
    assert scene.frames.tolist() == [1.0, 2.0, 3.0, 4.0, 6.0, 7.0]
    kinds = {m.path: m.animation for m in scene.meshes}
    assert kinds == {"/Wave": "deforming", "/Mover/Box": "rigid"}
    np.testing.assert_allclose(scene.points_at(4.0)[3], [2, 0, 0])  # the translate interpolated: 4 * (4-2)/(6-2)
    assert scene.lights[0].track is not None


def test_skel_animation_without_a_range_is_read_at_its_samples(tmp_path):
    from warpshade.io import bundled_asset_directory

    text = (Path(bundled_asset_directory()) / "bend.usda").read_text()
    stripped = "\n".join(line for line in text.splitlines() if not line.strip().startswith(("startTimeCode", "endTimeCode")))
    (tmp_path / "bend.usda").write_text(stripped)
    (tmp_path / "sky.hdr").symlink_to(Path(bundled_asset_directory()) / "sky.hdr")
    ranged = load_usd("bundled:bend")
    unranged = load_usd(tmp_path / "bend.usda")
    assert unranged.frames.tolist() == ranged.frames.tolist() == [float(f) for f in range(60)]
    np.testing.assert_allclose(unranged.skeletons[0].local_transforms, ranged.skeletons[0].local_transforms)


def test_too_many_time_samples_are_refused_naming_the_attribute(tmp_path, monkeypatch):
    import warpshade.io._usd as usd

    samples = ", ".join(f"{t}: [(0,0,{t}), (1,0,0), (0,1,0)]" for t in range(6))
    path = _write(tmp_path / "long.usda", _tri("Long", f"point3f[] points.timeSamples = {{ {samples} }}"))
    monkeypatch.setattr(usd, "MAX_TIME_CODES", 5)
    with pytest.raises(ValueError, match=r"long\.usda: the stage has no startTimeCode/endTimeCode .* more than 5 time "
                                         r"samples \(reached at /Long\.points\).*are sampled: author startTimeCode"):
        load_usd(path)


# ---- 2. static assets need no frame_count --------------------------------------------------------
def test_a_static_asset_is_one_frame_and_animated_lights_give_it_frames(tmp_path):
    still = load_usd(_write(tmp_path / "still.usda", _tri("Still", "point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]")))
    assert still.frames.tolist() == [0.0] and still.is_static and scene_animation(still) is None
    lit = _tri("Still", "point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]") + """
    def DistantLight "Sun"
    {
        float xformOp:rotateY.timeSamples = { 0: 0, 12: 60, 24: 120 }
        uniform token[] xformOpOrder = ["xformOp:rotateY"]
    }
    """
    scene = load_usd(_write(tmp_path / "lit.usda", lit))
    assert scene.frames.tolist() == [0.0, 12.0, 24.0] and scene.is_static
    assert scene_animation(scene) == "light /Sun moves"
    with pytest.raises(GraphError, match=r"frame_count only applies to static scenes \(in this one light /Sun moves; "
                                         r"it runs its own 3 time codes 0\.\.24\)"):
        extend_static_frames(scene, 48)
    assert extend_static_frames(still, 4).frames.tolist() == [0.0, 1.0, 2.0, 3.0]


GRAPH = """\
[graph]
name = "g"
scene = "{scene}"
output = "shade.radiance"
{extra}
[lighting]
source = "sky"

[validate]
frames = {validate}
samples = 16

[[stage]]
name = "shade"
type = "prt.unshadowed"
order = 2
"""


def _graph(tmp_path: Path, scene: str, extra: str = "", validate: str = "[0, 12]") -> Path:
    g = tmp_path / "g.toml"
    g.write_text(GRAPH.format(scene=scene, extra=extra, validate=validate))
    return g


def _cube(tmp_path: Path, name: str = "cube.usda") -> Path:
    from grids import CUBE_USDA

    path = tmp_path / name
    path.write_text(CUBE_USDA)
    return path


def test_copied_validate_frames_on_a_static_scene_measure_its_one_frame(tmp_path, capsys):
    _cube(tmp_path)
    g = _graph(tmp_path, "cube.usda")  # no frame_count: one frame; [validate] frames = [0, 12]
    spec = load(g)
    scene = spec.load_scene()
    plan = spec.validation_plan(scene)
    assert (plan.measured, plan.not_in_scene, plan.fallback) == ([0.0], [12.0], False)
    assert plan.note() == ("--validate measures frame(s) 0; [validate] frame(s) 12 are not time codes of the scene "
                           "(one frame, time code 0) and are left out")
    spec.compile(scene, device="cpu", progress=False, cache_dir=None)  # compiles: [validate] frames no longer fail
    g = _graph(tmp_path, "cube.usda", validate="[12, 24]")
    out = tmp_path / "o"
    rc = cli.main(["run", str(g), "--validate", "--out", str(out), "--no-previews", "--device", "cpu"])
    printed, err = capsys.readouterr()
    assert rc == 0, err
    assert ("--validate measures frame(s) 0 (the first frame run); [validate] frame(s) 12, 24 are not time codes of the "
            "scene (one frame, time code 0) and are left out") in err
    assert "[12.0, 24.0] are not time codes of the scene (one frame, time code 0) and were not measured; measured the " \
           "first frame run, 0" in printed
    report = json.loads((out / "g.json").read_text())
    assert [m["frame"] for m in report["error"]["per_frame"]] == [0.0]
    assert report["error"]["frames_left_out"] == [12.0, 24.0]


# ---- 3. warpshade run GRAPH --scene FILE ---------------------------------------------------------
def test_run_with_scene_replaces_the_graphs_scene(tmp_path, capsys, monkeypatch):
    _cube(tmp_path)
    g = _graph(tmp_path, "cube.usda", extra="frame_count = 4", validate="[0, 2]")
    other = tmp_path / "elsewhere"
    other.mkdir()
    _write(other / "ball.usda", 'def Sphere "Ball"\n{\n    double radius = 0.5\n}\n')
    monkeypatch.chdir(other)  # --scene is relative to the current directory, not the graph file
    rc = cli.main(["run", str(g), "--scene", "ball.usda", "--validate", "--out", str(tmp_path / "o"), "--no-previews",
                   "--device", "cpu"])
    printed, err = capsys.readouterr()
    assert rc == 0, err
    report = json.loads((tmp_path / "o" / "g.json").read_text())
    assert report["scene"]["source"] == "ball.usda" and report["scene"]["meshes"] == ["/Ball"]
    assert report["frames_run"] == [0.0, 1.0, 2.0, 3.0], "the graph's frame_count applies to a static --scene"
    assert [m["frame"] for m in report["error"]["per_frame"]] == [0.0, 2.0]


def test_run_with_an_animated_scene_skips_frame_count_and_says_so(tmp_path, capsys):
    _cube(tmp_path)
    g = _graph(tmp_path, "cube.usda", extra="frame_count = 48", validate="[0, 24]")
    wave = _write(tmp_path / "wave.usda", _tri(
        "Wave", "point3f[] points.timeSamples = { 1: [(0,0,0), (1,0,0), (0,1,0)], 2: [(0,0,1), (1,0,0), (0,1,0)], "
                "3: [(0,0,2), (1,0,0), (0,1,0)] }"))
    rc = cli.main(["run", str(g), "--scene", str(wave), "--out", str(tmp_path / "o"), "--no-previews", "--device", "cpu"])
    printed, err = capsys.readouterr()
    assert rc == 0, err
    assert (f"--scene {wave} is animated (mesh /Wave is deforming): the graph's frame_count = 48 is for static scenes and "
            "is not applied; the run steps the scene's 3 time codes 1..3") in err
    assert json.loads((tmp_path / "o" / "g.json").read_text())["frames_run"] == [1.0, 2.0, 3.0]
    # the graph naming an animated scene itself keeps the error
    g2 = _graph(tmp_path, "wave.usda", extra="frame_count = 48")
    with pytest.raises(GraphError, match="frame_count only applies to static scenes .*mesh /Wave is deforming"):
        load(g2).load_scene()


@pytest.mark.parametrize("given", ["my.usd", "my.usda", "warp-example:bunny", "bundled:figure"])
def test_a_usd_scene_where_a_graph_is_expected_says_how_to_run_one(tmp_path, capsys, monkeypatch, given):
    monkeypatch.chdir(tmp_path)
    if given.startswith("my"):
        _write(tmp_path / given, _tri("T", "point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]"))
    rc = cli.main(["run", given])
    err = capsys.readouterr().err
    assert rc == 2 and "invalid TOML" not in err and "Traceback" not in err
    assert f"error: {given} is a USD scene" in err
    assert f"warpshade run stages/bunny_prt.toml --scene {given}" in err


def test_the_loader_names_a_usd_file_given_as_a_graph(tmp_path):
    binary = tmp_path / "scene.toml"  # a binary layer under a misleading name
    from pxr import Usd

    Usd.Stage.CreateNew(str(tmp_path / "s.usdc")).Save()
    binary.write_bytes((tmp_path / "s.usdc").read_bytes())
    with pytest.raises(GraphError, match=r"scene\.toml: is a USD scene \(a binary USD layer\), not a stage graph"):
        load(binary)


# ---- 4. implicit prims tessellated ---------------------------------------------------------------
def _axis_frame(points, axis):
    """(coordinate along the spine, distance from it) of local points."""
    k = "XYZ".index(axis)
    along = points[:, k]
    radial = np.linalg.norm(np.delete(points, k, axis=1), axis=1)
    return along, radial


def _surface_residual(kind, p, points):
    """Largest distance of ``points`` (local space) from the analytic surface of the UsdGeom shape."""
    axis = p.get("axis", "Z")
    a, rho = _axis_frame(points, axis)
    if kind == "Sphere":
        return np.abs(np.linalg.norm(points, axis=1) - p["radius"]).max()
    if kind == "Cube":
        return np.abs(np.abs(points).max(axis=1) - p["size"] / 2).max()
    if kind == "Plane":
        return np.abs(a).max()
    if kind in ("Capsule", "Capsule_1"):
        rb, rt = (p["radius"],) * 2 if kind == "Capsule" else (p["radiusBottom"], p["radiusTop"])
        h = p["height"]
        db = np.hypot(a + h / 2, rho) - rb  # the bottom sphere
        dt = np.hypot(a - h / 2, rho) - rt  # the top sphere
        s = (rb - rt) / h  # the cone tangent to both: outward normal (sin, cos) in (along, radial)
        side = s * (a + h / 2) + math.sqrt(1 - s * s) * rho - rb
        on_one = np.minimum(np.minimum(np.abs(db), np.abs(dt)), np.abs(side))
        return np.maximum(on_one, np.maximum(-np.minimum(db, dt), 0.0)).max()  # and inside neither sphere
    h = p["height"]
    rb = p.get("radiusBottom", p.get("radius"))
    rt = p.get("radiusTop", p["radius"] if kind == "Cylinder" else 0.0)
    side = np.abs(rho - (rb + (rt - rb) * (a + h / 2) / h))
    caps = np.where(np.isclose(np.abs(a), h / 2, atol=1e-12), 0.0, np.inf)
    inside = np.maximum(rho - np.where(a < 0, rb, rt), 0.0)
    return np.minimum(side, np.maximum(caps, inside)).max()


def _area_volume(points, faces):
    a, b, c = points[faces[:, 0]], points[faces[:, 1]], points[faces[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()
    volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0  # > 0 for outward (counter-clockwise) windings
    return area, volume


def _capsule_1(rb, rt, h):
    """Area and volume of the convex hull of spheres rb at -h/2 and rt at +h/2 (USD's Capsule_1)."""
    s = (rb - rt) / h
    c = math.sqrt(1 - s * s)
    cap_b, cap_t = rb * (1 + s), rt * (1 - s)  # heights of the spherical caps kept
    slant = math.hypot((rb - rt) * c, h + (rt - rb) * s)
    area = 2 * math.pi * rb * cap_b + 2 * math.pi * rt * cap_t + math.pi * (rb * c + rt * c) * slant
    vol_caps = math.pi * cap_b ** 2 * (3 * rb - cap_b) / 3 + math.pi * cap_t ** 2 * (3 * rt - cap_t) / 3
    length = h + (rt - rb) * s
    vol_frustum = math.pi * length * ((rb * c) ** 2 + rb * c * rt * c + (rt * c) ** 2) / 3
    return area, vol_caps + vol_frustum


SHAPES = {
    # type: (attributes as authored, parameters, analytic (area, volume))
    "Sphere": ("double radius = 0.7", {"radius": 0.7}, (4 * math.pi * 0.49, 4 / 3 * math.pi * 0.343)),
    "Cube": ("double size = 1.5", {"size": 1.5}, (6 * 2.25, 1.5 ** 3)),
    "Cylinder": ('double radius = 0.4\n    double height = 1.2\n    uniform token axis = "X"',
                 {"radius": 0.4, "height": 1.2, "axis": "X"}, (2 * math.pi * 0.16 + 2 * math.pi * 0.4 * 1.2, math.pi * 0.16 * 1.2)),
    "Cone": ('double radius = 0.5\n    double height = 1.0\n    uniform token axis = "Y"', {"radius": 0.5, "height": 1.0, "axis": "Y"},
             (math.pi * 0.25 + math.pi * 0.5 * math.hypot(0.5, 1.0), math.pi * 0.25 / 3)),
    "Capsule": ("double radius = 0.3\n    double height = 0.8", {"radius": 0.3, "height": 0.8, "axis": "Z"},
                (4 * math.pi * 0.09 + 2 * math.pi * 0.3 * 0.8, 4 / 3 * math.pi * 0.027 + math.pi * 0.09 * 0.8)),
    "Plane": ('double width = 4\n    double length = 2\n    uniform token axis = "X"', {"width": 4.0, "length": 2.0, "axis": "X"},
              (8.0, None)),
    "Capsule_1": ('double radiusTop = 0.2\n    double radiusBottom = 0.4\n    double height = 1.0\n    uniform token axis = "Y"',
                  {"radiusTop": 0.2, "radiusBottom": 0.4, "height": 1.0, "axis": "Y"}, _capsule_1(0.4, 0.2, 1.0)),
    "Cylinder_1": ('double radiusTop = 0.25\n    double radiusBottom = 0.5\n    double height = 0.9',
                   {"radiusTop": 0.25, "radiusBottom": 0.5, "height": 0.9, "axis": "Z"},
                   (math.pi * (0.0625 + 0.25) + math.pi * 0.75 * math.hypot(0.9, 0.25), math.pi * 0.9 * (0.25 + 0.125 + 0.0625) / 3)),
}


def _has_schema(kind: str) -> bool:
    from pxr import UsdGeom

    return hasattr(UsdGeom, kind)


@pytest.mark.parametrize("kind", list(SHAPES))
def test_implicit_prims_are_tessellated_onto_their_analytic_surface(tmp_path, kind):
    if not _has_schema(kind):
        pytest.skip(f"this usd-core has no UsdGeom.{kind}")
    authored, params, (area, volume) = SHAPES[kind]
    body = f"""
    def Xform "Place"
    {{
        double3 xformOp:translate = (1, 2, 3)
        double3 xformOp:scale = (2, 2, 2)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
        def {kind} "Shape"
        {{
            {authored.replace(chr(10), chr(10) + "        ")}
            color3f[] primvars:displayColor = [(0.2, 0.4, 0.6)]
        }}
    }}
    """
    scene = load_usd(_write(tmp_path / f"{kind}.usda", body))
    mesh = scene.meshes[0]
    assert mesh.path == "/Place/Shape" and mesh.animation == "static" and mesh.implicit == (kind, params)
    np.testing.assert_allclose(mesh.albedo, np.tile([0.2, 0.4, 0.6], (mesh.vertex_count, 1)), atol=1e-6)
    size = max(v for k, v in params.items() if k != "axis")
    assert _surface_residual(kind, params, mesh.points) <= ON_SURFACE_RTOL * size
    world = scene.points_at(0.0)
    assert _surface_residual(kind, params, (world - [1, 2, 3]) / 2.0) <= WORLD_RTOL * size
    # analytic normals: unit, and on the outward side of every triangle
    assert np.allclose(np.linalg.norm(mesh.normals, axis=1), 1.0)
    p = mesh.points[mesh.faces]
    face_normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    face_normals /= np.linalg.norm(face_normals, axis=1, keepdims=True)
    assert np.all(np.einsum("fkj,fj->fk", mesh.normals[mesh.faces], face_normals) > 0.9)
    got_area, got_volume = _area_volume(mesh.points, mesh.faces.astype(np.int64))
    exact = kind in ("Cube", "Plane")
    assert got_area == pytest.approx(area, rel=EXACT_RTOL if exact else AREA_RTOL)
    if volume is not None:
        assert got_volume == pytest.approx(volume, rel=EXACT_RTOL if exact else VOLUME_RTOL)
    if not exact:  # finer tessellations approach the analytic values (second order)
        fine_points, _, fine_faces, _ = tessellate(kind, params, segments=2 * SEGMENTS)
        fine_area, fine_volume = _area_volume(fine_points, fine_faces)
        assert abs(fine_area - area) <= CONVERGENCE_RATIO * abs(got_area - area)
        assert abs(fine_volume - volume) <= CONVERGENCE_RATIO * abs(got_volume - volume)


@pytest.mark.parametrize("kind, authored, centre, radius", [
    ("Capsule", "double radius = 0.5\n    double height = 0", 0.0, 0.5),
    ("Capsule_1", "double radiusBottom = 1\n    double radiusTop = 0.2\n    double height = 0.5", -0.25, 1.0),
    ("Capsule_1", "double radiusBottom = 0.2\n    double radiusTop = 1\n    double height = 0.5", 0.25, 1.0),
])
def test_capsules_that_are_spheres_tessellate_as_the_sphere(tmp_path, kind, authored, centre, radius):
    """A capsule of height 0, or one whose larger sphere holds the smaller, is that sphere."""
    if not _has_schema(kind):
        pytest.skip(f"this usd-core has no UsdGeom.{kind}")
    mesh = load_usd(_write(tmp_path / "ball.usda", f'def {kind} "Ball"\n{{\n    {authored}\n}}\n')).meshes[0]
    sphere = load_usd(_write(tmp_path / "sphere.usda", 'def Sphere "S"\n{\n}\n')).meshes[0]
    assert (mesh.vertex_count, mesh.triangle_count) == (sphere.vertex_count, sphere.triangle_count)
    distance = np.linalg.norm(mesh.points - [0.0, 0.0, centre], axis=1)
    assert np.abs(distance - radius).max() <= ON_SURFACE_RTOL * radius


def test_implicit_prims_follow_transforms_materials_purpose_and_animation(tmp_path):
    body = """
    def Material "Red"
    {
        token outputs:surface.connect = </Red/Shader.outputs:surface>
        def Shader "Shader"
        {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor = (0.9, 0.1, 0.1)
            token outputs:surface
        }
    }
    def Sphere "Rolling" (
        prepend apiSchemas = ["MaterialBindingAPI"]
    )
    {
        double radius = 0.5
        rel material:binding = </Red>
        double3 xformOp:translate.timeSamples = { 0: (0, 0, 0), 10: (5, 0, 0) }
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def Sphere "Growing"
    {
        double radius.timeSamples = { 0: 0.5, 10: 1.5 }
    }
    def Capsule "Collider"
    {
        uniform token purpose = "guide"
    }
    def Cube "Hidden"
    {
        token visibility = "invisible"
    }
    """
    scene = load_usd(_write(tmp_path / "shapes.usda", body))
    rolling, growing = scene.meshes
    assert scene.frames.tolist() == [0.0, 10.0]
    assert rolling.animation == "rigid" and np.allclose(rolling.albedo, [0.9, 0.1, 0.1])
    np.testing.assert_allclose(np.linalg.norm(scene.points_at(10.0)[: rolling.vertex_count] - [5, 0, 0], axis=1), 0.5)
    assert growing.animation == "deforming" and growing.normals is None
    kind, params = growing.implicit
    assert kind == "Sphere" and params["radius"].tolist() == [0.5, 1.5]
    sl = slice(growing.vertex_offset, growing.vertex_offset + growing.vertex_count)
    np.testing.assert_allclose(np.linalg.norm(scene.points_at(10.0)[sl], axis=1), 1.5)
    assert dict(scene.skipped) == {"/Collider": "purpose guide", "/Hidden": "invisible"}


def test_point_instancer_prototypes_may_be_implicit(tmp_path):
    body = """
    def PointInstancer "Balls"
    {
        point3f[] positions = [(0, 0, 0), (3, 0, 0), (6, 0, 0)]
        int[] protoIndices = [0, 0, 0]
        int64[] invisibleIds = [2]
        int64[] ids = [0, 1, 2]
        rel prototypes = </Balls/Protos/Ball>
        def Scope "Protos"
        {
            def Xform "Ball"
            {
                def Sphere "Shape"
                {
                    double radius = 0.25
                }
                def Capsule "Collider"
                {
                    uniform token purpose = "guide"
                }
            }
        }
    }
    """
    scene = load_usd(_write(tmp_path / "instanced.usda", body))
    assert [m.path for m in scene.meshes] == ["/Balls/instance_0/Shape", "/Balls/instance_1/Shape"]
    assert all(m.implicit == ("Sphere", {"radius": 0.25}) for m in scene.meshes)
    centre = scene.points_at(0.0)[scene.meshes[1].vertex_offset:].mean(axis=0)
    np.testing.assert_allclose(centre, [3, 0, 0], atol=1e-9)
    reasons = dict(scene.skipped)
    assert reasons["/Balls"] == "1 of 3 instance(s) hidden by invisibleIds or inactiveIds at some frame"
    assert reasons["/Balls/Protos/Ball/Collider"] == "purpose guide (in a point instancer's prototype)"


@pytest.mark.parametrize("authored, message", [
    ("def Sphere \"Bad\"\n{\n    double radius = -1\n}\n", r"Sphere /Bad in .*bad\.usda: radius must be finite and > 0, got -1\.0"),
    ("def Cylinder \"Bad\"\n{\n    double height = 0\n}\n", r"Cylinder /Bad in .*: height must be finite and > 0, got 0\.0"),
    ("def Cube \"Bad\"\n{\n    double size = inf\n}\n", r"Cube /Bad in .*: size must be finite and > 0, got inf"),
    ("def Capsule \"Bad\"\n{\n    double radius.timeSamples = { 0: 1, 4: -1 }\n}\n",
     r"Capsule /Bad in .* at time 4: radius must be finite and > 0, got -1\.0"),
])
def test_implicit_parameters_that_make_no_surface_are_named(tmp_path, authored, message):
    with pytest.raises(ValueError, match=message):
        load_usd(_write(tmp_path / "bad.usda", authored))


# ---- 5. every skipped prim is named with its reason ----------------------------------------------
def test_nothing_renderable_names_every_skipped_prim(tmp_path):
    body = """
    def Mesh "Guide"
    {
        uniform token purpose = "guide"
    }
    def Xform "Hidden"
    {
        token visibility = "invisible"
    }
    def BasisCurves "Hair"
    {
    }
    """
    with pytest.raises(ValueError, match=r"nothing\.usda: contains no \(visible, renderable\) UsdGeom\.Mesh or implicit "
                                         r"\(Sphere, .*\) prims; skipped 3 prim\(s\): /Guide \(purpose guide\); /Hidden "
                                         r"\(invisible\); /Hair \(unsupported gprim type BasisCurves"):
        load_usd(_write(tmp_path / "nothing.usda", body))
    with pytest.raises(ValueError, match=r"its 2 prim\(s\) are 1 Xform, 1 Scope; 1 prim\(s\) are inactive, undefined "
                                         r"\('over'\) or abstract \('class'\) and are not read \(first: /Later\)"):
        load_usd(_write(tmp_path / "empty.usda", 'def Xform "A"\n{\n}\ndef Scope "B"\n{\n}\nover Mesh "Later"\n{\n}\n'))


def test_info_lists_skipped_prims_and_extra_cameras(tmp_path, capsys):
    body = _tri("Shown", "point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]") + """
    def Points "Dust"
    {
        point3f[] points = [(0, 0, 0)]
    }
    def Camera "Main"
    {
    }
    def Camera "Spare"
    {
    }
    """
    path = _write(tmp_path / "cams.usda", body)
    assert cli.main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "skipped 2 prim(s)\n" in out
    assert "  /Dust: unsupported gprim type Points" in out
    assert "  /Spare: camera (only the first camera, /Main, is read)" in out


# ---- 6. warpshade info FILE | head ---------------------------------------------------------------
def test_a_closed_stdout_ends_quietly(tmp_path):
    path = _write(tmp_path / "t.usda", _tri("T", "point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]"))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, "-m", "warpshade.cli", "info", str(path)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=env)
    proc.stdout.close()  # the reader is gone before anything is written (| head that has read enough)
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == cli.EXIT_BROKEN_PIPE
    assert "Broken pipe" not in err and "error" not in err and "Exception ignored" not in err, err


def test_broken_pipe_in_process_returns_the_sigpipe_status(tmp_path, monkeypatch, capsys):
    class Closed:
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

        def flush(self):
            raise BrokenPipeError(32, "Broken pipe")

    path = _write(tmp_path / "t.usda", _tri("T", "point3f[] points = [(0,0,0), (1,0,0), (0,1,0)]"))
    monkeypatch.setattr(sys, "stdout", Closed())
    assert cli.main(["info", str(path)]) == cli.EXIT_BROKEN_PIPE
    monkeypatch.undo()
    assert capsys.readouterr().err == ""


# ---- real assets: Warp's and Newton's examples ---------------------------------------------------
def _warp_examples() -> list:
    import warp.examples

    d = Path(warp.examples.get_asset_directory())
    return sorted(d.glob("*.usd")) if d.is_dir() else []


@pytest.mark.parametrize("path", _warp_examples(), ids=lambda p: p.name)
def test_warp_example_assets_load_as_one_static_frame(path):
    if path.name == "square_cloth.usd":  # its dome light names a texture Warp does not ship
        with pytest.raises(ValueError, match=r"dome light /root/env_light in .*square_cloth\.usd: texture file .* not found"):
            load_usd(path)
        return
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = load_usd(path)
    assert not [w for w in caught if "time code" in str(w.message)]
    assert scene.frames.tolist() == [0.0] and scene.is_static and scene.skipped == []


def _newton_asset(name: str) -> Path:
    newton = pytest.importorskip("newton")
    path = Path(newton.__file__).parent / "examples" / "assets" / name
    if not path.exists():
        pytest.skip(f"this newton has no examples/assets/{name}")
    return path


def test_newton_humanoid_capsules_and_spheres_are_tessellated(capsys):
    path = _newton_asset("humanoid.usda")
    scene = load_usd(path)
    kinds = [m.implicit[0] for m in scene.meshes]
    assert kinds.count("Capsule") == 16 and kinds.count("Sphere") == 3 and len(scene.meshes) == 19
    assert all("/visuals/" in m.path for m in scene.meshes)
    # the collision copies are guides: each named with its reason
    assert len(scene.skipped) == 19 and all(why == "purpose guide" and "/collisions/" in p for p, why in scene.skipped)
    for mesh in scene.meshes:
        kind, params = mesh.implicit
        assert _surface_residual(kind, params, mesh.points) <= ON_SURFACE_RTOL * max(params["radius"], params.get("height", 0))
    head = next(m for m in scene.meshes if m.path.endswith("/head"))
    assert head.implicit == ("Sphere", {"radius": pytest.approx(0.09, rel=1e-6)})
    assert cli.main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "skipped 19 prim(s)" in out and "/nv_humanoid/head/collisions/head: purpose guide" in out
    assert "[tessellated Capsule]" in out


@pytest.mark.parametrize("name, kinds", [("cartpole.usda", {"Cube"}), ("ant.usda", {"Capsule", "Sphere"}),
                                         ("sensor_contact_scene.usda", {"Cube", "Sphere"})])
def test_newton_assets_load(name, kinds):
    scene = load_usd(_newton_asset(name))
    assert {m.implicit[0] for m in scene.meshes} == kinds and scene.frames.tolist() == [0.0]


def test_a_graph_runs_on_a_newton_asset_given_with_scene(tmp_path, capsys):
    path = _newton_asset("cartpole.usda")
    _cube(tmp_path)
    g = _graph(tmp_path, "cube.usda", validate="[0]")
    rc = cli.main(["run", str(g), "--scene", str(path), "--out", str(tmp_path / "o"), "--no-previews", "--device", "cpu"])
    _, err = capsys.readouterr()
    assert rc == 0, err
    report = json.loads((tmp_path / "o" / "g.json").read_text())
    assert report["scene"]["source"] == str(path) and len(report["scene"]["meshes"]) == 4


def test_implicit_types_cover_this_usd(tmp_path):
    """Every implicit gprim type of the installed usd-core is tessellated (none skipped as unsupported)."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateInMemory()
    names = [n for n in ("Sphere", "Cube", "Cylinder", "Cone", "Capsule", "Plane", "Capsule_1", "Cylinder_1")
             if hasattr(UsdGeom, n)]
    implicit = [n for n in names if Usd.SchemaRegistry().FindConcretePrimDefinition(n) is not None
                and stage.DefinePrim(f"/{n}", n).IsA(UsdGeom.Gprim)]
    assert set(implicit) <= set(IMPLICIT_TYPES)
