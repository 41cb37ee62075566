"""Data-driven visibility (methods/visibility): float64 mirrors, the kernels against them, the
fits against their definitions, and the failure cases (novel poses, tiny clusters, a network
that does not beat ridge, constant inputs) bounded or reported, never NaN."""

import numpy as np
import pytest
from scipy.optimize import check_grad
from scipy.spatial.transform import Rotation

from tolerances import ATOL_FLOAT32, ATOL_FLOAT64, REPLAY_RTOL, RTOL_FLOAT32

from warpshade._wp import wp
from warpshade.geometry._frames import frame_rule, tangent_frames_f64
from warpshade.io import load_scene
from warpshade.methods.visibility import (cluster_frame_rule, cluster_frames_f64, cluster_vertices, diffuse_f64,
                                          fit_cluster, fit_visibility, _kernels as kernels, mean_shift, model_from_arrays,
                                          predict_f64, to_local)
from warpshade.methods.visibility._fit import _loss_grad, network_forward, warm_start
from warpshade.methods.visibility._mirror import inputs_f64
from warpshade.transfer import compute

#: A network warm start reproduces the linear map up to O(eps^2) of the tanh: first-layer
#: pre-activations at most 0.5 give tanh(a) - a <= a^3 / 3 ~ 0.04 of the largest output.
WARM_START_RTOL = 0.05


@pytest.fixture(scope="module")
def bend():
    return load_scene("bundled:bend")


def _rest(scene):
    from warpshade.methods.visibility._training import rest_points

    return rest_points(scene)


def test_world_visibility_turned_into_tangent_frames_is_the_local_trace(bend):
    """One world-frame trace serves every local frame: the exact SH rotation of the world
    projection equals the projection traced with the same rays in the one-ring frames."""
    frame = 30.0
    world = compute(bend, frame, 3, 64, space="world", seed=3, below_horizon="visible").visibility
    local = compute(bend, frame, 3, 64, space="local", seed=3, below_horizon="visible").visibility
    frames = tangent_frames_f64(bend.points_at(frame), bend.normals_at(frame), frame_rule(_rest(bend), bend.faces))
    np.testing.assert_allclose(to_local(world, frames), local, atol=1e-4)


def test_trace_task_traces_visibility_without_cosine(bend):
    from warpshade.methods._shared.training import trace_task

    task = {"scene": bend, "frame_indices": [3], "seeds": [11], "order": 2, "samples": 32, "space": "world",
            "bounces": 0, "quantity": "visibility"}
    got = trace_task(task)[0]
    want = compute(bend, float(bend.frames[3]), 2, 32, space="world", seed=11, below_horizon="visible")
    np.testing.assert_array_equal(got, want.visibility)
    assert not np.allclose(got, want.transfer)


def test_mean_shift_finds_separated_modes_and_merges_tiny_clusters(rng):
    centres = np.array([[0.0, 0.0], [5.0, 0.0], [0.0, 5.0]])
    pts = np.concatenate([c + rng.normal(scale=0.2, size=(40, 2)) for c in centres] + [[[10.0, 10.0]]])
    labels, modes = mean_shift(pts, 1.5)
    assert len(modes) == 4 and labels[-1] not in labels[:-1]
    for k in range(3):
        assert np.unique(labels[40 * k:40 * (k + 1)]).size == 1
    # as a mesh without skin, min_size merges the lone point into its nearest cluster
    merged = cluster_vertices(np.zeros((121, 1)), np.c_[pts, np.zeros(121)], np.zeros(121, np.int32),
                              static_bandwidth=1.5 / 14.2, min_size=5)
    assert np.unique(merged).size == 3 and np.bincount(merged).min() >= 5


def test_skinning_weight_clusters_follow_joints(bend):
    from warpshade.methods.visibility._training import dense_skin_weights, mesh_ids

    w = dense_skin_weights(bend)
    labels = cluster_vertices(w, _rest(bend), mesh_ids(bend), bandwidth=0.3)
    assert 2 <= labels.max() + 1 <= 12
    # vertices in one cluster share their dominant joint mostly
    for c in range(labels.max() + 1):
        dom = np.argmax(w[labels == c], axis=1)
        assert np.bincount(dom).max() >= 0.6 * dom.size


