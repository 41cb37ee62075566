"""Cloth inputs of data-driven visibility: the simulated clips, dihedral-angle features, rotation clusters.

Oracles: hinges folded by known angles and flat sheets (analytic dihedral angles); a strip folded
along two lines by independent angles (an angle matrix of rank two: two PCA components hold all
of its variance); the float64 mirror (``dihedral_angles_f64``, ``DihedralFeatures.transform``) for
the Warp kernels; rigid motions (exact rotations, a zero rigid-fit residual) for the clusters.
The Newton simulation itself runs only in the asset generator: here the bundled clips are loaded.
"""

import os
import types

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tolerances import ATOL_FLOAT64, assert_close
from warpshade._wp import wp
from warpshade.io import bundled_asset_directory, load_usd
from warpshade.methods.visibility._cloth import (
    DEGENERATE_RELATIVE_AREA,
    DihedralFeatures,
    DihedralInputs,
    cluster_labels,
    dihedral_angles,
    dihedral_angles_f64,
    dihedral_angles_kernel,
    interior_edges,
    rigid_fit_residual,
    rotation_clusters,
    triangle_rotations_f64,
)

#: float32 dihedral angles against float64 on the same float32 points (radians): edge and normal
#: vectors are differences of coordinates up to ~2.5 m for edges >= 0.05 m, so their relative
#: error is ~50 ulp (6e-6), and atan2 of unit vectors keeps it: 1e-4 leaves a margin of ten.
ATOL_ANGLE_FLOAT32 = 1e-4
#: float32 PCA features (a sum over ~3,000 edges of basis (<= 1) times centred angle errors of
#: ATOL_ANGLE_FLOAT32 at worst, random in sign): relative to the features' training spread.
RTOL_FEATURES_FLOAT32 = 1e-3
#: Bytes of each bundled clip (issue 24: repo files under ~8 MB).
MAX_CLIP_BYTES = 8 * 1024 * 1024
CLIPS = {"cloth_train": 120, "cloth_heldout": 60}
#: No held-out frame after the first half second is a copy of a training frame: each lies at least
#: this far (metres, mean over vertices of the distance) from every training frame, 50 times the
#: 0.1 mm rounding of the files. Measured: 29 mm to the nearest training frame at the closest,
#: 52 mm on average -- the held-out shapes lie among the training ones without repeating them.
HELD_OUT_MIN_GAP = 0.005


# ---- meshes ---------------------------------------------------------------------------------------
def _grid(nx: int, ny: int, size: float = 1.0):
    """A flat (nx + 1) x (ny + 1) grid in z = 0 split into 2 nx ny triangles (counter-clockwise from +z)."""
    x, y = np.meshgrid(np.linspace(0.0, size * nx / max(nx, ny), nx + 1), np.linspace(0.0, size * ny / max(nx, ny), ny + 1), indexing="ij")
    points = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    v00 = (i * (ny + 1) + j).ravel()
    v10, v01, v11 = v00 + ny + 1, v00 + 1, v00 + ny + 2
    faces = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])
    return points, faces


def _hinge(angle: float):
    """Two triangles on the edge (0,0,0)-(1,0,0): (a, b, c) in the +y half-plane, normal +z, and
    (b, a, d) whose wing d is folded by ``angle`` about the edge towards +z."""
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 1.0, 0.0], [0.5, -np.cos(angle), np.sin(angle)]])
    return points, np.array([[0, 1, 2], [1, 0, 3]])


