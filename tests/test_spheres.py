"""Blocker sphere sets: bounding, outside volume, attachment, hierarchy, receiver cut.

Oracles: analytic outside volumes (sphere around a cube, cube around a sphere), analytic
volumes of the meshes (trimesh's divergence-theorem volume), float64 NumPy references of every
kernel (coverage, attachment, refit, cluster bounds, cut), scipy's Powell for the batched
centre update, and the mean-value-coordinate identities (partition of unity, linear precision).
Fits use coarse grids and few spheres so the whole file stays fast.

The sphere geometry is :mod:`warpshade.geometry.spheres`; the scene's blocker spheres and their
per-frame animation are :mod:`warpshade.methods.shexp._spheres`, driven here by a
:class:`~warpshade.scene.FrameEvaluator` as a frame would drive them.
"""

import io
import math

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from warpshade._wp import record_program
from warpshade.geometry import spheres as sp
from warpshade.geometry.spheres import _attach as attach
from warpshade.geometry.spheres import _fit as fit_internals
from warpshade.geometry.spheres import _mvc as mvc
from warpshade.io import load_scene
from warpshade.scene import FrameEvaluator, Mesh, Scene


from warpshade.methods.shexp import _spheres as ss  # noqa: E402

from tolerances import ATOL_FLOAT32, REPLAY_RTOL, assert_close

#: Coarse construction settings for tests (a few hundred ms per fit).
FAST_FIT = {"grid_cells": 8000, "iterations": 4, "teleports": 2, "samples_per_sphere": 256}

#: float32 coverage tests: distances of ~1 scene unit carry ~1e-7 relative rounding; the fit
#: pads radii by 2e-6 relative, so a covered sample is never further out than this.
COVERAGE_ATOL = 1e-6

#: QMC estimates are compared with analytic values to this many standard errors (plus a
#: relative floor of 0.5% for the fast-winding-number classification within float32 of the
#: surface).
QMC_SIGMAS = 4.0
QMC_RELATIVE_FLOOR = 5e-3

#: The grid estimator's error is O(h) times the area of the surface inside the sphere; at
#: 8000 cells (h ~ 1/20 of the box) it stays within 5% on the analytic cases.
GRID_RELATIVE = 0.05

#: A skinned bend deforms the tube by ~90 degrees; fixed radii may leave deformed samples
#: outside by at most this fraction of the mean radius (measured: ~0.14 with 8 spheres).
SKINNED_GAP_FRACTION = 0.25

#: Refit parents bound their children up to float32 rounding of the radius (pad 1e-6).
REFIT_ATOL = 1e-5


# ---- fixtures -------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def box():
    return trimesh.creation.box(extents=(1.0, 0.6, 0.4))


@pytest.fixture(scope="module")
def capsule():
    return trimesh.creation.capsule(height=1.0, radius=0.25, count=[12, 12])


@pytest.fixture(scope="module")
def icosphere():
    return trimesh.creation.icosphere(subdivisions=2, radius=0.5)


@pytest.fixture(scope="module")
def capsule_sets(capsule):
    return {n: sp.fit_spheres(capsule.vertices, capsule.faces, n, name="capsule", **FAST_FIT) for n in (1, 3, 8)}


@pytest.fixture(scope="module")
def box_set(box):
    return sp.fit_spheres(box.vertices, box.faces, 4, name="box", **FAST_FIT)


@pytest.fixture(scope="module")
def figure_scene():
    return load_scene("bundled:figure")


@pytest.fixture(scope="module")
def figure_spheres(figure_scene):
    return ss.spheres_for_scene(figure_scene, budget=12, **FAST_FIT)


def _frame(evaluator, frame):
    """Evaluate one frame on the device (host write of the index, then kernels); its state."""
    evaluator.set_frame(frame)
    evaluator.launch()
    return evaluator.state


def _all_samples(sphere_set, points, faces):
    return np.concatenate([sphere_set.surface_samples(points, faces), sphere_set.interior_points, points])


