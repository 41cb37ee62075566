"""The data-driven visibility model (Nowrouzezahrai, Kalogerakis, Fiume 2009, sec. 5): the artifact.

Made by :func:`fit_visibility` from the training data of ``visibility.data``:

1. **Inputs**: the pose vectors (joint rotations, :mod:`warpshade.methods._shared.pose`) or the
   dihedral angles of a point-cached mesh, standardised and reduced by PCA to the fewest
   components holding ``input_variance`` of their variance (the budget), each divided by its
   standard deviation: ``x = (a - mean) W`` (a x k_in). At run time ``x`` is clamped to the training
   range widened by ``margin`` of its width on each side, so that a pose far outside the training
   range gives a bounded prediction (the novelty is reported, :func:`novelty_report`).
2. **Clusters** (:mod:`._clusters`) and the **local frames** the visibility is modelled in:
   ``"cluster"`` (each cluster's principal directions in the vertex tangent planes), ``"one_ring"``
   (:mod:`warpshade.geometry._frames`) or ``"world"`` (no frame: the paper's Fig. 9 comparison;
   the frame stages take local frames only).
3. **Per cluster** (:mod:`._fit`, executor tasks): PCA of its local visibility to the budget
   ``variance`` and a linear, quadratic or network model from ``x`` to the PCA weights, or
   (``"auto"``) the ridge model cross-validation on the training clip picks for the cluster,
   possibly from inputs of its own: the PCA of the rotations of the joints near it, appended to
   ``x`` (:func:`_auto_layout`); or (``"stack"``, :mod:`._stack`) a weighted sum of those candidates,
   one map per cluster on the union of their inputs.

Arrays (``arrays()`` / :func:`model_from_arrays`): the input statistics; per vertex its cluster,
its mean visibility (V, C) and basis (V, C, k_max) (zero past its cluster's ``k``); per cluster its
output offset and the rest-pose frame rule; the models' layers packed flat:

* ``act`` (the frame's activations) = ``[phi (D), hidden units (sum H)]`` with ``phi = x`` or its
  quadratic expansion;
* hidden unit ``u``: ``tanh(b1[u] + w1[u] . x)``;
* output ``o``: ``b2[o] + w2[w_offset[o] : + length[o]] . act[source[o] : + length[o]]``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .._shared.pose_space import PoseSpace, pose_space
from ._clusters import cluster_frame_rule, cluster_frames_f64, cluster_vertices
from ._fit import expand_features, fit_cluster
from ._relative import cluster_neighbours, relative_features_f64
from ._select import FOLD_TRAIN_MIN, fewest_frames, prefix_pairs
from ._training import to_local

__all__ = ["FRAME_KINDS", "cosine_product_matrix", "input_space", "local_frames_f64"]

MODELS = ("linear", "quadratic", "network", "auto", "stack")
#: Errors the per-cluster fits minimise (:func:`fit_visibility`'s ``metric``).
METRICS = ("visibility", "diffuse")
FRAME_KINDS = ("cluster", "one_ring", "world")


@dataclass
class VisibilityModel:
    """The fitted model as flat arrays (module docstring); ``report`` is not stored."""

    arrays: dict
    report: dict = field(default_factory=dict)

    @property
    def order(self) -> int:
        return int(self.arrays["meta"][0])

    @property
    def model(self) -> str:
        return MODELS[int(self.arrays["meta"][1])]

    @property
    def frames(self) -> str:
        return FRAME_KINDS[int(self.arrays["meta"][2])]

    def stored_floats(self) -> int:
        skip = ("meta", "training_poses", "labels", "rest_points", "faces", "topology")
        return int(sum(np.asarray(v).size for k, v in self.arrays.items() if k not in skip))


def input_space(poses: np.ndarray, variance: float, k_max: int) -> tuple[PoseSpace, np.ndarray]:
    """Input PCA to the budget: ``(space, W)`` with ``x = (a - space.mean) @ W`` of unit variance."""
    full = pose_space(poses, pca=True)
    v = np.asarray(full.variance, np.float64)
    cum = np.cumsum(v) / max(float(v.sum()), 1e-300)
    k = int(min(np.searchsorted(cum, variance - 1e-12) + 1, k_max, v.size))
    k = max(k, 1)
    space = full.truncated(k)
    w = space.weights / np.sqrt(np.maximum(space.variance, 1e-300))
    return space, w


def local_frames_f64(kind: str, points, normals, rest, faces, labels):
    """Frames of every training pose, (p, V, 3, 3) (identity for ``"world"``)."""
    p = np.asarray(points).shape[0]
    v = np.asarray(points).shape[1]
    if kind == "world":
        return np.broadcast_to(np.eye(3), (p, v, 3, 3))
    if kind == "one_ring":
        from ...geometry._frames import frame_rule, tangent_frames_f64

        rule = frame_rule(rest, faces)
        return np.stack([tangent_frames_f64(points[t], normals[t], rule) for t in range(p)])
    rule = cluster_frame_rule(rest, labels)
    return np.stack([cluster_frames_f64(points[t], normals[t], rule) for t in range(p)])


def _quadratic_pairs(k: int) -> tuple[np.ndarray, np.ndarray]:
    return np.triu_indices(k)


def cosine_product_matrix(order: int) -> np.ndarray:
    """The SH product matrix of the clamped cosine about the local normal (+z), (n*n, n*n)
    float64: local visibility to local transfer (eq. 14)."""
    from ...basis import sh

    return sh.product_matrix(sh.clamped_cosine_sh(order))


def fit_visibility(data: dict, *, regressor: str = "network", space: str = "cluster", pose: str = "quaternion",
                   root: str = "include", input_variance: float = 0.99, input_max: int = 24, variance: float = 0.95,
                   predictable: float = 0.99, k_max: int = 32, bandwidth: float = 0.3, min_cluster: int = 8, hidden=(8, 16),
                   max_iterations: int = 300, margin: float = 0.25, seed: int = 0, labels=None, executor=None,
                   progress: bool = False, target: str = "visibility", metric: str = "visibility", stack_top: int = 0,
                   stack_total: str = "one", relative: int = 0) -> VisibilityModel:
    """Fit the model to a ``visibility.data`` artifact (module docstring). ValueError on bad input.

    ``target = "transfer"`` fits the cosine-weighted transfer instead (each local visibility vector
    times the clamped cosine about the normal, the SH product of eq. 14): the paper's Fig. 8
    comparison, measured by ``benchmarks/bench_visibility.py``; the stages fit visibility.

    ``metric``: the error the per-cluster PCA, the model selection and the fits minimise:
    ``"visibility"`` (the squared error of the local visibility) or ``"diffuse"`` (of the
    cosine-weighted transfer ``M_cos v`` of eq. 14, the only part of ``v`` diffuse shading sees:
    the PCA of the transfer, the selection's errors in it; the basis is stored in visibility space,
    mapped back by the pseudo-inverse of ``M_cos``, so that the model's arrays and stages are those
    of the visibility metric). Local frames only.

    ``stack_top``, ``stack_total`` (``regressor = "stack"``, :mod:`._stack`): the candidates (least
    blocked-CV error first; 0: all) the per-cluster combination may use, and the constraint on its weights.

    ``relative`` (``"auto"``, ``"stack"``): the most neighbouring clusters whose centroids, in each
    cluster's rigid frame, are candidate inputs of the cluster (:mod:`._relative`; 0: none). They
    are appended to the input vector, after the pose vector (``pose_mean`` and the rows of
    ``input_weights`` cover both; ``relative_neighbours`` stores the neighbours).
    """
    from ...tasks import executor as new_executor

    t0 = time.perf_counter()
    from ._stack import TOTALS

    if regressor == "stack" and (int(stack_top) < 0 or stack_total not in TOTALS):
        raise ValueError(f"stack_top must be 0 (every candidate) or more and stack_total one of {TOTALS}, got "
                         f"{stack_top!r} and {stack_total!r}")
    if regressor not in MODELS or space not in FRAME_KINDS:
        raise ValueError(f"regressor must be one of {MODELS} and space one of {FRAME_KINDS}")
    if metric not in METRICS or (metric == "diffuse" and (space == "world" or target == "transfer")):
        raise ValueError(f"metric must be one of {METRICS} ('diffuse': a visibility target in a local frame), got "
                         f"{metric!r} with target {target!r} and space {space!r}")
    if int(relative) < 0 or (int(relative) > 0 and regressor not in ("auto", "stack")):
        raise ValueError(f"relative must be 0 or a neighbour count for regressor 'auto' or 'stack', got {relative!r} "
                         f"with regressor {regressor!r}")
    if target not in ("visibility", "transfer") or (target == "transfer" and space == "world"):
        raise ValueError(f"target must be 'visibility' or 'transfer' (the latter in a local frame), got {target!r} "
                         f"with space {space!r}")
    settings = np.asarray(data["settings"]).reshape(-1)
    order = int(settings[0])
    source = int(settings[3])
    vis = np.asarray(data["visibility"], np.float32)
    pcount, vcount, c = vis.shape
    fewest = fewest_frames()
    if pcount < fewest:
        raise ValueError(f"the training data holds {pcount} frame(s); the fit needs at least {fewest} (its "
                         f"cross-validation trains every fold on at least {FOLD_TRAIN_MIN} frames): select more "
                         "training frames (visibility.data parameter 'frames')")
    if source == 0:
        from .._shared.training import pose_columns

        a = pose_columns(data, pose, root)
    else:
        a = np.asarray(data["dihedral"], np.float64)
    inputs, w_in = input_space(a, input_variance, input_max)
    x = (a - inputs.mean) @ w_in
    span = x.max(0) - x.min(0)
    lo, hi = x.min(0) - margin * span, x.max(0) + margin * span
    if labels is None:
        labels = cluster_vertices(data["skin_weights"], data["rest_points"], data["mesh_ids"], bandwidth=bandwidth,
                                  min_size=min_cluster)
    labels = np.asarray(labels, np.int32)
    kc = int(labels.max()) + 1
    neighbours = cluster_neighbours(data["rest_points"], labels, int(relative))
    if int(relative) > 0 and kc > 1:  # relative inputs appended to the pose vectors (a_full), none in the global PCA
        g = relative_features_f64(data["points"], data["rest_points"], labels, neighbours)
        a_full = np.concatenate([a, g], axis=1)
        w_in = np.concatenate([w_in, np.zeros((g.shape[1], w_in.shape[1]))], axis=0)
        mean_full = np.concatenate([inputs.mean, g.mean(0)])
    else:
        neighbours = neighbours[:, :0]
        a_full, mean_full = a, inputs.mean
    fr = local_frames_f64(space, data["points"], data["normals"], data["rest_points"], data["faces"], labels)
    local = np.empty(vis.shape, np.float32)
    for t in range(pcount):
        local[t] = vis[t] if space == "world" else to_local(vis[t], fr[t])
    if target == "transfer":
        local = local @ cosine_product_matrix(order).T.astype(np.float32)
    weight = {}
    if metric == "diffuse":
        from ._fit import metric_inverse

        cos = cosine_product_matrix(order)
        weight = {"metric": cos, "metric_inverse": metric_inverse(cos)}
    tasks = []
    local_w = [{} for _ in range(kc)]
    for cl in range(kc):
        rows = np.flatnonzero(labels == cl)
        tasks.append({"x": x, "y": local[:, rows, :].reshape(pcount, -1), "model": regressor, "variance": variance,
                      "predictable": predictable, "k_max": k_max, "hidden": tuple(int(h) for h in hidden), "max_iterations": max_iterations,
                      "seed": seed, "cluster": cl, "vertices": int(rows.size), "stack_top": int(stack_top),
                      "stack_total": stack_total, **weight})
        if regressor in ("auto", "stack"):
            tasks[-1]["input_sets"] = _input_sets(data, source, pose, root, a_full, x, labels, cl, input_variance, input_max,
                                                  local_w[cl], neighbours, a.shape[1],
                                                  ("linear", "quadratic") if regressor == "auto" else ("linear",))
    tasks_order = sorted(range(kc), key=lambda i: -tasks[i]["vertices"])
    own = executor is None
    ex = new_executor() if own else executor
    try:
        done = ex.map(fit_cluster, [tasks[i] for i in tasks_order], desc=f"fitting {kc} clusters ({regressor})",
                      progress=progress)
    finally:
        if own:
            ex.close()
    results = [None] * kc
    for i, r in zip(tasks_order, done):
        results[i] = r
    layout = None
    if regressor in ("auto", "stack"):
        w_in, layout = _auto_layout(results, local_w, w_in)
        xa = (a_full - mean_full) @ w_in
        span = xa.max(0) - xa.min(0)
        lo, hi = xa.min(0) - margin * span, xa.max(0) + margin * span
    arrays = _pack(results, labels, order, regressor, space, source, inputs, w_in, lo, hi, data, a, pose, root, layout)
    arrays["pose_mean"] = np.asarray(mean_full, np.float64)
    arrays["relative_neighbours"] = np.asarray(neighbours, np.int32)
    reports = [r["report"] for r in results]
    fallbacks = [r for r in reports if "fallback" in r]
    report = {"clusters": kc, "cluster_sizes": [int(r["vertices"]) for r in reports],
              "components": [int(r["components"]) for r in reports], "input_components": int(w_in.shape[1]),
              "input_features": int(a.shape[1]), "relative_inputs": int(a_full.shape[1] - a.shape[1]), "model": regressor, "frames": space, "metric": metric,
              "models_used": {m: sum(r["model_used"] == m for r in reports)
                              for m in ("constant", "linear", "quadratic", "network", "stack")},
              "fallbacks": [{"cluster": r["cluster"], "reason": r["fallback"]} for r in fallbacks],
              **({"selected": [{k: r[k] for k in ("cluster", "vertices", "model_used", "input_set", "inputs", "ridge", "cv_error",
                                                  "cv_error_best", "stack") if k in r} for r in reports]}
                 if regressor in ("auto", "stack") else {}),
              "cv_error": float(np.sqrt(sum(r["cv_error"] ** 2 * r["vertices"] for r in reports) / vcount)),
              "cluster_fit_s": [round(r["fit_s"], 3) for r in reports], "total_fit_s": time.perf_counter() - t0,
              "retained_variance_min": float(min(r["retained_variance"] for r in reports))}
    out = VisibilityModel(arrays, report)
    report["stored_floats"] = out.stored_floats()
    return out


def _input_sets(data, source, pose, root, a, x, labels, cluster, variance, k_max, weights_out, neighbours=None,
                pose_width=None, relative_kinds=("linear", "quadratic")) -> dict:
    """Candidate inputs of one cluster for :mod:`._select`: the global input PCA (linear and
    quadratic); with ``neighbours`` (K, N), N > 0, the centroids of its nearest clusters in its frame
    (:mod:`._relative`, columns from ``pose_width`` on, ``near<n>`` for n in :data:`._relative.COUNTS`
    up to N, and N; ``relative_kinds``); and, for a skinned cluster with joint inputs, its local joints' inputs
    per skeleton ring (:mod:`._locality`, linear). The local inputs' weights go to ``weights_out``."""
    from ._locality import RINGS, cluster_joints, joint_columns, local_inputs
    from ._relative import COUNTS, candidate_columns

    sets = {"global": (x, ("linear", "quadratic"))}
    n = 0 if neighbours is None else int(np.asarray(neighbours).shape[1])
    for count in sorted({q for q in COUNTS if q < n} | ({n} if n else set())):
        w, xl = local_inputs(a, candidate_columns(cluster, count, n, int(pose_width)), variance, k_max)
        if w.shape[1]:
            sets[f"near{count}"] = (xl, relative_kinds)
            weights_out[f"near{count}"] = w
    if source != 0:
        return sets
    try:
        columns = joint_columns(data[f"root_{pose}"], pose, root)
    except ValueError:
        return sets  # the pose vectors are not joint rotations: global inputs only
    if len(columns) != np.asarray(data["skin_weights"]).shape[1] or max(int(c.max(initial=-1)) for c in columns) >= a.shape[1]:
        return sets  # the pose vectors do not follow the joints of the skinning weights: global inputs only
    seen = set()
    for ring in RINGS:
        joints = cluster_joints(data["skin_weights"], labels, cluster, ring)
        if joints is None:
            break
        if tuple(joints) in seen or len(joints) == len(columns):
            continue
        seen.add(tuple(joints))
        w, xl = local_inputs(a, np.concatenate([columns[j] for j in joints]), variance, k_max)
        if w.shape[1]:
            sets[f"ring{ring}"] = (xl, ("linear",))
            weights_out[f"ring{ring}"] = w
    return sets