def _folded_strip(alpha, beta):
    """A 3 x 1 strip of unit squares (normal +z) folded towards +z about the line x = 1 by
    ``alpha`` and about x = 2 by a further ``beta``: points (T, V, 3) for angle sequences (T,),
    faces, and the flat rest points."""
    rest, faces = _grid(3, 1, size=3.0)  # x in 0..3, y in 0..1
    x, y = rest[:, 0], rest[:, 1]
    seg1, seg2 = (x > 1.0) & (x <= 2.0), x > 2.0
    out = []
    for a, b in zip(np.atleast_1d(alpha), np.atleast_1d(beta)):
        p = rest.copy()
        p[seg1] = np.stack([1.0 + (x[seg1] - 1.0) * np.cos(a), y[seg1], (x[seg1] - 1.0) * np.sin(a)], 1)
        p[seg2] = np.stack([1.0 + np.cos(a) + (x[seg2] - 2.0) * np.cos(a + b), y[seg2],
                            np.sin(a) + (x[seg2] - 2.0) * np.sin(a + b)], 1)
        out.append(p)
    return np.stack(out), faces, rest


# ---- the bundled clips ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def clips():
    """The two bundled cloth clips: name -> (Scene, the cloth Mesh)."""
    out = {}
    for name in CLIPS:
        scene = load_usd(f"bundled:{name}")
        cloth = next(m for m in scene.meshes if m.path == "/World/Cloth")
        out[name] = scene, cloth
    return out


def test_bundled_cloth_clips_share_topology_and_are_finite(clips):
    faces = None
    for name, frames in CLIPS.items():
        path = os.path.join(bundled_asset_directory(), f"{name}.usdc")
        assert os.path.getsize(path) < MAX_CLIP_BYTES, f"{name}.usdc is {os.path.getsize(path)} bytes"
        scene, cloth = clips[name]
        assert cloth.animation == "deforming" and len(scene.frames) == frames
        assert 1000 <= cloth.vertex_count <= 2000 and cloth.point_samples.shape == (frames, cloth.vertex_count, 3)
        assert np.all(np.isfinite(cloth.point_samples))
        assert scene.camera is not None and scene.lights and any(m.path == "/World/Ground" for m in scene.meshes)
        assert cloth.point_samples[..., 2].min() > 0.0  # above the ground it shadows
        if faces is None:
            faces = cloth.faces
        np.testing.assert_array_equal(cloth.faces, faces)
    train = clips["cloth_train"][1].point_samples
    heldout = clips["cloth_heldout"][1].point_samples
    # both start from the same rest state, the rod stays pinned, and the held-out forcing differs:
    # no held-out frame after the first half second repeats a training frame
    rod = np.isclose(train[0, :, 2], train[0, :, 2].max(), atol=1e-4)
    assert rod.sum() == 33
    assert_close(train[:, rod], train[:1, rod], atol=1e-4, what="pinned rod")
    assert_close(heldout[:, rod], train[:1, rod], atol=1e-4, what="pinned rod (held out)")
    gap = np.linalg.norm(heldout[12:, None] - train[None], axis=-1).mean(axis=-1).min(axis=1)
    assert gap.min() > HELD_OUT_MIN_GAP, f"held-out frame {12 + gap.argmin()} is within {gap.min():.4f} m of a training frame"


def test_features_of_the_bundled_clips(clips, device):
    cloth_train = clips["cloth_train"][1]
    cloth_test = clips["cloth_heldout"][1]
    model = DihedralFeatures.fit(cloth_train.point_samples, cloth_train.faces, variance=0.9)
    assert model.retained_variance >= 0.9 and 1 <= model.component_count < 40
    # fewer components for a looser target, more for a tighter one
    assert DihedralFeatures.fit(cloth_train.point_samples, cloth_train.faces, variance=0.5).component_count < model.component_count
    frame = cloth_test.point_samples[31].astype(np.float32)
    program = model.bind(device)
    program.launch(wp.array(frame, dtype=wp.vec3, device=device))
    expected = model.transform(frame.astype(np.float64))
    spread = np.sqrt(model.variances)
    assert_close(program.features.numpy() / spread, expected / spread, atol=RTOL_FEATURES_FLOAT32, what="held-out features")
    assert_close(program.angles.numpy(), model.angles(frame.astype(np.float64)), atol=ATOL_ANGLE_FLOAT32, what="angles")


