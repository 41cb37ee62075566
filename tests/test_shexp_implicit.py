"""SHEXP's blockers of UsdGeom Sphere and Capsule prims: their own spheres, not a fit of the tessellation.

A Sphere blocks as itself; a Capsule as spheres along its spine whose radius exceeds the capsule's
by at most ``RADIUS_EXCESS``. Expected values come from the file text (radius, height, axis,
transform), never from the loader: the sphere's centre and radius exactly, the capsule's surface
(its tessellated points, analytic to rounding) inside the union of its spheres, the outside volume
against an independent Monte Carlo estimate, the spheres following an animated transform, and a
scene of implicit prims alone shading without a closed mesh.
"""

import math
import textwrap

import numpy as np
import pytest

from warpshade.io import load_usd
from warpshade.methods.shexp._model import build_blocker_model
from warpshade.methods.shexp._spheres import RADIUS_EXCESS, spheres_for_scene

#: Centres and radii go through USD's double matrices and one float64 product.
EXACT_RTOL = 1e-9
#: Monte Carlo points of the independent outside-volume estimate, and its tolerance (absolute, in
#: fractions of the capsule's volume: about 4 standard errors at 2e5 points).
MC_POINTS = 200_000
MC_ATOL = 0.01

SCENE = """#usda 1.0
(
    upAxis = "Z"
    startTimeCode = 0
    endTimeCode = 2
)
def Xform "Ball"
{
    double3 xformOp:translate = (1, 2, 3)
    double3 xformOp:scale = (2, 2, 2)
    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]
    def Sphere "Shape"
    {
        double radius = 0.25
    }
}
def Xform "Limb"
{
    double3 xformOp:translate.timeSamples = {0: (0, 0, 1), 1: (0, 0, 1.5), 2: (0, 0, 2)}
    uniform token[] xformOpOrder = ["xformOp:translate"]
    def Capsule "Shape"
    {
        double radius = 0.2
        double height = 1.5
        uniform token axis = "X"
    }
}
def Cube "Box"
{
    double size = 0.5
    double3 xformOp:translate = (-2, 0, 0.25)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}
"""


def _scene(tmp_path, text=SCENE):
    path = tmp_path / "shapes.usda"
    path.write_text(textwrap.dedent(text))
    return load_usd(str(path))


def _sets(spheres):
    return {s.source: s for s in spheres.sets}


#: The Cube's fit: a coarse grid and no teleports (its spheres are not under test, only that it has
#: fitted ones).
FIT = {"grid_cells": 2000, "teleports": 0}


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    scene = _scene(tmp_path_factory.mktemp("shapes"))
    return scene, spheres_for_scene(scene, budget=4, **FIT)


def test_a_sphere_blocks_as_itself_and_a_capsule_by_its_spine(fitted):
    scene, spheres = fitted
    sets = _sets(spheres)
    ball, limb, box = sets["/Ball/Shape"], sets["/Limb/Shape"], sets["/Box"]
    np.testing.assert_allclose(ball.centres, [[1.0, 2.0, 3.0]], rtol=EXACT_RTOL)
    np.testing.assert_allclose(ball.radii, [0.5], rtol=EXACT_RTOL)
    assert ball.parameters["exact"] and ball.error == 0.0
    # the capsule: centres on its spine (X through (0, 0, 1)) from -h/2 to +h/2, evenly spaced
    c = limb.centres
    np.testing.assert_allclose(c[:, 1:], np.tile([0.0, 1.0], (len(c), 1)), atol=1e-12)
    np.testing.assert_allclose(c[:, 0], np.linspace(-0.75, 0.75, len(c)), atol=1e-12)
    assert np.all(limb.radii >= 0.2) and np.all(limb.radii <= 0.2 * (1 + RADIUS_EXCESS) + 1e-12)
    assert limb.parameters["exact"]
    # the Cube has no spheres of its own: fitted from its tessellation
    assert not box.parameters.get("exact")


