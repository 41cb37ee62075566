"""Data-driven visibility (Nowrouzezahrai, Kalogerakis, Fiume 2009, sec. 5): error, cost, sizes.

Part 1 -- glossy (Table 1, Fig. 7): on each held-out clip, the graph ``stages/<scene>_visibility.toml``
with ``model`` = linear, quadratic and network (the cached training data shared), against the
glossy ray-traced reference on the graph's ``[validate]`` frames (``warpshade.measure.measure_error``,
the same cached reference as ``warpshade run --validate``); next to it, in the same run,
``stages/<scene>_rpo_traced.toml`` (RPO over visibility ray traced every frame, the baseline):
error ratio and time-per-frame ratio (median of replayed frames, and each stage from a profile),
fit time (every cluster, cross-validation included), model size.

Part 2 -- diffuse: ``stages/figure_visibility_diffuse.toml`` against the 2007 linear model
(``stages/figure_datadriven.toml``) with the *same* training frames and rays as the visibility
graph (its own graph traces every frame at 256 rays; this is said in the JSON; ``--diffuse-as-written`` runs it as
written too) and against the graph's previous settings (:data:`PREVIOUS_DIFFUSE_FIT`), on the
figure clip and on figure_walk (``stages/figure_walk_datadriven.toml``'s frames), and the floors of the diffuse path (:func:`diffuse_floors`): visibility ray traced at
the frame through eq. 14 (training rays and 1024 rays), the held-out visibility projected on the
model's PCA bases, the model's prediction; eq. 14 with the cosine truncated (the kernel) or exact.

Part 3 -- the paper's studies in visibility space, on the held-out frames against visibility
ray traced there (``--truth-rays``), ridge models fitted in-process on the graph's training data:
clusters vs error (Fig. 4: the mean-shift bandwidth), retained variance vs error (Fig. 5), the
frame the visibility is modelled in (Fig. 9: cluster frames, one-ring frames, world), errors
measured in the world frame (local predictions turned back by their frames); and Fig. 8, the
cosine-weighted transfer on the held-out frames predicted by a visibility model (the cosine
applied after, eq. 14) or by a model of the transfer itself (the cosine in the training targets).

``--wanderer-diffuse``: the harness's wanderer diffuse row next to the 2007 linear model
(``stages/wanderer_datadriven.toml``) trained on the same frames and rays (:func:`part_wanderer_diffuse`).

Writes ``visibility-<date>-cpu[-quick][-tag].json`` and ``-models.png``, ``-studies.png``, ``-diffuse.png``
into ``--out``.

Usage::

    python benchmarks/bench_visibility.py [--quick] [--scenes figure,wanderer] [--out DIR]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

#: Smoke profile (tests/test_benchmarks.py): slow, kept out of the default suite (``-m "not slow"``):
#: ~120 s on a loaded machine: two training traces -- visibility and the 2007 model's
#: transfer --, three graphs, glossy and diffuse truths and the three frame-kind fits.
PROFILE = {"slow": True}

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
STAGES = ROOT / "stages"
MODELS = ("linear", "quadratic", "network")
#: Rays of the visibility the studies of part 3 compare with.
TRUTH_RAYS = 512
#: ``--quick``: every 60th training frame at 16 rays, ridge only, 64-ray truths, one frame.
QUICK = {"frames": "0:600:60", "samples": 16, "truth": 64}
#: Replayed frames timed per graph (the median is reported).
TIMED_FRAMES = 12


def _spec(name, quick, regressor=None, data=None, fit=None):
    from warpshade.graph import load

    spec = load(STAGES / f"{name}.toml")
    for st in spec.stages:
        if st.type in ("visibility.data", "datadriven.data"):
            st.params.update(data or {})
            if quick:
                st.params.update(frames=QUICK["frames"], samples=QUICK["samples"])
        if st.type == "visibility.fit":
            if regressor is not None:
                st.params["regressor"] = regressor
            st.params.update(fit or {})
            if quick:
                st.params.update(hidden=(4,), max_iterations=20)
    if quick:
        spec.validate_spec["frames"] = spec.validate_spec["frames"][:1]
    return spec


def _measure(spec, quick, scene=None, timed_frames=TIMED_FRAMES):
    """Compile, time replayed frames, profile the stages, measure the error on [validate] frames."""
    from warpshade.measure import measure_error

    t0 = time.perf_counter()
    rt = spec.compile(scene, device="cpu", progress=True)
    compile_s = time.perf_counter() - t0
    frames = [float(f) for f in spec.validate_spec["frames"]]
    n = len(rt.scene.frames)
    timed = frames if quick else sorted(set(frames) | {float(rt.scene.frames[i]) for i in
                                                       np.linspace(0, n - 1, timed_frames).astype(int)})
    rt.run(timed, warmup=True)
    summary = rt.timing_summary()
    prof = rt.profile(frames=[timed[0]] if quick else timed[:4])
    m = measure_error(rt, frames, samples=QUICK["truth"] if quick else None)
    fit = next((st.report for st in rt.stages if st.type_name == "visibility.fit"), None)
    pred = next((st for st in rt.stages if st.type_name == "visibility.predict"), None)
    return rt, {"rel_rms": float(m.error["mean"]["rel_rms"]),
                "per_frame": [float(e["rel_rms"]) for e in m.error["per_frame"]],
                "median_frame_s": summary["median_frame_s"], "stage_s": prof, "compile_s": compile_s,
                "model_bytes": int(rt.model_bytes()),
                "fit": None if fit is None else {k: fit[k] for k in ("clusters", "components", "input_components",
                                                                     "models_used", "fallbacks", "cv_error",
                                                                     "total_fit_s", "stored_floats") if k in fit},
                "novelty": None if pred is None else pred.diagnostics()}


def part_glossy(scene_name, quick, timed_frames=TIMED_FRAMES, models=MODELS):
    out = {}
    for model in (("linear",) if quick else models):
        print(f"== {scene_name}: {model}", flush=True)
        _, out[model] = _measure(_spec(f"{scene_name}_visibility", quick, model), quick, timed_frames=timed_frames)
    print(f"== {scene_name}: RPO over traced visibility", flush=True)
    _, out["traced"] = _measure(_spec(f"{scene_name}_rpo_traced", quick), quick, timed_frames=timed_frames)
    base = out["traced"]
    for model in MODELS:
        if model in out:
            out[model]["error_ratio_to_traced"] = out[model]["rel_rms"] / base["rel_rms"]
            out[model]["speedup_over_traced"] = base["median_frame_s"] / out[model]["median_frame_s"]
    return out


#: The previous settings of stages/figure_visibility_diffuse.toml: the per-cluster selection without
#: the relative inputs (joint rotations only). The settings before those (12 quadratic global inputs
#: for every cluster, chosen on the held-out figure clip: {"regressor": "quadratic", "input_max": 12})
#: are in benchmarks/results/visibility-2026-12-02-cpu-diffuse-auto.json.
PREVIOUS_DIFFUSE_FIT = {"relative": 0}
#: Held-out clips of part 2 and their validation frames (those of the 2007 graphs).
DIFFUSE_CLIPS = {"figure": ("figure_datadriven", None), "figure_walk": ("figure_walk_datadriven", "bundled:figure_walk")}


def _diffuse_clip(quick, clip, previous=True):
    """The diffuse graph, its previous settings and the 2007 model (same training frames and rays)
    on one held-out clip."""
    dd_name, scene = DIFFUSE_CLIPS[clip]
    vis_spec = _spec("figure_visibility_diffuse", quick)
    dd_spec0 = _spec(dd_name, quick)
    if scene is not None:
        vis_spec.scene = scene
        vis_spec.validate_spec["frames"] = list(dd_spec0.validate_spec["frames"])
    data = next(st.params for st in vis_spec.stages if st.type == "visibility.data")
    print(f"== {clip}: figure_visibility_diffuse", flush=True)
    vis_rt, vis = _measure(vis_spec, quick)
    out = {"visibility": vis, "frames": vis_spec.validate_spec["frames"]}
    if previous:
        prev_spec = _spec("figure_visibility_diffuse", quick, fit=PREVIOUS_DIFFUSE_FIT)
        prev_spec.scene, prev_spec.validate_spec = vis_spec.scene, dict(vis_spec.validate_spec)
        print(f"== {clip}: previous settings {PREVIOUS_DIFFUSE_FIT}", flush=True)
        _, out["previous"] = _measure(prev_spec, quick)
    print(f"== {clip}: {dd_name} on the same training frames and rays", flush=True)
    _, out["datadriven_2007"] = _measure(_spec(dd_name, quick, data={"frames": data["frames"], "samples": data["samples"]}),
                                         quick)
    out["error_ratio"] = vis["rel_rms"] / out["datadriven_2007"]["rel_rms"]
    return vis_rt, out


def part_diffuse(quick, as_written=False, walk=True, previous=True):
    vis_spec = _spec("figure_visibility_diffuse", quick)
    data = next(st.params for st in vis_spec.stages if st.type == "visibility.data")
    fit = next(st.params for st in vis_spec.stages if st.type == "visibility.fit")
    vis_rt, out = _diffuse_clip(quick, "figure", previous)
    out.update({"visibility_settings": {"data": dict(data), "fit": dict(fit)}, "previous_settings": PREVIOUS_DIFFUSE_FIT,
                "note": f"both trained on figure_train frames {data['frames']} at {data['samples']} rays "
                        "(stages/figure_datadriven.toml as written: every frame at 256 rays)"})
    if as_written:
        print("== figure_datadriven as written (every training frame, 256 rays)", flush=True)
        _, out["datadriven_2007_as_written"] = _measure(_spec("figure_datadriven", quick), quick)
        out["error_ratio_to_as_written"] = out["visibility"]["rel_rms"] / out["datadriven_2007_as_written"]["rel_rms"]
    out["floors"] = diffuse_floors(vis_rt, quick)
    if walk:
        _, out["figure_walk"] = _diffuse_clip(quick, "figure_walk", previous)
    return out


def part_wanderer_diffuse(quick):
    """The harness's wanderer diffuse row (``visibility auto n6 diffuse``: the settings of
    stages/figure_visibility_diffuse.toml on the wanderer's training data of
    :data:`warpshade.methods.visibility._rows.TRAINING_CLIPS`) next to the 2007 linear model
    (stages/wanderer_datadriven.toml) trained on the *same* frames and rays, both on the wanderer's
    held-out clip against the diffuse reference at stages/wanderer_datadriven.toml's [validate] frames."""
    from warpshade.methods.visibility._rows import TRAINING_CLIPS, TRAINING_RAYS

    training, frames = TRAINING_CLIPS["wanderer"]
    rays = TRAINING_RAYS["wanderer"]
    dd_spec = _spec("wanderer_datadriven", quick, data={"frames": frames, "samples": rays})
    vis_spec = _spec("figure_visibility_diffuse", quick, data={"training": training, "frames": frames, "samples": rays})
    vis_spec.scene = dd_spec.scene
    vis_spec.validate_spec = dict(dd_spec.validate_spec)
    out = {"training": training, "frames": frames, "samples": rays, "validate_frames": dd_spec.validate_spec["frames"]}
    print(f"== wanderer: figure_visibility_diffuse's settings on {training} {frames} ({rays} rays)", flush=True)
    _, out["visibility"] = _measure(vis_spec, quick)
    print("== wanderer: wanderer_datadriven (2007 linear) on the same training frames and rays", flush=True)
    _, out["datadriven_2007"] = _measure(dd_spec, quick)
    out["error_ratio"] = out["visibility"]["rel_rms"] / out["datadriven_2007"]["rel_rms"]
    print("wanderer diffuse:", json.dumps({k: out[k]["rel_rms"] for k in ("visibility", "datadriven_2007")}), flush=True)
    return out