# ---- edges and angles -----------------------------------------------------------------------------
def test_interior_edges_of_a_grid_leave_out_the_boundary():
    n = 5
    _, faces = _grid(n, n)
    edges, wings = interior_edges(faces)
    assert len(edges) == 3 * n * n - 2 * n  # all 3n^2 + 2n edges but the 4n on the boundary
    for (a, b), (c, d) in zip(edges, wings):
        tris = [set(f) for f in faces if a in f and b in f]
        assert sorted(map(sorted, tris)) == sorted([sorted({a, b, c}), sorted({a, b, d})])


def test_non_manifold_and_degenerate_faces_are_excluded():
    # three triangles on the edge 0-1 (non-manifold), one more glued to 0-2 (interior), and a
    # triangle that repeats a vertex
    faces = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [2, 0, 5], [6, 6, 7]])
    edges, wings = interior_edges(faces)
    assert [tuple(sorted(e)) for e in edges] == [(0, 2)]
    assert sorted(wings[0]) == [1, 5]
    assert len(interior_edges(np.array([[0, 1, 2]]))[0]) == 0  # a lone triangle: boundary only


@pytest.mark.parametrize("angle", [0.0, 0.3, -0.7, 1.2, -2.5, 3.0])
def test_a_hinge_folded_by_a_known_angle(angle, device):
    points, faces = _hinge(angle)
    edges, angles = dihedral_angles_f64(points, faces)
    assert edges.tolist() == [[0, 1]]
    assert_close(angles, [angle], atol=ATOL_FLOAT64 * 10, what="hinge angle")
    # rigidly moved, and with the second triangle wound the other way: the same angle
    rot = Rotation.from_rotvec([0.3, -1.1, 0.5]).as_matrix()
    moved = points @ rot.T + [2.0, -1.0, 0.5]
    assert_close(dihedral_angles_f64(moved, np.array([[0, 1, 2], [0, 1, 3]]))[1], [angle], atol=1e-12, what="moved hinge")
    out = wp.zeros(1, dtype=wp.float32, device=device)
    quads = wp.array(np.array([[0, 1, 2, 3]], np.int32), dtype=wp.int32, device=device)
    wp.launch(dihedral_angles_kernel, dim=1, inputs=[wp.array(moved.astype(np.float32), dtype=wp.vec3, device=device), quads, 0],
              outputs=[out], device=device)
    assert_close(out.numpy(), [angle], atol=ATOL_ANGLE_FLOAT32, what="hinge angle (kernel)")


def test_a_flat_sheet_has_zero_angles_and_a_cylinder_the_polygon_angle():
    points, faces = _grid(6, 4)
    _, angles = dihedral_angles_f64(points, faces)
    assert_close(angles, 0.0, atol=ATOL_FLOAT64, what="flat sheet")
    # a grid rolled into an open cylinder of 8 facets (normals outward): each edge along the
    # axis bends by 2 pi / 8 as a ridge (negative), the diagonals inside a facet stay flat
    n_around = 8
    u, v = np.meshgrid(np.arange(n_around - 2), np.arange(3), indexing="ij")  # 6 of 8 facets: open
    theta = 2.0 * np.pi * u.ravel() / n_around
    rolled = np.stack([np.cos(theta), np.sin(theta), v.ravel().astype(float)], 1)
    _, f = _grid(n_around - 3, 2)  # same vertex order: index = i * 3 + j
    edges, angles = dihedral_angles_f64(rolled, f)  # the grid's winding: normals point outward
    same = np.all(np.isclose(rolled[edges[:, 0], :2], rolled[edges[:, 1], :2]), axis=1)
    assert_close(angles[same], -2.0 * np.pi / n_around, atol=1e-12, what="cylinder ridges")
    assert_close(angles[~same], 0.0, atol=1e-12, what="facet diagonals")
    assert same.sum() == (n_around - 4) * 2  # 6 columns around: 4 interior axis lines of 2 edges
    _, inward = dihedral_angles_f64(rolled, f[:, [0, 2, 1]])  # seen from inside: valleys
    assert_close(inward[same], 2.0 * np.pi / n_around, atol=1e-12, what="cylinder valleys")


