"""Stacked regression of data-driven visibility (``regressor = "stack"``, methods/visibility/stack.py):
the combination weights against independent references (scipy's NNLS, a brute-force solve of the
simplex-constrained least squares over every support), the weighted sum of candidate maps as one
map on the union of their features, the packed model's kernels against the float64 mirror, and
degenerate inputs."""

import itertools

import numpy as np
import pytest
from scipy.optimize import nnls

from tolerances import ATOL_FLOAT32

from warpshade.methods.visibility import fit_visibility, predict_f64
from warpshade.methods.visibility._mirror import inputs_f64
from warpshade.methods.visibility._select import blocked_folds, candidates, fit_selected, penalty_scale, prefix_features
from warpshade.methods.visibility._stack import fit_stack, stack_weights, union_features, union_map

from test_visibility import _run_predict, _serial
from test_visibility_select import _frames_subset, _local_data, bend  # noqa: F401 (the module's scene fixture)

#: Weights of two solvers of the same small convex problem (float64, well conditioned).
WEIGHT_ATOL = 1e-6


def _brute_simplex(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """min ||a w - b||^2 over w >= 0, sum w = 1, by trying every support: the KKT solve of the
    equality-constrained problem on the support, kept when feasible; the least objective wins."""
    j = a.shape[1]
    best, best_f = None, np.inf
    for r in range(1, j + 1):
        for sup in itertools.combinations(range(j), r):
            s = list(sup)
            g = a[:, s].T @ a[:, s]
            kkt = np.block([[2 * g, np.ones((r, 1))], [np.ones((1, r)), np.zeros((1, 1))]])
            rhs = np.r_[2 * a[:, s].T @ b, 1.0]
            sol = np.linalg.lstsq(kkt, rhs, rcond=None)[0][:-1]
            if np.any(sol < -1e-12):
                continue
            w = np.zeros(j)
            w[s] = sol
            f = float(np.sum((a @ w - b) ** 2))
            if f < best_f - 1e-15:
                best, best_f = w, f
    return best


def test_weights_match_nnls_and_a_brute_force_simplex_solve(rng):
    n, j = 60, 5
    for trial in range(6):
        truth = rng.normal(size=n)
        # candidates: the truth with independent errors of different sizes, two of them near-collinear
        preds = truth + rng.normal(size=(j, n)) * np.array([0.3, 0.5, 0.8, 1.5, 0.31])[:, None]
        preds[4] = preds[0] + 0.01 * rng.normal(size=n)
        y = truth + 0.1 * rng.normal(size=n)
        w_free = stack_weights(preds, y, "free")
        w_ref, _ = nnls(preds.T, y)
        np.testing.assert_allclose(w_free, w_ref, atol=WEIGHT_ATOL)
        w_one = stack_weights(preds, y, "one")
        w_bf = _brute_simplex(preds.T, y)
        assert np.all(w_one >= 0.0) and abs(w_one.sum() - 1.0) < 1e-12
        np.testing.assert_allclose(w_one, w_bf, atol=WEIGHT_ATOL)
    # a known answer: y is exactly 0.25 p0 + 0.75 p1, the rest unrelated noise
    p = rng.normal(size=(4, 40))
    y = 0.25 * p[0] + 0.75 * p[1]
    np.testing.assert_allclose(stack_weights(p, y, "one"), [0.25, 0.75, 0.0, 0.0], atol=WEIGHT_ATOL)
    np.testing.assert_allclose(stack_weights(p, y, "free"), [0.25, 0.75, 0.0, 0.0], atol=WEIGHT_ATOL)
    np.testing.assert_allclose(stack_weights(p, y, "equal"), np.full(4, 0.25))
    with pytest.raises(ValueError, match="total"):
        stack_weights(p, y, "sum")


def test_weights_of_degenerate_problems_are_bounded_and_finite(rng):
    y = rng.normal(size=30)
    for preds in (np.zeros((3, 30)),  # candidates that predict nothing
                  np.broadcast_to(rng.normal(size=30), (4, 30)).copy(),  # identical candidates
                  rng.normal(size=(1, 30))):  # one candidate
        for total in ("one", "free"):
            w = stack_weights(preds, y, total)
            assert np.all(np.isfinite(w)) and np.all(w >= 0.0)
            assert (abs(w.sum() - 1.0) < 1e-12) if total == "one" else True
    assert np.all(np.isfinite(stack_weights(rng.normal(size=(3, 30)), np.zeros(30), "free")))
    np.testing.assert_allclose(stack_weights(rng.normal(size=(3, 30)), np.zeros(30), "free"), 0.0, atol=1e-12)


def test_out_of_fold_predictions_are_the_folds_own_maps(rng):
    p = 64
    x = rng.normal(size=(p, 6))
    y = x[:, :2] @ rng.normal(size=(2, 3)) + 0.1 * rng.normal(size=(p, 3))
    splits = blocked_folds(p)
    cands = candidates({"global": (x, ("linear", "quadratic"))}, y, splits, oof=True)
    for c in cands[::3]:
        f = prefix_features(x, c["kind"], c["inputs"])
        for tr, va in splits:  # every fold's penalty in the unit of every training frame's features
            w, b = fit_selected(f[tr], y[tr], "linear", f.shape[1], c["penalty"], scale=penalty_scale(f))
            np.testing.assert_allclose(c["oof"][va], f[va] @ w.T + b, atol=1e-9)
        assert abs(float(((c["oof"] - y) ** 2).sum()) - c["sse"]) < 1e-9 * max(c["sse"], 1.0)


def test_stacked_map_on_the_union_is_the_weighted_sum_of_the_candidates(rng):
    p = 80
    x = rng.normal(size=(p, 8))
    local = rng.normal(size=(p, 3))
    y = np.c_[x[:, 0] * x[:, 1] + local[:, 0], x[:, 2] - local[:, 1], x[:, 0] ** 2] + 0.05 * rng.normal(size=(p, 3))
    sets = {"global": (x, ("linear", "quadratic")), "ring0": (local, ("linear",))}
    st = fit_stack(sets, y, top=40)
    picks = st["picks"]
    assert abs(sum(pk["weight"] for pk in picks) - 1.0) < 1e-9
    want = np.zeros_like(y)
    for pk in picks:
        xs = sets[pk["set"]][0]
        w, b = fit_selected(xs, y, pk["kind"], pk["inputs"], pk["penalty"])
        want += pk["weight"] * (prefix_features(xs, pk["kind"], pk["inputs"]) @ w.T + b)
    got = union_features(sets, st["layout"]) @ st["w"].T + st["b"]
    np.testing.assert_allclose(got, want, atol=1e-9)
    # the combination's out-of-fold error is no worse than the best single candidate's
    assert st["sse"] <= st["best_sse"] * (1 + 1e-9)
    # one candidate of weight 1 is that candidate's map
    one = [dict(picks[0], weight=1.0)]
    xs = sets[one[0]["set"]][0]
    w1, b1 = fit_selected(xs, y, one[0]["kind"], one[0]["inputs"], one[0]["penalty"])
    from warpshade.methods.visibility._stack import _layout

    lay = _layout(one, {"global": 8})
    wu, bu = union_map(one, [(w1, b1)], np.ones(1), lay)
    np.testing.assert_allclose(union_features(sets, lay) @ wu.T + bu,
                               prefix_features(xs, one[0]["kind"], one[0]["inputs"]) @ w1.T + b1, atol=1e-10)


def test_stack_model_kernels_match_the_mirror_and_novel_poses_stay_bounded(device, bend, rng):  # noqa: F811
    full = _local_data(bend, rng, p=110)
    data, test = _frames_subset(full, slice(0, 90)), _frames_subset(full, slice(90, 110))
    model = fit_visibility(data, regressor="stack", executor=_serial(), stack_top=12)
    rep = model.report
    assert model.model == "stack" and rep["models_used"]["stack"] + rep["models_used"]["constant"] == rep["clusters"]
    stacked = [s for s in rep["selected"] if "stack" in s]
    assert stacked and all(abs(sum(c["weight"] for c in s["stack"]) - 1.0) < 1e-6 for s in stacked)
    assert any(len(s["stack"]) > 1 for s in stacked)  # some cluster combines candidates
    assert any(c["set"] != "global" for s in stacked for c in s["stack"])  # local blocks in the layout
    a = model.arrays
    scale = np.abs(a["mean"]).max()
    for pose in (data["poses_quaternion"][3], test["poses_quaternion"][0],
                 np.full(data["poses_quaternion"].shape[1], 30.0)):  # far outside: clamped, bounded
        got = _run_predict(a, pose, device)
        want = predict_f64(a, inputs_f64(a, pose[None])[0])
        assert np.all(np.isfinite(got))
        np.testing.assert_allclose(got, want, atol=50 * ATOL_FLOAT32 * scale)
    assert np.abs(_run_predict(a, np.full(data["poses_quaternion"].shape[1], 30.0), device)).max() < 100 * scale
    # the float64 mirror on training poses is the in-sample fit of the stacked maps: it explains
    # most of the visibility's variation
    from warpshade.methods.visibility import cluster_frame_rule, cluster_frames_f64, to_local

    rule = cluster_frame_rule(data["rest_points"], a["labels"])
    fr = cluster_frames_f64(data["points"][0], data["normals"][0], rule)
    x = inputs_f64(a, data["poses_quaternion"][:10])
    truth = np.stack([to_local(data["visibility"][t], fr) for t in range(10)])
    pred = np.stack([predict_f64(a, x[t]) for t in range(10)])
    assert np.sum((pred - truth) ** 2) < 0.5 * np.sum((truth - truth.mean(0)) ** 2)


def test_stack_with_constant_inputs_and_one_candidate_is_finite(rng):
    """Targets no input explains (constant inputs but one) and a single candidate: finite maps."""
    p = 40
    x = np.zeros((p, 3))
    x[:, 0] = rng.normal(size=p)
    y = rng.normal(size=(p, 2))
    for top in (1, 40):
        for total in ("one", "free"):
            st = fit_stack({"global": (x, ("linear",))}, y, top=top, total=total)
            assert np.all(np.isfinite(st["w"])) and np.all(np.isfinite(st["b"]))
            assert np.all(np.isfinite(union_features({"global": (x, ("linear",))}, st["layout"]) @ st["w"].T))
    with pytest.raises(ValueError, match="stack"):
        fit_stack({"global": (np.zeros((p, 0)), ("linear",))}, y)


def test_stack_parameters(bend, rng):  # noqa: F811
    from warpshade.graph import get_stage_type

    data = _local_data(bend, rng, p=40)
    with pytest.raises(ValueError, match="stack_total"):
        fit_visibility(data, regressor="stack", executor=_serial(), stack_total="most")
    fit_stage = get_stage_type("visibility.fit")
    assert fit_stage("fit", {}).cache_params()["stack_top"] == 0  # part of the artifact's key
    assert fit_stage("fit", {"stack_total": "free"}).cache_params()["stack_total"] == "free"
