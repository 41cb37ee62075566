"""SHEXP (Ren et al. 2006) measured: speed ratios, per-frame cost, errors, error budget.

Parts (``--parts``, default all), each measured side by side in one run:

* ``speed`` -- the paper's Figure 8 configuration: 200 x 200 ground receivers and 60 blocker
  spheres (no hierarchy); time per frame of log-space accumulation (PS*-2 as in the paper, and
  HYB) against product accumulation (Zhou et al. 2005) at n = 3, 4, 5, 6, and the ratios (paper,
  CPU: 1.9x, 3.4x, 6.5x, 11.0x). Repeats are interleaved across configurations and the median
  is kept. The 60 spheres are the sphere set of the bundled figure when the sphere module can
  build it, else a procedural 60-sphere figure (recorded in the JSON).
* ``battle`` -- the paper's battle-scene scale: about 65k receivers, 244 leaf spheres, about 47
  spheres accumulated per receiver (a synthesised scene: a 256 x 256 ground grid under four
  61-sphere figures, 256 receiver clusters whose lists are the 47 spheres nearest to the
  cluster, with ratio weights), n = 4, HYB: time per frame on the CPU. (The paper's GPU number
  needs CUDA, which this machine does not have.)
* ``exp`` -- the exp methods on the accumulated logs of the speed scene: error against the
  infinite product series exp* (eq. 28) and against the projection of exp(f(s)) (eq. 10),
  squarings per receiver, and kernel time.
* ``scenes`` -- error against ray-traced ground truth on the bundled scenes (blockers, figure,
  bunny and bear over a ground plane) for n = 3..6, every exp method, flat vs hierarchy, and the
  three error sources of the paper's Figure 7: sphere approximation (ray traced against the
  spheres vs against the mesh), product truncation (SH product accumulation vs ray traced
  spheres with the same SH lighting) and log space (SHEXP vs product accumulation).
* ``shading`` -- the three shading paths (direct: one SH product per receiver; the L*H(N)
  lat-long table over normals, rebuilt per frame; the product-matrix path (M_L g).H(N)) on
  41k receivers with varied normals: time per frame and difference from direct.
* ``budget`` -- the error budget (:func:`warpshade.measure._budget.choose` over
  :func:`warpshade.methods.shexp._budget.candidates`) on two bundled scenes: the cheapest
  setting (order, sphere budget, exp method) for each of the targets 0.1, 0.15, 0.2 and 0.25.
* ``compile`` -- cold compile time of the per-order receiver kernels (subprocess, empty cache).
* ``ratio`` -- what the per-band ratio vectors of hierarchy cuts fix (eq. 37, the seams of the
  paper's Fig. 6b/c): on the blockers scene, n = 4 HYB, the flat sphere list, the hierarchy with
  ratio vectors and the hierarchy without them, against ray-traced ground truth: relative RMS,
  99th percentile and the *seam* error (RMS over mesh edges of the difference of the two
  endpoints' errors, relative to the RMS radiance: a cut boundary between neighbouring receivers
  shows up there and not in smooth error), with a PNG of the errors.
* ``spherelights`` -- SHEXP with sphere lights (shadowed per receiver like the environment) on
  the blockers scene: one and four sphere lights added above the blockers, error against
  ray-traced ground truth with the same lights, and time per frame against no sphere light.

Usage::

    python benchmarks/bench_shexp.py [--parts speed,battle,exp] [--quick] [--repeats 7] [--out DIR]

Writes ``benchmarks/results/shexp-<date>-cpu.json`` (atomically) and a PNG of the speed ratios.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

#: Smoke profile (tests/test_benchmarks.py): slow, kept out of the default suite (``-m "not slow"``):
#: 59 s: SHEXP tables and sphere blockers per order.
PROFILE = {"slow": True}

ROOT = Path(__file__).resolve().parent.parent

from warpshade._fileio import atomic_path, write_json_atomic  # noqa: E402
from warpshade._wp import wp  # noqa: E402
from warpshade.basis import sh  # noqa: E402
from warpshade.methods.shexp import _pipeline as pipeline  # noqa: E402

RESULTS_DIR = ROOT / "benchmarks" / "results"
PAPER_SPEEDUP = {3: 1.9, 4: 3.4, 5: 6.5, 6: 11.0}
PAPER_BATTLE = {"receivers": 65_000, "leaf_spheres": 244, "spheres_per_receiver": 47, "gpu_hz_mean": 26.2}


def ground_grid(resolution: int, size: float):
    g = np.linspace(-0.5 * size, 0.5 * size, resolution)
    x, y = np.meshgrid(g, g)
    pts = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    return pts, np.tile([0.0, 0.0, 1.0], (pts.shape[0], 1))


def procedural_figure(count: int = 60, origin=(0.0, 0.0), seed: int = 0):
    """``count`` spheres along the limbs of a standing 1.9 m figure (legs, torso, arms, head)."""
    rng = np.random.default_rng(seed)
    ox, oy = origin
    limbs = [  # (start, end, radius)
        ((-0.12, 0, 0.05), (-0.12, 0, 0.9), 0.08), ((0.12, 0, 0.05), (0.12, 0, 0.9), 0.08),
        ((0, 0, 0.95), (0, 0, 1.5), 0.16), ((-0.2, 0, 1.45), (-0.55, -0.25, 1.0), 0.06),
        ((0.2, 0, 1.45), (0.55, -0.25, 1.0), 0.06), ((0, 0, 1.62), (0, 0, 1.8), 0.11),
    ]
    weights = np.array([0.2, 0.2, 0.25, 0.13, 0.13, 0.09])
    per = np.maximum(1, np.round(weights / weights.sum() * count).astype(int))
    per[2] += count - per.sum()
    centres, radii = [], []
    for (a, b, r), k in zip(limbs, per):
        t = np.linspace(0.0, 1.0, k)
        c = np.asarray(a) + t[:, None] * (np.asarray(b) - np.asarray(a))
        centres.append(c + rng.normal(scale=0.01, size=c.shape))
        radii.append(np.full(k, r) * rng.uniform(0.9, 1.1, k))
    c = np.concatenate(centres)
    c[:, 0] += ox
    c[:, 1] += oy
    return c, np.concatenate(radii)


def sky_light(order: int) -> np.ndarray:
    from warpshade.scene import Environment

    return Environment.sky().to_sh(order)


def interleaved_medians(fns: dict, repeats: int) -> dict:
    times = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    return {k: statistics.median(v) for k, v in times.items()}


def _shader(order, points, normals, centres, radii, light, **options):
    s = pipeline.ShexpShader(order, points.shape[0], centres.shape[0], device="cpu", **options)
    s.bind_receivers(points, normals, np.full((points.shape[0], 3), 0.8))
    s.set_flat_cut()
    s.upload_spheres(centres, radii)
    s.upload_lighting(light)
    return s


def figure_spheres(count: int = 60, procedural: bool = False):
    """Leaf spheres of the bundled figure at its first frame (sphere module), or procedural
    (always with ``procedural``: the ``--quick`` profile skips the sphere fit)."""
    if procedural:
        c, r = procedural_figure(count)
        return c, r, f"procedural {count}-sphere figure (--quick)"
    try:
        from warpshade.io import load_scene
        from warpshade.methods.shexp._model import build_blocker_model

        scene = load_scene("bundled:figure")
        spheres = build_blocker_model(scene, count, calibrate=False).spheres
        f0 = float(scene.frames[0])
        return spheres.centres_at(scene, f0), spheres.radii_at(scene, f0), "figure.usda sphere set (warpshade.methods.shexp._spheres)"
    except Exception as exc:  # the sphere module is optional here: say which spheres were used
        c, r = procedural_figure(count)
        return c, r, f"procedural 60-sphere figure ({type(exc).__name__}: {exc})"


def part_speed(args) -> dict:
    res = 32 if args.quick else 200
    points, normals = ground_grid(res, 6.0)
    centres, radii, source = figure_spheres(60, procedural=args.quick)
    out = {"receivers": int(points.shape[0]), "spheres": int(radii.shape[0]), "spheres_source": source, "orders": {}}
    for order in args.orders:
        light = sky_light(order)
        configs = {
            "log_ps_star2": dict(method="ps_star", degree=2),
            "log_hyb": dict(method="hyb"),
            "log_ol": dict(method="ol"),
            "product": dict(accumulate="product"),
        }
        shaders = {k: _shader(order, points, normals, centres, radii, light, **v) for k, v in configs.items()}
        for s in shaders.values():
            s.launch()  # compile + warm up
        med = interleaved_medians({k: s.launch for k, s in shaders.items()}, args.repeats)
        row = {f"{k}_ms": 1e3 * v for k, v in med.items()}
        row["ratio_product_over_ps_star2"] = med["product"] / med["log_ps_star2"]
        row["ratio_product_over_hyb"] = med["product"] / med["log_hyb"]
        row["paper_ratio"] = PAPER_SPEEDUP.get(order)
        out["orders"][str(order)] = row
        print(f"  speed n={order}: " + ", ".join(f"{k} {v:.1f}" for k, v in row.items() if k.endswith("_ms"))
              + f" ms; product/PS*-2 {row['ratio_product_over_ps_star2']:.1f}x (paper {row['paper_ratio']}x), "
              f"product/HYB {row['ratio_product_over_hyb']:.1f}x", flush=True)
    return out


def part_battle(args) -> dict:
    res = 32 if args.quick else 256
    points, normals = ground_grid(res, 20.0)
    figures = [procedural_figure(61, origin, seed=k) for k, origin in enumerate([(-4, -3), (3, -2), (-1, 4), (5, 5)])]
    centres = np.concatenate([f[0] for f in figures])
    radii = np.concatenate([f[1] for f in figures]) * 1.5  # bigger characters (troll, wizard)
    per_receiver = 47
    side = 16
    clusters = side * side
    cell = (np.clip(((points[:, :2] + 10.0) / 20.0 * side).astype(int), 0, side - 1))
    cluster = cell[:, 0] * side + cell[:, 1]
    centres_xy = (np.stack(np.meshgrid(np.arange(side), np.arange(side), indexing="ij"), -1).reshape(-1, 2) + 0.5) / side * 20 - 10
    cut = np.argsort(np.linalg.norm(centres[None, :, :2] - centres_xy[:, None, :], axis=2), axis=1)[:, :per_receiver]
    order = 4
    s = pipeline.ShexpShader(order, points.shape[0], centres.shape[0], clusters=clusters, cut_capacity=per_receiver,
                             method="hyb", device="cpu")
    s.bind_receivers(points, normals, np.full((points.shape[0], 3), 0.8))
    s.set_receiver_clusters(cluster)
    s.upload_spheres(centres, radii)
    dev = s.device
    weights = np.ones((clusters, per_receiver, order), np.float32)
    s.bind_cut(wp.array(cut.astype(np.int32), dtype=wp.int32, device=dev),
               wp.array(np.full(clusters, per_receiver, np.int32), dtype=wp.int32, device=dev),
               wp.array(weights, dtype=wp.float32, device=dev))
    s.upload_lighting(sky_light(order))
    s.launch()
    med = interleaved_medians({"frame": s.launch}, args.repeats)
    out = {
        "receivers": int(points.shape[0]), "leaf_spheres": int(centres.shape[0]), "spheres_per_receiver": per_receiver,
        "clusters": clusters, "order": order, "method": "hyb", "shade": "direct",
        "cpu_frame_ms": 1e3 * med["frame"], "cpu_hz": 1.0 / med["frame"], "cpu_workers": s.workers,
        "paper": PAPER_BATTLE, "cuda": "not measured: no CUDA device on this machine",
    }
    print(f"  battle: {out['receivers']} receivers x {per_receiver} spheres, n=4 HYB: {out['cpu_frame_ms']:.1f} ms/frame "
          f"on the CPU ({out['cpu_hz']:.1f} Hz; paper GPU mean {PAPER_BATTLE['gpu_hz_mean']} Hz)", flush=True)
    return out


def part_exp(args) -> dict:
    from warpshade.methods.shexp import _mirror as mirror

    res = 40
    points, normals = ground_grid(res, 6.0)
    centres, radii, source = figure_spheres(60, procedural=args.quick)
    out = {"receivers": int(points.shape[0]), "spheres_source": source, "orders": {}}
    for order in args.orders:
        f = mirror.log_visibility(points, normals, centres, radii, order)
        fhat = f.copy()
        fhat[:, 0] = 0.0
        norms = np.linalg.norm(fhat, axis=1)
        limit = sh.exp_series_limit(f)
        volterra = sh.exp_volterra(f)
        light = sky_light(order)
        rows = {}
        for name, method, degree in (("PS-10", "ps", 10), ("PS-21", "ps", 21), ("PS*-2", "ps_star", 2), ("PS*-4", "ps_star", 4),
                                     ("OL", "ol", None), ("HYB", "hyb", None)):
            g = sh.exp(f, method, degree)
            shaded = mirror.shade(g, normals, light, np.ones((len(points), 3)))
            shaded_ref = mirror.shade(limit, normals, light, np.ones((len(points), 3)))
            scale = np.sqrt(np.mean(shaded_ref**2))
            rows[name] = {
                "rel_err_vs_series_limit": float(np.median(np.linalg.norm(g - limit, axis=1) / np.linalg.norm(limit, axis=1))),
                "rel_err_vs_volterra": float(np.median(np.linalg.norm(g - volterra, axis=1) / np.linalg.norm(volterra, axis=1))),
                "radiance_rel_rms_vs_series_limit": float(np.sqrt(np.mean((shaded - shaded_ref) ** 2)) / scale),
            }
        squarings = sh._shexp.scaling_power(norms)
        out["orders"][str(order)] = {"methods": rows, "fhat_norm_median": float(np.median(norms)), "fhat_norm_max": float(norms.max()),
                                     "squarings_mean": float(squarings.mean())}
        print(f"  exp n={order}: ||f^|| median {np.median(norms):.2f} max {norms.max():.2f}; " + "; ".join(
            f"{k} {v['radiance_rel_rms_vs_series_limit']:.2e}" for k, v in rows.items()), flush=True)
    return out


def part_shading(args) -> dict:
    """Shading paths side by side: direct (one SH product), the L*H(N) table, (M_L g).H(N)."""
    import trimesh

    ico = trimesh.creation.icosphere(subdivisions=2 if args.quick else 6, radius=2.0)
    points = np.asarray(ico.vertices, np.float64)
    normals = points / np.linalg.norm(points, axis=1, keepdims=True)
    rng = np.random.default_rng(4)
    dirs = rng.normal(size=(60, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    centres = dirs * rng.uniform(2.4, 3.2, (60, 1))
    radii = rng.uniform(0.15, 0.35, 60)
    out = {"receivers": int(points.shape[0]), "spheres": 60, "orders": {}}
    for order in args.orders:
        light = sky_light(order)
        shaders = {mode: _shader(order, points, normals, centres, radii, light, shade=mode) for mode in ("direct", "table", "product_matrix")}
        for s in shaders.values():
            s.launch()
        med = interleaved_medians({k: s.launch for k, s in shaders.items()}, args.repeats)
        direct = shaders["direct"].radiance.numpy()
        scale = float(np.abs(direct).max())
        row = {}
        for mode, s in shaders.items():
            diff = np.abs(s.radiance.numpy() - direct)
            row[mode] = {"ms": 1e3 * med[mode], "max_rel_diff_vs_direct": float(diff.max() / scale),
                         "rms_rel_diff_vs_direct": float(np.sqrt(np.mean(diff**2)) / scale)}
        out["orders"][str(order)] = row
        print(f"  shading n={order}: " + "; ".join(f"{m} {v['ms']:.1f} ms (max diff {v['max_rel_diff_vs_direct']:.1e})" for m, v in row.items()),
              flush=True)
    return out


# ---- errors against ray-traced ground truth on the bundled scenes (paper Fig. 7) --------------

#: Scenes of ``--parts scenes`` and the leaf-sphere budget of their tables.
SCENE_BUDGETS = {"blockers": 16, "figure": 48, "bunny": 32, "bear": 32}
#: Exp methods compared in ``--parts scenes`` (method, series degree).
SCENE_METHODS = (("hyb", None), ("ps_star", 2), ("ol", None), ("ps", 10))
#: Seed of the rays traced against the blocker spheres.
SPHERE_TRACE_SEED = 7


def _rel(a: dict, b: dict) -> float:
    """Relative RMS of ``a`` against ``b`` pooled over frames (both {frame: (V, 3)})."""
    num = np.mean([np.mean((np.asarray(a[f], np.float64) - b[f]) ** 2) for f in b])
    den = np.mean([np.mean(np.asarray(b[f], np.float64) ** 2) for f in b])
    return float(np.sqrt(num / den))


def sphere_trace_errors(scene, lighting, frames, budget: int, orders, samples: int = 1024, device="cpu") -> dict:
    """Radiance of ray tracing against the blocker spheres, with the environment and with SH lighting.

    Returns ``{"env": {frame: (V, 3)}, "sh": {order: {frame: (V, 3)}}}``: the same traced rays
    give the environment integral and the cosine-weighted visibility transfer, shaded with each
    order's SH lighting. The blocker spheres are the ``shexp.blockers`` artifact of ``budget``
    (the one the SHEXP rows use), animated per frame by :class:`BlockerFrames` from the
    frame's state.
    """
    from warpshade.measure import run_setting
    from warpshade.methods.shexp._model import BlockerFrames, BlockerModel
    from warpshade.methods.shexp._pipeline import ShexpShader, SphereTracer
    from warpshade.scene import FrameEvaluator

    res = run_setting(scene, lighting, [("blockers", "shexp.blockers", {"budget": budget}, {}),
                                        ("trace", "shexp.sphere_trace", {"samples": 4}, {})],
                      frames[:1], output="trace.radiance", device=device, name="shexp-blockers", profile=False)
    model = BlockerModel.from_arrays(res["runtime"].artifacts["blockers"]["model"])
    evaluator = FrameEvaluator(scene, device, lighting=lighting)
    state = evaluator.state
    shader = ShexpShader(max(orders), scene.vertex_count, model.node_count, device=device)
    blockers = BlockerFrames(scene, model, 2, ratio=False, device=device)
    shader.bind_receivers(state.points, state.normals, evaluator.albedo)
    blockers.bind(shader)
    # the environment turns with the frame: the tracer reads its rotation from the state
    tracer = SphereTracer(shader, state.lighting.environment_map(0), samples, seed=SPHERE_TRACE_SEED)
    env_out, sh_out = {}, {o: {} for o in orders}
    for f in frames:
        evaluator.evaluate(f)
        blockers.launch(state)
        tracer.launch()
        env_out[float(f)] = tracer.radiance.numpy().astype(np.float64).copy()
        t_full = tracer.transfer.numpy().astype(np.float64)
        for o in orders:
            rgb = t_full[:, : o * o] @ lighting.sh(o, f).T
            sh_out[o][float(f)] = scene.albedo / np.pi * np.maximum(rgb, 0.0)
    return {"env": env_out, "sh": sh_out}


def scene_errors(quick: bool = False, orders=(3, 4, 5, 6), scenes=None, gt_samples: int | None = None, device="cpu") -> dict:
    """The error table of ``--parts scenes``: n = 3..6, every exp method, flat vs hierarchy,
    product accumulation, and ray tracing against the spheres with the environment and with the
    order-n SH lighting, which separates sphere approximation, lighting band limit, product
    truncation and log space (the paper's Figure 7)."""
    from warpshade.measure import error_frames, ground_truth, load_bench_scene, run_setting, setting_error
    from warpshade.methods.shexp import graph_stages

    keys = list(scenes or (("blockers",) if quick else tuple(SCENE_BUDGETS)))
    gt_samples = gt_samples or (64 if quick else 2048)
    out = {}
    for key in keys:
        t0 = time.perf_counter()
        scene, lighting = load_bench_scene(key)
        frames = error_frames(scene, 1 if quick else 2)
        gt = ground_truth(scene, lighting, frames, gt_samples, device)
        gt_rad = {f: v["radiance"] for f, v in gt.items()}
        budget = 4 if quick else SCENE_BUDGETS[key]
        rows = []

        def record(label, stages, output="shade.radiance", **facts):
            res = run_setting(scene, lighting, stages, frames, output, device=device, name=f"shexp-{label}".replace(" ", "-"))
            err = setting_error(res["radiance"], gt)
            stage_ms = res["stage_ms"].get("shade")
            row = {"label": label, **facts, "rel_rms": err["rel_rms"], "rel_rms_debiased": err.get("rel_rms_debiased"),
                   "rel_p99": err["rel_p99"], "noise_rel_rms": err.get("noise_rel_rms"), "stage_ms": stage_ms,
                   "fallbacks": int(res["diagnostics"].get("shade", {}).get("fallbacks", 0))}
            rows.append(row)
            print(f"    {key:9s} {label:26s} rel RMS {row['rel_rms']:.4f}  shade {stage_ms or 0:.2f} ms", flush=True)
            return res["radiance"]

        shexp, product = {}, {}
        for order in orders:
            record(f"unshadowed n{order}", (("shade", "prt.unshadowed", {"order": order}, {}),), order=order, kind="unshadowed")
            for method, degree in (SCENE_METHODS if (order == 4 or not quick) else SCENE_METHODS[:1]):
                name = {"hyb": "HYB", "ps_star": f"PS*-{degree}", "ol": "OL", "ps": f"PS-{degree}"}[method]
                rad = record(f"SHEXP n{order} {name}", graph_stages(order, method, budget, degree=degree), order=order,
                             method=method, degree=degree, kind="shexp", hierarchy=False, budget=budget)
                if method == "hyb":
                    shexp[order] = rad
            product[order] = record(f"product n{order}", graph_stages(order, budget=budget, accumulate="product"), order=order,
                                    kind="product", budget=budget)
        record("SHEXP n4 HYB tree", graph_stages(4, "hyb", budget, hierarchy=True), order=4, method="hyb", kind="shexp",
               hierarchy=True, budget=budget)
        traced = sphere_trace_errors(scene, lighting, frames, budget, orders, samples=64 if quick else 2048, device=device)
        sources = {}
        for order in orders:
            sources[str(order)] = {
                "sphere_approximation": _rel(traced["env"], gt_rad),
                "lighting_band_limit": _rel(traced["sh"][order], traced["env"]),
                "product_truncation": _rel(product[order], traced["sh"][order]),
                "log_space": _rel(shexp[order], product[order]),
                "shexp_vs_truth": _rel(shexp[order], gt_rad),
                "product_vs_truth": _rel(product[order], gt_rad),
                "traced_spheres_sh_vs_truth": _rel(traced["sh"][order], gt_rad),
            }
            s = sources[str(order)]
            print(f"    {key:9s} n{order} error sources: spheres {s['sphere_approximation']:.4f}, SH lighting "
                  f"{s['lighting_band_limit']:.4f}, product truncation {s['product_truncation']:.4f}, log space "
                  f"{s['log_space']:.4f}", flush=True)
        out[key] = {"vertex_count": scene.vertex_count, "frames": [float(f) for f in frames], "gt_samples": gt_samples,
                    "leaf_spheres": budget, "rows": rows, "error_sources": sources, "seconds": time.perf_counter() - t0}
    return out


def part_scenes(args) -> dict:
    return scene_errors(quick=args.quick, orders=args.orders)


# ---- error budget: the setting chosen per target -------------------------------------------

#: Targets (relative RMS) and scenes of ``--parts budget``: the candidates are measured once per
#: scene, and the choice for each target is read off them.
BUDGET_TARGETS = (0.1, 0.15, 0.2, 0.25)
BUDGET_SCENES = ("blockers", "figure")


def _candidate_row(c) -> dict:
    """One measured candidate as a flat row (order, sphere budget, exp method, error, time)."""
    return {"order": c.facts["order"], "spheres": c.facts["spheres"], "method": c.facts["method"], "rel_rms": c.rel_rms,
            "stage_ms": c.stage_ms, "leaf_spheres": int(c.facts.get("leaf_spheres", 0)),
            "fallbacks": int(c.diagnostics.get("shade", {}).get("fallbacks", 0)), "meets_target": c.meets_target}


def budget_report(quick: bool = False, targets=BUDGET_TARGETS, scenes=BUDGET_SCENES, device="cpu") -> dict:
    """:func:`warpshade.measure._budget.choose` over SHEXP's candidates on two bundled scenes,
    and the choice read off the same measurements for each target."""
    from warpshade.measure import choose, load_bench_scene, pick
    from warpshade.methods.shexp import _budget as budget

    out = {"targets": list(targets), "scenes": {}}
    for key in scenes:
        scene, lighting = load_bench_scene(key)
        cands = budget.candidates(orders=(3,) if quick else budget.DEFAULT_ORDERS,
                                  spheres=(8,) if quick else budget.DEFAULT_SPHERE_BUDGETS,
                                  methods=("hyb",) if quick else budget.DEFAULT_METHODS)
        choice = choose(scene, cands, min(targets), lighting=lighting, method="shexp", gt_samples=64 if quick else 1024,
                        device=device, progress=True)
        per_target = {}
        for t in targets:
            c, met = pick(choice.candidates, t)
            row = _candidate_row(c)
            per_target[str(t)] = {k: row[k] for k in ("order", "spheres", "leaf_spheres", "method", "rel_rms", "stage_ms")}
            per_target[str(t)]["met"] = met
            print(f"  {key}: target {t:.3f} -> n{row['order']}, {row['leaf_spheres']} leaf spheres (budget {row['spheres']}), "
                  f"{row['method']}: error {c.rel_rms:.4f}, {c.stage_ms:.2f} ms/frame{'' if met else ' (NOT met: most accurate)'}",
                  flush=True)
        chosen, met = pick(choice.candidates, min(targets))
        search = {"scene": choice.scene, "target": choice.target, "chosen": {**_candidate_row(chosen), "label": chosen.label},
                  "met": met, "candidates": [_candidate_row(c) for c in choice.candidates], "frames": choice.frames,
                  "gt_samples": choice.gt_samples, "seconds": choice.seconds}
        out["scenes"][key] = {"per_target": per_target, "search": search}
    out["choices_differ"] = {
        str(t): len({(out["scenes"][k]["per_target"][str(t)]["order"], out["scenes"][k]["per_target"][str(t)]["spheres"],
                      out["scenes"][k]["per_target"][str(t)]["method"]) for k in scenes}) > 1 for t in targets}
    return out


def part_budget(args) -> dict:
    return budget_report(quick=args.quick, scenes=BUDGET_SCENES[:1] if args.quick else BUDGET_SCENES)


_COLD_COMPILE = r"""
import sys, time, tempfile, numpy as np
import warp as wp
wp.config.kernel_cache_dir = tempfile.mkdtemp()
from warpshade.methods.shexp import pipeline
order = int(sys.argv[1]); accumulate = sys.argv[2]; method = sys.argv[3]
pts = np.zeros((4, 3)); nrm = np.tile([0, 0, 1.0], (4, 1))
light = np.zeros((3, order * order)); light[:, 0] = 1.0
t0 = time.perf_counter()
s = pipeline.ShexpShader(order, 4, 1, method=method, accumulate=accumulate, device="cpu")
s.bind_receivers(pts, nrm, np.ones((4, 3))); s.set_flat_cut(); s.upload_spheres([[0, 0, 1.0]], [0.2]); s.upload_lighting(light)
t1 = time.perf_counter(); s.launch(); wp.synchronize()
print(f"{t1 - t0:.3f} {time.perf_counter() - t1:.3f}")
"""


def part_compile(args) -> dict:
    out = {}
    configs = (("log", "hyb"), ("log", "ps_star"), ("product", "hyb"))
    for order in args.orders:
        for accumulate, method in configs[:1] if args.quick else configs:
            r = subprocess.run([sys.executable, "-c", _COLD_COMPILE, str(order), accumulate, method], capture_output=True, text=True,
                               cwd=str(ROOT))
            try:
                tables_s, compile_s = (float(x) for x in r.stdout.strip().split()[-2:])
            except ValueError:
                print(r.stderr[-2000:])
                raise
            out[f"n{order}_{accumulate}_{method}"] = {"tables_s": tables_s, "cold_compile_s": compile_s}
            print(f"  compile n={order} {accumulate}/{method}: tables {tables_s:.2f} s, cold compile {compile_s:.2f} s", flush=True)
    return out


def speed_chart(speed: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    orders = sorted(int(k) for k in speed["orders"])
    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    x = np.arange(len(orders))
    ours = [speed["orders"][str(o)]["ratio_product_over_ps_star2"] for o in orders]
    hyb = [speed["orders"][str(o)]["ratio_product_over_hyb"] for o in orders]
    paper = [PAPER_SPEEDUP[o] for o in orders]
    ax.bar(x - 0.27, paper, 0.27, label="paper (CPU, PS*-2)", color="0.6")
    ax.bar(x, ours, 0.27, label="warpshade CPU, PS*-2")
    ax.bar(x + 0.27, hyb, 0.27, label="warpshade CPU, HYB")
    ax.set_xticks(x, [f"n={o}" for o in orders])
    ax.set_ylabel("product time / log-space time")
    ax.set_title(f"SHEXP speed-up, {speed['receivers']:,} receivers, {speed['spheres']} spheres", fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", alpha=0.3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def _edges(scene) -> np.ndarray:
    """Unique mesh edges (E, 2) in scene vertex indices."""
    e = []
    for m in scene.meshes:
        f = m.faces + m.vertex_offset
        e.append(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]))
    e = np.sort(np.concatenate(e), axis=1)
    return np.unique(e, axis=0)


def seam_error(radiance: dict, truth: dict, edges: np.ndarray) -> float:
    """RMS over edges of the jump of the error between the endpoints, relative to RMS radiance."""
    num, den = 0.0, 0.0
    for f, ref in truth.items():
        err = np.asarray(radiance[f]) - np.asarray(ref["radiance"])
        jump = err[edges[:, 0]] - err[edges[:, 1]]
        num += float(np.mean(jump**2))
        den += float(np.mean(np.asarray(ref["radiance"]) ** 2))
    return float(np.sqrt(num / max(den, 1e-300)))


def part_ratio(args) -> dict:
    from warpshade.measure import error_frames, ground_truth, load_bench_scene, run_setting, setting_error
    from warpshade.methods.shexp import graph_stages

    scene, lighting = load_bench_scene("blockers")
    frames = error_frames(scene, 1 if args.quick else 2)
    gt = ground_truth(scene, lighting, frames, 64 if args.quick else 2048, "cpu")
    edges = _edges(scene)
    budget = 4 if args.quick else SCENE_BUDGETS["blockers"]
    rows = {}
    for label, hierarchy, ratio, theta in (("flat list", False, True, 25.0), ("tree + ratio vectors", True, True, 25.0),
                                           ("tree, no ratio vectors", True, False, 25.0),
                                           ("tree 45 deg + ratio vectors", True, True, 45.0),
                                           ("tree 45 deg, no ratio vectors", True, False, 45.0)):
        stages = graph_stages(4, "hyb", budget, hierarchy=hierarchy, ratio=ratio, theta_max=theta)
        res = run_setting(scene, lighting, stages, frames, device="cpu", name=f"shexp-ratio-{label}".replace(" ", "-"))
        err = setting_error(res["radiance"], gt)
        rows[label] = {"hierarchy": hierarchy, "ratio": ratio, "theta_max": theta, "rel_rms": err["rel_rms"],
                       "rel_p99": err["rel_p99"], "diagnostics": res["diagnostics"].get("shade", {}),
                       "seam": seam_error(res["radiance"], gt, edges), "frame_ms": res["frame_ms"],
                       "noise_rel_rms": err.get("noise_rel_rms")}
        rows[label]["_radiance"] = res["radiance"]
        r = rows[label]
        print(f"    {label:24s} rel RMS {r['rel_rms']:.4f}  p99 {r['rel_p99']:.4f}  seam {r['seam']:.4f}  "
              f"{r['frame_ms']:.2f} ms/frame", flush=True)
    out_dir = Path(args.out or RESULTS_DIR)
    out_dir.mkdir(parents=True, exist_ok=True)
    png = out_dir / f"shexp-ratio-{_dt.date.today().isoformat()}-cpu{'-quick' if args.quick else ''}.png"
    _ratio_chart(scene, frames[-1], gt, rows, png)
    for r in rows.values():
        r.pop("_radiance")
    return {"scene": "blockers", "order": 4, "method": "hyb", "leaf_spheres": budget, "frames": [float(f) for f in frames],
            "edges": int(edges.shape[0]), "rows": rows, "picture": png.name}


def _ratio_chart(scene, frame, gt, rows, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(rows)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    x = np.arange(len(labels))
    axes[0].bar(x - 0.27, [rows[k]["rel_rms"] for k in labels], 0.27, label="relative RMS")
    axes[0].bar(x, [rows[k]["rel_p99"] for k in labels], 0.27, label="99th percentile")
    axes[0].bar(x + 0.27, [rows[k]["seam"] for k in labels], 0.27, label="seam (edge jumps of the error)")
    axes[0].set_xticks(x, [k.replace(" + ", "\n+ ").replace(", ", ",\n") for k in labels], fontsize=7)
    axes[0].set_title("SHEXP n = 4 HYB on blockers vs ray-traced truth")
    axes[0].legend(fontsize=8)
    ref = np.asarray(gt[frame]["radiance"]).mean(axis=1)
    pts = np.concatenate([m.points for m in scene.meshes])
    for k, colour in zip(labels[1:], ("C0", "C3", "C2", "C1")):
        err = np.abs(np.asarray(rows[k]["_radiance"][frame]).mean(axis=1) - ref) / max(float(ref.max()), 1e-12)
        axes[1].hist(err, bins=60, histtype="step", color=colour, label=k, log=True)
    axes[1].set_xlabel(f"|error| / max radiance, frame {frame:g} ({pts.shape[0]} receivers)")
    axes[1].set_title("per-receiver error distribution")
    axes[1].legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def part_spherelights(args) -> dict:
    from warpshade.measure import error_frames, ground_truth, load_bench_scene, run_setting, setting_error
    from warpshade.methods.shexp import graph_stages
    from warpshade.scene import LightingSource, SphereLight

    scene, lighting = load_bench_scene("blockers")
    frames = error_frames(scene, 1 if args.quick else 2)
    pts = np.concatenate([m.points for m in scene.meshes])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre, size = 0.5 * (lo + hi), float(np.max(hi - lo))
    up = {"Y": 1, "Z": 2}.get(str(scene.up_axis).upper(), 2)
    budget = 4 if args.quick else SCENE_BUDGETS["blockers"]
    rows = {}
    rng = np.random.default_rng(6)
    for count in (0, 1, 4):
        lights = list(lighting.lights)
        for i in range(count):
            p = centre + size * np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3)])
            p[up] = hi[up] + 0.3 * size
            # radiance chosen so that one lamp's irradiance (~ L pi (r / d)^2) is comparable to the sky's
            lights.append(SphereLight(p, 0.04 * size, np.array([60.0, 50.0, 40.0]), path=f"/Bench/Lamp{i}"))
        src = LightingSource(lights, scene.up_axis, lighting.degrees_per_frame, float(scene.frames[0]))
        res = run_setting(scene, src, graph_stages(4, "hyb", budget), frames, device="cpu", name=f"shexp-lamps-{count}")
        row = {"sphere_lights": count, "frame_ms": res["frame_ms"], "shade_ms": res["stage_ms"].get("shade")}
        if count:
            gt = ground_truth(scene, src, frames, 64 if args.quick else 2048, "cpu")
            err = setting_error(res["radiance"], gt)
            row.update(rel_rms=err["rel_rms"], rel_p99=err["rel_p99"], noise_rel_rms=err.get("noise_rel_rms"))
        rows[str(count)] = row
        print(f"    {count} sphere light(s): {row['frame_ms']:.2f} ms/frame (shade {row['shade_ms'] or 0:.2f} ms)"
              + (f", rel RMS {row['rel_rms']:.4f}, p99 {row['rel_p99']:.4f}" if count else ""), flush=True)
    base = rows["0"]["frame_ms"]
    for r in rows.values():
        r["frame_ratio_vs_none"] = r["frame_ms"] / base
    result = {"scene": "blockers", "order": 4, "method": "hyb", "leaf_spheres": budget, "rows": rows,
              "light_radius": 0.04 * size}
    out_dir = Path(args.out or RESULTS_DIR)
    out_dir.mkdir(parents=True, exist_ok=True)
    png = out_dir / f"shexp-spherelights-{_dt.date.today().isoformat()}-cpu{'-quick' if args.quick else ''}.png"
    spherelights_chart(result, png)
    result["picture"] = png.name
    return result