def test_degenerate_triangles_give_bounded_angles(device):
    # a sliver (collinear wing), a collapsed edge (a == b) and a point triangle
    cases = [
        np.array([[0.0, 0, 0], [1, 0, 0], [0.5, 0, 0], [0.5, -1, 0.2]]),
        np.array([[0.0, 0, 0], [0, 0, 0], [0.5, 1, 0], [0.5, -1, 0.2]]),
        np.array([[1.0, 1, 1], [1, 1, 1], [1, 1, 1], [1, 1, 1]]),
        np.array([[0.0, 0, 0], [1, 0, 0], [0.5, 1e-9, 0], [0.5, -1, 0.3]]),  # below DEGENERATE_RELATIVE_AREA
    ]
    quads = wp.array(np.array([[0, 1, 2, 3]], np.int32), dtype=wp.int32, device=device)
    for points in cases:
        _, angles = dihedral_angles_f64(points, np.array([[0, 1, 2], [1, 0, 3]]))
        assert np.all(np.isfinite(angles)) and angles[0] == 0.0
        out = wp.full(1, 7.0, dtype=wp.float32, device=device)
        wp.launch(dihedral_angles_kernel, dim=1, inputs=[wp.array(points.astype(np.float32), dtype=wp.vec3, device=device), quads, 0],
                  outputs=[out], device=device)
        assert out.numpy()[0] == 0.0
    assert 1e-9 < DEGENERATE_RELATIVE_AREA  # the fourth case is degenerate by the named threshold


def test_kernel_matches_the_float64_angles_on_a_crumpled_sheet(rng, device):
    points, faces = _grid(12, 12, size=1.6)
    points = points + rng.normal(scale=0.04, size=points.shape) + [0.0, 0.0, 1.2]
    points32 = points.astype(np.float32)
    edges, expected = dihedral_angles_f64(points32.astype(np.float64), faces)
    _, wings = interior_edges(faces)
    quads = np.concatenate([edges, wings], 1).astype(np.int32)
    # the cloth sits after 5 other vertices in the scene's points: vertex_offset
    scene_points = np.concatenate([np.zeros((5, 3), np.float32), points32])
    out = wp.zeros(len(edges), dtype=wp.float32, device=device)
    wp.launch(dihedral_angles_kernel, dim=len(edges), inputs=[wp.array(scene_points, dtype=wp.vec3, device=device),
              wp.array(quads, dtype=wp.int32, device=device), 5], outputs=[out], device=device)
    assert np.abs(expected).max() > 0.3  # really crumpled
    assert_close(out.numpy(), expected, atol=ATOL_ANGLE_FLOAT32, what="crumpled sheet angles")


def test_bad_points_and_faces_are_reported():
    points, faces = _grid(2, 2)
    with pytest.raises(ValueError, match="non-finite"):
        dihedral_angles_f64(np.where(np.arange(points.size).reshape(points.shape) == 4, np.nan, points), faces)
    with pytest.raises(ValueError, match=r"\(F, 3\)"):
        dihedral_angles_f64(points, faces[:, :2])
    with pytest.raises(ValueError, match="outside"):
        dihedral_angles_f64(points, faces + 100)