# ---- construction -----------------------------------------------------------------------------
@pytest.mark.parametrize("shape", ["box", "capsule"])
def test_every_sample_is_bounded(shape, box, capsule, box_set, capsule_sets, device):
    mesh, sphere_set = (box, box_set) if shape == "box" else (capsule, capsule_sets[8])
    samples = _all_samples(sphere_set, mesh.vertices, mesh.faces)
    gap = sp.coverage_gap(samples, sphere_set.centres, sphere_set.radii, device=device)
    assert gap.max() <= COVERAGE_ATOL, f"{shape}: a sample lies {gap.max():.3g} outside every sphere"
    np.testing.assert_allclose(gap, sp.coverage_gap_f64(samples, sphere_set.centres, sphere_set.radii), atol=ATOL_FLOAT32)
    # every sample is in the sphere of its own cluster
    own = np.linalg.norm(sphere_set.surface_samples(mesh.vertices, mesh.faces) - sphere_set.centres[sphere_set.sample_sphere], axis=1)
    assert np.all(own <= sphere_set.radii[sphere_set.sample_sphere] * (1 + 1e-9))


def test_error_decreases_with_sphere_count(capsule_sets):
    errors = [capsule_sets[n].error for n in (1, 3, 8)]
    assert errors[0] > errors[1] > errors[2], errors
    for s in capsule_sets.values():
        assert np.all(np.isfinite(s.centres)) and np.all(s.radii > 0)
        assert s.error_union <= s.error + QMC_SIGMAS * s.error_stderr  # the union never exceeds the sum


def test_sphere_mesh_becomes_one_sphere(icosphere):
    s = sp.fit_spheres(icosphere.vertices, icosphere.faces, 8, target_error=0.1, name="icosphere", **{**FAST_FIT, "samples_per_sphere": 1024})
    assert s.sphere_count == 1
    radius = np.max(np.linalg.norm(icosphere.vertices - s.centres[0], axis=1))
    assert s.radii[0] >= radius and s.radii[0] <= radius * (1 + 1e-4)
    # E is the discretisation error of the mesh: the circumscribed ball over the polyhedron
    exact = (4.0 / 3.0 * np.pi * s.radii[0] ** 3 - icosphere.volume) / icosphere.volume
    assert abs(s.error - exact) <= QMC_SIGMAS * s.error_stderr + QMC_RELATIVE_FLOOR * exact, (s.error, exact, s.error_stderr)


def test_outside_volume_matches_analytic_cases():
    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    solid = fit_internals.make_solid(cube.vertices, cube.faces, "cube")
    disc = fit_internals.Discretisation(solid, grid_cells=8000)
    cases = [
        # sphere around the cube: V(S) - 1
        (1.0, 4.0 / 3.0 * np.pi - 1.0),
        # sphere of radius 0.6 at the cube centre pokes out through the six faces as caps of
        # height 0.1 (no edge is reached: 0.6 < sqrt(2)/2)
        (0.6, 6.0 * np.pi * 0.1**2 * (3 * 0.6 - 0.1) / 3.0),
    ]
    for radius, exact in cases:
        est = sp.outside_volume([[0.0, 0.0, 0.0]], [radius], solid=solid, samples_per_sphere=4096, replicates=4)
        assert abs(est.total - exact) <= QMC_SIGMAS * est.total_stderr + QMC_RELATIVE_FLOOR * exact, (radius, est.total, exact)
        assert abs(est.union - est.total) < 1e-12  # one sphere: union == sum
        grid = disc.outside_volume(np.zeros(3), radius)
        assert abs(grid - exact) <= GRID_RELATIVE * exact, (radius, grid, exact)
    vol, err = sp.solid_volume(solid=solid, samples=8192)
    assert abs(vol - 1.0) <= QMC_SIGMAS * err + QMC_RELATIVE_FLOOR


def test_union_volume_counts_overlap_once():
    cube = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    # two identical spheres far outside the mesh: the sum doubles, the union does not
    est = sp.outside_volume([[2.0, 0, 0], [2.0, 0, 0]], [0.5, 0.5], cube.vertices, cube.faces, samples_per_sphere=1024)
    ball = 4.0 / 3.0 * np.pi * 0.125
    assert abs(est.total - 2 * ball) < 1e-9 and abs(est.union - ball) < 1e-9