def test_cluster_frames_rotate_rigidly_and_are_orthonormal(rng, bend):
    rest = _rest(bend)
    labels = cluster_vertices(np.zeros((rest.shape[0], 1)), rest, np.zeros(rest.shape[0], np.int32),
                              static_bandwidth=0.3)
    rule = cluster_frame_rule(rest, labels)
    normals = bend.normals_at(0.0)
    f0 = cluster_frames_f64(rest, normals, rule)
    rot = Rotation.random(random_state=7).as_matrix()
    f1 = cluster_frames_f64(rest @ rot.T + [1.0, -2.0, 0.5], normals @ rot.T, rule)
    np.testing.assert_allclose(f1, f0 @ rot.T, atol=1e-9)
    np.testing.assert_allclose(f0 @ np.swapaxes(f0, 1, 2), np.broadcast_to(np.eye(3), f0.shape), atol=1e-12)
    assert np.all(np.linalg.det(f0) > 0)


def test_cluster_frame_kernels_match_mirror(device, bend):
    rest = _rest(bend)
    labels = cluster_vertices(np.zeros((rest.shape[0], 1)), rest, np.zeros(rest.shape[0], np.int32),
                              static_bandwidth=0.3)
    rule = cluster_frame_rule(rest, labels)
    pts, nrm = bend.points_at(40.0), bend.normals_at(40.0)
    want = cluster_frames_f64(pts, nrm, rule)
    axes = wp.zeros((rule.cluster_count, 2), dtype=wp.vec3, device=device)
    frames = wp.zeros(rest.shape[0], dtype=wp.mat33, device=device)
    p = wp.array(pts.astype(np.float32), dtype=wp.vec3, device=device)
    n = wp.array(nrm.astype(np.float32), dtype=wp.vec3, device=device)
    lab = wp.array(rule.labels, dtype=wp.int32, device=device)
    wp.launch(kernels.cluster_axes_kernel, dim=rule.cluster_count, device=device,
              inputs=[p, wp.array(rule.order, dtype=wp.int32, device=device),
                      wp.array(rule.offsets, dtype=wp.int32, device=device),
                      wp.array(rule.weights.astype(np.float32), dtype=wp.float32, device=device),
                      wp.array(rule.rest_axes.astype(np.float32), dtype=wp.vec3, device=device), axes])
    wp.launch(kernels.cluster_frames_kernel, dim=rest.shape[0], device=device, inputs=[n, lab, axes, 0, frames])
    got = frames.numpy()
    # the blend toward a2 is continuous, so float32 input noise moves frames by O(eps / BLEND)
    np.testing.assert_allclose(got, want, atol=20 * ATOL_FLOAT32)


def test_network_gradient_is_analytic_and_warm_start_is_linear(rng):
    x = rng.normal(size=(30, 4))
    y = rng.normal(size=(30, 3))
    h = 5
    theta = rng.normal(scale=0.3, size=h * 4 + h + 3 * h + 3)
    err = check_grad(lambda t: _loss_grad(t, x, y, h, 0.01)[0], lambda t: _loss_grad(t, x, y, h, 0.01)[1], theta)
    assert err < 1e-5 * max(1.0, np.linalg.norm(_loss_grad(theta, x, y, h, 0.01)[1]))
    w = rng.normal(size=(3, 4))
    b = rng.normal(size=3)
    lin = x @ w.T + b
    net = network_forward(x, *warm_start(w, b, x, 6))
    assert np.abs(net - lin).max() < WARM_START_RTOL * np.abs(lin).max()