# ---- PCA ------------------------------------------------------------------------------------------
def test_two_independent_folds_need_two_components(rng, device):
    alpha, beta = rng.uniform(-1.0, 1.0, 40), rng.uniform(-1.0, 1.0, 40)
    points, faces, rest = _folded_strip(alpha, beta)
    edges, angles = dihedral_angles_f64(points, faces)
    # the fold lines hold alpha and beta (valleys: folded towards the normal +z), the rest is flat
    line = rest[edges, 0]  # (E, 2) rest x of both ends
    on1, on2 = np.all(line == 1.0, axis=1), np.all(line == 2.0, axis=1)
    assert on1.sum() == 1 and on2.sum() == 1
    assert_close(angles[:, on1], alpha[:, None], atol=1e-12, what="first fold")
    assert_close(angles[:, on2], beta[:, None], atol=1e-12, what="second fold")
    assert_close(angles[:, ~(on1 | on2)], 0.0, atol=1e-12, what="flat squares")
    model = DihedralFeatures.fit(points, faces, variance=0.999)
    assert model.component_count == 2 and model.retained_variance > 1.0 - 1e-9
    # the two features reproduce every training angle exactly (rank two)
    assert_close(model.reconstruct(model.transform(points)), angles, atol=1e-9, what="rank-2 reconstruction")
    # a looser target keeps one; the retained variance meets each target
    one = DihedralFeatures.fit(points, faces, variance=0.3)
    assert one.component_count == 1 and one.retained_variance >= 0.3
    assert_close(1.0 - one.retained_variance,
                 ((one.reconstruct(one.transform(points)) - angles) ** 2).sum() / ((angles - angles.mean(0)) ** 2).sum(),
                 atol=1e-9, what="training error = 1 - retained variance")
    # the device program (a recordable pair of launches) against transform, on a new fold
    new_points, _, _ = _folded_strip([0.4], [-0.2])
    program = model.bind(device)
    program.launch(wp.array(new_points[0].astype(np.float32), dtype=wp.vec3, device=device))
    assert_close(program.features.numpy(), model.transform(new_points[0]), atol=4 * ATOL_ANGLE_FLOAT32, what="features")


def test_constant_input_is_bounded_and_reported(device):
    points, faces = _grid(4, 4)
    clip = np.repeat(points[None], 5, axis=0)
    model = DihedralFeatures.fit(clip, faces)
    assert model.constant and model.component_count == 1 and model.retained_variance == 1.0
    features = model.transform(clip)
    assert np.all(features == 0.0)
    program = model.bind(device)
    program.launch(wp.array(points.astype(np.float32), dtype=wp.vec3, device=device))
    assert np.all(np.isfinite(program.features.numpy())) and np.all(program.features.numpy() == 0.0)
    assert np.all(np.isfinite(model.novelty(features)))


def test_fit_and_cache_round_trip_and_bad_input():
    points, faces, _ = _folded_strip(np.linspace(-1, 1, 7), np.linspace(1, -0.5, 7))
    model = DihedralFeatures.fit(points, faces, variance=0.95)
    again = DihedralFeatures.from_arrays(model.arrays())
    assert_close(again.transform(points), model.transform(points), atol=0.0, what="cached features")
    assert model.novelty(model.transform(points)).max() == 0.0
    assert model.novelty(model.transform(points)[:1] + 10.0 * np.sqrt(model.variances)).max() > 5.0
    broken = dict(model.arrays(), basis=model.basis[:, :-1])
    with pytest.raises(ValueError, match="basis"):
        DihedralFeatures.from_arrays(broken)
    with pytest.raises(ValueError, match="not finite"):
        DihedralFeatures.from_arrays(dict(model.arrays(), mean=model.mean * np.nan))
    with pytest.raises(ValueError, match="variance"):
        DihedralFeatures.fit(points, faces, variance=0.0)
    with pytest.raises(ValueError, match="T >= 2"):
        DihedralFeatures.fit(points[:1], faces)
    with pytest.raises(ValueError, match="no interior edge"):
        DihedralFeatures.fit(np.zeros((3, 3, 3)), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="vertices"):
        model.transform(points[:, :3])