def diffuse_floors(rt, quick):
    """What each part of the diffuse visibility path costs, on the graph's [validate] frames against
    the same diffuse reference: the eq. 14 path over visibility ray traced at the frame (at the
    training ray count and at ``TRUTH_RAYS``: the floor of the SH order, and of the training noise),
    the held-out traced visibility projected on each cluster's PCA basis (the floor of the PCA
    budget), and the model's prediction (the float64 mirror next to the Warp graph). Also the same
    traced visibility turned into transfer with the cosine product truncated at the order (the
    kernel) and exact (the cosine to order 2n - 1, then truncated): what eq. 14's truncation costs."""
    from warpshade.basis import sh
    from warpshade.graph import GraphSpec, StageSpec
    from warpshade.measure import combine_metrics, error_metrics, measure_error
    from warpshade.methods.datadriven import pose_features, pose_layout
    from warpshade.methods.visibility import predict_f64, to_local
    from warpshade.methods.visibility._mirror import inputs_f64
    from warpshade.methods.visibility._model import local_frames_f64
    from warpshade.transfer import compute

    spec, scene = rt.spec, rt.scene
    order = next(st.params["order"] for st in spec.stages if st.type == "visibility.diffuse")
    data_params = next(st.params for st in spec.stages if st.type == "visibility.data")
    frames = [float(f) for f in spec.validate_spec["frames"]]
    truth_rays = QUICK["truth"] if quick else TRUTH_RAYS * 2
    light = rt.state.lighting.sh(order)
    m = measure_error(rt, frames, samples=QUICK["truth"] if quick else None)
    out = {"order": order, "frames": frames, "graph": float(m.error["mean"]["rel_rms"])}
    for rays in sorted({int(data_params["samples"]), truth_rays}):
        traced = GraphSpec([StageSpec("vis", "rpo.visibility_traced", {"order": order, "samples": rays}),
                            StageSpec("shade", "visibility.diffuse", {"order": order})], "shade.radiance",
                           name=f"{spec.name}_traced", scene=spec.scene, validate_spec=dict(spec.validate_spec))
        t_rt = traced.compile(scene, device="cpu", progress=False)
        tm = measure_error(t_rt, frames, samples=QUICK["truth"] if quick else None)
        out[f"traced_{rays}_rays"] = float(tm.error["mean"]["rel_rms"])
        print(f"floors: traced visibility at {rays} rays -> eq. 14: {out[f'traced_{rays}_rays']:.4f}", flush=True)
    a = rt.artifacts["fit"]["model"]
    data = rt.artifacts["data"]["data"]
    labels = np.asarray(a["labels"])
    kc = int(labels.max()) + 1
    idx = [scene.frame_index(f) for f in frames]
    poses = pose_features(scene, idx, pose_layout(scene, "quaternion", "include"), root_reference=data["root_reference"])
    x = inputs_f64(a, poses, np.stack([scene.points_at(f) for f in frames]))
    albedo = rt.evaluator.albedo.numpy().astype(np.float64)
    lw = light.numpy().astype(np.float64)
    cos_trunc = sh.product_matrix(sh.clamped_cosine_sh(order))
    cos_exact = sh.product_matrix(sh.clamped_cosine_sh(2 * order - 1))[:order * order, :order * order]
    mean, basis = np.asarray(a["mean"], np.float64), np.asarray(a["basis"], np.float64)

    def shade(local, fr, cos):
        world = sh.rotate(local @ cos.T, np.swapaxes(fr, 1, 2))
        return albedo / np.pi * np.maximum(world @ lw.T, 0.0)

    per = {"traced_exact_cosine": [], "traced_truncated_cosine": [], "pca_projection": [], "model_f64": []}
    for i, f in enumerate(frames):
        fr = local_frames_f64("cluster", scene.points_at(f)[None], scene.normals_at(f)[None], a["rest_points"],
                              a["faces"], labels)[0]
        local = to_local(compute(scene, f, order, truth_rays, space="world", seed=77, below_horizon="visible").visibility, fr)
        proj = np.empty_like(local)
        for c in range(kc):
            rows = np.flatnonzero(labels == c)
            u = basis[rows, :, :int(a["components"][c])].reshape(rows.size * order * order, -1)
            d = (local[rows] - mean[rows]).reshape(-1)
            proj[rows] = (mean[rows].reshape(-1) + u @ (u.T @ d)).reshape(rows.size, -1)
        ref = m.references[f]
        per["traced_exact_cosine"].append(error_metrics(shade(local, fr, cos_exact), ref))
        per["traced_truncated_cosine"].append(error_metrics(shade(local, fr, cos_trunc), ref))
        per["pca_projection"].append(error_metrics(shade(proj, fr, cos_trunc), ref))
        per["model_f64"].append(error_metrics(shade(predict_f64(a, x[i]), fr, cos_trunc), ref))
    for k, v in per.items():
        out[k] = float(combine_metrics(v)["rel_rms"])
    out["truth_rays"] = truth_rays
    print("floors:", json.dumps(out), flush=True)
    return out