def _auto_layout(results, local_w, w_in):
    """Input weights and activation layout of a model of per-cluster selections (``"auto"``).

    The inputs ``x`` are the global input PCA, then every chosen local block, the linear ones first
    and the quadratic ones (a relative set's, :mod:`._relative`) last; the products are those of the
    first global inputs (:func:`._select.prefix_pairs`, as many as the largest global quadratic
    cluster uses), then each quadratic local block's own (``qoff[c]``: where cluster ``c``'s start,
    counted from the first product). Returns ``(W, {"qi", "qj", "qoff", "source", "picks"})``;
    ``source[c]`` is the first activation cluster ``c`` reads (a global quadratic cluster reads from
    0, its linear weights padded to every input; a local quadratic one from its block, its row
    padded with zeros up to its products)."""
    picks = [r.get("select", ("global", "linear", 0)) if r["basis"].shape[1] else ("global", "linear", 0)
             for r in results]
    blocks, pos = [w_in], w_in.shape[1]
    source = [0] * len(picks)
    stacked = [None] * len(picks)  # a stacked cluster: {set: first input of its local block}
    quad = [m for name, kind, m in picks if name == "global" and kind == "quadratic"]
    for cl, r in enumerate(results):
        if "stack" not in r or not r["basis"].shape[1]:
            continue
        picks[cl] = ("stack", "union", 0)
        stacked[cl] = {}
        for name, m in r["stack"]["local"]:
            blocks.append(local_w[cl][name][:, :m])
            stacked[cl][name] = pos
            pos += m
        quad.append(r["stack"]["quad"])
    qi, qj = prefix_pairs(max(quad, default=0))
    qi, qj, qoff = [qi], [qj], [0] * len(picks)
    nq = int(qi[0].size)
    for kind_now in ("linear", "quadratic"):
        for cl, (name, kind, m) in enumerate(picks):
            if name in ("global", "stack") or kind != kind_now:
                continue
            if kind not in ("linear", "quadratic"):
                raise ValueError(f"cluster {cl}: local inputs take linear or quadratic maps, got {kind!r}")
            blocks.append(local_w[cl][name][:, :m])
            source[cl] = pos
            if kind == "quadratic":
                i, j = prefix_pairs(m)
                qi.append(i + pos)
                qj.append(j + pos)
                qoff[cl] = nq
                nq += int(i.size)
            pos += m
    return np.concatenate(blocks, axis=1), {"qi": np.concatenate(qi), "qj": np.concatenate(qj), "qoff": qoff,
                                            "source": source, "picks": picks, "stacked": stacked}