# ---- rotations and clusters -----------------------------------------------------------------------
def test_triangle_rotations_of_a_rigid_motion_and_degenerate_triangles(rng):
    points, faces = _grid(3, 3)
    points = points + rng.normal(scale=0.05, size=points.shape)
    rots = Rotation.from_rotvec(rng.normal(size=(4, 3))).as_matrix()
    clip = np.einsum("tij,vj->tvi", rots, points) + rng.normal(size=(4, 1, 3))
    r = triangle_rotations_f64(clip, faces, rest=points)
    assert_close(r, np.broadcast_to(rots[:, None], r.shape), atol=1e-9, what="triangle rotations")
    # a collapsed triangle still gets a proper rotation
    crushed = clip.copy()
    crushed[:, faces[0, 1]] = crushed[:, faces[0, 0]]
    r = triangle_rotations_f64(crushed, faces, rest=points)
    assert np.all(np.isfinite(r))
    assert_close(np.linalg.det(r), 1.0, atol=1e-9, what="det")
    assert_close(np.einsum("...ji,...jk->...ik", r, r), np.eye(3), atol=1e-9, what="orthonormal")


def _hinged_halves(frames: int = 12):
    """A 8 x 4 grid folded about x = 0.5 (the right half turns about the y axis line) while the
    whole sheet tumbles: two rigid parts sharing the hinge vertices."""
    points, faces = _grid(8, 4, size=1.0)
    t = np.linspace(0.0, 1.0, frames)
    out = []
    for k in range(frames):
        p = points.copy()
        right = points[:, 0] > 0.5 + 1e-9
        fold = Rotation.from_rotvec([0.0, -1.4 * t[k], 0.0]).as_matrix()
        p[right] = (points[right] - [0.5, 0.0, 0.0]) @ fold.T + [0.5, 0.0, 0.0]
        tumble = Rotation.from_rotvec([0.3 * t[k], 0.5 * t[k], -0.2 * t[k]]).as_matrix()
        out.append(p @ tumble.T + [t[k], 0.0, 0.2 * t[k]])
    return np.stack(out), faces, points


def test_two_rigid_halves_cluster_into_two():
    clip, faces, rest = _hinged_halves()
    clusters = rotation_clusters(clip, faces, tolerance=1e-6, seed=0)
    assert clusters.count == 2 and clusters.within_budget and clusters.residual < 1e-9
    assert [k for k, _ in clusters.tried] == [1, 2] and clusters.tried[0][1] > 0.05
    left = rest[:, 0] < 0.5 - 1e-9
    right = rest[:, 0] > 0.5 + 1e-9
    assert len(set(clusters.labels[left])) == 1 and len(set(clusters.labels[right])) == 1
    assert clusters.labels[left][0] != clusters.labels[right][0]
    centre_x = rest[faces].mean(axis=1)[:, 0]
    assert len(set(clusters.triangle_labels[centre_x < 0.5])) == 1 and len(set(clusters.triangle_labels[centre_x > 0.5])) == 1
    assert set(np.unique(clusters.labels)) == {0, 1} and clusters.labels[0] == 0


def test_cluster_labels_are_deterministic_for_a_seed():
    points, faces = _grid(8, 8, size=1.6)
    t = np.linspace(0.0, 1.0, 10)[:, None]
    x, y = points[:, 0][None], points[:, 1][None]
    clip = np.stack([np.broadcast_to(x, (10, len(points))), np.broadcast_to(y, (10, len(points))),
                     0.3 * np.sin(3.0 * x + 2.0 * t) * y], axis=-1)  # a flapping, bending sheet
    a = rotation_clusters(clip, faces, tolerance=1e-3, seed=3, max_clusters=12)
    b = rotation_clusters(clip, faces, tolerance=1e-3, seed=3, max_clusters=12)
    np.testing.assert_array_equal(a.labels, b.labels)
    assert a.tried == b.tried and a.count > 1
    # more clusters fit rigid motions better: the residual falls as the count grows
    residuals = [r for _, r in a.tried]
    assert residuals[-1] < residuals[0]
    assert a.residual == pytest.approx(rigid_fit_residual(clip, a.labels), abs=1e-15)
    if not a.within_budget:
        assert a.count <= 12 and a.residual > a.tolerance
    with pytest.raises(ValueError, match="tolerance"):
        rotation_clusters(clip, faces, tolerance=0.0)