def test_network_learns_a_nonlinear_map_that_ridge_cannot(rng):
    x = rng.uniform(-1.5, 1.5, size=(160, 2))
    basis = np.linalg.qr(rng.normal(size=(40, 2)))[0]
    y = np.tanh(2.0 * x[:, :1] * x[:, 1:2] + x[:, :1]) @ basis[:, :1].T + 0.3 * x[:, 1:2] @ basis[:, 1:].T
    task = {"x": x, "y": y, "model": "network", "variance": 0.999, "predictable": 1.0, "k_max": 8, "hidden": (8,),
            "max_iterations": 300, "seed": 0, "cluster": 0, "vertices": 10}
    r = fit_cluster(task)
    lin = fit_cluster({**task, "model": "linear"})
    assert r["report"]["model_used"] == "network", r["report"]
    assert r["report"]["cv_error"] < 0.7 * lin["report"]["cv_error"]


def test_network_that_does_not_beat_ridge_falls_back_and_says_so(rng):
    x = rng.normal(size=(60, 3))
    y = x @ rng.normal(size=(3, 12))  # exactly linear: ridge is exact, a network cannot beat it
    r = fit_cluster({"x": x, "y": y, "model": "network", "variance": 0.999, "predictable": 1.0, "k_max": 8, "hidden": (4,),
                     "max_iterations": 5, "seed": 0, "cluster": 3, "vertices": 4})
    assert r["report"]["model_used"] == "linear" and "not below" in r["report"]["fallback"]
    assert "w1" not in r and np.all(np.isfinite(r["w2"]))


def _synthetic_data(rng, p=24, joints=(0, 1)):
    """visibility.data-shaped arrays over the bend's mesh, visibility a smooth function of a 2-d pose."""
    scene = load_scene("bundled:bend")
    from warpshade.methods.visibility._training import dense_skin_weights, mesh_ids

    v = scene.vertex_count
    poses = rng.uniform(-1, 1, (p, 5))
    poses[:, 4] = 0.25  # a constant input
    base = rng.normal(size=(v, 9))
    dirs = rng.normal(size=(2, v, 9))
    vis = base + np.tanh(poses[:, 0])[:, None, None] * dirs[0] + (poses[:, 1] ** 2)[:, None, None] * dirs[1]
    pts = np.broadcast_to(_rest(scene), (p, v, 3))
    nrm = np.broadcast_to(scene.normals_at(0.0), (p, v, 3))
    return {"visibility": vis.astype(np.float32), "points": pts.astype(np.float32), "normals": nrm.astype(np.float32),
            "rest_points": _rest(scene), "faces": scene.faces.astype(np.int32),
            "skin_weights": dense_skin_weights(scene), "mesh_ids": mesh_ids(scene),
            "poses_quaternion": poses, "root_quaternion": np.zeros(5, np.int8), "topology": np.zeros(4, np.int64),
            "root_reference": np.zeros((0, 3, 3)), "settings": np.array([3, 16, 0, 0])}


@pytest.fixture(scope="module")
def synthetic_model():
    data = _synthetic_data(np.random.default_rng(5))
    return data, fit_visibility(data, regressor="network", hidden=(4,), max_iterations=40, executor=_serial())


def _serial():
    from warpshade.tasks import executor

    return executor("serial")


def test_fit_reports_and_round_trips(synthetic_model):
    data, model = synthetic_model
    rep = model.report
    assert rep["clusters"] >= 2 and sum(rep["models_used"].values()) == rep["clusters"]
    assert len(rep["fallbacks"]) == rep["models_used"]["linear"]  # every linear cluster says why
    again = model_from_arrays(model.arrays)
    assert again.model == "network" and again.frames == "cluster"
    # the model reproduces its (noise-free) training data closely in the cluster frames
    x = inputs_f64(model.arrays, data["poses_quaternion"][:1])[0]
    pred = predict_f64(model.arrays, x)
    rule = cluster_frame_rule(data["rest_points"], model.arrays["labels"])
    want = to_local(data["visibility"][0], cluster_frames_f64(data["points"][0], data["normals"][0], rule))
    assert np.linalg.norm(pred - want) < 0.1 * np.linalg.norm(want)
    damaged = dict(model.arrays)
    damaged["w2"] = damaged["w2"].copy()
    damaged["w2"][0] = np.nan
    with pytest.raises(ValueError, match="w2"):
        model_from_arrays(damaged)


