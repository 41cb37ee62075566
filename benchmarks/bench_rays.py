"""Shadow-ray throughput of every CPU path against Embree, side by side in one run, on the bundled
scenes (blockers, figure, wanderer) and a large mesh (Warp's nonuniform asset); plus the transfer
convergence table (error vs a high-sample estimate as the sample count quadruples).

Usage::

    python benchmarks/bench_rays.py --no-convergence           # the four scenes, CPU
    python benchmarks/bench_rays.py --scenes figure --receivers 4096 --samples 256
    python benchmarks/bench_rays.py --device cuda:0 --no-embree # Warp paths on a GPU

Writes ``benchmarks/results/rays-<date>-<device>.json`` and ``...-<device>.png`` (each path's
throughput over Embree's, per scene, with the goals 0.8 for bulk rays and 0.5 for in-frame
tracers). Per scene, the rays of ``--receivers`` random vertices x ``--samples`` directions
(:func:`warpshade.transfer.sample_rays`); each path is timed ``--repeats`` times after one
warm-up and the median reported. Paths:

* ``warp_anyhit``: ``Visibility.occluded``'s any-hit kernel on the explicit rays, Warp's default
  BVH (SAH, 4 triangles a leaf), chunked launches from the thread pool;
* ``warp_best``: the same with the best BVH settings of a sweep over leaf sizes (``--sweep``);
* ``bake_warp`` / ``bake_embree``: the bulk path, :class:`~warpshade.transfer.TransferTracer`
  (order 4: ray generation, shadow rays, SH sums) with ``rays="warp"`` / ``rays="embree"``;
* ``prt_trace``: the in-frame tracer of ``prt.trace`` (TransferTracer, order 6, 64 rays a vertex,
  every vertex);
* ``hybrid_trace``: the in-frame residual kernel of ``hybrid.trace`` (order 6, 64 rays a vertex,
  rays only above the horizon: those are counted), rated against Embree on its own rays;
* ``hybrid_rays_warp``: Warp's any-hit on exactly those rays, explicit (the same BVH): its time
  over ``hybrid_trace``'s is ``rays_share``, the part of the kernel that is tracing;
* ``embree``: Embree through ``embreex`` on the explicit rays, in this process (``embree_1``) and
  split over worker processes (``embree_n``, :class:`~warpshade.geometry._embree.EmbreeOcclusion`);
  the faster of the two is the reference of every ratio;
* ``mitsuba_ray_test``: Mitsuba 3's ``scene.ray_test`` when Mitsuba is installed.

Rays that disagree with Embree are counted for every path that yields per-ray answers; the bake's
two backends are compared on their outputs (max abs difference).
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from warpshade._fileio import atomic_path, write_json_atomic  # noqa: E402
from warpshade._wp import cpu_workers, launch_parallel, resolve_device, wp  # noqa: E402
from warpshade.geometry._bvh import RAY_MAX_DISTANCE, Visibility, _occlusion_kernel  # noqa: E402
from warpshade.geometry._embree import EmbreeOcclusion, embree_available  # noqa: E402
from warpshade.measure import load_bench_scene  # noqa: E402
from warpshade.basis.sh_warp import sh_kernels  # noqa: E402
from warpshade.methods.hybrid._kernels import (QUANTITY_TRANSFER, cycle_direction, cycle_table_kernel, frame_rotation,  # noqa: E402
                                               residual_kernel, residual_settings)
from warpshade.transfer import TransferTracer, sample_rays  # noqa: E402

from _checkout import checkout_commit  # noqa: E402  (a sibling module: benchmarks/_checkout.py)

#: The scenes of a full run: three bundled scenes and a large mesh from Warp's assets.
SCENES = {"blockers": "blockers", "figure": "figure", "wanderer": "wanderer", "nonuniform": "warp-example:nonuniform"}
#: Goals of issue 40: bulk shadow rays and in-frame tracers, as a fraction of Embree's throughput.
GOAL_BULK, GOAL_IN_FRAME = 0.8, 0.5
#: Leaf sizes of the BVH sweep (Warp's default on the CPU is SAH with 4 triangles a leaf).
LEAF_SIZES = (1, 2, 4, 8)
#: In-frame tracers: SH order and rays per vertex (prt.trace and hybrid.trace of the figure graphs).
IN_FRAME_ORDER, IN_FRAME_RAYS = 6, 64
BULK_PATHS = ("warp_anyhit", "warp_best", "bake_warp", "bake_embree", "embree_n")
IN_FRAME_PATHS = ("prt_trace", "hybrid_trace")


@wp.kernel
def _hybrid_rays_kernel(points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3), count: int, seed: int,
                        offset: float, origins: wp.array(dtype=wp.vec3), directions: wp.array(dtype=wp.vec3),
                        above: wp.array(dtype=wp.int32)):
    """The rays of the hybrid residual kernel at step 0 (``above``: the ones it traces)."""
    v, s = wp.tid()
    n = normals[v]
    d = frame_rotation(seed, 0, 1, v) * cycle_direction(s, count, 0, 1)
    i = v * count + s
    origins[i] = points[v] + offset * n
    directions[i] = d
    above[i] = wp.where(wp.dot(n, d) > 0.0, 1, 0)


def rounds(paths: dict, repeats: int, device) -> dict:
    """Seconds of each path per round: one warm-up, then ``repeats`` rounds running every path once
    in turn (so that load on a shared machine hits all paths alike)."""
    for fn in paths.values():
        fn()
    wp.synchronize_device(device)
    times = {name: [] for name in paths}
    for _ in range(repeats):
        for name, fn in paths.items():
            t0 = time.perf_counter()
            fn()
            wp.synchronize_device(device)
            times[name].append(time.perf_counter() - t0)
    return times


def bench_scene(key, spec, args, dev, workers):
    scene, _ = load_bench_scene(spec)
    frame = float(scene.frames[0])
    rng = np.random.default_rng(0)
    receivers = rng.choice(scene.vertex_count, args.receivers, replace=scene.vertex_count < args.receivers)
    rays = args.receivers * args.samples
    print(f"{key}: {scene.vertex_count} vertices, {scene.triangle_count} triangles; "
          f"{args.receivers} receivers x {args.samples} samples = {rays} rays on {dev}", flush=True)
    state = scene.evaluate(frame, device=dev)
    origins, dirs = sample_rays(scene, frame, args.samples, vertices=receivers, device=dev)
    origins, dirs = origins.reshape(-1, 3), dirs.reshape(-1, 3)
    o_wp = wp.array(origins, dtype=wp.vec3, device=dev)
    d_wp = wp.array(dirs, dtype=wp.vec3, device=dev)
    embree = dev.is_cpu and not args.no_embree and embree_available()
    if not embree and dev.is_cpu and not args.no_embree:
        print("  embreex not installed: Embree paths skipped (pip install -e '.[embree]')")

    def explicit(bvh, out):
        return lambda: launch_parallel(_occlusion_kernel, rays, lambda lo, hi: [bvh.mesh.id, o_wp[lo:hi], d_wp[lo:hi],
                                                                              float(RAY_MAX_DISTANCE), out[lo:hi]], dev, workers)

    # the BVH sweep: each leaf size on the explicit rays, side by side
    default_bvh = Visibility.from_scene(scene, frame, device=dev)
    sweep, best_leaf = {}, None
    if args.sweep:
        bvhs = {leaf: Visibility(scene.points_at(frame), scene.faces, device=dev, bvh_leaf_size=leaf) for leaf in LEAF_SIZES}
        outs = {leaf: wp.empty(rays, dtype=wp.int32, device=dev) for leaf in LEAF_SIZES}
        times = rounds({leaf: explicit(bvhs[leaf], outs[leaf]) for leaf in LEAF_SIZES}, args.repeats, dev)
        sweep = {f"sah_leaf{leaf}": rays / statistics.median(t) for leaf, t in times.items()}
        best_leaf = max(LEAF_SIZES, key=lambda leaf: sweep[f"sah_leaf{leaf}"])
        print("  sweep (Mrays/s): " + ", ".join(f"{k} {v / 1e6:.2f}" for k, v in sweep.items()))
    best_bvh = default_bvh if best_leaf is None else Visibility(scene.points_at(frame), scene.faces, device=dev,
                                                                bvh_leaf_size=best_leaf)

    outs = {name: wp.empty(rays, dtype=wp.int32, device=dev) for name in ("warp_anyhit", "warp_best")}
    paths = {"warp_anyhit": explicit(default_bvh, outs["warp_anyhit"]), "warp_best": explicit(best_bvh, outs["warp_best"])}
    bakes = {b: TransferTracer(scene, 4, args.samples, vertices=receivers, device=dev, rays=b)
             for b in (("warp", "embree") if embree else ("warp",))}
    for b, tracer in bakes.items():
        paths[f"bake_{b}"] = (lambda tr: lambda: tr.trace_state(state.points, state.normals))(tracer)
    prt = TransferTracer(scene, IN_FRAME_ORDER, IN_FRAME_RAYS, device=dev, rays="warp")
    paths["prt_trace"] = lambda: prt.trace_state(state.points, state.normals)

    # the hybrid residual kernel over every vertex, and its rays for Embree
    v = scene.vertex_count
    coeffs = IN_FRAME_ORDER * IN_FRAME_ORDER
    hybrid_kernel = residual_kernel(IN_FRAME_ORDER)
    residual = wp.empty((v, coeffs), dtype=wp.float32, device=dev)
    variance = wp.empty(v, dtype=wp.float32, device=dev)
    step = wp.zeros(1, dtype=wp.int32, device=dev)
    no_frames = wp.empty(0, dtype=wp.mat33, device=dev)
    no_control = wp.empty((0, coeffs), dtype=wp.float32, device=dev)
    offset = default_bvh.offset
    settings = residual_settings(quantity=QUANTITY_TRANSFER, count=IN_FRAME_RAYS, offset=offset)
    set_directions = wp.empty(IN_FRAME_RAYS, dtype=wp.vec3, device=dev)
    set_basis = wp.empty((IN_FRAME_RAYS, coeffs), dtype=wp.float32, device=dev)
    tables = sh_kernels(IN_FRAME_ORDER).tables(dev)

    def hybrid_trace():  # as the stage launches it: the step's shared set, then the rays
        wp.launch(cycle_table_kernel(IN_FRAME_ORDER), dim=IN_FRAME_RAYS, device=dev,
                  inputs=[step, IN_FRAME_RAYS, 1, set_directions, set_basis])
        launch_parallel(hybrid_kernel, v, lambda lo, hi: [
            default_bvh.id, state.points, state.normals, no_frames, no_control, settings, step, set_directions, set_basis,
            tables, lo, residual, variance], dev, workers)

    paths["hybrid_trace"] = hybrid_trace
    h_o = wp.empty(v * IN_FRAME_RAYS, dtype=wp.vec3, device=dev)
    h_d = wp.empty(v * IN_FRAME_RAYS, dtype=wp.vec3, device=dev)
    h_above = wp.empty(v * IN_FRAME_RAYS, dtype=wp.int32, device=dev)
    wp.launch(_hybrid_rays_kernel, dim=(v, IN_FRAME_RAYS), inputs=[state.points, state.normals, IN_FRAME_RAYS, 0, offset,
                                                                   h_o, h_d, h_above], device=dev)
    above = h_above.numpy().astype(bool)
    hybrid_o, hybrid_d = h_o.numpy()[above], h_d.numpy()[above]
    hybrid_rays = int(above.sum())
    # the kernel's rays alone (Warp any-hit on the same rays, explicit): what in hybrid_trace is tracing
    h_o_wp = wp.array(hybrid_o, dtype=wp.vec3, device=dev)
    h_d_wp = wp.array(hybrid_d, dtype=wp.vec3, device=dev)
    h_hits = wp.empty(hybrid_rays, dtype=wp.int32, device=dev)
    paths["hybrid_rays_warp"] = lambda: launch_parallel(_occlusion_kernel, hybrid_rays, lambda lo, hi: [
        default_bvh.mesh.id, h_o_wp[lo:hi], h_d_wp[lo:hi], float(RAY_MAX_DISTANCE), h_hits[lo:hi]], dev, workers)

    answers = {}
    if embree:
        engines = {"embree_1": EmbreeOcclusion(scene.points_at(frame), scene.faces, workers=1)}
        if workers > 1 and not args.quick:
            engines["embree_n"] = EmbreeOcclusion(scene.points_at(frame), scene.faces, workers=workers)
        for name, engine in engines.items():
            paths[name] = (lambda e, n: lambda: answers.__setitem__(n, e.occluded(origins, dirs, unit_directions=True)))(engine, name)
            paths[f"{name}_hybrid_rays"] = (lambda e, n: lambda: answers.__setitem__(n, e.occluded(hybrid_o, hybrid_d,
                                                                                               unit_directions=True)))(engine, f"{name}_hybrid_rays")
    times = rounds(paths, args.repeats, dev)

    counts = {name: rays for name in paths}
    counts["prt_trace"] = v * IN_FRAME_RAYS
    counts["hybrid_trace"] = hybrid_rays
    counts["hybrid_rays_warp"] = hybrid_rays
    for name in paths:
        if name.endswith("_hybrid_rays"):
            counts[name] = hybrid_rays
    results = {name: {"seconds": statistics.median(t), "rays": counts[name], "rays_per_second": counts[name] / statistics.median(t)}
               for name, t in times.items()}
    reference = [n for n in ("embree_1", "embree_n") if n in results]
    if reference:
        ref_explicit = {n: np.array(times[n]) for n in reference}
        ref_hybrid = {n: np.array(times[f"{n}_hybrid_rays"]) for n in reference}
        for name, t in times.items():
            if name.endswith("_hybrid_rays"):
                continue
            on_hybrid_rays = name in ("hybrid_trace", "hybrid_rays_warp")
            ref = ref_hybrid if on_hybrid_rays else ref_explicit
            # per round: the best Embree of that round over this path (rays per second)
            ref_rays = hybrid_rays if on_hybrid_rays else rays
            best = np.max([ref_rays / r for r in ref.values()], axis=0)
            results[name]["ratio_to_embree"] = float(np.median((counts[name] / np.array(t)) / best))
        embree_hits = answers["embree_1"].astype(bool)
        for name in ("warp_anyhit", "warp_best"):
            results[name]["rays_disagreeing_with_embree"] = int(np.sum(outs[name].numpy().astype(bool) != embree_hits))
        if "embree_n" in answers:
            results["embree_n"]["rays_disagreeing_with_embree"] = int(np.sum(answers["embree_n"].astype(bool) != embree_hits))
        # Warp's any-hit on the hybrid kernel's rays against Embree's
        h_out = h_hits.numpy().astype(bool)
        results["hybrid_trace"]["rays_disagreeing_with_embree"] = int(np.sum(h_out != answers["embree_1_hybrid_rays"].astype(bool)))
        if "bake_embree" in results:
            a, b = bakes["warp"].result(), bakes["embree"].result()
            results["bake_embree"]["max_abs_difference_vs_bake_warp"] = float(max(
                np.abs(a.transfer - b.transfer).max(), np.abs(a.visibility - b.visibility).max()))
    # the share of hybrid_trace's time that its rays alone take (per round, median)
    results["hybrid_trace"]["rays_share"] = float(np.median(np.array(times["hybrid_rays_warp"]) / np.array(times["hybrid_trace"])))
    for name, r in results.items():
        ratio = f"  {r['ratio_to_embree']:.2f}x Embree" if "ratio_to_embree" in r else ""
        dis = f"  {r['rays_disagreeing_with_embree']} disagree" if "rays_disagreeing_with_embree" in r else ""
        share = f"  rays {r['rays_share']:.0%} of it" if "rays_share" in r else ""
        print(f"  {name:24s} {r['rays_per_second'] / 1e6:8.2f} Mrays/s  ({r['seconds'] * 1e3:8.1f} ms){ratio}{dis}{share}", flush=True)

    mitsuba = None
    if not args.no_mitsuba:
        mitsuba = mitsuba_ray_test(scene.points_at(frame), scene.faces, origins, dirs, args.repeats)
        if mitsuba is not None:
            variant, seconds, hits, note = mitsuba
            disagree = int(np.sum(hits != outs["warp_anyhit"].numpy().astype(bool)[: len(hits)]))
            results["mitsuba_ray_test"] = {"seconds": seconds, "rays": rays, "rays_per_second": rays / seconds, "variant": variant,
                                           "note": note, "rays_disagreeing_with_warp": disagree}
    return {"vertex_count": scene.vertex_count, "triangle_count": scene.triangle_count, "rays": rays,
            "hybrid_rays": hybrid_rays, "bvh_sweep": sweep, "best_leaf_size": best_leaf, "results": results}, (scene, frame, receivers)


def goals(report: dict) -> dict:
    """Per scene: the best bulk and in-frame ratios to Embree against the goals."""
    out = {}
    for key, sc in report["scenes"].items():
        r = sc["results"]
        bulk = {n: r[n]["ratio_to_embree"] for n in BULK_PATHS if n in r and "ratio_to_embree" in r[n] and n != "embree_n"}
        frame = {n: r[n]["ratio_to_embree"] for n in IN_FRAME_PATHS if n in r and "ratio_to_embree" in r[n]}
        if bulk:
            best = max(bulk, key=bulk.get)
            out[key] = {"bulk_best": best, "bulk_ratio": bulk[best], "bulk_goal_met": bulk[best] >= GOAL_BULK,
                        "in_frame": frame, "in_frame_goal_met": all(x >= GOAL_IN_FRAME for x in frame.values())}
    return out


def chart(report: dict, path: Path) -> None:
    """Bars: each path's throughput over Embree's, per scene, with the two goals."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n in (*BULK_PATHS, *IN_FRAME_PATHS, "hybrid_rays_warp") if n != "embree_n"]
    scenes = [k for k, sc in report["scenes"].items() if any("ratio_to_embree" in v for v in sc["results"].values())]
    fig, ax = plt.subplots(figsize=(max(6.0, 1.6 * len(scenes) + 3.0), 4.0))
    width = 0.8 / len(names)
    for i, name in enumerate(names):
        vals = [report["scenes"][k]["results"].get(name, {}).get("ratio_to_embree", np.nan) for k in scenes]
        ax.bar(np.arange(len(scenes)) + (i - (len(names) - 1) / 2) * width, vals, width, label=name)
    ax.axhline(GOAL_BULK, color="k", ls="--", lw=1, label=f"bulk goal {GOAL_BULK}")
    ax.axhline(GOAL_IN_FRAME, color="gray", ls=":", lw=1, label=f"in-frame goal {GOAL_IN_FRAME}")
    ax.set_xticks(np.arange(len(scenes)), scenes)
    ax.set_ylabel("throughput / Embree's (best of 1 and N processes)")
    ax.set_title(f"shadow rays on {report['device']} ({report['machine']['cpu_count']} cores), {report['date']}")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=90)
    plt.close(fig)