def spherelights_chart(result: dict, path: Path) -> None:
    """Error against ground truth and time per frame with 0, 1 and 4 sphere lights."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    keys = sorted(rows, key=int)
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6))
    lit = [k for k in keys if int(k) > 0]
    x = np.arange(len(lit))
    a.bar(x - 0.2, [rows[k]["rel_rms"] for k in lit], 0.4, label="relative RMS")
    a.bar(x + 0.2, [rows[k]["rel_p99"] for k in lit], 0.4, label="99th percentile")
    a.set_xticks(x, [f"{k} sphere light(s)" for k in lit])
    a.set_title("SHEXP n = 4 HYB + sphere lights vs ray-traced truth", fontsize=9)
    a.legend(fontsize=8)
    b.bar(np.arange(len(keys)), [rows[k]["frame_ms"] for k in keys])
    for i, k in enumerate(keys):
        b.text(i, rows[k]["frame_ms"] * 1.02, f"{rows[k]['frame_ratio_vs_none']:.2f}x", ha="center", fontsize=8)
    b.set_xticks(np.arange(len(keys)), [f"{k} lights" for k in keys])
    b.set_ylabel("ms per frame (median)")
    b.set_title("cost (blockers scene, shared 2-core CPU)", fontsize=9)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


PARTS = {"speed": part_speed, "battle": part_battle, "exp": part_exp, "shading": part_shading, "compile": part_compile,
         "ratio": part_ratio, "spherelights": part_spherelights,
         "scenes": part_scenes, "budget": part_budget}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--parts", default=None,
                    help=f"comma-separated parts (default all: {','.join(PARTS)}; quick: all but compile, whose cold "
                         "compiles into an empty kernel cache take minutes)")
    ap.add_argument("--orders", default=None, help="comma-separated SH orders (default 3,4,5,6; quick 3)")
    ap.add_argument("--repeats", type=int, default=None, help="timing repeats (default 7; quick 1)")
    ap.add_argument("--quick", action="store_true",
                    help="smoke profile: order 3, one repeat, tiny grids, the blocker scene only, 64-ray truths")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = ap.parse_args(argv)
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    args.orders = [int(o) for o in (args.orders or ("3" if args.quick else "3,4,5,6")).split(",")]
    args.repeats = args.repeats or (1 if args.quick else 7)
    parts = args.parts.split(",") if args.parts else [p for p in PARTS if not (args.quick and p == "compile")]
    unknown = [p for p in parts if p not in PARTS]
    if unknown:
        ap.error(f"unknown part(s) {unknown} (parts: {', '.join(PARTS)})")
    date = _dt.date.today().isoformat()
    result = {
        "date": date,
        "device": "cpu",
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(), "python": platform.python_version(),
                    "numpy": np.__version__, "warp": wp.config.version},
        "command": "python benchmarks/bench_shexp.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "quick": args.quick,
        "repeats": args.repeats,
    }
    for part in parts:
        print(f"[{part}]", flush=True)
        t0 = time.perf_counter()
        result[part] = PARTS[part](args)
        result.setdefault("seconds", {})[part] = time.perf_counter() - t0
    out_dir = Path(args.out or RESULTS_DIR)
    stem = f"shexp-{date}-cpu" + ("-quick" if args.quick else "")
    path = out_dir / f"{stem}.json"
    if path.exists():  # merge with parts measured earlier today
        try:
            old = json.loads(path.read_text())
            old.update({k: v for k, v in result.items() if k != "seconds"})
            old.setdefault("seconds", {}).update(result.get("seconds", {}))
            result = old
        except json.JSONDecodeError:
            pass
    write_json_atomic(path, result, indent=1)
    if "speed" in result:
        speed_chart(result["speed"], out_dir / f"{stem}-speed.png")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
