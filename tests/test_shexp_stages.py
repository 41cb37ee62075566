"""SHEXP graph stages on small scenes: against the float64 mirror pipeline, PRT and itself.

Scenes are built from arrays (an icosphere moving over a ground grid) so sphere fitting takes a
second or two; the sphere construction itself is tested with :mod:`warpshade.geometry.spheres`.
"""

import numpy as np
import pytest
import trimesh

from warpshade.graph import GraphSpec, StageSpec
from warpshade.scene import LightingSource
from warpshade.methods.shexp import _mirror as mirror
from warpshade.methods.shexp._model import BlockerModel, plane_blockers
from warpshade.scene import Environment, Mesh, Scene
from warpshade.scene import ground_plane

ORDER = 4
# float32 pipeline (skinning/transform kernels, ~10 blockers, exp, product) vs float64.
RTOL_STAGE = 5e-4
# Hierarchy cut with ratio vectors vs the flat list of leaves on the same frame: the ratio
# vectors fit the leaves' log per band at each cluster's representative point; measured
# relative RMS 2e-3 here.
RTOL_HIERARCHY = 2e-2
# Static-only scene, every receiver baked: SHEXP reduces to dot(L, T_p) = static PRT with the
# same rays; float32 rounding only.
RTOL_BAKE = 1e-4
FIT = {"grid_cells": 4000, "teleports": 2}


def moving_ball_scene(frames=4):
    ico = trimesh.creation.icosphere(subdivisions=2, radius=0.4)
    xf = np.tile(np.eye(4), (frames, 1, 1))
    xf[:, 3, :3] = np.stack([np.linspace(-0.5, 0.5, frames), np.zeros(frames), np.full(frames, 0.8)], 1)
    ball = Mesh("/ball", ico.vertices, ico.faces, animation="rigid", transforms=xf, albedo=(0.8, 0.3, 0.2))
    ground = ground_plane([-1, -1, 0], [1, 1, 1], "Z", resolution=12, size_factor=2.0)
    return Scene.from_meshes([ball, ground], frames=range(frames), lights=[Environment.sky()])


@pytest.fixture(scope="module")
def scene():
    return moving_ball_scene()


def compile_graph(scene, shade_params=None, blocker_params=None, *, device):
    stages = [
        StageSpec("tables", "shexp.tables", {"order": ORDER}),
        StageSpec("blockers", "shexp.blockers", {"budget": 4, **FIT, **(blocker_params or {})}),
        StageSpec("shade", "shexp.shade", {"order": ORDER, **(shade_params or {})}),
    ]
    lighting = LightingSource(scene.lights, scene.up_axis, 10.0, 0.0)
    return GraphSpec(stages, "shade.radiance", name="shexp-test").compile(scene, device=device, cache_dir=None, progress=False,
                                                                          lighting=lighting)


def test_shade_stage_matches_reference_pipeline(device, scene):
    rt = compile_graph(scene, device=device)
    frame = 2.0
    out = rt.step(frame).numpy()
    model = BlockerModel.from_arrays(rt.artifacts["blockers"]["model"])
    assert model.planes.shape == (1, 7)  # the ground
    pts, nrm = scene.points_at(frame), scene.normals_at(frame)
    g = mirror.visibility(pts, nrm, model.spheres.centres_at(scene, frame), model.spheres.radii_at(scene, frame), ORDER,
                             "hyb", planes=model.planes)
    light = rt.lighting.sh(ORDER, frame)  # the float64 oracle of the frame's lighting
    want = mirror.shade(g, nrm, light, scene.albedo)
    np.testing.assert_allclose(out, want, atol=RTOL_STAGE * want.max())


def test_hierarchy_cut_close_to_flat_and_exact_when_cut_to_leaves(device, scene):
    flat = compile_graph(scene, device=device).step(1.0).numpy()
    tree = {"hierarchy": True, "vertices_per_cluster": 40}
    leaves = compile_graph(scene, {"theta_max": 1.0}, tree, device=device).step(1.0).numpy()
    np.testing.assert_allclose(leaves, flat, atol=RTOL_STAGE * flat.max())
    cut = compile_graph(scene, {"theta_max": 45.0}, tree, device=device)
    coarse = cut.step(1.0).numpy()
    shade_stage = next(s for s in cut.stages if s.name == "shade")
    assert shade_stage.frames.mean_cut_length() < shade_stage.model.leaf_count  # inner nodes were used
    rel = np.sqrt(np.mean((coarse - flat) ** 2)) / np.sqrt(np.mean(flat**2))
    assert rel < RTOL_HIERARCHY, rel


def test_static_bake_reduces_to_prt(device):
    box = trimesh.creation.box(extents=(0.5, 0.5, 0.5))
    box.apply_translation((0.0, 0.0, 0.25))
    scene = Scene.from_meshes([Mesh("/box", box.vertices, box.faces), ground_plane([-0.5, -0.5, 0], [0.5, 0.5, 0.5], "Z", 10)],
                              frames=range(2), lights=[Environment.sky()])
    stages = [
        StageSpec("tables", "shexp.tables", {"order": ORDER}),
        StageSpec("blockers", "shexp.blockers", {"budget": 2, **FIT}),
        StageSpec("bake", "shexp.static_bake", {"order": ORDER, "samples": 64}),
        StageSpec("shade", "shexp.shade", {"order": ORDER, "static_bake": True}),
    ]
    out = GraphSpec(stages, "shade.radiance").compile(scene, device=device, cache_dir=None, progress=False).step(0.0).numpy()
    prt = [StageSpec("t", "prt.transfer", {"order": ORDER, "samples": 64}), StageSpec("shade", "prt.shade", {"order": ORDER})]
    want = GraphSpec(prt, "shade.radiance").compile(scene, device=device, cache_dir=None, progress=False).step(0.0).numpy()
    np.testing.assert_allclose(out, want, atol=RTOL_BAKE * want.max())