def test_the_clips_are_written_on_request_with_their_own_wind():
    from warpshade.usd_assets import generator
    from warpshade.usd_assets.generator.cloth_clips import HELDOUT_WIND, TRAIN_WIND

    for name in CLIPS:  # simulated with Newton: never part of the default (byte-compared) set
        assert name in generator.MAKERS and name not in generator.SCENES
    for time, speed, heading, updraft in TRAIN_WIND.keys:
        a = np.radians(heading)
        assert_close(TRAIN_WIND.mean(time), [speed * np.sin(a), speed * np.cos(a), updraft], atol=1e-12, what="wind key")
    # the held-out forcing is another wind: its mean velocity differs from the training one's at
    # the same time by at least 1 m/s after the first 0.2 s
    times = np.linspace(0.2, 2.5, 24)
    gap = [np.linalg.norm(HELDOUT_WIND.mean(t) - TRAIN_WIND.mean(t)) for t in times]
    assert min(gap) > 1.0


def test_scene_inputs_for_the_visibility_stages(clips, device):
    """DihedralInputs (every interior edge of the scene, ground included) against dihedral_angles."""
    scene = clips["cloth_heldout"][0]
    inputs = DihedralInputs(scene, device)
    points = scene.points_at(40.0).astype(np.float32)
    inputs.launch(types.SimpleNamespace(points=wp.array(points, dtype=wp.vec3, device=device)))
    expected = dihedral_angles(points.astype(np.float64), scene.faces)
    assert expected.shape == (inputs.features.shape[0],) and inputs.quads.max() < scene.vertex_count
    assert_close(inputs.features.numpy(), expected, atol=ATOL_ANGLE_FLOAT32, what="scene dihedral angles")


def test_cluster_labels_of_a_training_artifact_keep_static_meshes_apart():
    clip, faces, rest = _hinged_halves()
    ground, ground_faces = _grid(3, 3)
    ground = ground - [0.0, 0.0, 1.0]
    v = len(rest)
    data = {"points": np.concatenate([clip, np.broadcast_to(ground, (len(clip), *ground.shape))], axis=1).astype(np.float32),
            "faces": np.concatenate([faces, ground_faces + v]), "rest_points": np.concatenate([rest, ground])}
    labels = cluster_labels(data, tolerance=1e-5)
    left, right = rest[:, 0] < 0.5 - 1e-9, rest[:, 0] > 0.5 + 1e-9
    assert len(set(labels[:v][left])) == 1 and len(set(labels[:v][right])) == 1 and labels[:v][left][0] != labels[:v][right][0]
    assert set(labels[v:]) == {2}  # the static grid: one label after the two moving clusters


def test_the_feature_program_replays_recorded(rng, device):
    """Recorded once (``record_program``, the runtime's frame recording), replayed on new points
    written into the same array: the same features as a direct launch."""
    from tolerances import REPLAY_RTOL
    from warpshade._wp import record_program

    clip, faces, _ = _folded_strip(rng.uniform(-1, 1, 12), rng.uniform(-1, 1, 12))
    model = DihedralFeatures.fit(clip, faces, variance=0.99)
    program = model.bind(device)
    points = wp.zeros(clip.shape[1], dtype=wp.vec3, device=device)
    recorded = record_program(lambda recorder: program.launch(points), device)
    new, _, _ = _folded_strip([0.25], [-0.6])
    points.assign(new[0].astype(np.float32))
    recorded.replay()
    replayed = program.features.numpy().copy()
    program.features.zero_()
    program.launch(points)
    direct = program.features.numpy()
    assert np.abs(direct).max() > 0.1
    assert_close(replayed, direct, rtol=REPLAY_RTOL, atol=REPLAY_RTOL * np.abs(direct).max(), what="replayed features")