def test_cluster_objective_kernel_matches_numpy_and_powell(capsule, device):
    solid = fit_internals.make_solid(capsule.vertices, capsule.faces, "capsule", device=device)
    disc = fit_internals.Discretisation(solid, grid_cells=8000)
    rng = np.random.default_rng(3)
    clusters = [disc.samples[rng.choice(disc.samples.shape[0], 40, replace=False)] for _ in range(3)]
    starts = np.array([c.mean(axis=0) for c in clusters])
    objective = fit_internals.ClusterObjective(disc, clusters)
    _, values = objective.evaluate(np.arange(3), starts)
    reference = [disc.outside_volume(c0, fit_internals.bounding_radius(c, c0)) for c, c0 in zip(clusters, starts)]
    # float32 grid sums of up to ~1e4 cells
    np.testing.assert_allclose(values, reference, rtol=1e-4, atol=1e-6)
    x = fit_internals.update_centres(disc, clusters, starts, sweeps=3)
    batched = [disc.outside_volume(c0, fit_internals.bounding_radius(c, c0)) for c, c0 in zip(clusters, x)]
    scipy_powell = [fit_internals.update_centre(disc, c, c0)[2] for c, c0 in zip(clusters, starts)]
    for b, s, start in zip(batched, scipy_powell, reference):
        assert b <= start + 1e-12  # never worse than the start
        # lockstep Powell reaches scipy's optimum within 10% of the start's excess
        assert b <= s + 0.1 * (start - s) + 1e-9, (b, s, start)


# ---- degenerate input ---------------------------------------------------------------------------
def test_bad_meshes_are_refused_by_name(box):
    open_box = trimesh.Trimesh(box.vertices, box.faces[:-2], process=False)
    with pytest.raises(ValueError, match="mesh /open: not closed"):
        sp.fit_spheres(open_box.vertices, open_box.faces, 2, name="/open", **FAST_FIT)
    flat = trimesh.Trimesh(box.vertices * [1.0, 1.0, 0.0], box.faces, process=False)
    with pytest.raises(ValueError, match="mesh /flat: .*zero volume"):
        sp.fit_spheres(flat.vertices, flat.faces, 2, name="/flat", **FAST_FIT)
    nan_points = box.vertices.copy()
    nan_points[3, 1] = np.nan
    with pytest.raises(ValueError, match="mesh /nan: 1 point"):
        sp.fit_spheres(nan_points, box.faces, 2, name="/nan", **FAST_FIT)
    with pytest.raises(ValueError, match="mesh /many: sphere_count 100000 exceeds"):
        sp.fit_spheres(box.vertices, box.faces, 100000, name="/many", **FAST_FIT)
    with pytest.raises(ValueError, match="mesh /zero: sphere_count must be"):
        sp.fit_spheres(box.vertices, box.faces, 0, name="/zero", **FAST_FIT)
    with pytest.raises(ValueError, match="NaN"):
        sp.coverage_gap([[0.0, 0.0, np.nan]], [[0.0, 0.0, 0.0]], [1.0])


def test_open_mesh_as_shell():
    sheet = trimesh.creation.box(extents=(1.0, 1.0, 0.2))
    top = sheet.faces[sheet.triangles_center[:, 2] > 0.09]  # the top face only: an open sheet
    s = sp.fit_spheres(sheet.vertices, top, 3, name="/sheet", open_mesh="shell", shell_thickness=0.02, **FAST_FIT)
    assert not s.closed and s.shell_thickness == 0.02
    gap = sp.coverage_gap(s.surface_samples(sheet.vertices, top), s.centres, s.radii)
    assert gap.max() <= COVERAGE_ATOL
    assert np.isfinite(s.error) and s.volume == pytest.approx(2 * 0.02 * 1.0, rel=0.25)  # shell ~ 2 t area