def mitsuba_ray_test(points, faces, origins, dirs, repeats):
    """Time Mitsuba's ray_test on the batch; returns (variant, seconds, hits, note)."""
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError:
        return None
    try:
        mi.set_variant("llvm_ad_rgb")
        variant = "llvm_ad_rgb"
    except Exception:
        mi.set_variant("scalar_rgb")
        variant = "scalar_rgb"
    mesh = mi.Mesh("scene", len(points), len(faces), has_vertex_normals=False)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(np.asarray(points, np.float32).ravel()) if variant != "scalar_rgb" else np.asarray(points, np.float32).ravel()
    params["faces"] = mi.UInt32(np.asarray(faces, np.uint32).ravel()) if variant != "scalar_rgb" else np.asarray(faces, np.uint32).ravel()
    params.update()
    scene = mi.load_dict({"type": "scene", "mesh": mesh})
    o = np.asarray(origins, np.float32)
    d = np.asarray(dirs, np.float32)
    if variant == "llvm_ad_rgb":
        ray = mi.Ray3f(mi.Point3f(o[:, 0], o[:, 1], o[:, 2]), mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))
        ray.maxt = RAY_MAX_DISTANCE

        def run():
            hit = scene.ray_test(ray)
            dr.eval(hit)
            return np.asarray(hit)

        run()
        times, hits = [], None
        for _ in range(repeats):
            t0 = time.perf_counter()
            hits = run()
            times.append(time.perf_counter() - t0)
        return variant, statistics.median(times), hits.astype(bool), f"drjit threads: {dr.thread_count()}"
    count = min(len(o), 20000)  # a Python loop: time a prefix
    t0 = time.perf_counter()
    hits = np.array([bool(scene.ray_test(mi.Ray3f(mi.Point3f(*o[i]), mi.Vector3f(*d[i])))) for i in range(count)])
    seconds = (time.perf_counter() - t0) * len(o) / count
    return variant, seconds, hits, f"python loop over {count} rays, extrapolated"


