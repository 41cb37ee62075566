"""Blocker sphere sets: outside volume E vs sphere count, construction time, and how the
attached spheres behave over the skinned figure's animation.

Usage::

    python benchmarks/bench_spheres.py                 # counts 8 16 32 64 128, CPU
    python benchmarks/bench_spheres.py --quick --out /tmp/spheres   # smoke run: the figure, 4 spheres, coarse fits
    python benchmarks/bench_spheres.py --counts 64 --meshes bunny --out /tmp/spheres

Writes ``spheres-<date>.json`` and ``spheres-<date>.png`` into ``--out`` (default
``benchmarks/results``; the PNG: E vs count next to the paper's Figure 4 numbers, the
64-sphere sets drawn over their meshes, and the figure's per-frame bounding statistics).
Measured:

* ``fits``: for the figure body, Warp's bunny and bear, per sphere count: E = sum_i V(S_i - T)
  / V(T) (eq. 35, QMC with standard error), the union form, the grid estimate the optimiser
  minimised, the final count after pruning, construction seconds; plus a k-means baseline
  (k-means clusters of the same samples, each bounded by its minimal sphere) for context;
* ``animation``: the figure fit at frame 0 (budget 32), over every frame: the fraction of
  deformed surface samples outside all spheres and the largest distance outside, for the MVC
  (4 bones, all bones) and cluster skin-weight (LBS of the centre) attachments, with fixed radii and with
  radii calibrated on the animation (and what calibration costs in E); drift of the attached
  centre from the centre Powell finds for the deformed cluster on the deformed mesh, on every
  10th frame;
* ``hierarchy``: tree size, mean parent radius per refit mode over the animation, mean cut
  length per receiver cluster at theta_max = 25 degrees;
* ``per_frame_ms``: median time of the per-frame kernels (sphere attachment, refit, receiver
  bounds, cut) on the figure, and the QMC classification single launch vs split over the pool.
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from warpshade._fileio import atomic_path, write_json_atomic
from warpshade._wp import launch_parallel, resolve_device, wp
from warpshade.geometry import spheres as sp
from warpshade.geometry.spheres import _core as core_internals
from warpshade.geometry.spheres import _fit as fit_internals
from warpshade.geometry.spheres import _kernels as kernels
from warpshade.geometry.spheres import _tree as tree_internals
from warpshade.io import load_scene
from warpshade.methods.shexp import _spheres as ss
from warpshade.scene import FrameEvaluator

#: Ren et al. 2006, Figure 4 (bunny): E for three sphere-set constructions.
PAPER_FIGURE4 = {"octree (Hubbard 1995)": (575, 4.1), "medial axis (Bradshaw 2004)": (64, 0.52), "variational (Ren 2006)": (64, 0.35)}

MESHES = {
    "figure": ("bundled:figure", "/World/Figure/Body"),
    "bunny": ("warp-example:bunny", None),
    "bear": ("warp-example:bear", None),
}
#: Fit settings of the ``--quick`` smoke profile (few iterations and teleports, a coarse grid).
QUICK_FIT = {"iterations": 2, "teleports": 2, "grid_cells": 20000, "samples_per_sphere": 256}


def mesh_points(key):
    spec, path = MESHES[key]
    scene = load_scene(spec)
    mesh = next(m for m in scene.meshes if path is None or m.path == path)
    pts = scene.points_at(scene.frames[0])[mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count]
    return pts, mesh.faces, mesh.path, scene.up_axis


def kmeans_baseline(points, faces, count, name, seed=0):
    """k-means of the construction's samples, each cluster bounded by its minimal sphere."""
    from scipy.cluster.vq import kmeans2

    solid = fit_internals.make_solid(points, faces, name)
    disc = fit_internals.Discretisation(solid)
    samples = np.concatenate([disc.surface, disc.interior])
    _, labels = kmeans2(samples, count, minit="++", seed=np.random.default_rng(seed))
    centres, radii = [], []
    for j in np.unique(labels):
        pts = samples[labels == j]
        c = tree_internals._min_enclosing_centre(pts, np.zeros(pts.shape[0]))
        centres.append(c)
        radii.append(fit_internals.bounding_radius(pts, c))
    volume, _ = sp.solid_volume(solid=solid)
    ov = sp.outside_volume(np.array(centres), np.array(radii), solid=solid)
    return {"count": len(radii), "E": ov.total / volume, "E_stderr": ov.total_stderr / volume, "E_union": ov.union / volume}