def _run_predict(arrays, features, device, precision="single"):
    """The per-frame model kernels on one input vector (the stage's launches without the pose)."""
    a = arrays

    def f32(x):
        return wp.array(np.asarray(x, np.float32), dtype=wp.float32, device=device)

    def i32(x):
        return wp.array(np.asarray(x, np.int32), dtype=wp.int32, device=device)

    kin, d = a["input_weights"].shape[1], int(a["meta"][7])
    x = wp.zeros(kin, dtype=wp.float32, device=device)
    act = wp.zeros(d + a["w1"].shape[0], dtype=wp.float32, device=device)
    y = wp.zeros(max(int(a["y_offset"][-1]), 1), dtype=wp.float32, device=device)
    vis = wp.zeros(a["mean"].shape, dtype=wp.float32, device=device)
    wp.launch(kernels.inputs_kernel, dim=kin, device=device,
              inputs=[f32(features), f32(a["pose_mean"]), f32(a["input_weights"]),
                      *(i32(r) for r in kernels.input_rows(a["input_weights"])), f32(a["x_low"]), f32(a["x_high"]), x])
    wp.launch(kernels.features_kernel, dim=d, device=device, inputs=[x, i32(a["quad_i"]), i32(a["quad_j"]), act])
    if int(a["hidden_offset"][-1]):
        wp.launch(kernels.hidden_kernel, dim=int(a["hidden_offset"][-1]), device=device,
                  inputs=[x, f32(a["w1"]), f32(a["b1"]), d, act])
    wp.launch(kernels.outputs_kernel, dim=int(a["y_offset"][-1]), device=device,
              inputs=[act, f32(a["w2"]), f32(a["b2"]), i32(a["source"]), i32(a["length"]), i32(a["w_offset"]), y])
    recon, mean, basis = kernels.reconstruct_setup(a["mean"], a["basis"], device, precision)
    wp.launch(recon, dim=vis.shape[0], device=device,
              inputs=[mean, basis, i32(a["labels"]), i32(a["components"]), i32(a["y_offset"]), y, 0, vis])
    return vis.numpy()


@pytest.mark.parametrize("precision", ["single", "half"])
@pytest.mark.parametrize("model_kind", ["network", "quadratic"])
def test_model_kernels_match_mirror_and_novel_poses_stay_bounded(device, synthetic_model, model_kind, precision):
    data, model = synthetic_model
    if model_kind != "network":
        model = fit_visibility(data, regressor=model_kind, executor=_serial())
    a = model.arrays
    # the float64 mirror over the basis the kernel stores (float16-rounded for half storage)
    stored = dict(a, basis=np.asarray(a["basis"], np.float16).astype(np.float64)) if precision == "half" else a
    scale = np.abs(a["mean"]).max()
    for pose in (data["poses_quaternion"][3], np.array([0.3, -0.2, 0.1, 0.0, 0.25]),
                 np.array([40.0, -40.0, 40.0, 40.0, 0.25]), np.array([0.3, -0.2, 0.1, 0.0, 9.0])):
        got = _run_predict(a, pose, device, precision)
        want = predict_f64(stored, inputs_f64(a, pose[None])[0])
        assert np.all(np.isfinite(got))
        np.testing.assert_allclose(got, want, atol=50 * ATOL_FLOAT32 * scale)
    # a pose far outside the training range is clamped: its prediction is that of the range's edge
    far = _run_predict(a, np.array([400.0, -400.0, 400.0, 400.0, 0.25]), device)
    edge = _run_predict(a, np.array([40.0, -40.0, 40.0, 40.0, 0.25]), device)
    np.testing.assert_allclose(far, edge, atol=ATOL_FLOAT32 * scale)


def test_constant_inputs_are_a_clear_error(rng):
    data = _synthetic_data(rng, p=10)
    data["poses_quaternion"] = np.ones_like(data["poses_quaternion"])
    with pytest.raises(ValueError, match="no pose feature varies"):
        fit_visibility(data, regressor="linear", executor=_serial())