def _stack_row(row: np.ndarray, union: dict, at: dict, kin: int) -> np.ndarray:
    """A stacked cluster's output row on its union (:mod:`._stack`) laid out on the model's
    activations (read from 0): the global inputs, its local blocks at ``at``, the products after
    the ``kin`` inputs (zeros between)."""
    dg = union["global"]
    nq = union["quad"] * (union["quad"] + 1) // 2
    ends = [dg] + [at[name] + m for name, m in union["local"]]
    out = np.zeros(kin + nq if nq else max(ends), np.float32)
    out[:dg] = row[:dg]
    pos = dg
    for name, m in union["local"]:
        out[at[name]:at[name] + m] = row[pos:pos + m]
        pos += m
    out[kin:kin + nq] = row[pos:pos + nq]
    return out


def _pack(results, labels, order, model, frames, source, space, w_in, lo, hi, data, a, pose, root, layout) -> dict:
    from .._shared.pose import PARAMETERISATIONS, ROOT_MODES

    vcount = labels.shape[0]
    c = order * order
    kc = len(results)
    kin = w_in.shape[1]
    if model in ("auto", "stack"):
        picks, qi, qj = layout["picks"], layout["qi"], layout["qj"]
        d = kin + qi.size
    else:
        qi, qj = _quadratic_pairs(kin) if model == "quadratic" else (np.zeros(0, np.int64), np.zeros(0, np.int64))
        d = expand_features(np.zeros((1, kin)), model).shape[1]
    comps = np.array([r["basis"].shape[1] for r in results], np.int32)
    kmax = max(int(comps.max()), 1)
    mean = np.zeros((vcount, c), np.float32)
    basis = np.zeros((vcount, c, kmax), np.float32)
    y_offset = np.concatenate([[0], np.cumsum(comps)]).astype(np.int32)
    hidden = np.array([r["w1"].shape[0] if "w1" in r else 0 for r in results], np.int32)
    h_offset = np.concatenate([[0], np.cumsum(hidden)]).astype(np.int32)
    w1 = np.zeros((max(int(h_offset[-1]), 1), kin), np.float32)
    b1 = np.zeros(max(int(h_offset[-1]), 1), np.float32)
    source_, length, w_offset, w2, b2 = [], [], [], [], []
    pos = 0
    for cl, r in enumerate(results):
        rows = np.flatnonzero(labels == cl)
        mean[rows] = r["mean"].reshape(rows.size, c)
        basis[rows, :, :comps[cl]] = r["basis"].reshape(rows.size, c, comps[cl])
        if hidden[cl]:
            w1[h_offset[cl]:h_offset[cl + 1]] = r["w1"]
            b1[h_offset[cl]:h_offset[cl + 1]] = r["b1"]
        for o in range(comps[cl]):
            row = np.asarray(r["w2"][o], np.float32)
            if layout and picks[cl][:2] == ("global", "quadratic"):  # [x_0..x_m-1, 0.., products]
                m = picks[cl][2]
                row = np.concatenate([row[:m], np.zeros(kin - m, np.float32), row[m:]])
            elif layout and picks[cl][1] == "quadratic":  # a local block: [its m inputs, 0.., its products]
                m = picks[cl][2]
                gap = kin - layout["source"][cl] - m + layout["qoff"][cl]
                row = np.concatenate([row[:m], np.zeros(gap, np.float32), row[m:]])
            elif layout and layout["stacked"][cl] is not None:
                row = _stack_row(row, r["stack"], layout["stacked"][cl], kin)
            source_.append(d + int(h_offset[cl]) if hidden[cl] else layout["source"][cl] if layout else 0)
            length.append(row.size)
            w_offset.append(pos)
            w2.append(row)
            b2.append(float(r["b2"][o]))
            pos += row.size
    rule = cluster_frame_rule(data["rest_points"], labels)
    kinds = list(PARAMETERISATIONS)
    return {
        "meta": np.array([order, MODELS.index(model), FRAME_KINDS.index(frames), source,
                          kinds.index(pose) if pose in kinds else 0, ROOT_MODES.index(root), kin, d, kmax, kc],
                         np.int64),
        "pose_mean": space.mean, "pose_scale": space.scale, "pose_active": space.active.astype(np.int8),
        "pose_components": space.components, "pose_variance": space.variance,
        "pose_total_variance": np.array([space.total_variance]), "pose_low": space.low, "pose_high": space.high,
        "input_weights": w_in, "x_low": lo, "x_high": hi,
        "quad_i": np.asarray(qi, np.int32), "quad_j": np.asarray(qj, np.int32),
        "labels": labels, "frame_order": rule.order, "frame_offsets": rule.offsets, "frame_weights": rule.weights,
        "rest_axes": rule.rest_axes, "rest_points": np.asarray(data["rest_points"], np.float64),
        "faces": np.asarray(data["faces"], np.int32),
        "mean": mean, "basis": basis, "components": comps, "y_offset": y_offset,
        "hidden": hidden, "hidden_offset": h_offset, "w1": w1, "b1": b1,
        "source": np.asarray(source_, np.int32), "length": np.asarray(length, np.int32),
        "w_offset": np.asarray(w_offset, np.int32),
        "w2": np.concatenate(w2).astype(np.float32) if w2 else np.zeros(1, np.float32),
        "b2": np.asarray(b2, np.float32),
        "topology": np.asarray(data["topology"], np.int64),
        "root_reference": np.asarray(data.get("root_reference", np.zeros((0, 3, 3))), np.float64),
        "training_poses": np.asarray(a, np.float64),
    }


