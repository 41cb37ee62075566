"""Rays per second of the visibility/transfer kernels, single launch vs chunked launches from a
thread pool, and Mitsuba 3's ray_test on the same rays in the same run; plus the transfer
convergence table (error vs a high-sample estimate as the sample count quadruples).

Usage::

    python benchmarks/bench_rays.py                      # bundled blockers scene, CPU
    python benchmarks/bench_rays.py --device cuda:0      # on a GPU
    python benchmarks/bench_rays.py --scene path.usda --receivers 4096 --samples 256

Writes ``benchmarks/results/rays-<date>-<device>.json``. Measurements:

* ``transfer``: the full transfer kernel (ray generation, any-hit, order-n SH accumulation);
* ``anyhit_generated``: any-hit shadow rays generated in the kernel (visibility count only);
* ``anyhit_explicit``: any-hit on an explicit (origin, direction) batch in device memory -- the
  rays Mitsuba is given;
* ``mitsuba_ray_test``: Mitsuba 3 ``scene.ray_test`` on the same explicit batch (llvm_ad_rgb,
  which uses every core; scalar_rgb in a Python loop otherwise, marked as such).

Each is timed ``--repeats`` times after one warm-up (kernel compilation / Mitsuba JIT) and the
median is reported.
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

from warpshade._fileio import write_json_atomic  # noqa: E402
from warpshade._wp import cpu_workers, launch_parallel, resolve_device, wp  # noqa: E402
from warpshade.geometry.bvh import RAY_MAX_DISTANCE, Visibility, _occlusion_kernel  # noqa: E402
from warpshade.io import bundled_asset_directory  # noqa: E402
from warpshade.transfer import TransferTracer, sample_rays  # noqa: E402

DEFAULT_SCENE = Path(bundled_asset_directory()) / "blockers.usda"


def array_scene():
    """Fallback scene from arrays: a ground grid with a sphere and a box resting above it."""
    import trimesh

    from warpshade.scene import Mesh, Scene

    ground = trimesh.creation.box(extents=(6.0, 6.0, 0.05))
    ground = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(ground.vertices, ground.faces, 0.2))
    ball = trimesh.creation.icosphere(4, radius=0.6)
    ball.apply_translation((0.0, 0.0, 0.9))
    box = trimesh.creation.box(extents=(0.8, 0.5, 0.6))
    box.apply_translation((1.2, -0.8, 0.35))
    return Scene.from_meshes([Mesh("ground", ground.vertices, ground.faces), Mesh("ball", ball.vertices, ball.faces), Mesh("box", box.vertices, box.faces)])


def load_scene(path):
    if path is not None or DEFAULT_SCENE.exists():
        from warpshade.io import load_usd

        p = Path(path) if path is not None else DEFAULT_SCENE
        return load_usd(str(p)), p.name
    return array_scene(), "arrays:ground+ball+box"


def timed(fn, repeats, device):
    fn()  # warm-up: compile / JIT
    wp.synchronize_device(device)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        wp.synchronize_device(device)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


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
    parser.add_argument("--scene", default=None, help="USD scene (default: the bundled blockers.usda, else an array scene)")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--receivers", type=int, default=4096)
    parser.add_argument("--samples", type=int, default=256)
    parser.add_argument("--order", type=int, default=4)
    parser.add_argument("--workers", type=int, default=None, help="thread-pool size for chunked CPU launches (default: warpshade._wp.cpu_workers())")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-mitsuba", action="store_true")
    parser.add_argument("--no-convergence", action="store_true")
    parser.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke profile: 256 receivers x 16 samples, one repeat, no Mitsuba, no convergence study")
    args = parser.parse_args(argv)
    if args.quick and args.out is None:
        parser.error("--quick writes only into --out DIR (never benchmarks/results)")
    args.out = args.out or str(ROOT / "benchmarks" / "results")
    if args.quick:
        args.receivers, args.samples, args.repeats, args.no_mitsuba, args.no_convergence = 256, 16, 1, True, True

    dev = resolve_device(args.device)
    scene, scene_name = load_scene(args.scene)
    frame = float(scene.frames[0])
    rng = np.random.default_rng(0)
    receivers = rng.choice(scene.vertex_count, args.receivers, replace=scene.vertex_count < args.receivers)
    workers = args.workers or cpu_workers()
    rays = args.receivers * args.samples
    print(f"scene {scene_name}: {scene.vertex_count} vertices, {scene.triangle_count} triangles; "
          f"{args.receivers} receivers x {args.samples} samples = {rays} rays on {dev}")

    state = scene.evaluate(frame, device=dev)
    results = {}

    def record(name, seconds, ray_count, **extra):
        results[name] = {"seconds": seconds, "rays": ray_count, "rays_per_second": ray_count / seconds, **extra}
        print(f"  {name:38s} {ray_count / seconds / 1e6:8.2f} Mrays/s  ({seconds * 1e3:.1f} ms)")

    launch_modes = [("single", 1)] + ([("chunked", workers)] if dev.is_cpu and workers > 1 else [])
    for mode, w in launch_modes:
        tracer = TransferTracer(scene, args.order, args.samples, vertices=receivers, device=dev, workers=w)
        seconds = timed(lambda: tracer.trace_state(state.points, state.normals), args.repeats, dev)
        record(f"transfer_order{args.order}_{mode}", seconds, rays, workers=w)
        seconds = timed(lambda: tracer.visible_fraction(state.points, state.normals), args.repeats, dev)
        record(f"anyhit_generated_{mode}", seconds, rays, workers=w)

    origins, dirs = sample_rays(scene, frame, args.samples, vertices=receivers, device=dev)
    origins, dirs = origins.reshape(-1, 3), dirs.reshape(-1, 3)
    bvh = Visibility.from_scene(scene, frame, device=dev)
    o_wp = wp.array(origins, dtype=wp.vec3, device=dev)
    d_wp = wp.array(dirs, dtype=wp.vec3, device=dev)
    out = wp.empty(len(origins), dtype=wp.int32, device=dev)
    seconds = timed(lambda: bvh.occluded(o_wp, d_wp, out=out), args.repeats, dev)
    record("anyhit_explicit_single", seconds, rays, workers=1)
    if dev.is_cpu and workers > 1:
        # the same any-hit kernel over 4 x workers slices of the batch, launched from the thread pool
        def chunked():
            launch_parallel(_occlusion_kernel, len(origins), lambda lo, hi: [bvh.mesh.id, o_wp[lo:hi], d_wp[lo:hi],
                                                                           float(RAY_MAX_DISTANCE), out[lo:hi]], dev, workers)

        seconds = timed(chunked, args.repeats, dev)
        record("anyhit_explicit_chunked", seconds, rays, workers=workers)
    warp_hits = out.numpy().astype(bool)

    mitsuba = None
    if not args.no_mitsuba:
        mitsuba = mitsuba_ray_test(scene.points_at(frame), scene.faces, origins, dirs, args.repeats)
        if mitsuba is None:
            print("  mitsuba not importable: skipped (pip install -e '.[validate]')")
        else:
            variant, seconds, hits, note = mitsuba
            disagree = int(np.sum(hits != warp_hits[: len(hits)]))
            record("mitsuba_ray_test", seconds, rays, variant=variant, note=note, rays_disagreeing_with_warp=disagree, rays_compared=len(hits))
            print(f"    mitsuba vs warp: {disagree} of {len(hits)} rays disagree ({note})")

    ratios = {}
    if "anyhit_explicit_chunked" in results:
        ratios["chunked_over_single_anyhit_explicit"] = results["anyhit_explicit_chunked"]["rays_per_second"] / results["anyhit_explicit_single"]["rays_per_second"]
    if f"transfer_order{args.order}_chunked" in results:
        ratios["chunked_over_single_transfer"] = results[f"transfer_order{args.order}_chunked"]["rays_per_second"] / results[f"transfer_order{args.order}_single"]["rays_per_second"]
    if "mitsuba_ray_test" in results:
        best = max(v["rays_per_second"] for k, v in results.items() if k.startswith("anyhit_explicit"))
        ratios["warp_best_explicit_over_mitsuba"] = best / results["mitsuba_ray_test"]["rays_per_second"]
    for k, v in ratios.items():
        print(f"  {k}: {v:.2f}")

    convergence = None
    if not args.no_convergence:
        subset = receivers[:256]
        convergence = convergence_table(scene, frame, dev, subset, min(args.order, 4), (64, 256, 1024, 4096), 16384)
        print(f"  convergence (order {convergence['order']}, {len(subset)} receivers, reference 16384 samples):")
        for row in convergence["rows"]:
            ratio = row.get("error_ratio_vs_previous")
            print(f"    S={row['samples']:5d}  rms={row['rms_error']:.3e}  rel={row['relative_rms_error']:.3e}" + (f"  ratio={ratio:.2f}" if ratio else ""))

    import warp

    report = {
        "date": datetime.date.today().isoformat(),
        "device": str(dev),
        "device_name": dev.name,
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "processor": platform.processor()},
        "warp_version": warp.__version__,
        "scene": scene_name,
        "vertex_count": scene.vertex_count,
        "triangle_count": scene.triangle_count,
        "receivers": args.receivers,
        "samples": args.samples,
        "order": args.order,
        "workers": workers,
        "repeats": args.repeats,
        "results": results,
        "ratios": ratios,
        "convergence": convergence,
        "command": "python benchmarks/bench_rays.py " + " ".join(argv if argv is not None else sys.argv[1:]),
    }
    if mitsuba is not None:
        import mitsuba as mi

        report["mitsuba_version"] = mi.__version__
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"rays-{report['date']}-{str(dev).replace(':', '')}.json"
    write_json_atomic(path, report)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
