"""Measuring SHEXP on scenes: ground truth, settings, and the paper's Figure 7 error sources.

Shared by the error budget (:mod:`.budget`) and ``benchmarks/bench_shexp.py``:

* :func:`load_bench_scene` -- the bundled scenes under the harness's conventions (static
  scenes get 24 frames; lighting rotates 5 degrees per frame about the up axis);
* :func:`ground_truth` -- ray-traced reference radiance and its standard error per frame
  (:func:`warpshade.reference.shade`), cached on disk by scene, frame, lighting and samples;
* :func:`run_setting` -- one SHEXP (or baseline) graph on the scene: radiance on the error
  frames and the median time of its shading stage per frame;
* :func:`scene_errors` -- the error table of the benchmark: n = 3..6, every exp method, flat vs
  hierarchy, product accumulation, and ray tracing against the spheres with the environment
  and with the order-n SH lighting, which separates sphere approximation, lighting band
  limit, product truncation and log space.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

__all__ = ["SCENES", "ROTATE_DEGREES_PER_FRAME", "load_bench_scene", "error_frames", "ground_truth", "run_setting",
           "sphere_trace_errors", "scene_errors"]

_ROOT = Path(__file__).resolve().parents[3]
#: Bundled scenes (as in benchmarks/run.py) and the leaf-sphere budget used for their tables.
SCENES = {
    "blockers": {"spec": str(_ROOT / "usd_assets" / "blockers.usda"), "options": {}, "budget": 16},
    "figure": {"spec": str(_ROOT / "usd_assets" / "figure.usda"), "options": {}, "budget": 48},
    "bunny": {"spec": "warp-example:bunny", "options": {"ground_plane": True}, "budget": 32},
    "bear": {"spec": "warp-example:bear", "options": {"ground_plane": True}, "budget": 32},
}
ROTATE_DEGREES_PER_FRAME = 5.0
STATIC_FRAME_COUNT = 24


def load_bench_scene(key: str):
    """(scene, lighting) of a bundled scene with the harness's frame count and rotating lighting."""
    from ...graph import LightingSource
    from ...graph.graph import extend_static_frames
    from ...io import load_scene

    if key not in SCENES:
        raise ValueError(f"unknown scene {key!r}; known: {sorted(SCENES)}")
    cfg = SCENES[key]
    scene = load_scene(cfg["spec"], **cfg["options"])
    if scene.is_static:
        scene = extend_static_frames(scene, STATIC_FRAME_COUNT)
    lighting = LightingSource(scene.lights, scene.up_axis, ROTATE_DEGREES_PER_FRAME, float(scene.frames[0]))
    return scene, lighting


def error_frames(scene, count: int = 2) -> np.ndarray:
    """``count`` frames spread inside the scene's range (first and last left out)."""
    f = scene.frames
    idx = np.unique(np.linspace(0, len(f) - 1, count + 2).round().astype(int))[1:-1]
    return f[idx] if idx.size else f[:1]


def ground_truth(scene, lighting, frames, samples: int = 1024, device="cpu", cache_dir="default") -> dict:
    """{frame: {"radiance": (V, 3), "stderr": (V, 3)}} ray traced (MIS), cached on disk."""
    from ...graph.cache import ArtifactCache, default_cache_dir, hash_json
    from ...graph.runtime import scene_fingerprint
    from ...reference import shade
    from ...reference.shading import ESTIMATOR_VERSION

    cache = ArtifactCache(default_cache_dir() / "shexp-gt" if cache_dir == "default" else cache_dir)
    fp = scene_fingerprint(scene)
    out = {}
    for f in frames:
        key = "gt-" + hash_json({"scene": fp, "frame": float(f), "samples": samples, "lighting": lighting.fingerprint(),
                                 "estimator": ESTIMATOR_VERSION})[:32]
        hit = cache.load(key)
        if hit is None:
            res = shade(scene, f, lighting.lights_at(f), samples, device=device, seed=12345)
            hit = {"radiance": np.asarray(res.radiance), "stderr": np.asarray(res.stderr)}
            cache.store(key, hit)
        out[float(f)] = hit
    return out