def test_tiny_clusters_fit_without_nan(rng):
    data = _synthetic_data(rng, p=12)
    labels = np.arange(data["mesh_ids"].size) % 3  # three clusters, and tiny ones:
    labels[:3] = 3  # 3 vertices
    labels[3] = 4  # 1 vertex
    labels[10:19] = 5  # 9 vertices whose visibility does not vary (k = 0)
    data["visibility"][:, labels == 5] = 0.0  # constant over the poses: no component
    data["visibility"][:, labels == 5, 0] = 0.5  # (rotation invariant: the same in every frame)
    model = fit_visibility(data, regressor="network", hidden=(2,), max_iterations=5, labels=labels, executor=_serial())
    assert 0 in model.report["components"]
    out = predict_f64(model.arrays, inputs_f64(model.arrays, data["poses_quaternion"][:1])[0])
    assert np.all(np.isfinite(out))
    want = np.zeros_like(out[labels == 5])
    want[:, 0] = 0.5
    np.testing.assert_allclose(out[labels == 5], want, atol=1e3 * ATOL_FLOAT64)


def test_diffuse_kernel_matches_mirror(device, rng):
    order, v = 4, 50
    vis = rng.normal(size=(v, order * order)) * 0.3
    vis[:, 0] += 3.0
    frames = Rotation.random(v, random_state=3).as_matrix()
    light = rng.normal(size=(3, order * order))
    light[:, 0] += 4.0
    albedo = rng.uniform(0.2, 0.9, (v, 3))
    from warpshade.basis import sh
    from warpshade.basis.sh_warp import sh_kernels

    out = wp.zeros((v, 3), dtype=wp.float32, device=device)
    wp.launch(kernels.diffuse_kernel(order), dim=v, device=device,
              inputs=[wp.array(vis.astype(np.float32), dtype=wp.float32, device=device),
                      wp.array(frames.astype(np.float32), dtype=wp.mat33, device=device),
                      wp.array(albedo.astype(np.float32), dtype=wp.float32, device=device),
                      wp.array(light.astype(np.float32), dtype=wp.float32, device=device),
                      wp.array(sh.clamped_cosine_sh(order).astype(np.float32), dtype=wp.float32, device=device),
                      sh_kernels(order).tables(device), 0, out])
    want = diffuse_f64(vis, frames, light, albedo)
    np.testing.assert_allclose(out.numpy(), want, rtol=50 * RTOL_FLOAT32, atol=50 * ATOL_FLOAT32)


def test_components_no_input_explains_are_cut_after_the_fit(rng):
    x = rng.normal(size=(200, 3))
    basis = np.linalg.qr(rng.normal(size=(30, 6)))[0]
    signal = x @ rng.normal(size=(3, 2))
    noise = rng.normal(scale=[1.5, 1.2, 1.0, 0.9], size=(200, 4))  # more variance than the signal, unexplained
    y = np.c_[signal, noise] @ basis.T
    task = {"x": x, "y": y, "model": "linear", "variance": 0.999, "predictable": 0.95, "k_max": 8, "hidden": (4,),
            "max_iterations": 5, "seed": 0, "cluster": 0, "vertices": 3}
    r = fit_cluster(task)
    assert r["report"]["components_fitted"] == 6 and r["report"]["components"] <= 3
    # what is kept still predicts the explained part (the cut loses < 5 % of the predicted variance)
    full = fit_cluster({**task, "predictable": 1.0})
    pred = r["mean"] + (x @ r["w2"].T + r["b2"]) @ r["basis"].T
    pred_full = full["mean"] + (x @ full["w2"].T + full["b2"]) @ full["basis"].T
    assert np.linalg.norm(pred - pred_full) < 0.25 * np.linalg.norm(pred_full - pred_full.mean(0))