def run_fits(keys, counts, fit_options):
    rows = []
    for key in keys:
        points, faces, name, up = mesh_points(key)
        for n in counts:
            t0 = time.perf_counter()
            s = sp.fit_spheres(points, faces, n, name=name, progress=True, **fit_options)
            seconds = time.perf_counter() - t0
            row = {
                "mesh": key,
                "source": name,
                "requested": n,
                "spheres": s.sphere_count,
                "E": s.error,
                "E_stderr": s.error_stderr,
                "E_union": s.error_union,
                "E_grid": s.grid_error,
                "volume": s.volume,
                "seconds": seconds,
                "teleports_accepted": s.parameters["teleports_accepted"],
                "samples_clustered": s.parameters["samples_clustered"],
            }
            if n in (16, 64):
                row["kmeans_baseline"] = kmeans_baseline(points, faces, n, name)
            rows.append(row)
            print(f"{key:7s} n={n:4d} -> {s.sphere_count:4d} spheres  E={s.error:.3f}+-{s.error_stderr:.3f}  "
                  f"union={s.error_union:.3f}  grid={s.grid_error:.3f}  {seconds:6.1f}s", flush=True)
            if key in ("bunny", "figure", "bear") and n == 64:
                rows[-1]["_set"] = s
                rows[-1]["_mesh"] = (points, faces, up)
    return rows


def frame_stats(spheres, scene, frames):
    out = []
    for f in frames:
        pts, _ = spheres.surface_samples_at(scene, f)
        gap = sp.coverage_gap_f64(pts, spheres.centres_at(scene, f), spheres.radii_at(scene, f))
        out.append({"frame": float(f), "outside_fraction": float(np.mean(gap > 0)), "max_gap": float(max(gap.max(), 0.0))})
    return out


def drift(spheres, scene, frames):
    """|attached centre - Powell centre of the deformed cluster on the deformed mesh| / radius."""
    mesh = scene.meshes[int(spheres.mesh_index[0])]
    ratios, radius_ratios = [], []
    for f in frames:
        world = scene.points_at(f)[mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count]
        solid = fit_internals.make_solid(world, mesh.faces, mesh.path)
        disc = fit_internals.Discretisation(solid)
        pts, owner = spheres.surface_samples_at(scene, f)
        centres = spheres.centres_at(scene, f)
        clusters = [pts[owner == i] for i in range(spheres.sphere_count)]
        keep = [i for i, c in enumerate(clusters) if c.shape[0] > 0]
        best = fit_internals.update_centres(disc, [clusters[i] for i in keep], centres[keep], sweeps=3)
        r = spheres.radii_at(scene, f)[keep]
        ratios.extend((np.linalg.norm(best - centres[keep], axis=1) / r).tolist())
        need_attached = np.array([fit_internals.bounding_radius(clusters[i], centres[i]) for i in keep])
        need_best = np.array([fit_internals.bounding_radius(clusters[i], b) for i, b in zip(keep, best)])
        radius_ratios.extend((need_attached / need_best).tolist())
    ratios = np.array(ratios)
    return {
        "frames": [float(f) for f in frames],
        "drift_over_radius_median": float(np.median(ratios)),
        "drift_over_radius_p95": float(np.percentile(ratios, 95)),
        "drift_over_radius_max": float(ratios.max()),
        "needed_radius_attached_over_optimal_median": float(np.median(radius_ratios)),
        "needed_radius_attached_over_optimal_max": float(np.max(radius_ratios)),
    }