def run_setting(scene, lighting, stages, frames, output: str = "shade.radiance", timing_frames=None, device="cpu",
                cache_dir="default", timed_stage: str | None = "shade") -> dict:
    """Run one graph: radiance on ``frames`` and the median per-frame time.

    Args:
        stages: ``(name, type, params, inputs)`` tuples.
        frames: frames whose radiance is returned.
        timing_frames: frames stepped for timing after a warm-up (default: ``frames``).
        timed_stage: the stage whose launch time is reported as ``stage_ms`` (the method's own
            cost; ``frame_ms`` includes scene evaluation and uploads).

    Returns:
        dict with ``radiance`` {frame: (V, 3)}, ``frame_ms``, ``stage_ms``, ``precompute_s``,
        ``fallbacks`` (receivers whose exp left its domain, last frame) and the runtime's report.
    """
    from ...graph import GraphSpec, StageSpec

    spec = GraphSpec([StageSpec(n, t, dict(p), dict(i)) for (n, t, p, i) in stages], output, name="shexp-eval")
    t0 = time.perf_counter()
    rt = spec.compile(scene, device=device, cache_dir=cache_dir, progress=False, lighting=lighting)
    precompute = time.perf_counter() - t0
    radiance = {}
    for f in frames:
        radiance[float(f)] = rt.step(f).numpy().copy()
    rt.reset_timings()
    for f in (frames if timing_frames is None else timing_frames):
        rt.step(f)
    timing = rt.timing_summary()
    stage_s = timing["stages"].get(timed_stage, {}).get("median_frame_s") if timed_stage else None
    shade = next((s for s in rt.stages if s.name == timed_stage), None)
    fallbacks = shade.shader.fallback_count() if shade is not None and hasattr(shade, "shader") and hasattr(shade.shader, "fallback_count") else 0
    return {
        "radiance": radiance,
        "frame_ms": 1e3 * timing["median_frame_s"],
        "stage_ms": 1e3 * stage_s if stage_s is not None else None,
        "precompute_s": precompute,
        "fallbacks": int(fallbacks),
        "runtime": rt,
    }


def combined_error(radiance: dict, gt: dict) -> dict:
    """Error metrics against ground truth combined over frames (RMS-style)."""
    from ...graph import combine_metrics, error_metrics

    per = []
    for f, ref in gt.items():
        m = error_metrics(radiance[f], ref["radiance"], ref["stderr"])
        m["frame"] = f
        per.append(m)
    return combine_metrics(per)


def _rel(a: dict, b: dict) -> float:
    """Relative RMS of a against b over frames (both {frame: (V, 3)})."""
    num = np.mean([np.mean((a[f] - b[f]) ** 2) for f in b])
    den = np.mean([np.mean(b[f] ** 2) for f in b])
    return float(np.sqrt(num / den))