def test_scene_without_closed_mesh_is_refused():
    plane = Mesh(path="/plane", points=[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], faces=[[0, 1, 2], [0, 2, 3]])
    with pytest.raises(ValueError, match="no closed mesh") as info:
        ss.spheres_for_scene(Scene.from_meshes([plane]), budget=4)
    # the skipped meshes are named with their reason, and the way to bound them as a shell
    assert "/plane: " in str(info.value) and "open_meshes = 'shell'" in str(info.value)


# ---- attachment ---------------------------------------------------------------------------------
def test_rigid_attachment_follows_the_transform_exactly(box, device):
    rng = np.random.default_rng(5)
    frames = []
    for k in range(3):
        m = np.eye(4)
        m[:3, :3] = Rotation.random(random_state=rng).as_matrix().T * (1.0 + 0.2 * k)  # uniform scale
        m[3, :3] = rng.uniform(-2, 2, 3)
        frames.append(m)
    mesh = Mesh(path="/box", points=box.vertices, faces=box.faces, animation="rigid", transforms=np.stack(frames))
    scene = Scene.from_meshes([mesh], frames=[0.0, 1.0, 2.0])
    spheres = ss.spheres_for_scene(scene, frame=1.0, budget=3, radius_scale=1.1, **FAST_FIT)
    animator = ss.SphereAnimator(scene, spheres, device=device)
    evaluator = FrameEvaluator(scene, device)
    fit_world = spheres.centres
    to_fit = np.linalg.inv(frames[1])
    for k, f in enumerate(scene.frames):
        expected = (fit_world @ to_fit[:3, :3] + to_fit[3, :3]) @ frames[k][:3, :3] + frames[k][3, :3]
        np.testing.assert_allclose(spheres.centres_at(scene, f), expected, atol=1e-12)
        # the safety factor times the scale of this frame relative to the fit frame
        np.testing.assert_allclose(spheres.radii_at(scene, f), 1.1 * spheres.radii * (1.0 + 0.2 * k) / 1.2, rtol=1e-12)
        animator.launch(_frame(evaluator, f))
        np.testing.assert_allclose(animator.centres.numpy(), expected, atol=ATOL_FLOAT32)
        np.testing.assert_allclose(animator.radii.numpy(), spheres.radii_at(scene, f), rtol=1e-6)
        # bounded on every frame
        pts, _ = spheres.surface_samples_at(scene, f)
        assert sp.coverage_gap_f64(pts, expected, spheres.radii_at(scene, f)).max() <= COVERAGE_ATOL


def test_skinned_attachment_is_mvc_of_the_deformed_mesh_and_tracks_a_bend(device):
    scene = load_scene("bundled:bend")
    joints = scene.skeletons[0].joint_count
    spheres = ss.spheres_for_scene(scene, budget=8, max_bones=joints, **FAST_FIT)
    mesh = scene.meshes[0]
    solid = fit_internals.make_solid(scene.points_at(scene.frames[0]), mesh.faces, mesh.path)
    weights, repro = attach.mvc_weights(solid, spheres.centres, spheres.sets[0])
    assert repro.max() < 1e-9  # linear precision at the fit pose
    animator = ss.SphereAnimator(scene, spheres, device=device)
    evaluator = FrameEvaluator(scene, device)
    mean_radius = float(spheres.rest_radii.mean())
    worst_gap = 0.0
    for f in scene.frames[::6]:
        centres = spheres.centres_at(scene, f)
        # all bones kept: the pre-multiplied bone form is exactly the MVC of the skinned mesh
        np.testing.assert_allclose(centres, weights @ scene.points_at(f), atol=1e-10)
        animator.launch(_frame(evaluator, f))
        np.testing.assert_allclose(animator.centres.numpy(), centres, atol=ATOL_FLOAT32)
        pts, _ = spheres.surface_samples_at(scene, f)
        worst_gap = max(worst_gap, sp.coverage_gap_f64(pts, centres, spheres.radii_at(scene, f)).max())
    assert worst_gap <= SKINNED_GAP_FRACTION * mean_radius, (worst_gap, mean_radius)
    # calibrated radii bound every frame by construction
    spheres.calibrate_radii(scene)
    for f in scene.frames[::6]:
        pts, _ = spheres.surface_samples_at(scene, f)
        assert sp.coverage_gap_f64(pts, spheres.centres_at(scene, f), spheres.radii_at(scene, f)).max() <= COVERAGE_ATOL