def run_animation(quick, device):
    scene = load_scene("bundled:figure")
    frames = scene.frames[::12] if quick else scene.frames
    results = {}
    budget, fit_options = (4, QUICK_FIT) if quick else (32, {})
    base = ss.spheres_for_scene(scene, budget=budget, progress=True, device=device, **fit_options)
    variants = {
        "mvc_4_bones": base,
        "mvc_all_bones": ss.spheres_for_scene(scene, budget=budget, max_bones=scene.skeletons[0].joint_count, device=device,
                                              **fit_options),
        "cluster_skin_weights": ss.spheres_for_scene(scene, budget=budget, skinned_attachment="skin_weights", device=device,
                                                     **fit_options),
    }
    mesh = scene.meshes[int(base.mesh_index[0])]
    solid = fit_internals.make_solid(scene.points_at(scene.frames[0])[mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count], mesh.faces, mesh.path)
    for name, spheres in variants.items():
        stats = frame_stats(spheres, scene, frames)
        mean_r = float(spheres.rest_radii.mean())
        row = {
            "spheres": spheres.sphere_count,
            "E_fit_frame": spheres.sets[0].error,
            "mean_radius": mean_r,
            "per_frame": stats,
            "max_outside_fraction": max(s["outside_fraction"] for s in stats),
            "max_gap": max(s["max_gap"] for s in stats),
            "max_gap_over_mean_radius": max(s["max_gap"] for s in stats) / mean_r,
            "drift": drift(spheres, scene, scene.frames[10::10] if not quick else scene.frames[15:16]),
        }
        calibrated = ss.SceneSpheres.from_arrays(spheres.to_arrays())
        growth = calibrated.calibrate_radii(scene)
        cal_stats = frame_stats(calibrated, scene, frames)
        vol, _ = sp.solid_volume(solid=solid)
        ov = sp.outside_volume(calibrated.centres_at(scene, scene.frames[0]), calibrated.radii_at(scene, scene.frames[0]), solid=solid)
        row["calibrated"] = {
            "radius_growth_max": float(growth.max()),
            "radius_growth_mean": float(growth.mean()),
            "E_fit_frame": ov.total / vol,
            "max_outside_fraction": max(s["outside_fraction"] for s in cal_stats),
            "max_gap": max(s["max_gap"] for s in cal_stats),
        }
        results[name] = row
        print(f"animation {name:22s} outside<= {row['max_outside_fraction']:.4f}  max gap {row['max_gap']:.4f} "
              f"({row['max_gap_over_mean_radius']:.3f} r)  drift median {row['drift']['drift_over_radius_median']:.3f} r  "
              f"calibrated: growth x{growth.max():.3f}, E {ov.total / vol:.3f} (fixed {spheres.sets[0].error:.3f})", flush=True)
    return scene, base, results


def run_hierarchy(scene, spheres, device, quick):
    tree = sp.build_sphere_tree(spheres.centres, spheres.rest_radii, groups=spheres.sphere_mesh)
    evaluator = FrameEvaluator(scene, device)
    state = evaluator.state
    animator = ss.SphereAnimator(scene, spheres, device=device)
    refits = {m: sp.SphereTreeRefit(tree, device=device, mode=m) for m in sp.REFIT_MODES}
    clusters = ss.scene_receiver_clusters(scene, vertices_per_cluster=300)
    bounds = sp.ReceiverBounds(clusters, device=device)
    cut = sp.HierarchyCut(refits["min"], clusters.cluster_count)
    radius = {m: [] for m in refits}
    cut_len = []
    times = {"attach": [], "refit": [], "receiver_bounds": [], "cut": []}
    frames = scene.frames[::12] if quick else scene.frames
    for f in frames:
        evaluator.set_frame(f)
        evaluator.launch()
        wp.synchronize_device(device)
        for name, fn in (
            ("attach", lambda: animator.launch(state)),
            ("refit", lambda: refits["min"].launch(animator.centres, animator.radii)),
            ("receiver_bounds", lambda: bounds.launch(state.points)),
            ("cut", lambda: cut.launch(bounds.centres, bounds.radii)),
        ):
            t0 = time.perf_counter()
            fn()
            wp.synchronize_device(device)
            times[name].append(1e3 * (time.perf_counter() - t0))
        for m, r in refits.items():
            r.launch(animator.centres, animator.radii)
            radius[m].append(float(r.node_radii.numpy()[tree.level_nodes].mean()))
        cut_len.append(float(cut.cut_count.numpy().mean()))
    return {
        "nodes": tree.node_count,
        "leaves": tree.leaf_total,
        "height": tree.height,
        "inner_branching_mean": float(tree.child_count[tree.level_nodes].mean()),
        "mean_parent_radius": {m: float(np.mean(v)) for m, v in radius.items()},
        "rest_mean_parent_radius": float(tree.node_radius[tree.level_nodes].mean()),
        "receiver_clusters": clusters.cluster_count,
        "mean_cut_length": float(np.mean(cut_len)),
        "theta_max_degrees": sp.DEFAULT_THETA_MAX_DEGREES,
        "per_frame_ms_median": {k: statistics.median(v[1:]) for k, v in times.items()},
    }