def sphere_trace_errors(scene, lighting, frames, budget: int, orders, samples: int = 1024, device="cpu",
                        cache_dir="default") -> dict:
    """Radiance of ray tracing against the blocker spheres, with the environment and with SH lighting.

    Returns ``{"env": {frame: (V, 3)}, "sh": {order: {frame: (V, 3)}}}``: the same traced rays
    give the environment integral and the cosine-weighted visibility transfer, shaded with each
    order's SH lighting.
    """
    from ...scene.lighting import Environment
    from .blockers import BlockerFrames, BlockerModel
    from .pipeline import ShexpShader, SphereTracer

    res = run_setting(scene, lighting, [("blockers", "shexp.blockers", {"budget": budget}, {}),
                                        ("trace", "shexp.sphere_trace", {"samples": 4}, {})],
                      frames[:1], output="trace.radiance", device=device, cache_dir=cache_dir, timed_stage=None)
    rt = res["runtime"]
    model = BlockerModel.from_arrays(rt.artifacts["blockers"]["model"])
    order_max = max(orders)
    shader = ShexpShader(order_max, scene.vertex_count, model.node_count, device=device)
    blockers = BlockerFrames(scene, model, 2, ratio=False, device=device)
    env_out, sh_out = {}, {o: {} for o in orders}
    for f in frames:
        fs = scene.evaluate(f, device=device)
        shader.bind_receivers(fs.points, fs.normals, scene.albedo)
        blockers.bind(shader)
        blockers.prepare(fs)
        blockers.launch(fs.points)
        env = next(l for l in lighting.lights_at(f) if isinstance(l, Environment))
        tracer = SphereTracer(shader, env, samples, seed=7)
        tracer.launch()
        env_out[float(f)] = tracer.radiance.numpy().astype(np.float64).copy()
        t_full = tracer.transfer.numpy().astype(np.float64)
        for o in orders:
            light = lighting.sh(o, f)
            rgb = t_full[:, : o * o] @ light.T
            sh_out[o][float(f)] = scene.albedo / np.pi * np.maximum(rgb, 0.0)
    return {"env": env_out, "sh": sh_out}


def scene_errors(quick: bool = False, orders=(3, 4, 5, 6), scenes=None, gt_samples: int | None = None, device="cpu") -> dict:
    """The error table of ``benchmarks/bench_shexp.py --parts scenes`` (see module docstring)."""
    from . import graph_stages

    keys = list(scenes or (("blockers", "figure") if quick else ("blockers", "figure", "bunny", "bear")))
    gt_samples = gt_samples or (512 if quick else 2048)
    methods = [("hyb", None), ("ps_star", 2), ("ol", None), ("ps", 10)]
    out = {}
    for key in keys:
        t0 = time.perf_counter()
        scene, lighting = load_bench_scene(key)
        frames = error_frames(scene, 1 if quick else 2)
        gt = ground_truth(scene, lighting, frames, gt_samples, device)
        gt_rad = {f: v["radiance"] for f, v in gt.items()}
        budget = SCENES[key]["budget"]
        rows = []

        def record(label, stages, output="shade.radiance", **facts):
            res = run_setting(scene, lighting, stages, frames, output, device=device)
            err = combined_error(res["radiance"], gt)
            row = {"label": label, **facts, "rel_rms": err["rel_rms"], "rel_rms_debiased": err.get("rel_rms_debiased"),
                   "rel_p99": err["rel_p99"], "noise_rel_rms": err.get("noise_rel_rms"), "stage_ms": res["stage_ms"],
                   "fallbacks": res["fallbacks"]}
            rows.append(row)
            print(f"    {key:9s} {label:26s} rel RMS {row['rel_rms']:.4f}  shade {row['stage_ms'] or 0:.2f} ms", flush=True)
            return res["radiance"]

        unshadowed = {}
        shexp, product = {}, {}
        for order in orders:
            unshadowed[order] = record(f"unshadowed n{order}", (("shade", "prt.unshadowed", {"order": order}, {}),),
                                       order=order, kind="unshadowed")
            for method, degree in (methods if (order == 4 or not quick) else methods[:1]):
                name = {"hyb": "HYB", "ps_star": f"PS*-{degree}", "ol": "OL", "ps": f"PS-{degree}"}[method]
                rad = record(f"SHEXP n{order} {name}", graph_stages(order, method, budget, degree=degree), order=order,
                             method=method, degree=degree, kind="shexp", hierarchy=False, budget=budget)
                if method == "hyb":
                    shexp[order] = rad
            product[order] = record(f"product n{order}", graph_stages(order, budget=budget, accumulate="product"), order=order,
                                    kind="product", budget=budget)
        record("SHEXP n4 HYB tree", graph_stages(4, "hyb", budget, hierarchy=True), order=4, method="hyb", kind="shexp",
               hierarchy=True, budget=budget)
        traced = sphere_trace_errors(scene, lighting, frames, budget, orders, samples=1024 if quick else 2048, device=device)
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