def test_skin_weight_attachment_reproduces_the_fit_pose(device):
    scene = load_scene("bundled:bend")
    spheres = ss.spheres_for_scene(scene, budget=4, skinned_attachment="skin_weights", **FAST_FIT)
    assert spheres.attachments[0]["method"] == "skin_weights"
    np.testing.assert_allclose(spheres.centres_at(scene, scene.frames[0]), spheres.centres, atol=1e-10)
    animator = ss.SphereAnimator(scene, spheres, device=device)
    evaluator = FrameEvaluator(scene, device)
    f = scene.frames[30]
    animator.launch(_frame(evaluator, f))
    np.testing.assert_allclose(animator.centres.numpy(), spheres.centres_at(scene, f), atol=ATOL_FLOAT32)


def test_deforming_meshes_follow_their_points(box, device):
    # a closed deforming mesh (vertex-weight MVC) and an open one bounded as a shell (triangle
    # frames), both animated by per-frame affine maps of their points
    rng = np.random.default_rng(8)
    maps = [np.eye(4)]
    for _ in range(2):
        m = np.eye(4)
        m[:3, :3] = Rotation.random(random_state=rng).as_matrix().T
        m[3, :3] = rng.uniform(-1, 1, 3)
        maps.append(m)
    sheet_points = np.array([[x, y, 0.0] for x in np.linspace(0, 1, 5) for y in np.linspace(0, 1, 5)]) + [2.0, 0.0, 0.0]
    i, j = np.meshgrid(np.arange(4), np.arange(4), indexing="ij")
    v = (i * 5 + j).ravel()
    sheet_faces = np.concatenate([np.stack([v, v + 5, v + 6], 1), np.stack([v, v + 6, v + 1], 1)])

    def samples(p):
        return np.stack([p @ m[:3, :3] + m[3, :3] for m in maps])

    closed = Mesh(path="/blob", points=box.vertices, faces=box.faces, animation="deforming", point_samples=samples(box.vertices))
    sheet = Mesh(path="/sheet", points=sheet_points, faces=sheet_faces, animation="deforming", point_samples=samples(sheet_points))
    scene = Scene.from_meshes([closed, sheet], frames=[0.0, 1.0, 2.0])
    spheres = ss.spheres_for_scene(scene, budget=4, open_meshes="shell", shell_thickness=0.05, **FAST_FIT)
    assert spheres.kinds == ["vertex_weights", "triangle_frame"]
    animator = ss.SphereAnimator(scene, spheres, device=device)
    evaluator = FrameEvaluator(scene, device)
    for k, f in enumerate(scene.frames):
        expected = spheres.centres @ maps[k][:3, :3] + maps[k][3, :3]  # rigid maps: exact
        np.testing.assert_allclose(spheres.centres_at(scene, f), expected, atol=1e-9)
        animator.launch(_frame(evaluator, f))
        np.testing.assert_allclose(animator.centres.numpy(), expected, atol=ATOL_FLOAT32)