def test_the_capsule_spheres_bound_it_with_the_stated_outside_volume(fitted):
    scene, spheres = fitted
    limb = _sets(spheres)["/Limb/Shape"]
    mesh = next(m for m in scene.meshes if m.path == "/Limb/Shape")
    pts = scene.points_at(0.0)[mesh.vertex_offset:mesh.vertex_offset + mesh.vertex_count]
    inside = np.linalg.norm(pts[:, None, :] - limb.centres[None], axis=2) <= limb.radii[None] * (1 + 1e-9)
    assert inside.any(axis=1).all(), "every point of the capsule's surface is inside a sphere"
    # independent estimate of the union's volume outside the capsule (uniform points in a box)
    rng = np.random.default_rng(7)
    lo, hi = limb.centres.min(0) - limb.radii.max(), limb.centres.max(0) + limb.radii.max()
    p = rng.uniform(lo, hi, (MC_POINTS, 3))
    in_union = (np.linalg.norm(p[:, None, :] - limb.centres[None], axis=2) <= limb.radii[None]).any(axis=1)
    q = p - [0.0, 0.0, 1.0]
    z = np.clip(q[:, 0], -0.75, 0.75)
    in_capsule = np.hypot(q[:, 0] - z, np.hypot(q[:, 1], q[:, 2])) <= 0.2
    v_box = float(np.prod(hi - lo))
    v_capsule = math.pi * 0.04 * 1.5 + 4 / 3 * math.pi * 0.008
    outside = (in_union & ~in_capsule).mean() * v_box / v_capsule
    assert limb.error_union == pytest.approx(outside, abs=MC_ATOL)
    assert limb.volume == pytest.approx(v_capsule, rel=EXACT_RTOL)


def test_the_spheres_follow_the_prim_transform(fitted):
    scene, spheres = fitted
    rows = np.flatnonzero(np.asarray(spheres.mesh_path)[spheres.sphere_set] == "/Limb/Shape")
    for frame, height in ((0.0, 1.0), (1.0, 1.5), (2.0, 2.0)):
        c = spheres.centres_at(scene, frame)[rows]
        np.testing.assert_allclose(c[:, 2], height, atol=1e-9)
        np.testing.assert_allclose(spheres.radii_at(scene, frame)[rows], spheres.rest_radii[rows], rtol=EXACT_RTOL)


def test_implicit_prims_alone_need_no_closed_mesh(tmp_path):
    text = SCENE[:SCENE.index('def Cube "Box"')]
    scene = _scene(tmp_path, text)
    model = build_blocker_model(scene, budget=2)
    assert model.summary["leaf_spheres"] >= 3
    assert not model.summary["skipped"]


@pytest.mark.parametrize("device", ["cpu"])
def test_a_graph_shades_a_capsule_scene(tmp_path, device):
    """shexp over a capsule above a ground plane: finite, and the ground under the capsule darker."""
    from warpshade.graph import GraphSpec, StageSpec
    from warpshade.measure._auto import default_lighting

    n = 13  # a grid ground: per-vertex shading needs vertices under the capsule
    xs = np.linspace(-3.0, 3.0, n)
    points = ", ".join(f"({x:g}, {y:g}, 0)" for y in xs for x in xs)
    quads = ", ".join(f"{j * n + i}, {j * n + i + 1}, {(j + 1) * n + i + 1}, {(j + 1) * n + i}"
                      for j in range(n - 1) for i in range(n - 1))
    text = SCENE[:SCENE.index('def Xform "Ball"')] + f"""
def Xform "Limb"
{{
    double3 xformOp:translate = (0, 0, 0.6)
    uniform token[] xformOpOrder = ["xformOp:translate"]
    def Capsule "Shape"
    {{
        double radius = 0.3
        double height = 1.0
        uniform token axis = "X"
    }}
}}
def Mesh "Ground"
{{
    int[] faceVertexCounts = [{", ".join(["4"] * (n - 1) ** 2)}]
    int[] faceVertexIndices = [{quads}]
    point3f[] points = [{points}]
}}
"""
    scene = _scene(tmp_path, text)
    stages = [StageSpec("tables", "shexp.tables", {"order": 4}), StageSpec("blockers", "shexp.blockers", {"budget": 2}),
              StageSpec("shade", "shexp.shade", {"order": 4})]
    rt = GraphSpec(stages, "shade.radiance", name="capsule").compile(scene, device=device, progress=False,
                                                                     lighting=default_lighting(scene),
                                                                     cache_dir=tmp_path / "cache")
    f = float(scene.frames[0])
    rt.run([f], warmup=False)
    out = np.asarray(rt.results[f])
    assert np.all(np.isfinite(out))
    blockers = next(st for st in rt.stages if st.name == "blockers")
    assert [s["mesh"] for s in blockers.report["sets"]] == ["/Limb/Shape"]
    ground = next(m for m in scene.meshes if m.path == "/Ground")
    g = out[ground.vertex_offset:ground.vertex_offset + ground.vertex_count].mean(axis=1)
    p = scene.points_at(f)[ground.vertex_offset:ground.vertex_offset + ground.vertex_count]
    under = np.hypot(p[:, 0], p[:, 1]) < 0.3
    far = np.hypot(p[:, 0], p[:, 1]) > 2.5
    assert g[under].mean() < 0.8 * g[far].mean(), "the capsule shadows the ground under it"