def split_launch_ratio(device, key="bunny", spheres=64, samples=4096, repeats=3):
    """QMC classification of 64 spheres x 4096 samples on a mesh (the bunny): one launch vs the
    pool, median of ``repeats`` after a warm-up."""
    points, faces, name, _ = mesh_points(key)
    solid = fit_internals.make_solid(points, faces, name, device=device)
    rng = np.random.default_rng(0)
    centres = points[rng.choice(points.shape[0], spheres)]
    radii = np.full(spheres, 0.1)
    n = spheres * samples
    dev = solid.device
    cw = wp.array(centres.astype(np.float32), dtype=wp.vec3, device=dev)
    rw = wp.array(radii.astype(np.float32), dtype=wp.float32, device=dev)
    ub = wp.array(core_internals._unit_ball(samples, 1, 0)[0].astype(np.float32), dtype=wp.vec3, device=dev)
    out = wp.empty(n, dtype=wp.float32, device=dev)
    uw = wp.empty(n, dtype=wp.float32, device=dev)
    mid = solid.mesh_id

    def single():
        wp.launch(kernels.ball_samples_kernel, dim=n, inputs=[mid, 0.0, cw, rw, ub, 0, out, uw], device=dev)
        wp.synchronize_device(dev)

    def split():
        launch_parallel(kernels.ball_samples_kernel, n, lambda start, stop: [mid, 0.0, cw, rw, ub, start, out, uw], dev,
                        min_count=fit_internals.SPLIT_MIN)
        wp.synchronize_device(dev)

    res = {}
    for key, fn in (("single_launch_s", single), ("split_launch_s", split)):
        fn()
        ts = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        res[key] = statistics.median(ts)
    res["speedup"] = res["single_launch_s"] / res["split_launch_s"]
    print(f"QMC classification {n} points: single {res['single_launch_s']:.2f}s, split {res['split_launch_s']:.2f}s (x{res['speedup']:.2f})")
    return res


