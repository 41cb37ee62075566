"""LDPRT on deforming scenes: error against ray-traced ground truth and shading cost.

Part 1 -- accuracy and time per frame, per scene (figure: skinned figure on a ground plane;
bend: bending/twisting cylinder), all methods run through the stage-graph runtime on the same
scene, lighting and frames:

* static PRT baked at frame 0 (``prt.transfer`` + ``prt.shade``): "undeformed PRT";
* unshadowed irradiance (``prt.unshadowed``): no visibility at all;
* LDPRT with N = 1..4 lobes (light-specialised table), an error-budgeted lobe count, N = 3 with
  direct SH evaluation, and the full local SH transfer rotated per vertex (no ZH fit);

errors (relative RMS over vertices, debiased by the ground truth's own noise, and per mesh) on
several frames, median time per frame over all 60 frames (the recorded frame replayed), the
time of each stage (a profile over every frame), precompute time.

Part 2 -- shading cost per vertex, measured side by side in one run on synthetic per-vertex
data: light-specialised table (O(nN)) vs direct SH evaluation at the rotated axes (O(n^2 N)) vs
rotating the full SH transfer vector with the zxzxz rotation (O(n^3)), for n = 4, 6 and
N = 1..4; ratios to the table variant. Also the table build time and its interpolation error.

Writes ``ldprt-<date>-cpu[-quick].json`` and ``...-errors.png`` / ``...-cost.png`` into ``--out``
(default ``benchmarks/results``).

Usage::

    python benchmarks/bench_ldprt.py [--quick] [--scenes figure,bend] [--order 4] [--gt-samples 2048] [--out DIR]
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

from warpshade._fileio import atomic_path, write_json_atomic
from warpshade._wp import resolve_device, wp
from warpshade.measure import (
    combine_metrics,
    error_metrics,
    ground_truth,
    load_bench_scene,
    pick_frames,
    run_setting,
    setting_error,
)

RESULTS = ROOT / "benchmarks" / "results"
#: Deforming bundled scenes (keys of :data:`warpshade.measure.BENCH_SCENES`).
SCENES = ("figure", "bend", "cloth")
#: Seed of this benchmark's ray-traced ground truth.
GT_SEED = 4242


def methods(order: int, samples: int, quick: bool) -> list[tuple[str, tuple]]:
    """(label, stages) of every compared setting."""
    out = [
        (f"static PRT n{order}", (("bake", "prt.transfer", {"order": order, "samples": samples}, {}),
                                  ("shade", "prt.shade", {"order": order}, {"transfer": "bake.transfer"}))),
        ("unshadowed n3", (("shade", "prt.unshadowed", {"order": 3}, {}),)),
        (f"rotated SH n{order}", (("bake", "ldprt.transfer", {"order": order, "samples": samples}, {}),
                                  ("tangents", "ldprt.tangents", {}, {}),
                                  ("shade", "ldprt.shade_rotated", {"order": order}, {}))),
    ]
    lobe_counts = (1, 2, 3, 4) if not quick else (1,)
    for n in lobe_counts:
        out.append((f"LDPRT N{n}", _ldprt(order, samples, n)))
    if not quick:
        out.append(("LDPRT N3 direct", _ldprt(order, samples, 3, evaluation="direct")))
        out.append(("LDPRT budget 5%", _ldprt(order, samples, 4, target=0.05)))
    return out


def _ldprt(order, samples, lobes, evaluation="table", target=None):
    fit = {"order": order, "lobes": lobes, "samples": samples}
    if target is not None:
        fit["target_error"] = target
    return (("fit", "ldprt.fit", fit, {}), ("tangents", "ldprt.tangents", {}, {}),
            ("shade", "ldprt.shade", {"order": order, "lobes": lobes, "evaluation": evaluation}, {}))


def mesh_slices(scene) -> dict:
    return {m.path.rsplit("/", 1)[-1]: slice(m.vertex_offset, m.vertex_offset + m.vertex_count) for m in scene.meshes}


def run_method(label, stages, scene, lighting, device, gt, timing_frames):
    """One setting over ``timing_frames`` (every frame in the full run): replayed time per frame,
    per-stage times (profiled over the same frames), precompute, errors on the ground-truth
    frames, overall and per mesh."""
    res = run_setting(scene, lighting, stages, list(gt), timing_frames=timing_frames, device=device, cache_dir=None,
                      name=label.replace(" ", "-"), profile=False)
    rt = res["runtime"]
    stage_ms = {k: 1e3 * v for k, v in rt.profile(timing_frames).items() if k != "scene"}
    timing = rt.timing_summary()
    err = setting_error(res["radiance"], gt)
    per_frame = err.pop("per_frame")
    per_mesh = {k: [] for k in mesh_slices(scene)}
    for f, ref in gt.items():
        est = res["radiance"][f]
        for name, sl in mesh_slices(scene).items():
            mm = error_metrics(est[sl], ref["radiance"][sl], ref["stderr"][sl])
            mm["frame"] = f
            per_mesh[name].append(mm)
    return {
        "method": label,
        "median_frame_ms": res["frame_ms"],
        "stage_ms": stage_ms,
        "precompute_s": sum(v.get("precompute_s", 0.0) for v in timing["stages"].values()),
        "compile_and_precompute_s": res["compile_s"],
        "model_bytes": res["model_bytes"],
        "error": err,
        "error_per_frame": per_frame,
        "error_per_mesh": {k: combine_metrics(v) for k, v in per_mesh.items()},
        "error_per_mesh_per_frame": per_mesh,
        "fit": res["reports"].get("fit"),
    }


def error_budget(scene, order: int, samples: int, targets=(0.1, 0.05, 0.02), max_lobes: int = 4) -> list[dict]:
    """Lobe counts (and the SH order) chosen from target errors on the scene's bake-frame transfer."""
    from warpshade.basis import zh
    from warpshade.methods.ldprt import fit_transfer, local_transfer

    t = local_transfer(scene, float(scene.frames[0]), max(order, 6), samples, device="cpu").astype(np.float64)
    _, order_errors = zh.choose_order(t, 1.0)
    rows = []
    for target in targets:
        chosen_order, _ = zh.choose_order(t, target)
        model = fit_transfer(t[:, : order * order], max_lobes, target_error=target, restarts=2)
        rows.append({"target": target, "histogram": model.histogram, "total_fit_error": model.total_error,
                     "mean_lobes": float(model.counts.mean()), "met": float(np.mean(model.fit_error <= target + 1e-6)),
                     "order_for_target": chosen_order, "fit_seconds": model.seconds})
        print(f"  target {target:.2f}: lobes {model.histogram} (mean {model.counts.mean():.2f}), total fit error "
              f"{model.total_error:.4f}; SH order meeting the target on truncation alone: {chosen_order}", flush=True)
    return [{"truncation_error_by_order": [float(e) for e in order_errors]}] + rows


