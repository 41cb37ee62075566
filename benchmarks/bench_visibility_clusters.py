"""Where the held-out error of the diffuse visibility graph is: per cluster, and per candidate model.

For ``stages/figure_visibility_diffuse.toml`` (its cached training data and fit; a run of
``python -m warpshade.cli run stages/figure_visibility_diffuse.toml --validate`` fills the cache),
on the graph's [validate] frames against the same diffuse reference (``measure_error``):

* per cluster, its share of the squared error (relative to the reference's norm over every vertex,
  so the shares add up to the graph's ``rel_rms``) of three estimates, all through eq. 14 and the
  cluster frames: the model's prediction (the float64 mirror), the held-out visibility ray traced
  at ``--truth-rays`` projected on the cluster's PCA basis (the floor of the PCA), and that traced
  visibility itself (the floor of the SH order);
* for the ``--worst`` clusters with the largest excess of the model over its PCA floor, every
  candidate of the ``auto`` selection (the relative inputs' too when the graph's fit has them,
  ``visibility.fit relative``) and their stacked combination (``regressor = "stack"``) (:mod:`warpshade.methods.visibility._select`: input set,
  kind, input count, its blocked-CV penalty), refitted in-process on the training clip: its
  blocked cross-validation error on the training clip (the selection's criterion) next to its
  held-out contribution -- a diagnosis of the selection, never a selection (the held-out clip
  chooses nothing).

With ``--nested``: nested blocked cross-validation on the training clip alone -- the whole
per-cluster procedure (PCA, then the selection among a family of candidates with its own inner
blocked CV) repeated inside each outer fold, the outer segment's visibility error summed over every
cluster -- for candidate families: every candidate (``auto``), every candidate but the relative
inputs (``auto without relative``), the global inputs only (linear and quadratic), the nearby joints' inputs only, and 12 quadratic global inputs for every cluster (the
graph's settings before ``auto``), and the stacked combination of every candidate (``stack``). It
compares selection procedures without the held-out clip.

Writes ``visibility-clusters-<date>-cpu.json`` into ``--out``.

Usage::

    python benchmarks/bench_visibility_clusters.py [--worst 4] [--nested] [--out DIR]
    python benchmarks/bench_visibility_clusters.py --quick --out /tmp/vc     # smoke profile
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import time
from pathlib import Path

import numpy as np

#: Smoke profile (tests/test_benchmarks.py): slow, kept out of the default suite (``-m "not slow"``):
#: 25 s on a loaded machine: a 30-frame training trace, the auto fit with its
#: cross-validation, references and one cluster's refitted candidates.
PROFILE = {"slow": True}

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
GRAPH = ROOT / "stages" / "figure_visibility_diffuse.toml"


def main(argv=None) -> int:
    from warpshade.basis import sh
    from warpshade.graph import load
    from warpshade.measure import measure_error
    from warpshade.methods.datadriven import pose_features, pose_layout
    from warpshade.methods.visibility import predict_f64, to_local
    from warpshade.methods.visibility import _select as S
    from warpshade.methods.visibility._fit import _principal, pca_size
    from warpshade.methods.visibility._mirror import inputs_f64
    from warpshade.methods.visibility._model import _input_sets, cosine_product_matrix, input_space, local_frames_f64
    from warpshade.methods.visibility._relative import relative_features_f64
    from warpshade.methods.visibility._stack import fit_stack, union_features
    from warpshade.transfer import compute

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--worst", type=int, default=4, help="clusters whose candidates are tabulated")
    ap.add_argument("--truth-rays", type=int, default=1024, help="rays of the held-out traced visibility")
    ap.add_argument("--nested", action="store_true", help="nested blocked CV of candidate families (minutes)")
    ap.add_argument("--quick", action="store_true", help="smoke profile: 30 training frames at 16 rays, 64-ray "
                    "references, one cluster's candidates")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = ap.parse_args(argv)
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    t_all = time.perf_counter()
    load0 = os.getloadavg()
    spec = load(GRAPH)
    if args.quick:
        args.worst, args.truth_rays, args.nested = 1, 32, False
        spec.validate_spec["samples"] = 64
        for st in spec.stages:
            if st.type == "visibility.data":
                st.params.update(frames="0:600:20", samples=16)
    rt = spec.compile(None, device="cpu", progress=True)
    frames = [float(f) for f in spec.validate_spec["frames"]]
    m = measure_error(rt, frames)
    scene = rt.scene
    fit_stage = next(st for st in rt.stages if st.type_name == "visibility.fit")
    fit_params = fit_stage.params  # every parameter, defaults included
    order = next(st.params["order"] for st in spec.stages if st.type == "visibility.diffuse")
    c = order * order
    a = rt.artifacts["fit"]["model"]
    data = rt.artifacts["data"]["data"]
    labels = np.asarray(a["labels"])
    kc = int(labels.max()) + 1
    cos = cosine_product_matrix(order)
    light = rt.state.lighting.sh(order).numpy().astype(np.float64)
    albedo = rt.evaluator.albedo.numpy().astype(np.float64)
    idx = [scene.frame_index(f) for f in frames]
    poses = pose_features(scene, idx, pose_layout(scene, fit_params["pose"], fit_params["root"]),
                          root_reference=data["root_reference"])
    x = inputs_f64(a, poses, np.stack([scene.points_at(f) for f in frames]))
    mean, basis = np.asarray(a["mean"], np.float64), np.asarray(a["basis"], np.float64)

    def shade(local, fr, rows=slice(None)):
        world = sh.rotate(local @ cos.T, np.swapaxes(fr, 1, 2))
        return albedo[rows] / np.pi * np.maximum(world @ light.T, 0.0)

    sq = {k: np.zeros(kc) for k in ("model", "pca_projection", "traced")}
    den = 0.0
    held = {}
    for i, f in enumerate(frames):
        fr = local_frames_f64("cluster", scene.points_at(f)[None], scene.normals_at(f)[None], a["rest_points"],
                              a["faces"], labels)[0]
        local = to_local(compute(scene, f, order, args.truth_rays, space="world", seed=77,
                                 below_horizon="visible").visibility, fr)
        proj = np.empty_like(local)
        for cl in range(kc):
            rows = np.flatnonzero(labels == cl)
            u = basis[rows, :, :int(a["components"][cl])].reshape(rows.size * c, -1)
            d = (local[rows] - mean[rows]).reshape(-1)
            proj[rows] = (mean[rows].reshape(-1) + u @ (u.T @ d)).reshape(rows.size, -1)
        ref = np.asarray(m.references[f], np.float64)
        for key, v in (("model", predict_f64(a, x[i])), ("pca_projection", proj), ("traced", local)):
            sq[key] += np.bincount(labels, ((shade(v, fr) - ref) ** 2).sum(1), minlength=kc)
        den += float((ref ** 2).sum())
        held[f] = (fr, ref)
    sizes = np.bincount(labels, minlength=kc)
    selected = {s["cluster"]: s for s in (getattr(fit_stage, "report", None) or {}).get("selected", [])}
    clusters = []
    for cl in range(kc):
        row = {"cluster": cl, "vertices": int(sizes[cl])}
        row.update({f"{k}_rel": float(np.sqrt(v[cl] / den)) for k, v in sq.items()})
        row["share_of_model_sq"] = float(sq["model"][cl] / sq["model"].sum())
        row["total_without_excess"] = float(np.sqrt((sq["model"].sum() - sq["model"][cl] + sq["pca_projection"][cl]) / den))
        if cl in selected:
            row["selected"] = {k: selected[cl][k] for k in ("input_set", "model_used", "inputs", "ridge", "cv_error")
                               if k in selected[cl]}
        clusters.append(row)
    clusters.sort(key=lambda r: -(r["model_rel"] ** 2 - r["pca_projection_rel"] ** 2))
    out = {"graph": spec.name, "frames": frames, "truth_rays": args.truth_rays, "load_average_start": load0,
           "rel_rms": {k: float(np.sqrt(v.sum() / den)) for k, v in sq.items()},
           "graph_rel_rms": float(m.error["mean"]["rel_rms"]), "clusters": clusters}
    print(json.dumps(out["rel_rms"]), flush=True)

    # candidates of the worst clusters: blocked CV on the training clip vs held-out contribution
    train_poses = np.asarray(data[f"poses_{fit_params['pose']}"], np.float64)
    if fit_params["root"] == "exclude":
        train_poses = train_poses[:, np.asarray(data[f"root_{fit_params['pose']}"]) == 0]
    space, w_in = input_space(train_poses, fit_params["input_variance"], fit_params["input_max"])
    xg = (train_poses - space.mean) @ w_in
    pcount = xg.shape[0]
    fr_train = local_frames_f64("cluster", data["points"], data["normals"], data["rest_points"], data["faces"], labels)
    xh_global = x[:, :w_in.shape[1]]  # the model's global inputs (clamped) come first
    # the relative inputs (visibility.fit relative), appended to the pose vectors as the fit does
    nb = np.asarray(a["relative_neighbours"]) if "relative_neighbours" in a else np.zeros((kc, 0), np.int32)
    a_train, a_held = train_poses, poses
    if nb.shape[1]:
        a_train = np.concatenate([train_poses, relative_features_f64(data["points"], data["rest_points"], labels, nb)], 1)
        a_held = np.concatenate([poses, relative_features_f64(np.stack([scene.points_at(f) for f in frames]),
                                                              data["rest_points"], labels, nb)], 1)
    relative = (nb if nb.shape[1] else None, train_poses.shape[1])
    splits = S.blocked_folds(pcount)
    out["candidates"] = {}
    for row in clusters[:args.worst]:
        cl = row["cluster"]
        rows = np.flatnonzero(labels == cl)
        y = np.stack([to_local(np.asarray(data["visibility"][t][rows], np.float64), fr_train[t][rows])
                      for t in range(pcount)]).reshape(pcount, -1)
        ym = y.mean(0)
        s, vt = _principal(y - ym)
        k = pca_size(s, fit_params["variance"], min(fit_params["k_max"], pcount - 1))
        u = vt[:k].T
        target = (y - ym) @ u
        norm, trunc = float((y * y).sum()), float((((y - ym) - target @ u.T) ** 2).sum())
        local_w = {}
        sets = _input_sets(data, 0, fit_params["pose"], fit_params["root"], a_train, xg, labels, cl,
                           fit_params["input_variance"], fit_params["input_max"], local_w, *relative)
        table, held_sets = [], {}
        for name, (xs, kinds) in sets.items():
            if name == "global":
                xh = xh_global
            else:  # the model's clamp: the training range widened by the margin
                span = xs.max(0) - xs.min(0)
                xh = np.clip((a_held - a_train.mean(0)) @ local_w[name], xs.min(0) - fit_params["margin"] * span,
                             xs.max(0) + fit_params["margin"] * span)
            held_sets[name] = (xh, kinds)
            for kind in kinds:
                for mm in sorted({q for q in S.INPUT_COUNTS if q <= xs.shape[1]} | {xs.shape[1]}):
                    fe = S.prefix_features(xs, kind, mm)
                    per = np.stack([S._path_sse(fe[tr], target[tr], fe[va], target[va]) for tr, va in splits]).sum(0)
                    g = int(np.argmin(per))
                    w, b = S.fit_selected(xs, target, kind, mm, float(S.RIDGE_GRID[g]))
                    ph = S.prefix_features(xh, kind, mm) @ w.T + b
                    err = 0.0
                    for i, f in enumerate(frames):
                        fr, ref = held[f]
                        v = (ym + u @ ph[i]).reshape(rows.size, c)
                        err += float(((shade(v, fr[rows], rows) - ref[rows]) ** 2).sum())
                    table.append({"set": name, "kind": kind, "inputs": int(mm), "penalty": float(S.RIDGE_GRID[g]),
                                  "cv_error": float(np.sqrt((per[g] + trunc) / norm)),
                                  "heldout_rel": float(np.sqrt(err / den))})
        table.sort(key=lambda r: r["cv_error"])
        cv = np.array([r["cv_error"] for r in table])
        ho = np.array([r["heldout_rel"] for r in table])
        rank = lambda v: np.argsort(np.argsort(v))  # noqa: E731
        # the stacked combination of every candidate (regressor = "stack"): its weighted out-of-fold error
        # on the training clip next to its held-out contribution
        st = fit_stack(_linear_local(sets), target)
        ph = union_features(held_sets, st["layout"]) @ st["w"].T + st["b"]
        err = 0.0
        for i, f in enumerate(frames):
            fr, ref = held[f]
            err += float(((shade((ym + u @ ph[i]).reshape(rows.size, c), fr[rows], rows) - ref[rows]) ** 2).sum())
        stacked = {"cv_error_oof": float(np.sqrt((st["sse"] + trunc) / norm)), "heldout_rel": float(np.sqrt(err / den)),
                   "weights": {f"{p['set']} {p['kind']} {p['inputs']}": p["weight"] for p in st["picks"]}}
        out["candidates"][cl] = {"table": table, "spearman_cv_heldout": float(np.corrcoef(rank(cv), rank(ho))[0, 1]),
                                 "stack": stacked}
        print(f"cluster {cl}: {len(table)} candidates, CV-best held-out {table[0]['heldout_rel']:.4f}, "
              f"least held-out {ho.min():.4f}, stacked {stacked['heldout_rel']:.4f}, "
              f"rank correlation {out['candidates'][cl]['spearman_cv_heldout']:.2f}",
              flush=True)
    if args.nested:
        out["nested_cv"] = nested_cv(data, labels, fr_train, a_train, xg, fit_params, relative)
        print("nested blocked CV:", json.dumps(out["nested_cv"]["rel"]), flush=True)
    out["load_average_end"] = os.getloadavg()
    out["wall_s"] = time.perf_counter() - t_all
    out_dir = Path(args.out or RESULTS)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"visibility-clusters-{datetime.date.today().isoformat()}-cpu.json"
    from warpshade._fileio import write_json_atomic

    write_json_atomic(path, out, indent=1)
    print(f"wrote {path}")
    return 0


def _linear_local(sets: dict) -> dict:
    """The candidate sets with linear maps only on local inputs (what ``regressor = "stack"`` combines)."""
    return {k: (v[0], v[1] if k == "global" else ("linear",)) for k, v in sets.items()}


def nested_cv(data, labels, fr_train, poses, xg, fit_params, relative=(None, None)) -> dict:
    """Nested blocked CV of candidate families (module docstring): ``{"rel": family -> relative
    error over every cluster, "per_cluster": family -> [squared error per cluster]}``."""
    from warpshade.methods.visibility import _select as S
    from warpshade.methods.visibility import to_local
    from warpshade.methods.visibility._fit import _principal, pca_size
    from warpshade.methods.visibility._model import _input_sets

    pcount = xg.shape[0]
    kc = int(labels.max()) + 1
    outer = S.blocked_folds(pcount)
    from warpshade.methods.visibility._stack import fit_stack, union_features

    fams = ("auto", "auto without relative", "global", "local", "quadratic 12", "stack")
    sse = {f: np.zeros(kc) for f in fams}
    norm = 0.0
    for cl in range(kc):
        rows = np.flatnonzero(labels == cl)
        y = np.stack([to_local(np.asarray(data["visibility"][t][rows], np.float64), fr_train[t][rows])
                      for t in range(pcount)]).reshape(pcount, -1)
        norm += float((y * y).sum())
        sets = _input_sets(data, 0, fit_params["pose"], fit_params["root"], poses, xg, labels, cl,
                           fit_params["input_variance"], fit_params["input_max"], {}, *relative)
        glob = {"global": sets["global"]}
        joints = {k: v for k, v in sets.items() if not k.startswith("near")}
        family = {"auto": (sets, S.INPUT_COUNTS), "auto without relative": (joints, S.INPUT_COUNTS),
                  "global": (glob, S.INPUT_COUNTS),
                  "local": ({k: v for k, v in sets.items() if k != "global"} or glob, S.INPUT_COUNTS),
                  "quadratic 12": ({"global": (xg[:, :12], ("quadratic",))}, (12,)),
                  "stack": (_linear_local(sets), S.INPUT_COUNTS)}
        for name, (fsets, counts) in family.items():
            for tr, va in outer:
                ym = y[tr].mean(0)
                s, vt = _principal(y[tr] - ym)
                k = pca_size(s, fit_params["variance"], min(fit_params["k_max"], tr.size - 1))
                pred = np.broadcast_to(ym, (va.size, ym.size))
                if k:
                    u = vt[:k].T
                    target = (y[tr] - ym) @ u
                    sub = {n: (xs[tr], kinds) for n, (xs, kinds) in fsets.items()}
                    if name == "stack":  # the combination of every candidate, weighted on the inner out-of-fold error
                        st = fit_stack(sub, target)
                        feats = union_features({n: (xs[va], kinds) for n, (xs, kinds) in fsets.items()}, st["layout"])
                        pred = ym + (feats @ st["w"].T + st["b"]) @ u.T
                        sse[name][cl] += float(((pred - y[va]) ** 2).sum())
                        continue
                    sel = S.select_ridge(sub, target, input_counts=counts)
                    xs = fsets[sel["set"]][0]
                    w, b = S.fit_selected(xs[tr], target, sel["kind"], sel["inputs"], sel["penalty"])
                    pred = ym + (S.prefix_features(xs[va], sel["kind"], sel["inputs"]) @ w.T + b) @ u.T
                sse[name][cl] += float(((pred - y[va]) ** 2).sum())
        print(f"nested CV, cluster {cl}:", {f: round(float(np.sqrt(v.sum() / norm)), 4) for f, v in sse.items()},
              flush=True)
    return {"rel": {f: float(np.sqrt(v.sum() / norm)) for f, v in sse.items()},
            "per_cluster_sq": {f: v.tolist() for f, v in sse.items()}, "norm": norm}


if __name__ == "__main__":
    raise SystemExit(main())
