"""Data-driven PRT (Nowrouzezahrai et al. 2007): the paper's measurements on our characters.

For one character (its training clip and held-out test clips, :data:`CHARACTERS`), everything
through the same cached training data (``datadriven.data``: ray-traced transfer at every
training frame, order 6, 256 rays per vertex, world frame):

* transfer error (lighting independent: relative SH L2 over every vertex, and the paper's
  hemisphere-integrated per-vertex error of section 6, as a picture) on held-out test frames
  and on training frames (fresh rays), against transfer ray traced with 1024 rays;
* the residual distribution of the regularised full fit (mean, variance; paper Fig. 2) as a
  histogram and empirical CDF;
* training and test error with and without regularisation (paper Fig. 3), alpha chosen by LOO;
* error against retained variance in pose and coefficient space (paper Fig. 4) and the spectra;
* storage (paper Table 2): MB, % of the training data, % of one mesh's PRT (float32);
* runtime (paper Table 1): multiply-adds per frame, median time of the transfer stage and of
  the whole recorded frame (transfer + PRT shading), Hz; fitting and PCA time;
* pose parameterisations (rotvec, quaternion, matrix entries; root in or out) and the
  local-frame alternative (transfer fitted in per-vertex tangent frames, rotated back to world
  at each vertex), by held-out error;
* novelty score against error per frame (every test frame and the training frames).

Shading error against ray-traced ground truth (with LDPRT, SHEXP, per-frame ray tracing and
unshadowed in the same chart) is the harness's (``benchmarks/run.py``).

Writes ``datadriven-<character>-<date>-cpu[-quick].json`` and PNGs next to it in ``--out``.

Usage::

    python benchmarks/bench_datadriven.py [--character figure|wanderer] [--quick] [--out DIR]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

#: Smoke profile (tests/test_benchmarks.py): slow, kept out of the default suite (``-m "not slow"``):
#: 70 s: training trace, fit and coefficient PCA.
PROFILE = {"slow": True}

ROOT = Path(__file__).resolve().parent.parent

from warpshade._fileio import atomic_path, write_json_atomic  # noqa: E402
from warpshade._wp import wp  # noqa: E402
from warpshade.graph import GraphSpec, StageSpec  # noqa: E402
from warpshade.io import load_scene  # noqa: E402
from warpshade.measure import combine_metrics, error_metrics, ground_truth  # noqa: E402
from warpshade.measure import VALIDATE_SEED
from warpshade.methods.prt import shade_transfer_f64
from warpshade.scene import LightingSource  # noqa: E402
from warpshade.methods.datadriven import _model as dd  # noqa: E402
from warpshade.methods.datadriven import PARAMETERISATIONS, novelty, pose_features, pose_layout, pose_space
from warpshade.methods.datadriven import hemisphere_transfer_error
from warpshade.methods.datadriven._rows import TRAINING_CLIPS, stages_for  # noqa: E402
from warpshade.transfer import compute  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
#: character -> training clip, held-out test clips.
CHARACTERS = {
    "figure": {"training": "bundled:figure_train", "tests": ("bundled:figure", "bundled:figure_walk"),
               "validate": {"figure": (0.0, 30.0, 59.0), "figure_walk": (0.0, 48.0, 95.0)}},
    "wanderer": {"training": "bundled:wanderer_train", "tests": ("bundled:wanderer_test",),
                 "validate": {"wanderer_test": (0.0, 60.0, 119.0)}},
}
#: Ground truth of the shading errors: as `warpshade run stages/<graph> --validate` (cached).
GT_SAMPLES = 1024
#: Training frames per training clip (as in stages/*_datadriven.toml and the harness rows, so
#: the cached training data is shared).
TRAINING_FRAMES = {training: frames for training, frames in TRAINING_CLIPS.values()}
ORDER = 6
TRAIN_RAYS = 256
TRUTH_RAYS = 1024
TRUTH_SEED = 9001
#: The ``--quick`` smoke profile: training data on every 60th frame at 16 rays, 64-ray truths.
QUICK_DATA = {"frames": "::60", "samples": 16}
QUICK_RAYS = 64
#: The paper's numbers, quoted next to ours.
PAPER = {"residual_mean": 5.1e-5, "residual_variance": 3.25e-4, "pca": (8, 22), "storage_of_one_mesh_prt": 0.629,
         "hz": 105.0, "fit_minutes": 2.0}


def _graph(training: str, model: str, fit=None, data=None) -> GraphSpec:
    stages = list(stages_for(training, model, ORDER, TRAIN_RAYS, fit=fit, frames=TRAINING_FRAMES.get(training)))
    if data:
        n, t, p, i = stages[0]
        stages[0] = (n, t, {**p, **data}, i)
    return GraphSpec([StageSpec(n, t, dict(p), dict(i)) for (n, t, p, i) in stages], "shade.radiance", name="datadriven")


def _rel(a, b) -> float:
    return float(np.linalg.norm(np.asarray(a, np.float64) - b) / max(np.linalg.norm(b), 1e-300))


def _truth(scene, frames, progress=True, rays=TRUTH_RAYS):
    out = {}
    for f in frames:
        t0 = time.perf_counter()
        out[float(f)] = compute(scene, float(f), ORDER, rays, seed=TRUTH_SEED).transfer.astype(np.float64)
        if progress:
            print(f"    truth transfer {scene.source and Path(scene.source).name} frame {float(f):g}: {time.perf_counter() - t0:.1f} s",
                  flush=True)
    return out


def _poses(scene, frames, kind, root, reference):
    layout = pose_layout(scene, kind, root)
    return pose_features(scene, [scene.frame_index(f) for f in frames], layout, root_reference=reference)


def _select(data, kind, root):
    poses = np.asarray(data[f"poses_{kind}"], np.float64)
    return poses[:, np.asarray(data[f"root_{kind}"]) == 0] if root == "exclude" else poses


def _frames(scene, count):
    idx = np.unique(np.linspace(0, len(scene.frames) - 1, count).round().astype(int))
    return [float(scene.frames[i]) for i in idx]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--character", default="figure", choices=sorted(CHARACTERS))
    ap.add_argument("--quick", action="store_true",
                    help="smoke profile: every 60th training frame at 16 rays, one test clip and frame, 64-ray truths, "
                         "one sweep point and parameterisation")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    ap.add_argument("--replot", metavar="JSON", help="redraw the PCA chart of an earlier results JSON (next to it) without measuring")
    args = ap.parse_args(argv)
    if args.replot:
        src = Path(args.replot)
        old = json.loads(src.read_text())
        _plot_sweep(old["sweep"], old["spectra"], src.with_name(src.stem + "-pca.png"))
        return 0
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    wp.init()
    cfg = CHARACTERS[args.character]
    data_params = QUICK_DATA if args.quick else None
    gt_samples, truth_rays = (QUICK_RAYS, QUICK_RAYS) if args.quick else (GT_SAMPLES, TRUTH_RAYS)
    if args.quick:
        test_clip = cfg["tests"][0]
        clip = test_clip.split(":")[-1]
        cfg = {**cfg, "tests": (test_clip,), "validate": {clip: cfg["validate"][clip][:1]}}
    out_dir = Path(args.out or RESULTS)
    out_dir.mkdir(parents=True, exist_ok=True)
    stamp = datetime.date.today().isoformat()
    tag = f"datadriven-{args.character}-{stamp}-cpu" + ("-quick" if args.quick else "")
    tests = [load_scene(t) for t in cfg["tests"]]
    train_scene = load_scene(cfg["training"])
    result = {"character": args.character, "training": cfg["training"], "tests": list(cfg["tests"]), "order": ORDER,
              "train_rays": TRAIN_RAYS, "truth_rays": TRUTH_RAYS, "machine": platform.platform(),
              "cpu_count": os.cpu_count(), "paper": PAPER}

    # ---- training data and the chosen reduced model, through the graph (cached) ----------------
    t0 = time.perf_counter()
    rt = _graph(cfg["training"], "reduced", data=data_params).compile(tests[0], device="cpu", progress=True)
    result["graph_compile_s"] = time.perf_counter() - t0
    data = rt.artifacts["data"]["data"]
    fit_report = rt.stages[1].report
    result["fit_report"] = {k: v for k, v in fit_report.items() if k != "choice"}
    result["choice"] = fit_report.get("choice")
    B = np.asarray(data["transfer"])
    p, V, C = B.shape
    ref_rot = np.asarray(data["root_reference"])
    kind, root = "quaternion", "include"  # the fit stage's default (see the parameterisation study below)
    A = _select(data, kind, root)
    print(f"{args.character}: {p} training frames, {V} vertices, {C} coefficients, {A.shape[1]} pose features "
          f"({int(pose_space(A, False).active.sum())} vary)", flush=True)

    # ---- shading against ray-traced ground truth on the graphs' [validate] frames ---------------
    lights = {s.source: LightingSource.fixed(s.lights, s.up_axis) for s in tests}
    weights = dd.lighting_weights(lights[tests[0].source].sh(ORDER, float(tests[0].frames[0])), C)
    gt = {s.source: ground_truth(s, lights[s.source], cfg["validate"][Path(s.source).stem], gt_samples, "cpu", "default",
                                 None, VALIDATE_SEED, progress=True) for s in tests}

    def shading_error(model, kind=None, root=None, local=None):
        kind, root = kind or result_kind[0], root or result_kind[1]
        out = {}
        for s in tests:
            frames = cfg["validate"][Path(s.source).stem]
            pred = model.predict(_poses(s, frames, kind, root, ref_rot)) if model is not None else None
            per = []
            for i, f in enumerate(frames):
                t = local(s, f, pred[i]) if local is not None else pred[i]
                rad = shade_transfer_f64(t, lights[s.source].sh(ORDER, f), s.albedo)
                per.append(error_metrics(rad, gt[s.source][f]["radiance"], gt[s.source][f]["stderr"]))
            out[Path(s.source).stem] = combine_metrics(per)["rel_rms"]
        return out

    result_kind = (kind, root)
    traced = {}
    for s in tests:
        per = []
        for f in cfg["validate"][Path(s.source).stem]:
            t = compute(s, f, ORDER, truth_rays, seed=3).transfer
            rad = shade_transfer_f64(t, lights[s.source].sh(ORDER, f), s.albedo)
            per.append(error_metrics(rad, gt[s.source][f]["radiance"], gt[s.source][f]["stderr"]))
        traced[Path(s.source).stem] = combine_metrics(per)["rel_rms"]
    result["traced_n6_s1024_shading_error"] = traced
    result["band_weights"] = [float(weights[l * l]) for l in range(ORDER)]
    print(f"  per-frame ray-traced transfer (order 6, 1024 rays): shading error {traced}", flush=True)

    # ---- truth transfer on test and training frames ---------------------------------------------
    n_test = 2 if args.quick else 12
    test_frames = {s.source: _frames(s, n_test) for s in tests}
    truth = {s.source: _truth(s, test_frames[s.source], rays=truth_rays) for s in tests}
    train_idx = np.linspace(0, p - 1, 2 if args.quick else 8).round().astype(int)
    train_frames = [float(data["frames"][i]) for i in train_idx]
    truth_train = _truth(train_scene, train_frames, rays=truth_rays)

    def held_out_error(model, kind=kind, root=root):
        errs = {}
        for s in tests:
            P = _poses(s, test_frames[s.source], kind, root, ref_rot)
            pred = model.predict(P)
            errs[Path(s.source).stem] = [_rel(pred[i], truth[s.source][f]) for i, f in enumerate(test_frames[s.source])]
        return errs

    def train_error(model, kind=kind, root=root):
        P = _poses(train_scene, train_frames, kind, root, ref_rot)
        pred = model.predict(P)
        return [_rel(pred[i], truth_train[f]) for i, f in enumerate(train_frames)]

    # ---- full model: regularised (LOO) and not (paper Fig. 3) ------------------------------------
    t0 = time.perf_counter()
    full = dd.fit_full(A, B)
    full_fit_s = time.perf_counter() - t0
    ls = dd.fit_full(A, B, alpha=0.0)
    result["full"] = {"fit_s": full_fit_s, "alphas": full.alphas.tolist(), "loo_error": full.loo_error.tolist(),
                      "test_error": held_out_error(full), "train_error": train_error(full),
                      "unregularised_test_error": held_out_error(ls), "unregularised_train_error": train_error(ls),
                      "rank": full.info["rank"], "condition": full.info["condition"],
                      "shading_error": shading_error(full), "unregularised_shading_error": shading_error(ls)}
    print(f"  full model: fit {full_fit_s:.1f} s, test {np.mean(sum(result['full']['test_error'].values(), [])):.4f} "
          f"(alpha = 0: {np.mean(sum(result['full']['unregularised_test_error'].values(), [])):.4f})", flush=True)

    # ---- residuals of the regularised fit (paper Fig. 2) ----------------------------------------
    resid = (full.predict(A) - B).ravel()
    result["residuals"] = {"mean": float(resid.mean()), "variance": float(resid.var()), "median": float(np.median(resid)),
                           "count": int(resid.size), "coefficient_rms": float(np.sqrt(np.mean(B.astype(np.float64) ** 2)))}
    _plot_residuals(resid, out_dir / f"{tag}-residuals.png", result["residuals"])

    # ---- reduced models: the budget's choice, the paper's PCA(8,22), and the sweep (Fig. 4) -----
    t0 = time.perf_counter()
    basis = dd.coefficient_basis(B, 64 if args.quick else 512, weights=weights)
    pca_s = time.perf_counter() - t0
    space = pose_space(A, pca=True)
    result["spectra"] = {"pose_variance": (space.variance / space.total_variance).tolist(),
                         "coefficient_energy": (basis[1] ** 2 / basis[2]).tolist(), "pca_s": pca_s}
    ka_sweep = sorted({k for k in (1, 2, 4, 8, 16, 32) if k <= space.size} | {space.size})
    kv_sweep = [k for k in (8, 22, 48, 96, 192, 384) if k <= basis[0].shape[1]]
    if args.quick:
        ka_sweep, kv_sweep = ka_sweep[:1], kv_sweep[:1]
    sweep = {}
    for ka in ka_sweep:
        for kv in kv_sweep:
            m = dd.fit_reduced(A, B, ka, kv, basis=basis, weights=weights)
            sweep[f"{ka},{kv}"] = {"shading_error": shading_error(m), "ka": ka, "kv": kv, "pose_variance": m.info["pose_variance_retained"],
                                   "coefficient_energy": m.info["coefficient_energy_retained"],
                                   "test_error": float(np.mean(sum(held_out_error(m).values(), []))),
                                   "train_error": float(np.mean(train_error(m)))}
    result["sweep"] = sweep
    models = {"full": full}
    chosen = (fit_report["ka"], fit_report["kv"])
    for name, (ka, kv) in (("chosen", chosen), ("paper_pca_8_22", (8, 22))):
        t0 = time.perf_counter()
        m = dd.fit_reduced(A, B, ka, kv, basis=basis, weights=weights)
        models[name] = m
        result[name] = {"ka": m.info["ka"], "kv": m.info["kv"], "fit_s": time.perf_counter() - t0,
                        "test_error": held_out_error(m), "train_error": train_error(m), "shading_error": shading_error(m)}
        print(f"  {name} PCA({m.info['ka']},{m.info['kv']}): shading error {result[name]['shading_error']}", flush=True)
    _plot_sweep(sweep, result["spectra"], out_dir / f"{tag}-pca.png")
    _plot_regularisation(result, out_dir / f"{tag}-regularisation.png")

    # ---- storage (Table 2) and runtime (Table 1) -------------------------------------------------
    one_mesh = V * C
    storage = {}
    for name, m in models.items():
        floats = m.stored_floats()
        storage[name] = {"MB": 4 * floats / 2 ** 20, "of_training_data": floats / B.size, "of_one_mesh_prt": floats / one_mesh,
                         "flops_per_frame": m.flops_per_frame()}
    result["storage"] = storage
    sizes = {"chosen": chosen} if args.quick else {"chosen": chosen, "paper_pca_8_22": (8, 22)}
    result["runtime"] = _runtime(cfg["training"], tests[0], sizes, args.quick, data_params)
    result["fit_seconds"] = {"full": full_fit_s, "pca": pca_s, "chosen_total": fit_report.get("total_fit_s")}

    # ---- pose parameterisations and the local frame ----------------------------------------------
    params = {}
    for k in (kind,) if args.quick else PARAMETERISATIONS:
        for r in ("include",) if args.quick else ("include", "exclude"):
            Ak = _select(data, k, r)
            mf = dd.fit_full(Ak, B)
            mr = dd.fit_reduced(Ak, B, *chosen, basis=basis, weights=weights)
            params[f"{k}/{r}"] = {"features": int(Ak.shape[1]),
                                  "full": float(np.mean(sum(held_out_error(mf, k, r).values(), []))),
                                  "reduced": float(np.mean(sum(held_out_error(mr, k, r).values(), []))),
                                  "full_shading": shading_error(mf, k, r), "reduced_shading": shading_error(mr, k, r)}
            print(f"  pose {k:10s} root {r:7s}: transfer error full {params[f'{k}/{r}']['full']:.4f}, reduced "
                  f"{params[f'{k}/{r}']['reduced']:.4f}; shading full {params[f'{k}/{r}']['full_shading']}, reduced "
                  f"{params[f'{k}/{r}']['reduced_shading']}", flush=True)
    result["parameterisations"] = params
    if not args.quick:
        result["local_frame"] = _local_frame(train_scene, data, tests, test_frames, truth, A, ref_rot, shading_error)
        result["interreflection"] = _interreflection(cfg, tests[0], lights[tests[0].source], ref_rot, full)

    # ---- novelty against error, and the per-vertex transfer error picture -----------------------
    nov = []
    for s in tests + [train_scene]:
        frames = test_frames.get(s.source, train_frames)
        P = _poses(s, frames, kind, root, ref_rot)
        score = novelty(full.pose, P, A)["nearest"]
        pred = models["chosen"].predict(P)
        tr = truth.get(s.source, truth_train)
        for i, f in enumerate(frames):
            nov.append({"clip": Path(s.source).stem, "frame": f, "novelty": float(score[i]), "error": _rel(pred[i], tr[f])})
    result["novelty"] = nov
    _plot_novelty(nov, out_dir / f"{tag}-novelty.png")
    _transfer_error_picture(tests[0], test_frames[tests[0].source], truth[tests[0].source], models["chosen"], ref_rot,
                            out_dir / f"{tag}-transfer-error.png")
    path = write_json_atomic(out_dir / f"{tag}.json", result)
    print(f"wrote {path}")
    return 0


def _runtime(training, scene, sizes, quick, data=None) -> dict:
    """Median recorded frame and transfer-stage time, over the scene's frames (quick: every 10th),
    per model; ``data``: parameters of the training-data stage over the default ones."""
    out = {}
    frames = [float(f) for f in scene.frames[:: 10 if quick else 1]]
    for name, fit in (("full", {}), *((n, {"ka": ka, "kv": kv}) for n, (ka, kv) in sizes.items())):
        model = "full" if name == "full" else "reduced"
        rt = _graph(training, model, fit=fit, data=data).compile(scene, device="cpu", progress=False)
        rt.run(frames)
        rt.reset_timings()
        rt.run(frames * (1 if quick else 3))
        summary = rt.timing_summary()
        prof = rt.profile(frames)
        frame_s = summary["median_frame_s"]
        out[name] = {"frame_ms": 1e3 * frame_s, "hz": 1.0 / frame_s, "transfer_stage_ms": 1e3 * prof["transfer"],
                     "shade_stage_ms": 1e3 * prof["shade"], "scene_ms": 1e3 * prof["scene"],
                     "transfer_hz": 1.0 / prof["transfer"], "flops_per_frame": rt.stages[1].report["flops_per_frame"],
                     "captured": summary["captured"]}
        print(f"  runtime {name}: frame {1e3 * frame_s:.2f} ms ({1 / frame_s:.0f} Hz), transfer stage {1e3 * prof['transfer']:.2f} ms",
              flush=True)
    return out


def _local_frame(train_scene, world_data, tests, test_frames, truth, A_world, ref_rot, shading_error) -> dict:
    """Fit the transfer in per-vertex tangent frames (the same training frames and seeds as the
    world-frame data), rotate predictions back to world per vertex."""
    from warpshade.basis import sh
    from warpshade.geometry._frames import TangentFrames, tangent_frames_f64
    from warpshade.methods._shared.training import trace_training

    seed = int(np.asarray(world_data["settings"]).reshape(-1)[4])
    B = trace_training(train_scene, np.asarray(world_data["frame_indices"]), ORDER, TRAIN_RAYS, seed=seed, space="local",
                       progress=True)
    m = dd.fit_full(A_world, B)
    errs = {}
    for s in tests:
        frames = test_frames[s.source]
        P = _poses(s, frames, "quaternion", "include", ref_rot)
        pred = m.predict(P)
        rule = TangentFrames.from_scene(s, device="cpu").rule
        e = []
        for i, f in enumerate(frames):
            # rows (t, b, n) map world to local: the world function is the local one carried by F^T
            frames_v = tangent_frames_f64(s.points_at(f), s.normals_at(f), rule)
            world = sh.rotate(pred[i], np.transpose(frames_v, (0, 2, 1)))
            e.append(_rel(world, truth[s.source][f]))
        errs[Path(s.source).stem] = e
    rules = {s.source: TangentFrames.from_scene(s, device="cpu").rule for s in tests}

    def to_world(scene, f, t):
        frames_v = tangent_frames_f64(scene.points_at(f), scene.normals_at(f), rules[scene.source])
        return sh.rotate(t, np.transpose(frames_v, (0, 2, 1)))

    shading = shading_error(m, "quaternion", "include", local=to_world)
    print(f"  local frame (full model): transfer error {np.mean(sum(errs.values(), [])):.4f}, shading {shading}", flush=True)
    return {"test_error": errs, "mean": float(np.mean(sum(errs.values(), []))), "shading_error": shading}


def _interreflection(cfg, scene, lighting, ref_rot, direct_model, bounces: int = 1) -> dict:
    """The model trained on transfer with ``bounces`` diffuse bounces (per channel), against the
    reference with the same bounces; the direct-only model against the same reference shows
    what the bounces add."""
    spec = _graph(cfg["training"], "full", data={"bounces": bounces})
    spec.stages[2] = StageSpec("transfer", "datadriven.transfer", {"order": ORDER, "color": True}, {"model": "fit.model"})
    spec.stages[3] = StageSpec("shade", "prt.shade", {"order": ORDER, "color": True, "bounces": bounces},
                               {"transfer_rgb": "transfer.transfer_rgb"})
    rt = spec.compile(scene, device="cpu", progress=True)
    data = rt.artifacts["data"]["data"]
    B = np.asarray(data["transfer"])
    A = _select(data, "quaternion", "include")
    m = dd.fit_full(A, B)
    frames = cfg["validate"][Path(scene.source).stem]
    gt = ground_truth(scene, lighting, frames, GT_SAMPLES, "cpu", "default", {"bounces": bounces}, VALIDATE_SEED, progress=True)
    P = _poses(scene, frames, "quaternion", "include", ref_rot)
    pred = m.predict(P).reshape(len(frames), scene.vertex_count, 3, ORDER * ORDER)
    direct = direct_model.predict(P)
    per, per_direct = [], []
    for i, f in enumerate(frames):
        light = lighting.sh(ORDER, f)
        per.append(error_metrics(shade_transfer_f64(pred[i], light, scene.albedo), gt[f]["radiance"], gt[f]["stderr"]))
        per_direct.append(error_metrics(shade_transfer_f64(direct[i], light, scene.albedo), gt[f]["radiance"],
                                        gt[f]["stderr"]))
    out = {"bounces": bounces, "shading_error": combine_metrics(per)["rel_rms"],
           "direct_model_vs_bounced_reference": combine_metrics(per_direct)["rel_rms"],
           "training_s": rt.timings["data"].precompute_s}
    print(f"  {bounces} bounce(s): model {out['shading_error']:.4f} vs the {bounces}-bounce reference "
          f"(direct-only model: {out['direct_model_vs_bounced_reference']:.4f})", flush=True)
    return out


# ---- pictures ------------------------------------------------------------------------------------
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path):
    plt = _plt()
    try:
        with atomic_path(Path(path)) as tmp:
            fig.savefig(tmp, format="png", dpi=110)
    finally:
        plt.close(fig)
    print(f"wrote {path}")


def _plot_residuals(resid, path, stats):
    plt = _plt()
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    lim = np.percentile(np.abs(resid), 99.5)
    a.hist(resid, bins=200, range=(-lim, lim), density=True, color="#3465a4")
    a.set_title(f"signed residuals of the regularised fit\nmean {stats['mean']:.2e}, variance {stats['variance']:.2e} "
                f"(paper {PAPER['residual_mean']:.1e}, {PAPER['residual_variance']:.2e})", fontsize=9)
    a.set_xlabel("residual (SH transfer coefficient)")
    sub = np.sort(resid[:: max(1, resid.size // 200000)])
    b.plot(sub, np.linspace(0, 1, sub.size), color="#cc0000")
    b.set_xlim(-lim, lim)
    b.set_title("empirical CDF", fontsize=9)
    b.grid(alpha=0.3)
    _save(fig, path)


def _plot_regularisation(result, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    full = result["full"]
    for key, label, style in (("test_error", "test, alpha by LOO", "-o"), ("unregularised_test_error", "test, alpha = 0", "--o")):
        for clip, errs in full[key].items():
            ax.plot(errs, style, label=f"{clip}: {label}", ms=3)
    ax.plot(full["train_error"], "-s", label="training frames, alpha by LOO", ms=3)
    ax.plot(full["unregularised_train_error"], "--s", label="training frames, alpha = 0", ms=3)
    ax.set_xlabel("frame (evenly spaced over each clip)")
    ax.set_ylabel("relative transfer error")
    ax.set_title("full linear model with and without regularisation (cf. paper Fig. 3)", fontsize=9)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    _save(fig, path)


def _plot_sweep(sweep, spectra, path):
    plt = _plt()
    fig, (a, b, c) = plt.subplots(1, 3, figsize=(15, 4.4), layout="constrained")
    pv = np.cumsum(spectra["pose_variance"])
    ce = np.cumsum(spectra["coefficient_energy"])
    a.plot(np.arange(1, pv.size + 1), pv, "-o", ms=3, label="pose (variance)")
    a.plot(np.arange(1, ce.size + 1), ce, "-", label="vertex coefficients (energy)")
    a.set_xscale("log")
    a.set_xlabel("components")
    a.set_ylabel("fraction retained")
    a.legend(fontsize=8)
    a.grid(alpha=0.3)
    a.set_title("PCA spectra (cf. paper Fig. 4)", fontsize=9)
    rows = list(sweep.values())

    def shading(r):
        return float(np.sqrt(np.mean(np.square(list(r["shading_error"].values())))))

    for ka in sorted({r["ka"] for r in rows}):
        sel = sorted((r for r in rows if r["ka"] == ka), key=lambda r: r["kv"])
        b.plot([1.0 - r["coefficient_energy"] for r in sel], [shading(r) for r in sel], "-o", ms=3, label=f"ka = {ka}")
    b.set_xscale("log")
    b.xaxis.set_minor_formatter(plt.NullFormatter())
    b.invert_xaxis()
    b.set_xlabel("coefficient energy (lighting-weighted) left out by kv")
    b.set_ylabel("held-out shading error (relative RMS)")
    b.legend(fontsize=7)
    b.grid(alpha=0.3)
    for kv in sorted({r["kv"] for r in rows}):
        sel = sorted((r for r in rows if r["kv"] == kv), key=lambda r: r["ka"])
        c.plot([r["pose_variance"] for r in sel], [shading(r) for r in sel], "-o", ms=3, label=f"kv = {kv}")
    c.set_xlabel("pose variance retained (ka)")
    c.set_ylabel("held-out shading error (relative RMS)")
    c.legend(fontsize=7)
    c.grid(alpha=0.3)
    _save(fig, path)


def _plot_novelty(rows, path):
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    for clip in sorted({r["clip"] for r in rows}):
        sel = [r for r in rows if r["clip"] == clip]
        ax.plot([r["novelty"] for r in sel], [r["error"] for r in sel], "o", ms=4, label=clip)
    ax.set_xlabel("novelty (RMS standardised distance to the nearest training pose)")
    ax.set_ylabel("relative transfer error (chosen reduced model)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    _save(fig, path)


def _transfer_error_picture(scene, frames, truth, model, ref_rot, path):
    """Per-vertex hemisphere-integrated transfer error (paper section 6) on a held-out frame."""
    from warpshade.render import render

    f = frames[len(frames) // 2]
    pred = model.predict(_poses(scene, [f], "quaternion", "include", ref_rot))[0]
    normals = scene.normals_at(f)
    err = hemisphere_transfer_error(pred, truth[f], normals)
    scale = hemisphere_transfer_error(np.zeros_like(truth[f]), truth[f], normals)
    rel = np.sqrt(err / max(float(np.mean(scale)), 1e-300))
    import matplotlib

    limit = 0.5
    t = np.clip(rel / limit, 0.0, 1.0)
    colors = matplotlib.colormaps["magma"](t)[:, :3] ** 2.2  # linear RGB; the renderer encodes sRGB
    image = render(scene, f, colors=colors.astype(np.float32), width=480, height=360, supersample=2).image
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.2, 4.2))
    ax.imshow(image)
    ax.set_axis_off()
    ax.set_title(f"{Path(scene.source).stem} frame {f:g}: per-vertex transfer error (paper sec. 6)\n"
                 f"sqrt(E_transfer / mean E_simulated), median {np.median(rel):.3f}, p95 {np.percentile(rel, 95):.3f}", fontsize=8)
    fig.colorbar(plt.cm.ScalarMappable(norm=matplotlib.colors.Normalize(0, limit), cmap="magma"), ax=ax, shrink=0.8)
    _save(fig, path)


if __name__ == "__main__":
    sys.exit(main())