# ---- part 2: cost per vertex ------------------------------------------------------------------


def cost_ratios(device, vertex_count: int, orders, lobe_counts, repeats: int) -> list[dict]:
    from warpshade.basis.sh_warp import sh_kernels
    from warpshade.methods.ldprt import _kernels as kernels

    rng = np.random.default_rng(5)
    rows = []
    frames = np.linalg.qr(rng.normal(size=(vertex_count, 3, 3)))[0]
    frames *= np.sign(np.linalg.det(frames))[:, None, None]
    frames_wp = wp.array(frames.astype(np.float32), dtype=wp.mat33, device=device)
    albedo = wp.array(np.full((vertex_count, 3), 0.8, np.float32), device=device)
    rebuild = wp.ones(1, dtype=wp.int32, device=device)
    radiance = wp.zeros((vertex_count, 3), dtype=wp.float32, device=device)

    def timed(variants):
        """Median seconds per launch of each (kernel, dim, inputs), launched round-robin so that
        load changes on a shared machine hit every variant alike."""
        for kernel, dim, inputs in variants:
            wp.launch(kernel, dim=dim, inputs=inputs, device=device)
        wp.synchronize_device(device)
        ts = [[] for _ in variants]
        for _ in range(repeats):
            for k, (kernel, dim, inputs) in enumerate(variants):
                t0 = time.perf_counter()
                wp.launch(kernel, dim=dim, inputs=inputs, device=device)
                wp.synchronize_device(device)
                ts[k].append(time.perf_counter() - t0)
        return [float(np.median(t)) for t in ts]

    for order in orders:
        table_k, shade_table, shade_direct, shade_rot = kernels.shade_kernels(order)
        light = wp.array(rng.normal(size=(3, order * order)).astype(np.float32), device=device)
        table = wp.zeros((65, 128, 3, order), dtype=wp.float32, device=device)
        transfer = wp.array(rng.normal(size=(vertex_count, order * order)).astype(np.float32), device=device)
        tables = sh_kernels(order).tables(device)
        stored = wp.array(rng.normal(size=(vertex_count, 4)).astype(np.float32), device=device)
        for n in lobe_counts:
            axes = rng.normal(size=(vertex_count, n, 3))
            axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
            axes_wp = wp.array(axes.astype(np.float32), dtype=wp.vec3, device=device)
            coeffs = wp.array(rng.normal(size=(vertex_count, n, order)).astype(np.float32), device=device)
            counts = wp.array(np.full(vertex_count, n, np.int32), device=device)
            t_table, t_direct, t_rot, t_build = timed([
                (shade_table, vertex_count, [frames_wp, axes_wp, coeffs, counts, stored, table, light, albedo, radiance]),
                (shade_direct, vertex_count, [frames_wp, axes_wp, coeffs, counts, stored, light, albedo, radiance]),
                (shade_rot, vertex_count, [frames_wp, transfer, tables, light, albedo, radiance]),
                (table_k, table.shape[:2], [light, rebuild, table]),
            ])
            rows.append({
                "order": order, "lobes": n, "vertex_count": vertex_count,
                "table_ns_per_vertex": 1e9 * t_table / vertex_count,
                "direct_ns_per_vertex": 1e9 * t_direct / vertex_count,
                "rotate_full_ns_per_vertex": 1e9 * t_rot / vertex_count,
                "table_build_ms": 1e3 * t_build,
                "direct_over_table": t_direct / t_table,
                "rotate_full_over_table": t_rot / t_table,
            })
            r = rows[-1]
            print(f"  n={order} N={n}: table {r['table_ns_per_vertex']:.0f} ns/v, direct {r['direct_ns_per_vertex']:.0f}"
                  f" ({r['direct_over_table']:.2f}x), full rotation {r['rotate_full_ns_per_vertex']:.0f}"
                  f" ({r['rotate_full_over_table']:.2f}x), table build {r['table_build_ms']:.2f} ms", flush=True)
    return rows