def test_recorded_animator_replays_the_skinned_figure(figure_scene, figure_spheres, device):
    # the frame (scene evaluation, then the animator) recorded once and replayed per frame
    scene, spheres = figure_scene, figure_spheres
    assert "skinned" in spheres.kinds
    evaluator = FrameEvaluator(scene, device)
    animator = ss.SphereAnimator(scene, spheres, device=device)

    def record(recorder):
        evaluator.launch(recorder)
        animator.launch(evaluator.state)

    program = record_program(record, device)
    assert program.graph_count == 1 and not program.uncaptured  # one graph, no Python calls
    lo, hi = scene.bounds_over_frames()
    tolerance = REPLAY_RTOL * float(np.linalg.norm(hi - lo))
    frames = scene.frames[:: max(1, len(scene.frames) // 6)]
    assert len(frames) >= 4
    for f in frames:
        evaluator.set_frame(f)
        program.replay()
        centres, radii = animator.centres.numpy().copy(), animator.radii.numpy().copy()
        animator.centres.zero_()
        animator.radii.zero_()
        animator.launch(_frame(evaluator, f))
        assert_close(centres, animator.centres.numpy(), atol=tolerance, what=f"replayed sphere centres at frame {f}")
        assert_close(radii, animator.radii.numpy(), atol=tolerance, what=f"replayed sphere radii at frame {f}")
        # the replay follows the frame it was given (float64 mirror of the attachment)
        np.testing.assert_allclose(centres, spheres.centres_at(scene, f), atol=ATOL_FLOAT32)
        np.testing.assert_allclose(radii, spheres.radii_at(scene, f), rtol=1e-6)


def test_recorded_blocker_frames_match_uncaptured_launches(figure_scene, device):
    # SHEXP's per-frame blocker pass (animator, refit, receiver bounds, cut, ratio vectors)
    # recorded with the scene evaluation and replayed, against uncaptured launches
    from warpshade.methods.shexp import _model as blockers
    scene = figure_scene
    model = blockers.build_blocker_model(scene, 12, hierarchy=True, vertices_per_cluster=300, **FAST_FIT)
    frames = blockers.BlockerFrames(scene, model, 3, theta_max_degrees=25.0, device=device)
    evaluator = FrameEvaluator(scene, device)

    def record(recorder):
        evaluator.launch(recorder)
        frames.launch(evaluator.state)

    program = record_program(record, device)
    assert not program.uncaptured
    lo, hi = scene.bounds_over_frames()
    tolerance = REPLAY_RTOL * float(np.linalg.norm(hi - lo))
    outputs = (frames.node_centres, frames.node_radii, frames.cut.cut_nodes, frames.cut.cut_count, frames.cut_weights)
    tree = model.tree
    for f in scene.frames[:: max(1, len(scene.frames) // 4)]:
        evaluator.set_frame(f)
        program.replay()
        replayed = [a.numpy().copy() for a in outputs]
        for a in outputs:
            a.zero_()
        frames.launch(_frame(evaluator, f))
        names = ("node centres", "node radii", "cut nodes", "cut counts", "cut weights")
        for got, a, name in zip(replayed, outputs, names):
            assert_close(got, a.numpy(), atol=tolerance, what=f"replayed {name} at frame {f}")
        # the refit tree bounds the frame's leaf spheres; every cut covers every leaf once
        nc, nr = replayed[0], replayed[1]
        spheres_c, spheres_r = model.spheres.centres_at(scene, f), model.spheres.radii_at(scene, f)
        np.testing.assert_allclose(nc[tree.leaf_node], spheres_c[tree.leaf_sphere], atol=ATOL_FLOAT32)
        for node in tree.level_nodes:
            below = tree.leaves(node)
            excess = np.linalg.norm(spheres_c[below] - nc[node], axis=1) + spheres_r[below] - nr[node]
            assert excess.max() <= REFIT_ATOL + ATOL_FLOAT32, (f, node, excess.max())
        for c in range(frames.clusters):
            cut = replayed[2][c, : replayed[3][c]]
            assert sorted(np.concatenate([tree.leaves(n) for n in cut])) == list(range(tree.leaf_total))
        assert np.all(np.isfinite(replayed[4]))


def test_blocker_scene_spheres_come_out_as_one_sphere(device):
    scene = load_scene("bundled:blockers")
    spheres = ss.spheres_for_scene(scene, budget=12, split="volume", target_error=0.1, device=device, **FAST_FIT)
    counts = dict(zip(spheres.mesh_path, (s.sphere_count for s in spheres.sets)))
    assert counts["/World/Blockers/BigSphere/Mesh"] == 1 and counts["/World/Blockers/SmallSphere/Mesh"] == 1
    assert [p for p, _ in spheres.skipped] == ["/World/Ground"]
    assert all(s.error <= 0.1 or s.sphere_count >= 2 for s in spheres.sets)
    sphere_set = spheres.sets[spheres.mesh_path.index("/World/Blockers/BigSphere/Mesh")]
    assert sphere_set.error < 0.06  # the circumscribed ball of a 182-vertex sphere mesh: ~0.042


def test_mean_value_coordinates_identities(capsule):
    p, f = np.asarray(capsule.vertices), np.asarray(capsule.faces)
    rng = np.random.default_rng(2)
    for x in list(rng.uniform(-0.15, 0.15, (3, 3))) + [np.array([0.0, 0.0, 2.0])]:  # inside and outside
        w = mvc.mean_value_coordinates(p, f, x)
        assert abs(w.sum() - 1.0) < 1e-12
        np.testing.assert_allclose(w @ p, x, atol=1e-10)
    assert mvc.winding_number(p, f, np.zeros(3)) == pytest.approx(1.0, abs=1e-9)
    assert mvc.winding_number(p, f, np.array([0.0, 0.0, 2.0])) == pytest.approx(0.0, abs=1e-9)


# ---- hierarchy and receivers -------------------------------------------------------------------
def test_tree_stays_valid_on_every_frame_of_the_figure(figure_scene, figure_spheres, device):
    spheres = figure_spheres
    tree = sp.build_sphere_tree(spheres.centres, spheres.rest_radii, groups=spheres.sphere_mesh)
    assert tree.leaf_total == spheres.sphere_count and sorted(tree.leaf_sphere) == list(range(spheres.sphere_count))
    assert np.all(tree.leaf_count[0] == spheres.sphere_count) and tree.skip[0] == tree.node_count
    animator = ss.SphereAnimator(figure_scene, spheres, device=device)
    evaluator = FrameEvaluator(figure_scene, device)
    refits = {mode: sp.SphereTreeRefit(tree, device=device, mode=mode) for mode in sp.REFIT_MODES}
    inner = tree.level_nodes
    for f in figure_scene.frames:
        animator.launch(_frame(evaluator, f))
        for mode, refit in refits.items():
            refit.launch(animator.centres, animator.radii)
            nc, nr = refit.node_centres.numpy(), refit.node_radii.numpy()
            for node in inner:
                kids = tree.children(node)
                excess = np.linalg.norm(nc[kids] - nc[node], axis=1) + nr[kids] - nr[node]
                assert excess.max() <= REFIT_ATOL, (mode, f, node, excess.max())
        _, ref_r = sp.refit_f64(tree, animator.centres.numpy(), animator.radii.numpy(), mode="min")
        np.testing.assert_allclose(refits["min"].node_radii.numpy(), ref_r, rtol=1e-5, atol=ATOL_FLOAT32)
        ref_c, ref_r = sp.refit_f64(tree, animator.centres.numpy(), animator.radii.numpy(), mode="anchored")
        np.testing.assert_allclose(refits["anchored"].node_centres.numpy(), ref_c, atol=ATOL_FLOAT32)
        np.testing.assert_allclose(refits["anchored"].node_radii.numpy(), ref_r, rtol=1e-5, atol=ATOL_FLOAT32)
    # the rest tree is what the build's Powell produced
    _, ref_r = sp.refit_f64(tree, spheres.centres, spheres.rest_radii, mode="anchored")
    np.testing.assert_allclose(ref_r, tree.node_radius, rtol=1e-9)


def test_cut_matches_brute_force_eq36(device):
    rng = np.random.default_rng(11)
    centres = rng.uniform(-2, 2, (40, 3))
    radii = rng.uniform(0.05, 0.3, 40)
    tree = sp.build_sphere_tree(centres, radii, branching=4)
    refit = sp.SphereTreeRefit(tree, device=device)
    from warpshade._wp import wp

    refit.launch(wp.array(centres.astype(np.float32), dtype=wp.vec3, device=device), wp.array(radii.astype(np.float32), dtype=wp.float32, device=device))
    cluster_c = rng.uniform(-4, 4, (25, 3))
    cluster_r = rng.uniform(0.0, 0.5, 25)
    cut = sp.HierarchyCut(refit, 25, theta_max_degrees=25.0)
    cut.launch(wp.array(cluster_c.astype(np.float32), dtype=wp.vec3, device=device), wp.array(cluster_r.astype(np.float32), dtype=wp.float32, device=device))
    nc, nr = refit.node_centres.numpy().astype(np.float64), refit.node_radii.numpy().astype(np.float64)
    reference = sp.cut_f64(tree, nc, nr, cluster_c, cluster_r, 25.0)
    nodes, counts = cut.cut_nodes.numpy(), cut.cut_count.numpy()
    s = math.sin(math.radians(25.0))
    compared = 0
    for c in range(25):
        # skip clusters where some node sits within float32 rounding of the threshold
        margin = np.abs(nr - s * (np.linalg.norm(nc - cluster_c[c], axis=1) - cluster_r[c]))
        if margin.min() < 1e-5:
            continue
        compared += 1
        assert list(nodes[c, : counts[c]]) == reference[c]
        assert np.all(nodes[c, counts[c] :] == -1)
        # the cut covers every leaf exactly once
        leaves = np.concatenate([tree.leaves(n) for n in reference[c]])
        assert sorted(leaves) == list(range(40))
    assert compared >= 20 and not cut.overflowed()
    small = sp.HierarchyCut(refit, 25, capacity=2)
    small.launch(wp.array(cluster_c.astype(np.float32), dtype=wp.vec3, device=device), wp.array(cluster_r.astype(np.float32), dtype=wp.float32, device=device))
    assert small.overflowed() == any(len(r) > 2 for r in reference)


def test_receiver_clusters_and_bounds(figure_scene, device):
    clusters = ss.scene_receiver_clusters(figure_scene, vertices_per_cluster=300)
    assert clusters.cluster_start[-1] == figure_scene.vertex_count
    assert sorted(clusters.cluster_vertices) == list(range(figure_scene.vertex_count))
    bounds = sp.ReceiverBounds(clusters, device=device)
    for f in figure_scene.frames[::20]:
        fs = figure_scene.evaluate(f, device=device)
        bounds.launch(fs.points)
        c, r, rep = clusters.bounds_f64(fs.points.numpy())
        np.testing.assert_allclose(bounds.centres.numpy(), c, atol=ATOL_FLOAT32)
        np.testing.assert_allclose(bounds.radii.numpy(), r, rtol=1e-5, atol=ATOL_FLOAT32)
        np.testing.assert_allclose(bounds.representative_points.numpy(), rep, atol=0)
        pts = fs.points.numpy()
        for k in range(clusters.cluster_count):
            d = np.linalg.norm(pts[clusters.vertices(k)] - bounds.centres.numpy()[k], axis=1)
            assert d.max() <= bounds.radii.numpy()[k] * (1 + 1e-6)


def _through_npz(arrays):
    """Save and load as the artifact cache does (np.savez, no pickles)."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    buffer.seek(0)
    with np.load(buffer, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


def test_artifact_round_trips(box_set, figure_spheres):
    again = sp.SphereSet.from_arrays(_through_npz(box_set.to_arrays()))
    np.testing.assert_array_equal(again.centres, box_set.centres)
    assert again.error == box_set.error and again.parameters == box_set.parameters
    arrays = figure_spheres.to_arrays()
    assert all(isinstance(v, np.ndarray) for v in arrays.values())
    scene_again = ss.SceneSpheres.from_arrays(_through_npz(arrays))
    np.testing.assert_array_equal(scene_again.rest_radii, figure_spheres.rest_radii)
    assert scene_again.kinds == figure_spheres.kinds
    tree = sp.build_sphere_tree(box_set.centres, box_set.radii)
    tree_again = sp.SphereTree.from_arrays(_through_npz(tree.to_arrays()))
    np.testing.assert_array_equal(tree_again.skip, tree.skip)
