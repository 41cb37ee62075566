"""Relative inputs of data-driven visibility (``visibility.fit relative``, methods/visibility/relative.py):
the clusters' rigid motions against SciPy, the kernels against the float64 mirror, invariance to a
motion of the whole mesh, the selection of relative inputs (linear and quadratic, packed after the
linear blocks) on data generated from them, and the frame stage against the float64 model."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tolerances import ATOL_FLOAT32

from warpshade._wp import wp
from warpshade.io import load_scene
from warpshade.methods.visibility import fit_visibility, _kernels as kernels, predict_f64
from warpshade.methods.visibility._mirror import inputs_f64
from warpshade.methods.visibility._relative import (EXTRA, WIDTH, candidate_columns, cluster_neighbours,
                                                   relative_features_f64, rigid_f64, width)

from test_visibility import _bend_graph, _serial

#: Rotation error of the float32 Kabsch kernel against the float64 mirror: Warp's svd3 (a fixed
#: number of Jacobi sweeps) in float32 is good to about 1e-5 at a condition number of 30 and 1e-4
#: at 1000 (measured on random 3x3 matrices); these clusters' sums are below 100.
ROTATION_ATOL = 1e-4


def _moved(rng, rest, labels, noise=0.0):
    """Each cluster of ``rest`` turned and moved rigidly (random), plus noise; and the motions."""
    kc = labels.max() + 1
    rots = Rotation.random(kc, random_state=int(rng.integers(1 << 30))).as_matrix()
    shift = rng.normal(size=(kc, 3))
    pts = np.einsum("vij,vj->vi", rots[labels], rest) + shift[labels] + noise * rng.normal(size=rest.shape)
    return pts, rots


def _blobs(rng, kc=5, per=30):
    labels = np.repeat(np.arange(kc), per).astype(np.int32)
    rest = rng.normal(size=(kc * per, 3)) * [1.0, 0.5, 0.2] + 4.0 * rng.normal(size=(kc, 3))[labels]
    return rest, labels


def test_rigid_motion_is_scipys_least_squares_rotation(rng):
    rest, labels = _blobs(rng)
    exact, rots = _moved(rng, rest, labels)
    r, c = rigid_f64(exact, rest, labels)
    np.testing.assert_allclose(r[0], rots, atol=1e-10)
    np.testing.assert_allclose(c[0], np.stack([exact[labels == k].mean(0) for k in range(5)]), atol=1e-12)
    noisy, _ = _moved(rng, rest, labels, noise=0.05)
    r, _ = rigid_f64(noisy, rest, labels)
    for k in range(5):
        rows = labels == k
        want, _ = Rotation.align_vectors(noisy[rows] - noisy[rows].mean(0), rest[rows] - rest[rows].mean(0))
        np.testing.assert_allclose(r[0, k], want.as_matrix(), atol=1e-9)
        assert np.linalg.det(r[0, k]) > 0.0


def test_kernels_match_the_mirror_including_degenerate_clusters(device, rng):
    rest, labels = _blobs(rng, kc=7)
    rest[labels == 4] = rest[labels == 4][:1] + np.outer(np.linspace(0, 1, 30), [1.0, 2.0, 0.5])  # on a line
    labels[np.flatnonzero(labels == 5)[1:]] = 6  # cluster 5: one point
    pts, _ = _moved(rng, rest, labels, noise=0.01)
    nb = cluster_neighbours(rest, labels, 3)
    want_r, want_c = rigid_f64(pts, rest, labels)
    want = relative_features_f64(pts, rest, labels, nb)[0]

    kc = 7
    order = np.argsort(labels, kind="stable").astype(np.int32)
    offsets = np.r_[0, np.cumsum(np.bincount(labels, minlength=kc))].astype(np.int32)
    cent = np.stack([rest[labels == k].mean(0) for k in range(kc)]).astype(np.float32)
    rot = wp.zeros(kc, dtype=wp.mat33, device=device)
    cen = wp.zeros(kc, dtype=wp.vec3, device=device)
    wp.launch(kernels.cluster_rigid_kernel, dim=kc, device=device,
              inputs=[wp.array(pts.astype(np.float32), dtype=wp.vec3, device=device),
                      wp.array(rest.astype(np.float32), dtype=wp.vec3, device=device),
                      wp.array(order, dtype=wp.int32, device=device), wp.array(offsets, dtype=wp.int32, device=device),
                      wp.array(cent, dtype=wp.vec3, device=device), rot, cen])
    got_r = rot.numpy()
    assert np.all(np.isfinite(got_r)) and np.all(np.isfinite(cen.numpy()))
    for k in range(kc):  # every rotation is a rotation, the degenerate ones too
        np.testing.assert_allclose(got_r[k] @ got_r[k].T, np.eye(3), atol=1e-5)
        assert np.linalg.det(got_r[k]) > 0.0
    ok = [0, 1, 2, 3, 6]  # clusters whose points fix the rotation
    np.testing.assert_allclose(got_r[ok], want_r[0, ok], atol=ROTATION_ATOL)
    np.testing.assert_allclose(got_r[[4, 5]], np.stack([np.eye(3)] * 2), atol=1e-6)  # a line, a point: none
    np.testing.assert_allclose(want_r[0, [4, 5]], np.stack([np.eye(3)] * 2), atol=0.0)
    np.testing.assert_allclose(cen.numpy(), want_c[0], atol=ATOL_FLOAT32 * 10 * np.abs(want_c).max())

    base = 7
    feats = wp.zeros(base + kc * width(3), dtype=wp.float32, device=device)
    wp.launch(kernels.relative_features_kernel, dim=kc * (3 + 3), device=device,
              inputs=[wp.array(want_r[0].astype(np.float32), dtype=wp.mat33, device=device),
                      wp.array(want_c[0].astype(np.float32), dtype=wp.vec3, device=device),
                      wp.array(nb, dtype=wp.int32, device=device), base, feats])
    got = feats.numpy()
    assert np.all(got[:base] == 0.0)
    np.testing.assert_allclose(got[base:], want, atol=10 * ATOL_FLOAT32 * np.abs(want).max())


def test_relative_inputs_ignore_a_motion_of_the_whole_mesh(rng):
    rest, labels = _blobs(rng)
    pts, _ = _moved(rng, rest, labels, noise=0.02)
    turn = Rotation.random(random_state=3).as_matrix()
    moved = pts @ turn.T + [3.0, -1.0, 2.0]
    nb = cluster_neighbours(rest, labels, 4)
    a = relative_features_f64(np.stack([pts, moved]), rest, labels, nb).reshape(2, 5, width(4))
    np.testing.assert_allclose(a[1, :, :WIDTH * 4], a[0, :, :WIDTH * 4], atol=1e-10)  # the neighbours' centroids
    r, _ = rigid_f64(pts, rest, labels)
    np.testing.assert_allclose(a[0, :, WIDTH * 4:WIDTH * 4 + 3], r[0, :, 1, :], atol=1e-12)  # R^T e_y: R's 2nd row
    assert EXTRA == 9 and not np.allclose(a[1, :, WIDTH * 4:], a[0, :, WIDTH * 4:])  # the cluster's world pose


def test_neighbours_are_the_nearest_clusters_nearest_first():
    rest = np.repeat(np.array([[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0], [7.0, 0, 0]]), 3, axis=0)
    rest += np.tile([[0, 0.1, 0], [0, -0.1, 0], [0, 0, 0.1]], (4, 1))
    labels = np.repeat(np.arange(4), 3)
    np.testing.assert_array_equal(cluster_neighbours(rest, labels, 2), [[1, 2], [0, 2], [1, 0], [2, 1]])
    assert cluster_neighbours(rest, labels, 10).shape == (4, 3)  # no more than the other clusters
    np.testing.assert_array_equal(candidate_columns(1, 1, 2, 5), 5 + width(2) + np.r_[0, 1, 2, 6:6 + EXTRA])


def _relative_data(rng, p=200):
    """visibility.data-shaped arrays over blobs that move (translations: the clusters' frames stay put):
    each cluster's visibility linear in its nearest neighbour's centroid in its frame, and cluster 0's
    mostly the product of two of its coordinates."""
    rest, labels = _blobs(rng, kc=4, per=25)
    pts = rest[None] + rng.normal(size=(p, 4, 3))[:, labels]
    g = relative_features_f64(pts, rest, labels, cluster_neighbours(rest, labels, 1)).reshape(p, 4, width(1))
    v = rest.shape[0]
    vis = np.broadcast_to(rng.normal(size=(v, 9)), (p, v, 9)).copy()
    for k in range(4):
        rows = labels == k
        rel = g[:, k, :3] - g[:, k, :3].mean(0)
        vis[:, rows] += (0.1 if k == 0 else 1.0) * np.einsum("pc,cvk->pvk", rel, rng.normal(size=(3, rows.sum(), 9)))
        if k == 0:
            vis[:, rows] += (rel[:, 0] * rel[:, 1])[:, None, None] * rng.normal(size=(rows.sum(), 9))
    vis += 0.01 * rng.normal(size=vis.shape)
    nrm = np.broadcast_to([0.0, 0.0, 1.0], pts.shape)
    return {"visibility": vis.astype(np.float32), "points": pts.astype(np.float32), "normals": nrm.astype(np.float32),
            "rest_points": rest, "faces": np.zeros((0, 3), np.int32), "skin_weights": np.ones((v, 1), np.float32),
            "mesh_ids": np.zeros(v, np.int32), "poses_quaternion": rng.uniform(-1, 1, (p, 3)),
            "root_quaternion": np.zeros(3, np.int8), "topology": np.zeros(4, np.int64),
            "root_reference": np.zeros((0, 3, 3)), "settings": np.array([3, 16, 0, 0])}, labels


def test_auto_selects_relative_inputs_and_packs_their_products(rng):
    """On visibility generated from the relative inputs, "auto" picks them for every cluster (a
    quadratic map where the data has a product), the packed model equals the selected maps, and on
    novel poses it is far closer than the model without them."""
    data, labels = _relative_data(rng)
    train = {k: (v[:160] if k in ("visibility", "points", "normals", "poses_quaternion") else v) for k, v in data.items()}
    model = fit_visibility(train, regressor="auto", labels=labels, relative=2, space="world", executor=_serial())
    sel = {s["cluster"]: s for s in model.report["selected"]}
    assert all(sel[k]["input_set"].startswith("near") for k in range(4)), sel
    assert sel[0]["model_used"] == "quadratic"
    a = model.arrays
    assert a["relative_neighbours"].shape == (4, 2) and model.report["relative_inputs"] == 4 * width(2)
    x = inputs_f64(a, data["poses_quaternion"][160:], data["points"][160:])
    err = sum(np.sum((predict_f64(a, x[t]) - data["visibility"][160 + t]) ** 2) for t in range(40))
    plain = fit_visibility(train, regressor="auto", labels=labels, space="world", executor=_serial())
    xp = inputs_f64(plain.arrays, data["poses_quaternion"][160:])
    err_plain = sum(np.sum((predict_f64(plain.arrays, xp[t]) - data["visibility"][160 + t]) ** 2) for t in range(40))
    # measured 0.0026; the products shifted by one activation in the packed rows give 0.77
    assert err < 0.01 * err_plain, (err, err_plain)
    with pytest.raises(ValueError, match="posed points"):
        inputs_f64(a, data["poses_quaternion"][:1])


def test_relative_needs_a_selecting_model(rng):
    data, labels = _relative_data(rng, p=30)
    for model, relative in (("linear", 2), ("auto", -1)):
        with pytest.raises(ValueError, match="relative"):
            fit_visibility(data, regressor=model, labels=labels, relative=relative, space="world", executor=_serial())


def test_stage_frame_with_relative_inputs_is_the_float64_model(device, tmp_path):
    """The recorded frame (pose, relative inputs of the frame's points, model) equals the float64
    model on the pose and points, on training frames and between them."""
    from warpshade.methods.datadriven import pose_features, pose_layout

    bend = load_scene("bundled:bend")
    rt = _bend_graph("auto", fit={"relative": 4}).compile(bend, device=device, cache_dir=tmp_path, progress=False,
                                                         scheduler="serial")
    pred = next(s for s in rt.stages if s.type_name == "visibility.predict")
    a = pred.model.arrays
    assert a["relative_neighbours"].shape[1] >= 1
    layout = pose_layout(bend, "quaternion", "include")
    for frame in (0.0, 17.0, 43.0):
        rt.step(frame, record=True)
        pose = pose_features(bend, [bend.frame_index(frame)], layout, root_reference=a["root_reference"])
        want = predict_f64(a, inputs_f64(a, pose, bend.points_at(frame)[None])[0])
        np.testing.assert_allclose(pred._vis.numpy(), want, atol=2e-4 * np.abs(want).max())
    assert np.all(np.isfinite(rt.output.numpy()))
    assert pred.diagnostics()["frames"] == len(bend.frames)
