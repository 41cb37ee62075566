"""Cloth inputs of data-driven visibility (Nowrouzezahrai et al. 2009, sec. 5): features and clusters.

On the bundled Newton banner clips (``bundled:cloth_train``, 120 frames, and
``bundled:cloth_heldout``, 60 frames; 1,089 vertices, 2,048 triangles), on the CPU:

* the dihedral-angle PCA (:class:`warpshade.methods.visibility._cloth.DihedralFeatures`) for
  retained-variance targets from 0.5 to 0.99: components kept, and the relative RMS error of the
  angles rebuilt from the features on the training and the held-out clip (the input side of the
  paper's Fig. 5);
* the time of the per-frame feature program (two Warp kernel launches: angles, projection) and of
  the float64 NumPy path, median over the held-out frames;
* rotation-sequence clusters (:func:`~warpshade.methods.visibility._cloth.rotation_clusters`) for
  1 to 64 clusters: the rigid-fit residual of the training clip's labels on the training and the
  held-out clip (clusters against error, the paper's Fig. 4 for the segmentation alone), and the
  count the default budget (0.01 m) picks.

Writes ``visibility-cloth-<date>-cpu.json``, ``visibility-cloth-<date>-cpu-variance.png`` and
``visibility-cloth-<date>-cpu-clusters.png`` into ``--out`` (default ``benchmarks/results``).

Usage::

    python benchmarks/bench_visibility_cloth.py [--out DIR] [--quick]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DATE = "2026-12-02"
TARGETS = (0.5, 0.7, 0.8, 0.9, 0.95, 0.99)
COUNTS = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64)
#: The default rigid-fit budget of rotation_clusters (m).
TOLERANCE = 0.01


def _clip(name: str):
    from warpshade.io import load_usd

    scene = load_usd(f"bundled:{name}")
    cloth = next(m for m in scene.meshes if m.path == "/World/Cloth")
    return cloth.point_samples.astype(np.float64), cloth.faces


def _relative_error(model, points) -> float:
    angles = model.angles(points)
    rebuilt = model.reconstruct(model.transform(points))
    return float(np.sqrt(((rebuilt - angles) ** 2).sum() / ((angles - model.mean) ** 2).sum()))


def _features(train, test, faces, targets):
    from warpshade.methods.visibility._cloth import DihedralFeatures

    rows = []
    for target in targets:
        t0 = time.perf_counter()
        model = DihedralFeatures.fit(train, faces, variance=target)
        fit_s = time.perf_counter() - t0
        row = {"variance_target": target, "components": model.component_count,
               "retained_variance": round(model.retained_variance, 5), "fit_s": round(fit_s, 3),
               "train_rel_error": round(_relative_error(model, train), 5),
               "heldout_rel_error": round(_relative_error(model, test), 5),
               "heldout_novelty_max": round(float(model.novelty(model.transform(test)).max()), 3)}
        print(f"  variance {target:4.2f}: {row['components']:3d} components, held-out angle error {row['heldout_rel_error']:.3f}", flush=True)
        rows.append(row)
    return rows


def _timing(model, test):
    from warpshade._wp import wp

    program = model.bind("cpu")
    arrays = [wp.array(p.astype(np.float32), dtype=wp.vec3, device="cpu") for p in test]
    program.launch(arrays[0])  # compile
    wp.synchronize_device("cpu")
    kernel, numpy_s = [], []
    for a, p in zip(arrays, test):
        t0 = time.perf_counter()
        program.launch(a)
        wp.synchronize_device("cpu")
        kernel.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        model.transform(p)
        numpy_s.append(time.perf_counter() - t0)
    return {"components": model.component_count, "edges": model.edge_count,
            "kernel_ms": round(float(np.median(kernel)) * 1e3, 4), "numpy_f64_ms": round(float(np.median(numpy_s)) * 1e3, 4),
            "frames": len(test)}


def _clusters(train, test, faces, counts):
    from warpshade.methods.visibility._cloth import rigid_fit_residual, rotation_clusters

    rows = []
    for k in counts:
        t0 = time.perf_counter()
        c = rotation_clusters(train, faces, tolerance=1e-12, counts=(k,), max_clusters=k)
        seconds = time.perf_counter() - t0
        rows.append({"asked": k, "clusters": c.count, "train_residual_m": round(c.residual, 6),
                     "heldout_residual_m": round(rigid_fit_residual(test, c.labels, rest=train[0]), 6),
                     "seconds": round(seconds, 2)})
        print(f"  {k:3d} clusters asked, {c.count:3d} kept: residual train {c.residual * 1e3:6.2f} mm, "
              f"held-out {rows[-1]['heldout_residual_m'] * 1e3:6.2f} mm ({seconds:.1f} s)", flush=True)
    t0 = time.perf_counter()
    chosen = rotation_clusters(train, faces, tolerance=TOLERANCE, counts=counts, max_clusters=max(counts))
    budget = {"tolerance_m": TOLERANCE, "clusters": chosen.count, "residual_m": round(chosen.residual, 6),
              "within_budget": chosen.within_budget, "seconds": round(time.perf_counter() - t0, 2)}
    print(f"  budget {TOLERANCE} m: {chosen.count} clusters, residual {chosen.residual * 1e3:.2f} mm", flush=True)
    return rows, budget


def _charts(result, out_variance, out_clusters):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["features"]
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    ax[0].plot([r["variance_target"] for r in rows], [r["components"] for r in rows], "o-")
    ax[0].set_xlabel("retained variance target")
    ax[0].set_ylabel("PCA components kept")
    ax[0].set_title("dihedral-angle PCA (training clip)")
    ax[1].plot([r["components"] for r in rows], [r["train_rel_error"] for r in rows], "o-", label="training")
    ax[1].plot([r["components"] for r in rows], [r["heldout_rel_error"] for r in rows], "s-", label="held out")
    ax[1].set_xlabel("components")
    ax[1].set_ylabel("relative RMS error of the rebuilt angles")
    ax[1].legend()
    fig.tight_layout()
    fig.savefig(out_variance, dpi=100)
    plt.close(fig)
    rows = result["clusters"]
    fig, ax = plt.subplots(figsize=(5.5, 4))
    ax.plot([r["clusters"] for r in rows], [1e3 * r["train_residual_m"] for r in rows], "o-", label="training")
    ax.plot([r["clusters"] for r in rows], [1e3 * r["heldout_residual_m"] for r in rows], "s-", label="held out (training labels)")
    ax.axhline(1e3 * result["cluster_budget"]["tolerance_m"], color="gray", ls="--", label="default budget")
    ax.set_xscale("log", base=2)
    ax.set_xlabel("clusters")
    ax.set_ylabel("rigid-fit residual (mm RMS)")
    ax.set_title("rotation-sequence clusters")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out_clusters, dpi=100)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=None, help="output directory (default benchmarks/results)")
    parser.add_argument("--quick", action="store_true", help="smoke run: 24 training frames, 12 held out, targets 0.9, up to 8 clusters")
    args = parser.parse_args(argv)
    if args.quick and args.out is None:
        parser.error("--quick writes only into --out DIR (a smoke run never writes into benchmarks/results)")
    out = Path(args.out) if args.out else ROOT / "benchmarks" / "results"
    out.mkdir(parents=True, exist_ok=True)
    train, faces = _clip("cloth_train")
    test, test_faces = _clip("cloth_heldout")
    if not np.array_equal(faces, test_faces):
        raise SystemExit("bench_visibility_cloth: the two clips have different topology")
    targets, counts = TARGETS, COUNTS
    if args.quick:
        train, test, targets, counts = train[:24], test[:12], (0.9,), (1, 2, 4, 8)
    t_start = time.perf_counter()
    print(f"dihedral features: {len(train)} training frames, {len(test)} held out", flush=True)
    features = _features(train, test, faces, targets)
    from warpshade.methods.visibility._cloth import DihedralFeatures

    timing = _timing(DihedralFeatures.fit(train, faces, variance=0.9), test)
    print(f"  feature program: {timing['kernel_ms']} ms per frame (Warp, CPU), float64 NumPy {timing['numpy_f64_ms']} ms", flush=True)
    print("rotation clusters:", flush=True)
    clusters, budget = _clusters(train, test, faces, counts)
    result = {
        "date": DATE, "machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "python": sys.version.split()[0]},
        "quick": args.quick, "vertices": int(train.shape[1]), "triangles": int(len(faces)),
        "train_frames": int(len(train)), "heldout_frames": int(len(test)),
        "features": features, "feature_timing": timing, "clusters": clusters, "cluster_budget": budget,
        "wall_s": round(time.perf_counter() - t_start, 1),
    }
    stem = f"visibility-cloth-{DATE}-cpu" + ("-quick" if args.quick else "")
    (out / f"{stem}.json").write_text(json.dumps(result, indent=1))
    _charts(result, out / f"{stem}-variance.png", out / f"{stem}-clusters.png")
    print(f"wrote {out / stem}.json and its two charts ({result['wall_s']} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