def table_error(device, orders, widths) -> list[dict]:
    """Max |table shade - direct shade| relative to the RMS of the direct shade, random models."""
    from warpshade.methods.ldprt import _kernels as kernels

    rng = np.random.default_rng(6)
    out = []
    count, n_lobes = 20000, 3
    frames = wp.array(np.tile(np.eye(3, dtype=np.float32), (count, 1, 1)), dtype=wp.mat33, device=device)
    albedo = wp.array(np.full((count, 3), np.pi, np.float32), device=device)
    stored = wp.zeros((count, 4), dtype=wp.float32, device=device)
    counts = wp.array(np.full(count, n_lobes, np.int32), device=device)
    rebuild = wp.ones(1, dtype=wp.int32, device=device)
    for order in orders:
        table_k, shade_table, shade_direct, _ = kernels.shade_kernels(order)
        from warpshade.scene import Environment, up_rotation

        sky = Environment.sky(to_world=up_rotation("Z"))
        light = wp.array(sky.to_sh(order).astype(np.float32), device=device)
        axes = rng.normal(size=(count, n_lobes, 3))
        axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
        axes_wp = wp.array(axes.astype(np.float32), dtype=wp.vec3, device=device)
        from warpshade.basis import sh as shb

        coeffs = wp.array(np.tile(shb.clamped_cosine_zh(order), (count, n_lobes, 1)).astype(np.float32), device=device)
        direct = wp.zeros((count, 3), dtype=wp.float32, device=device)
        wp.launch(shade_direct, dim=count, inputs=[frames, axes_wp, coeffs, counts, stored, light, albedo, direct],
                  device=device)
        ref = direct.numpy()
        for width in widths:
            table = wp.zeros((width // 2 + 1, width, 3, order), dtype=wp.float32, device=device)
            wp.launch(table_k, dim=table.shape[:2], inputs=[light, rebuild, table], device=device)
            res = wp.zeros((count, 3), dtype=wp.float32, device=device)
            wp.launch(shade_table, dim=count, inputs=[frames, axes_wp, coeffs, counts, stored, table, light, albedo, res],
                      device=device)
            d = res.numpy() - ref
            rms = float(np.sqrt(np.mean(ref**2)))
            out.append({"order": order, "table_width": width, "table_height": width // 2 + 1,
                        "max_rel": float(np.abs(d).max() / rms), "rms_rel": float(np.sqrt(np.mean(d**2)) / rms)})
            print(f"  table {width // 2 + 1}x{width}, n={order}: max {out[-1]['max_rel']:.2e}, "
                  f"RMS {out[-1]['rms_rel']:.2e} (relative to the RMS shade)", flush=True)
    return out


# ---- charts -----------------------------------------------------------------------------------


def charts(result, stem):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = list(result["scenes"])
    fig, axes = plt.subplots(1, max(1, len(scenes)), figsize=(6.2 * max(1, len(scenes)), 4.4), squeeze=False)
    for ax, sc in zip(axes[0], scenes):
        for r in result["scenes"][sc]["methods"]:
            fr = [m["frame"] for m in r["error_per_frame"]]
            err = [m.get("rel_rms_debiased", m["rel_rms"]) for m in r["error_per_frame"]]
            style = "-" if r["method"].startswith("LDPRT") else "--"
            ax.plot(fr, err, style, marker="o", ms=3, label=r["method"])
        noise = np.mean([m["noise_rel_rms"] for m in result["scenes"][sc]["methods"][0]["error_per_frame"]])
        ax.axhline(noise, color="0.3", ls=":", lw=0.8, label="ground-truth noise")
        ax.set_title(f"{sc}: error vs ray-traced ground truth")
        ax.set_xlabel("frame")
        ax.set_ylabel("relative RMS error (debiased)")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    if scenes:
        _save(fig, Path(f"{stem}-errors.png"))
    else:
        plt.close(fig)
    cost = result["cost"]
    if cost:
        orders = sorted({c["order"] for c in cost})
        fig, axes = plt.subplots(1, len(orders), figsize=(5.5 * len(orders), 4), squeeze=False)
        for ax, order in zip(axes[0], orders):
            rows = [c for c in cost if c["order"] == order]
            x = np.arange(len(rows))
            ax.bar(x - 0.25, [c["table_ns_per_vertex"] for c in rows], 0.25, label="table e^ (O(nN))")
            ax.bar(x, [c["direct_ns_per_vertex"] for c in rows], 0.25, label="direct SH (O(n^2 N))")
            ax.bar(x + 0.25, [c["rotate_full_ns_per_vertex"] for c in rows], 0.25, label="full SH rotation (O(n^3))")
            ax.set_xticks(x, [f"N={c['lobes']}" for c in rows])
            ax.set_ylabel("ns per vertex (CPU, one run)")
            ax.set_title(f"shading cost per vertex, n = {order}")
            ax.legend(fontsize=8)
            ax.grid(True, axis="y", alpha=0.3)
        fig.tight_layout()
        _save(fig, Path(f"{stem}-cost.png"))


def _save(fig, path):
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="smoke profile: the bend, N = 1 only, 2 frames, 32 transfer and 64 truth rays, tiny cost runs")
    ap.add_argument("--scenes", default=None, help="comma-separated scenes (default figure,bend; quick: bend)")
    ap.add_argument("--order", type=int, default=4, help="SH order of PRT and LDPRT")
    ap.add_argument("--samples", type=int, default=None, help="transfer rays per vertex (default 256; quick 32)")
    ap.add_argument("--gt-samples", type=int, default=None, help="ground-truth rays per vertex (default 2048; quick 64)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--skip-cost", action="store_true")
    ap.add_argument("--cost-only", action="store_true", help="only part 2 (written as ldprt-cost-<date>-<device>)")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = ap.parse_args(argv)
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    args.scenes = args.scenes or ("bend" if args.quick else "figure,bend")
    args.samples = args.samples or (32 if args.quick else 256)
    args.gt_samples = args.gt_samples or (64 if args.quick else 2048)
    keys = [] if args.cost_only else args.scenes.split(",")
    unknown = [k for k in keys if k not in SCENES]
    if unknown:
        ap.error(f"--scenes: unknown scene(s) {unknown} (known: {', '.join(SCENES)})")

    device = resolve_device(args.device)
    result = {"date": datetime.date.today().isoformat(), "device": str(device),
              "machine": f"{platform.machine()}, {os.cpu_count()} cores", "warp": wp.config.version,
              "command": "python benchmarks/bench_ldprt.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "order": args.order, "samples": args.samples, "gt_samples": args.gt_samples, "scenes": {}}
    for key in keys:
        scene, lighting = load_bench_scene(key, rotate_degrees_per_frame=0.0)  # the scenes' own lights, fixed
        count = 2 if args.quick else 7
        frames = pick_frames(scene, count)
        timing_frames = scene.frames[::12] if args.quick else scene.frames
        print(f"{key}: {scene.vertex_count} vertices, ground truth on frames {list(frames)}", flush=True)
        gt = ground_truth(scene, lighting, frames, args.gt_samples, device, seed=GT_SEED, progress=True)
        rows = []
        for label, stages in methods(args.order, args.samples, args.quick):
            t0 = time.perf_counter()
            r = run_method(label, stages, scene, lighting, device, gt, timing_frames)
            rows.append(r)
            e = r["error"]
            meshes = ", ".join(f"{k} {v['rel_rms_debiased']:.4f}" for k, v in r["error_per_mesh"].items())
            print(f"  {label:18s} rel RMS {e['rel_rms']:.4f} (debiased {e['rel_rms_debiased']:.4f}; {meshes}) "
                  f"{r['median_frame_ms']:.2f} ms/frame, precompute {r['precompute_s']:.1f} s "
                  f"[{time.perf_counter() - t0:.0f} s] {r['fit'] or ''}", flush=True)
        print(f"  error budget (order {args.order}, at most 4 lobes per vertex):", flush=True)
        budget = error_budget(scene, args.order, args.samples, *(((0.1,), 2) if args.quick else ()))
        result["scenes"][key] = {"vertex_count": scene.vertex_count, "frames": [float(f) for f in frames],
                                 "meshes": {k: v.stop - v.start for k, v in mesh_slices(scene).items()},
                                 "methods": rows, "error_budget": budget}
    if not args.skip_cost:
        print("shading cost per vertex (one run, side by side):", flush=True)
        if args.quick:
            result["cost"] = cost_ratios(device, 2000, (4,), (1, 2), 2)
        else:
            result["cost"] = cost_ratios(device, 200000, (4, 6, 8), (1, 2, 3, 4), 15)
        print("light-specialised table vs direct evaluation:", flush=True)
        result["table_error"] = table_error(device, (4,), (64,)) if args.quick else table_error(device, (4, 6), (64, 128, 256))
    else:
        result["cost"], result["table_error"] = [], []
    out_dir = Path(args.out or RESULTS)
    out_dir.mkdir(parents=True, exist_ok=True)
    kind = "ldprt-cost" if args.cost_only else "ldprt"
    stem = out_dir / f"{kind}-{result['date']}-{device.alias.replace(':', '')}{'-quick' if args.quick else ''}"
    write_json_atomic(f"{stem}.json", result, indent=1)
    charts(result, str(stem))
    written = [f"{stem}.json"] + [str(p) for p in (Path(f"{stem}-errors.png"), Path(f"{stem}-cost.png")) if p.exists()]
    print("wrote " + ", ".join(written))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