def _bend_graph(regressor="linear", fit=None):
    from warpshade.graph import GraphSpec, StageSpec
    from warpshade.methods.visibility._rows import stages_for

    stages = list(stages_for("", "0:60:4", regressor, order=3, samples=32, fit={"hidden": (4,), "max_iterations": 20,
                                                                           **(fit or {})}))
    stages[-1] = ("shade", "rpo.shade", {"order": 3, "rank": 4, "brdf": "ggx", "roughness": 0.5}, {})
    return GraphSpec([StageSpec(n, t, dict(p), dict(i)) for (n, t, p, i) in stages], "shade.radiance", name="vis")


def test_stage_frame_is_the_float64_model_and_beats_the_rest_pose(device, bend, tmp_path):
    """The recorded frame's visibility and frames equal the float64 model at the frame's pose
    and the cluster frames of its points; held-out odd frames are closer to the traced
    visibility than the rest-pose bake is."""
    from warpshade.methods.datadriven import pose_features, pose_layout

    rt = _bend_graph().compile(bend, device=device, cache_dir=tmp_path, progress=False, scheduler="serial")
    pred = next(s for s in rt.stages if s.type_name == "visibility.predict")
    a = pred.model.arrays
    rule = cluster_frame_rule(a["rest_points"], a["labels"])
    layout = pose_layout(bend, "quaternion", "include")
    static = None
    for frame in (0.0, 17.0, 43.0):
        rt.step(frame, record=True)
        got = pred._vis.numpy()
        pose = pose_features(bend, [bend.frame_index(frame)], layout, root_reference=a["root_reference"])
        want = predict_f64(a, inputs_f64(a, pose)[0])
        np.testing.assert_allclose(got, want, atol=1e-4 * np.abs(want).max())
        frames = cluster_frames_f64(bend.points_at(frame), bend.normals_at(frame), rule)
        np.testing.assert_allclose(pred._frames.numpy(), frames, atol=1e-3)
        truth = to_local(compute(bend, frame, 3, 512, space="world", seed=9, below_horizon="visible").visibility, frames)
        if static is None:
            static = truth  # the rest pose (frame 0) in its own frames
            continue
        err = np.linalg.norm(got - truth) / np.linalg.norm(truth)
        err_static = np.linalg.norm(static - truth) / np.linalg.norm(truth)
        assert err < err_static, (frame, err, err_static)
    assert np.all(np.isfinite(rt.output.numpy()))
    # the recorded frame replays what launching the stages one by one gives
    rt.step(17.0, record=False)
    plain = pred._vis.numpy().copy()
    rt.step(17.0, record=True)
    np.testing.assert_allclose(pred._vis.numpy(), plain, rtol=REPLAY_RTOL, atol=REPLAY_RTOL * np.abs(plain).max())
    diag = pred.diagnostics()
    assert diag["frames"] == len(bend.frames) and diag["novelty_max"] >= 0.0


def test_world_frame_model_is_refused_by_the_frame_stage(device, bend, tmp_path):
    from warpshade.graph import StageError

    with pytest.raises(StageError, match="world frame"):
        _bend_graph(fit={"space": "world"}).compile(bend, device=device, cache_dir=tmp_path, progress=False,
                                                    scheduler="serial")


def test_bad_training_selection_names_the_stage(device, bend, tmp_path):
    from warpshade.graph import GraphSpec, StageError, StageSpec

    stages = [StageSpec(s.name, s.type, dict(s.params), dict(s.inputs)) for s in _bend_graph().stages]
    stages[0].params["frames"] = "0:3"
    with pytest.raises(StageError, match="stage .data.*at least 8"):
        GraphSpec(stages, "shade.radiance", name="vis").compile(bend, device=device, cache_dir=tmp_path, progress=False,
                                                                scheduler="serial")


def test_transfer_target_is_for_local_frames_only():
    """The Fig. 8 comparison fits the cosine-weighted transfer in a local frame: the world frame
    has no fixed normal to weight by, so it is refused, and an unknown target is named."""
    from warpshade.methods.visibility import fit_visibility

    with pytest.raises(ValueError, match="target must be 'visibility' or 'transfer'.*'world'"):
        fit_visibility({}, space="world", target="transfer")
    with pytest.raises(ValueError, match="target must be .* got 'cosine'"):
        fit_visibility({}, target="cosine")