def convergence_table(scene, frame, device, receivers, order, counts, reference_samples):
    """RMS error of the transfer vectors vs a high-sample estimate (independent seed)."""
    ref_tracer = TransferTracer(scene, order, reference_samples, vertices=receivers, device=device, seed=1000)
    ref_tracer.trace(frame)
    reference = ref_tracer.result().transfer.astype(np.float64)
    scale = float(np.sqrt(np.mean(reference**2)))
    rows = []
    for count in counts:
        tracer = TransferTracer(scene, order, count, vertices=receivers, device=device, seed=1)
        tracer.trace(frame)
        err = float(np.sqrt(np.mean((tracer.result().transfer - reference) ** 2)))
        rows.append({"samples": count, "rms_error": err, "relative_rms_error": err / scale})
    for a, b in zip(rows[:-1], rows[1:]):
        b["error_ratio_vs_previous"] = a["rms_error"] / b["rms_error"]
    return {"order": order, "receivers": len(receivers), "reference_samples": reference_samples, "rows": rows}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", default=",".join(SCENES), help=f"comma-separated: {', '.join(SCENES)} or scene specs")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--receivers", type=int, default=4096)
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--workers", type=int, default=None, help="thread-pool size for chunked CPU launches and Embree "
                        "worker processes (default: warpshade._wp.cpu_workers())")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-sweep", dest="sweep", action="store_false", help="skip the BVH leaf-size sweep")
    parser.add_argument("--no-embree", action="store_true")
    parser.add_argument("--no-mitsuba", action="store_true")
    parser.add_argument("--no-convergence", action="store_true")
    parser.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke profile: blockers, 256 receivers x 16 samples, one repeat, no sweep, Embree in-process "
                             "only, no Mitsuba, no convergence study")
    args = parser.parse_args(argv)
    if args.quick and args.out is None:
        parser.error("--quick writes only into --out DIR (never benchmarks/results)")
    args.out = args.out or str(ROOT / "benchmarks" / "results")
    if args.quick:
        args.scenes, args.receivers, args.samples, args.repeats = "blockers", 256, 16, 1
        args.sweep, args.no_mitsuba, args.no_convergence = False, True, True

    dev = resolve_device(args.device)
    workers = args.workers or cpu_workers()
    scenes, last = {}, None
    for key in [k.strip() for k in args.scenes.split(",") if k.strip()]:
        scenes[key], last = bench_scene(key, SCENES.get(key, key), args, dev, workers)

    convergence = None
    if not args.no_convergence and last is not None:
        scene, frame, receivers = last
        subset = receivers[:256]
        convergence = convergence_table(scene, frame, dev, subset, 4, (64, 256, 1024, 4096), 16384)
        print(f"  convergence (order 4, {len(subset)} receivers, reference 16384 samples):")
        for row in convergence["rows"]:
            ratio = row.get("error_ratio_vs_previous")
            print(f"    S={row['samples']:5d}  rms={row['rms_error']:.3e}  rel={row['relative_rms_error']:.3e}" + (f"  ratio={ratio:.2f}" if ratio else ""))

    import warp

    report = {
        "date": datetime.date.today().isoformat(),
        "device": str(dev),
        "device_name": dev.name,
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "processor": platform.processor(),
                    "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None},
        "warp_version": warp.__version__,
        "commit": checkout_commit(ROOT),
        "receivers": args.receivers,
        "samples": args.samples,
        "workers": workers,
        "repeats": args.repeats,
        "goals": {"bulk": GOAL_BULK, "in_frame": GOAL_IN_FRAME},
        "scenes": scenes,
        "convergence": convergence,
        "command": "python benchmarks/bench_rays.py " + " ".join(argv if argv is not None else sys.argv[1:]),
    }
    if embree_available():
        from importlib.metadata import version

        report["embreex_version"] = version("embreex")
    report["goal_check"] = goals(report)
    for key, g in report["goal_check"].items():
        frame = ", ".join(f"{n} {x:.2f}x" for n, x in g["in_frame"].items())
        print(f"{key}: bulk best {g['bulk_best']} {g['bulk_ratio']:.2f}x Embree (goal {GOAL_BULK}: "
              f"{'met' if g['bulk_goal_met'] else 'missed'}); in-frame {frame} (goal {GOAL_IN_FRAME}: "
              f"{'met' if g['in_frame_goal_met'] else 'missed'})")
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = f"rays-{report['date']}-{str(dev).replace(':', '')}"
    write_json_atomic(out_dir / f"{stem}.json", report)
    if report["goal_check"]:
        chart(report, out_dir / f"{stem}.png")
    print(f"wrote {out_dir / stem}.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