def plot(path, rows, animation):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(16, 10))
    ax = axes[0, 0]
    for colour, key in zip(("tab:blue", "tab:orange", "tab:green"), MESHES):
        r = [x for x in rows if x["mesh"] == key]
        if r:
            ax.errorbar([x["spheres"] for x in r], [x["E"] for x in r], yerr=[x["E_stderr"] for x in r], marker="o", color=colour, label=f"{key}: sum (eq. 35)")
            ax.plot([x["spheres"] for x in r], [x["E_union"] for x in r], ls=":", marker=".", color=colour, label=f"{key}: union")
    for marker, (label, (n, e)) in zip(("*", "P", "X"), PAPER_FIGURE4.items()):
        ax.scatter([n], [e], marker=marker, s=120, color="k", label=f"paper, bunny: {label}")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("spheres")
    ax.set_ylabel("E = outside volume / object volume")
    ax.set_title("Outside volume vs sphere count")
    ax.legend(fontsize=7)
    ax = axes[0, 1]
    for key in MESHES:
        r = [x for x in rows if x["mesh"] == key]
        if r:
            ax.plot([x["spheres"] for x in r], [x["seconds"] for x in r], marker="o", label=key)
    ax.set_xscale("log", base=2)
    ax.set_xlabel("spheres")
    ax.set_ylabel("construction seconds (2-core CPU)")
    ax.legend()
    ax.set_title("Construction time")
    ax = axes[0, 2]
    for name, row in animation.items():
        ax.plot([s["frame"] for s in row["per_frame"]], [s["max_gap"] / row["mean_radius"] for s in row["per_frame"]], label=name)
    ax.set_xlabel("frame")
    ax.set_ylabel("max distance outside / mean radius")
    ax.set_title("Figure: deformed samples outside fixed-radius spheres")
    ax.legend(fontsize=8)
    drawn = [x for x in rows if "_set" in x]
    for ax, row in zip(axes[1], drawn):
        s = row["_set"]
        pts, _, up = row["_mesh"]
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        ext = hi - lo
        b = {"Y": 1, "Z": 2}[up]  # the up axis is vertical, the wider other axis horizontal
        a = max((k for k in range(3) if k != b), key=lambda k: ext[k])
        ax.scatter(pts[:, a], pts[:, b], s=0.2, c="k", alpha=0.3)
        for c, r in zip(s.centres, s.radii):
            ax.add_patch(plt.Circle((c[a], c[b]), r, fill=True, alpha=0.12, color="tab:blue"))
            ax.add_patch(plt.Circle((c[a], c[b]), r, fill=False, lw=0.5, color="tab:blue"))
        ax.set_aspect("equal")
        ax.set_xlim(lo[a] - 0.2 * ext[a], hi[a] + 0.2 * ext[a])
        ax.set_ylim(lo[b] - 0.2 * ext[b], hi[b] + 0.2 * ext[b])
        ax.set_title(f"{row['mesh']}: {s.sphere_count} spheres, E={s.error:.2f} (orthographic)")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--counts", type=int, nargs="+", default=None)
    parser.add_argument("--meshes", nargs="+", default=list(MESHES), choices=list(MESHES))
    parser.add_argument("--quick", action="store_true",
                        help="smoke profile: the figure only, 4 spheres, coarse fits, every 12th frame")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--skip-animation", action="store_true")
    parser.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = parser.parse_args()
    if args.quick and args.out is None:
        parser.error("--quick writes only into --out DIR (never benchmarks/results)")
    device = resolve_device(args.device)
    counts = args.counts or ([4] if args.quick else [8, 16, 32, 64, 128])
    meshes = ["figure"] if args.quick and args.meshes == list(MESHES) else args.meshes
    t_start = time.perf_counter()
    rows = run_fits(meshes, counts, QUICK_FIT if args.quick else {})
    animation, hierarchy = {}, {}
    if not args.skip_animation:
        scene, base, animation = run_animation(args.quick, device)
        hierarchy = run_hierarchy(scene, base, device, args.quick)
        print("hierarchy", json.dumps({k: v for k, v in hierarchy.items()}, indent=None))
    split = split_launch_ratio(device, "figure", 8, 1024, 1) if args.quick else split_launch_ratio(device)
    date = datetime.date.today().isoformat()
    stem = f"spheres-{date}" + ("-quick" if args.quick else "")
    out_dir = Path(args.out or ROOT / "benchmarks" / "results")
    out_dir.mkdir(parents=True, exist_ok=True)
    png = out_dir / f"{stem}.png"
    plot(png, rows, animation)
    bunny64 = next((x for x in rows if x["mesh"] == "bunny" and x["requested"] == 64), None)
    report = {
        "date": date,
        "device": str(device),
        "machine": platform.platform(),
        "cpu_count": __import__("os").cpu_count(),
        "command": " ".join(sys.argv),
        "fits": [{k: v for k, v in x.items() if not k.startswith("_")} for x in rows],
        "paper_figure4_bunny": {k: {"spheres": n, "E": e} for k, (n, e) in PAPER_FIGURE4.items()},
        "bunny_64_vs_paper": None if bunny64 is None else {"ours_E": bunny64["E"], "ours_spheres": bunny64["spheres"], "paper_E": 0.35},
        "animation": animation,
        "hierarchy": hierarchy,
        "qmc_split_launch": split,
        "total_seconds": time.perf_counter() - t_start,
    }
    write_json_atomic(out_dir / f"{stem}.json", report)
    print(f"wrote {out_dir / f'{stem}.json'} and {png}")


if __name__ == "__main__":
    main()