def part_studies(quick, rt):
    """Visibility-space error on the held-out frames (module docstring, part 3)."""
    from warpshade.methods.datadriven import pose_features, pose_layout
    from warpshade.methods.visibility import fit_visibility, predict_f64, to_local
    from warpshade.methods.visibility._mirror import inputs_f64
    from warpshade.methods.visibility._model import cosine_product_matrix, local_frames_f64
    from warpshade.tasks import executor
    from warpshade.transfer import compute

    data = rt.artifacts["data"]["data"]
    scene = rt.scene
    frames = [float(f) for f in rt.spec.validate_spec["frames"]]
    rays = QUICK["truth"] if quick else TRUTH_RAYS
    truth = {f: compute(scene, f, 4, rays, space="world", seed=77, below_horizon="visible").visibility for f in frames}
    idx = [scene.frame_index(f) for f in frames]
    layout = pose_layout(scene, "quaternion", "include")
    poses = pose_features(scene, idx, layout, root_reference=data["root_reference"])

    def error(model):
        a = model.arrays
        x = inputs_f64(a, poses, np.stack([scene.points_at(f) for f in frames]))
        num = den = 0.0
        for i, f in enumerate(frames):
            local = predict_f64(a, x[i])
            kind = model.frames
            if kind == "world":
                world = local
            else:
                fr = local_frames_f64(kind, scene.points_at(f)[None], scene.normals_at(f)[None], a["rest_points"],
                                      a["faces"], a["labels"])[0]
                world = to_local(local, np.swapaxes(fr, 1, 2))
            num += float(((world - truth[f]) ** 2).sum())
            den += float((truth[f] ** 2).sum())
        return float(np.sqrt(num / den))

    def transfer_error(model, target):
        """Fig. 8: error of the cosine-weighted transfer on the held-out frames, local frame (the
        same norm as the world frame), from a visibility model (cosine applied after) or a
        transfer model (cosine in its training targets)."""
        a = model.arrays
        cos = cosine_product_matrix(4)
        x = inputs_f64(a, poses, np.stack([scene.points_at(f) for f in frames]))
        num = den = 0.0
        for i, f in enumerate(frames):
            fr = local_frames_f64(model.frames, scene.points_at(f)[None], scene.normals_at(f)[None], a["rest_points"],
                                  a["faces"], a["labels"])[0]
            want = to_local(truth[f], fr) @ cos.T
            got = predict_f64(a, x[i])
            if target == "visibility":
                got = got @ cos.T
            num += float(((got - want) ** 2).sum())
            den += float((want**2).sum())
        return float(np.sqrt(num / den))

    out = {"truth_rays": rays, "frames": frames, "bandwidth": [], "variance": [], "frames_kind": {}, "cosine": {}}
    with executor("serial") as ex:
        def fit(**kw):
            t0 = time.perf_counter()
            m = fit_visibility(data, regressor="linear", executor=ex, **kw)
            return m, time.perf_counter() - t0

        for kind in ("cluster", "one_ring", "world"):
            m, s = fit(space=kind)
            out["frames_kind"][kind] = {"error": error(m), "fit_s": s, "cv_error": m.report["cv_error"]}
            print("frames", kind, out["frames_kind"][kind], flush=True)
            if kind == "cluster":
                out["cosine"]["without (visibility, cosine applied after)"] = {"transfer_error": transfer_error(m, "visibility"),
                                                                              "components": int(np.sum(m.report["components"]))}
                mt, _ = fit(space=kind, target="transfer")
                out["cosine"]["with (transfer modelled)"] = {"transfer_error": transfer_error(mt, "transfer"),
                                                            "components": int(np.sum(mt.report["components"]))}
                print("cosine", out["cosine"], flush=True)
        for bw in ((0.3,) if quick else (0.1, 0.2, 0.3, 0.5, 0.8)):
            m, s = fit(bandwidth=bw)
            out["bandwidth"].append({"bandwidth": bw, "clusters": m.report["clusters"], "error": error(m),
                                     "stored_floats": m.report["stored_floats"]})
            print("bandwidth", out["bandwidth"][-1], flush=True)
        for var in ((0.95,) if quick else (0.8, 0.9, 0.95, 0.99)):
            m, s = fit(variance=var, predictable=1.0)
            out["variance"].append({"variance": var, "components": int(np.sum(m.report["components"])),
                                    "error": error(m)})
            print("variance", out["variance"][-1], flush=True)
    return out