def test_blocker_model_arrays_roundtrip(device, scene, tmp_path):
    from warpshade.methods.shexp._model import build_blocker_model

    model = build_blocker_model(scene, 3, hierarchy=True, vertices_per_cluster=40, device=device, **FIT)
    # through the on-disk artifact format: flattened "arrays" port entries in one .npz
    from warpshade.graph import ArtifactCache
    from warpshade.graph._precompute import _flatten, _unflatten
    from warpshade.graph import Port

    ports = {"model": Port("arrays")}
    cache = ArtifactCache(tmp_path)
    cache.store("k", _flatten({"model": model.to_arrays()}, ports))
    back = BlockerModel.from_arrays(_unflatten(cache.load("k"), ports)["model"])
    np.testing.assert_array_equal(back.spheres.rest_radii, model.spheres.rest_radii)
    np.testing.assert_array_equal(back.tree.skip, model.tree.skip)
    np.testing.assert_array_equal(back.clusters.representative, model.clusters.representative)
    np.testing.assert_array_equal(back.planes, model.planes)
    assert back.summary["leaf_spheres"] == model.leaf_count
    with pytest.raises(ValueError, match="not a blocker model"):
        BlockerModel.from_arrays({"planes": model.planes})


def test_plane_blockers_and_kernel(device, scene):
    planes = plane_blockers(scene)
    assert planes.shape == (1, 7)
    np.testing.assert_allclose(planes[0, 3:6], [0, 0, 1], atol=1e-12)
    assert planes[0, 6] == pytest.approx(np.sqrt(4.0 * 4.0 / np.pi))  # the 4 m square ground as a disc
    # receivers above, on and below the plane; no spheres
    from warpshade.methods.shexp._pipeline import shade_receivers

    pts = np.array([[0, 0, 0.5], [0.3, 0.2, 0.0], [0.1, 0, -0.7], [0, 0, 3.0]])
    nrm = np.tile([1.0, 0, 0], (4, 1))
    light = Environment.sky().to_sh(ORDER)
    _, g = shade_receivers(pts, nrm, np.ones((4, 3)), np.zeros((0, 3)), np.zeros(0), light, order=ORDER, planes=planes,
                           device=device)
    want = mirror.visibility(pts, nrm, np.zeros((0, 3)), np.zeros(0), ORDER, "hyb", planes=planes)
    np.testing.assert_allclose(g, want, atol=2e-4)
    assert np.allclose(g[1, 1:], 0.0) and g[1, 0] == pytest.approx(np.sqrt(4 * np.pi), rel=1e-6)  # on the plane: nothing
    axes, theta = mirror.plane_caps(pts, planes)
    assert theta[0, 0] == pytest.approx(np.arctan(planes[0, 6] / 0.5)) and np.allclose(axes[0, 0], [0, 0, -1])
    assert np.allclose(axes[2, 0], [0, 0, 1])  # below the plane it blocks upwards


def test_sphere_trace_stage_and_bad_inputs(device, scene):
    stages = [StageSpec("blockers", "shexp.blockers", {"budget": 3, **FIT}),
              StageSpec("trace", "shexp.sphere_trace", {"samples": 16})]
    rt = GraphSpec(stages, "trace.radiance").compile(scene, device=device, cache_dir=None, progress=False)
    out = rt.step(0.0).numpy()
    assert np.all(np.isfinite(out)) and out.min() >= 0.0
    from warpshade.graph import GraphError

    with pytest.raises(GraphError, match="method"):
        GraphSpec([StageSpec("shade", "shexp.shade", {"method": "taylor"})], "shade.radiance").build()


def test_error_budget_picks_cheapest_setting_meeting_target(scene, tmp_path):
    from warpshade.measure import choose
    from warpshade.methods.shexp._budget import candidates

    lighting = LightingSource(scene.lights, scene.up_axis, 0.0, 0.0)
    grid = candidates(orders=(4,), spheres=(1, 4), methods=("ol", "hyb"), blocker_params=FIT)
    common = dict(lighting=lighting, frames=[1.0], gt_samples=64, cache_dir=tmp_path, method="shexp")
    loose = choose(scene, grid, 10.0, **common)
    assert loose.met and len(loose.candidates) == 4
    assert all(c.meets_target for c in loose.candidates)
    assert loose.chosen.stage_ms == min(c.stage_ms for c in loose.candidates)
    assert all(c.facts["leaf_spheres"] <= c.facts["spheres"] for c in loose.candidates), "the fitted count is reported"
    impossible = choose(scene, grid, 1e-9, **common)  # ground truth is re-used from the cache
    assert not impossible.met
    assert impossible.chosen.rel_rms == min(c.rel_rms for c in impossible.candidates)
    assert "does NOT meet" in impossible.summary()
    with pytest.raises(ValueError, match="target_error"):
        choose(scene, grid, 0.0, **common)
    with pytest.raises(ValueError, match="unknown exp method"):
        candidates(methods=("taylor",))