_REQUIRED = ("meta", "pose_mean", "input_weights", "x_low", "x_high", "labels", "frame_order", "frame_offsets",
             "frame_weights", "rest_axes", "mean", "basis", "components", "y_offset", "hidden", "hidden_offset", "w1",
             "b1", "source", "length", "w_offset", "w2", "b2", "quad_i", "quad_j")


def model_from_arrays(arrays: dict) -> VisibilityModel:
    """Check the arrays of a model: keys, shapes, offsets within bounds, finite values."""
    missing = [k for k in _REQUIRED if k not in arrays]
    if missing:
        raise ValueError(f"visibility model: missing {missing}")
    a = {k: np.asarray(v) for k, v in arrays.items()}
    meta = a["meta"].reshape(-1)
    if meta.size < 10:
        raise ValueError("visibility model: malformed meta")
    order, _, _, _, _, _, kin, d, kmax, kc = (int(v) for v in meta[:10])
    v = a["labels"].shape[0]
    c = order * order
    checks = [
        (a["mean"].shape == (v, c), f"mean {a['mean'].shape} is not ({v}, {c})"),
        (a["basis"].shape == (v, c, kmax), f"basis {a['basis'].shape} is not ({v}, {c}, {kmax})"),
        (a["input_weights"].shape[1] == kin, "input weights do not match the input components"),
        (a["input_weights"].shape[0] == a["pose_mean"].size, "input weights do not match the input mean"),
        (a["components"].shape == (kc,) and a["y_offset"].shape == (kc + 1,), "per-cluster arrays"),
        (int(a["labels"].min(initial=0)) >= 0 and int(a["labels"].max(initial=0)) < kc, "labels out of range"),
        (int(a["components"].max(initial=0)) <= kmax, "components exceed the basis"),
        (a["source"].shape[0] == int(a["y_offset"][-1]) == a["b2"].shape[0], "output layer size"),
        (a["w1"].shape[1] == kin, "hidden layer width"),
    ]
    nb = a.get("relative_neighbours")
    if nb is not None and nb.size:
        from ._relative import width

        checks += [(nb.ndim == 2 and nb.shape[0] == kc and int(nb.min()) >= 0 and int(nb.max()) < kc,
                    "relative neighbours out of range"),
                   (a["pose_mean"].size == a["pose_scale"].size + kc * width(nb.shape[1]),
                    "the input mean does not hold the relative inputs")]
    for ok, what in checks:
        if not ok:
            raise ValueError(f"visibility model: {what}")
    if a["length"].size:
        end = a["w_offset"].astype(np.int64) + a["length"]
        if end.max() > a["w2"].size or (a["source"].astype(np.int64) + a["length"]).max() > d + a["w1"].shape[0]:
            raise ValueError("visibility model: output layer offsets out of bounds")
    for k in ("mean", "basis", "w1", "b1", "w2", "b2", "input_weights", "x_low", "x_high"):
        if not np.all(np.isfinite(a[k])):
            raise ValueError(f"visibility model: {k} has NaN or infinite values")
    return VisibilityModel(a)


def pose_space_of(model: VisibilityModel) -> PoseSpace:
    a = model.arrays
    width = np.asarray(a["pose_scale"]).size  # the pose vector's (relative inputs follow it in pose_mean)
    return PoseSpace(np.asarray(a["pose_mean"], np.float64)[:width], np.asarray(a["pose_scale"], np.float64),
                     np.asarray(a["pose_active"]).astype(bool), np.asarray(a["pose_components"], np.float64),
                     np.asarray(a["pose_variance"], np.float64), float(np.asarray(a["pose_total_variance"])[0]),
                     np.asarray(a["pose_low"], np.float64), np.asarray(a["pose_high"], np.float64))