def _plot_models(plt, glossy, path_models):
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for name, res in glossy.items():
        labels = [k for k in (*MODELS, "traced") if k in res]
        err = [res[k]["rel_rms"] for k in labels]
        ms = [1e3 * res[k]["median_frame_s"] for k in labels]
        axes[0].bar([f"{name}\n{k}" for k in labels], err)
        axes[1].bar([f"{name}\n{k}" for k in labels], ms)
    axes[0].set_ylabel("relative RMS vs glossy reference")
    axes[1].set_ylabel("ms per frame (replayed, 2-core CPU)")
    axes[1].set_yscale("log")
    for ax in axes:
        ax.tick_params(axis="x", labelsize=7)
    fig.suptitle("data-driven visibility (per-cluster models) vs RPO over per-frame traced visibility")
    fig.tight_layout()
    fig.savefig(path_models, dpi=110)
    plt.close(fig)


def _plot_diffuse(plt, diffuse, path):
    """Part 2: the diffuse error of the visibility graph and of the 2007 model, next to the floors
    of the visibility path (:func:`diffuse_floors`)."""
    fl = diffuse.get("floors", {})
    bars = [("2007 linear\n(same data)", diffuse["datadriven_2007"]["rel_rms"])]
    if "datadriven_2007_as_written" in diffuse:
        bars.append(("2007 linear\n(as written)", diffuse["datadriven_2007_as_written"]["rel_rms"]))
    bars.append(("visibility\nmodel", diffuse["visibility"]["rel_rms"]))
    if "previous" in diffuse:
        bars.append(("visibility\nprevious", diffuse["previous"]["rel_rms"]))
    names = {"pca_projection": "traced, PCA\nprojection", "traced_exact_cosine": "traced,\nexact cosine"}
    for key, value in fl.items():
        if key.startswith("traced_") and key.endswith("_rays"):
            bars.append((f"traced\n{key.split('_')[1]} rays", value))
        elif key in names:
            bars.append((names[key], value))
    walk = diffuse.get("figure_walk")
    if walk:
        bars.append(("walk: 2007\nlinear", walk["datadriven_2007"]["rel_rms"]))
        bars.append(("walk: visibility\nmodel", walk["visibility"]["rel_rms"]))
        if "previous" in walk:
            bars.append(("walk: visibility\nprevious", walk["previous"]["rel_rms"]))
    fig, ax = plt.subplots(figsize=(12, 4))
    colors = ["C1" if "2007" in b[0] else "C0" if "visibility" in b[0] else "C2" for b in bars]
    ax.bar([b[0] for b in bars], [b[1] for b in bars], color=colors)
    ax.set_ylabel("relative RMS vs diffuse reference")
    ax.set_title(f"figure (and figure_walk), diffuse, held-out frames: visibility model (order {fl.get('order', '?')}), "
                 "the floors of its parts")
    ax.tick_params(axis="x", labelsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot(result, path_models, path_studies, path_diffuse=None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    glossy = result["glossy"]
    if glossy:
        _plot_models(plt, glossy, path_models)
    if result.get("diffuse") and path_diffuse is not None:
        _plot_diffuse(plt, result["diffuse"], path_diffuse)
    st = result.get("studies")
    if not st:
        return
    fig, axes = plt.subplots(1, 4 if st.get("cosine") else 3, figsize=(17, 3.8))
    axes[0].plot([b["clusters"] for b in st["bandwidth"]], [b["error"] for b in st["bandwidth"]], "o-")
    axes[0].set_xlabel("clusters (mean-shift bandwidth)")
    axes[1].plot([v["variance"] for v in st["variance"]], [v["error"] for v in st["variance"]], "o-")
    axes[1].set_xlabel("retained variance per cluster")
    kinds = list(st["frames_kind"])
    axes[2].bar(kinds, [st["frames_kind"][k]["error"] for k in kinds])
    axes[2].set_xlabel("frame of the model")
    for ax in axes[:3]:
        ax.set_ylabel("held-out visibility rel. error (ridge)")
    if st.get("cosine"):
        names = list(st["cosine"])
        axes[3].bar([n.split(" (")[0] + " cosine" for n in names], [st["cosine"][n]["transfer_error"] for n in names])
        axes[3].set_ylabel("held-out transfer rel. error (ridge)")
        axes[3].set_xlabel("Fig. 8: the cosine in the model or not")
    fig.tight_layout()
    fig.savefig(path_studies, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="smoke profile: every 60th training frame at 16 rays, ridge only, one frame, 64-ray truths")
    ap.add_argument("--scenes", default="figure", help="held-out clips with a stages/<scene>_visibility.toml "
                    "('' skips part 1)")
    ap.add_argument("--models", default=",".join(MODELS), help="models of part 1")
    ap.add_argument("--timed-frames", type=int, default=TIMED_FRAMES, help="replayed frames timed per graph")
    ap.add_argument("--tag", default="", help="suffix of the output names (e.g. the scene of a separate run)")
    ap.add_argument("--skip-diffuse", action="store_true")
    ap.add_argument("--skip-studies", action="store_true")
    ap.add_argument("--skip-walk", action="store_true", help="part 2 on the figure clip only (not figure_walk too)")
    ap.add_argument("--skip-previous", action="store_true",
                    help="part 2 without the diffuse graph's previous settings (PREVIOUS_DIFFUSE_FIT)")
    ap.add_argument("--diffuse-as-written", action="store_true",
                    help="part 2 also runs stages/figure_datadriven.toml as written (every training frame, 256 rays)")
    ap.add_argument("--wanderer-diffuse", action="store_true",
                    help="also the wanderer's diffuse row against the 2007 linear model on the same training data "
                         "(part_wanderer_diffuse)")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = ap.parse_args(argv)
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    out_dir = Path(args.out or RESULTS)
    out_dir.mkdir(parents=True, exist_ok=True)
    tag = f"visibility-{datetime.date.today().isoformat()}-cpu" + ("-quick" if args.quick else "") + (f"-{args.tag}" if args.tag else "")
    result = {"machine": platform.platform(), "cpu_count": os.cpu_count(), "quick": args.quick,
              "load_average_start": os.getloadavg(), "glossy": {}}
    t_all = time.perf_counter()
    for scene in [s for s in args.scenes.split(",") if s]:
        result["glossy"][scene] = part_glossy(scene, args.quick, args.timed_frames, tuple(args.models.split(",")))
        (out_dir / f"{tag}.json").write_text(json.dumps(result, indent=1, default=str))
    if not args.skip_diffuse:
        result["diffuse"] = part_diffuse(args.quick, args.diffuse_as_written, not args.skip_walk, not args.skip_previous)
        (out_dir / f"{tag}.json").write_text(json.dumps(result, indent=1, default=str))
    if args.wanderer_diffuse:
        result["wanderer_diffuse"] = part_wanderer_diffuse(args.quick)
        (out_dir / f"{tag}.json").write_text(json.dumps(result, indent=1, default=str))
    if not args.skip_studies:
        rt = _spec("figure_visibility", args.quick, "linear").compile(device="cpu", progress=True)
        result["studies"] = part_studies(args.quick, rt)
    result["load_average_end"] = os.getloadavg()
    result["wall_s"] = time.perf_counter() - t_all
    (out_dir / f"{tag}.json").write_text(json.dumps(result, indent=1, default=str))
    _plot(result, out_dir / f"{tag}-models.png", out_dir / f"{tag}-studies.png", out_dir / f"{tag}-diffuse.png")
    print(json.dumps({s: {k: (v["rel_rms"], v["median_frame_s"]) for k, v in r.items()}
                      for s, r in result["glossy"].items()}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
