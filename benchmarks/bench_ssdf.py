"""SSDF visibility (Wang et al. 2009, sec. 5) on the blockers scene: bake cost, PCA, SG products.

Part 1 -- bake cost per vertex at the paper's 512 -> 128 (ray tracing the 512^2 hemisphere map,
the signed distance by k-d tree and by the brute-force Warp kernel, measured on the same maps).

Part 2 -- PCA (Fig. 9 analogue): RMS reconstruction error (radians) against the term count, the
count chosen for the error budget, exact vs randomised SVD time.

Part 3 -- the product with an SG lobe (Fig. 7 analogue): per vertex and lobe axis,
``integral G(i; p, lambda, 1) V(i)`` over the upper hemisphere ray traced by sampling the lobe
(:func:`warpshade.transfer._ssdf.trace_lobe_visibility`) against ``f_h(Vd(p), lambda)`` (eq. 30)
from the uncompressed SSDF and from the PCA at each term count; errors in units of
``f_h(pi/2, lambda)`` (the unoccluded lobe). Two references explain the error: ``horizon_only``
(an open sky, where the SSDF is +pi/2 but the truth stops at the horizon: exactly
``f_h(elevation, lambda)``) and the variant ``ssdf_horizon`` (``theta_d = min(Vd(p), elevation)``).

Writes ``benchmarks/results/ssdf-<date>-cpu[-quick].json`` and ``-fig7.png``, ``-fig9.png``,
``-maps.png``.

Usage::

    python benchmarks/bench_ssdf.py [--quick] [--vertices 512] [--budget 0.02] [--out DIR]
"""

from __future__ import annotations

import argparse
import datetime
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

RESULTS = ROOT / "benchmarks" / "results"
SCENE = "bundled:blockers"
SHARPNESS = (2.0, 10.0, 50.0, 200.0, 1000.0)
TERMS = (1, 2, 4, 8, 12, 16, 24, 32, 48, 64)
#: Lobe axes in the local tangent frame: (elevation above the horizon, azimuth), degrees.
AXES_DEG = ((90.0, 0.0), (60.0, 0.0), (60.0, 120.0), (60.0, 240.0), (30.0, 60.0), (30.0, 180.0), (30.0, 300.0))
ORACLE_SAMPLES = 4096
WARP_DISTANCE_VERTICES = 8


def _axes_local() -> np.ndarray:
    e = np.radians([a[0] for a in AXES_DEG])
    az = np.radians([a[1] for a in AXES_DEG])
    return np.stack([np.cos(e) * np.cos(az), np.cos(e) * np.sin(az), np.sin(e)], -1)


def _errors(approx, truth, pole) -> dict:
    """Errors over (vertex, axis) for one lambda: in units of the unoccluded lobe, and relative RMS."""
    e = (approx - truth) / pole
    return {
        "mean_abs_fraction": float(np.mean(np.abs(e))),
        "rms_fraction": float(np.sqrt(np.mean(e**2))),
        "p99_abs_fraction": float(np.percentile(np.abs(e), 99)),
        "rel_rms": float(np.sqrt(np.sum((approx - truth) ** 2) / max(np.sum(truth**2), 1e-300))),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smoke profile: 32 vertices at 128 -> 32")
    ap.add_argument("--vertices", type=int, default=512, help="receivers (a seeded random subset of the scene's)")
    ap.add_argument("--budget", type=float, default=0.02, help="PCA RMS error budget, radians")
    ap.add_argument("--frame", type=float, default=0.0)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--out", type=Path, default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = ap.parse_args(argv)
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    out_dir = args.out or RESULTS

    from warpshade._fileio import write_json_atomic
    from warpshade._wp import cpu_workers
    from warpshade.basis import sg
    from warpshade.io import load_scene
    from warpshade.transfer import _ssdf as ssdf, _ssdf_pca as ssdf_pca, _ssdf_products as ssdf_products

    resolution, supersample = (32, 4) if args.quick else (128, 4)
    count = 32 if args.quick else args.vertices
    fine = resolution * supersample
    scene = load_scene(SCENE)
    rng = np.random.default_rng(2009)
    vertices = np.sort(rng.choice(scene.vertex_count, size=min(count, scene.vertex_count), replace=False))
    report: dict = {
        "scene": SCENE, "frame": args.frame, "vertices": int(vertices.size),
        "scene_vertices": scene.vertex_count, "resolution": resolution, "supersample": supersample,
        "fine_resolution": fine, "device": args.device, "cpu_threads": cpu_workers(),
        "machine": platform.platform(), "date": datetime.date.today().isoformat(),
    }

    # ---- part 1: bake cost ------------------------------------------------------------------
    ssdf.bake_ssdf(scene, args.frame, resolution=4, supersample=2, vertices=vertices[:1], device=args.device)  # compile
    ssdf.signed_distance(np.ones((1, 8, 8), bool), 4, method="warp", device=args.device)
    timings: dict = {}
    t0 = time.perf_counter()
    maps = ssdf.bake_ssdf(scene, args.frame, resolution=resolution, supersample=supersample, vertices=vertices,
                          device=args.device, progress=True, timings=timings)
    total = time.perf_counter() - t0
    vis = ssdf.bake_visibility(scene, args.frame, resolution=fine, vertices=vertices[:WARP_DISTANCE_VERTICES], device=args.device)
    per_method = {}
    for method in ("kdtree", "warp"):
        t = time.perf_counter()
        out = ssdf.signed_distance(vis, resolution, method=method, device=args.device)
        per_method[method] = (time.perf_counter() - t) / vis.shape[0]
        if method == "kdtree":
            ref = out
    boundary = [ssdf.boundary_points(m).shape[0] for m in vis]
    report["bake"] = {
        "total_s": total, "per_vertex_s": total / vertices.size,
        "trace_per_vertex_s": timings["trace_s"] / vertices.size,
        "distance_per_vertex_s": timings["distance_s"] / vertices.size,
        "rays_per_s": vertices.size * fine * fine / timings["trace_s"],
        "distance_method_per_vertex_s": per_method,
        "distance_methods_max_abs_diff_rad": float(np.abs(out - ref).max()),
        "boundary_samples_per_vertex": {"mean": float(np.mean(boundary)), "max": int(np.max(boundary))},
        "fully_visible_vertices": int(np.sum(np.all(maps >= ssdf.SSDF_LIMIT - 1e-6, axis=(1, 2)))),
        "fully_blocked_vertices": int(np.sum(np.all(maps <= -ssdf.SSDF_LIMIT + 1e-6, axis=(1, 2)))),
        "model_bytes_uncompressed": int(maps.nbytes),
    }
    print(f"bake {fine}->{resolution}: {total / vertices.size * 1e3:.1f} ms/vertex "
          f"(trace {timings['trace_s'] / vertices.size * 1e3:.1f}, distance {timings['distance_s'] / vertices.size * 1e3:.1f}); "
          f"distance kdtree {per_method['kdtree'] * 1e3:.1f} ms, warp {per_method['warp'] * 1e3:.1f} ms per vertex")

    # ---- part 2: PCA ------------------------------------------------------------------------
    max_terms = max(TERMS)
    pca = {}
    models = {}
    for method in ("exact", "randomized"):
        t = time.perf_counter()
        models[method] = ssdf_pca.compress_ssdf(maps, error_budget=args.budget, max_terms=max_terms, method=method)
        pca[method] = {"time_s": time.perf_counter() - t, "terms": models[method].terms,
                       "rms_error_rad": models[method].rms_error, "budget_met": models[method].budget_met,
                       "error_curve_rad": models[method].error_curve.tolist()}
    model = models["exact"]
    pca["budget_rad"] = args.budget
    pca["curve_max_abs_diff_exact_vs_randomized"] = float(np.abs(models["exact"].error_curve - models["randomized"].error_curve).max())
    pca["model_bytes"] = int(model.mean.nbytes + model.basis.nbytes + model.coeffs.nbytes)
    report["pca"] = pca
    print(f"PCA: {model.terms} terms for {args.budget} rad RMS (error {model.rms_error:.4f}); exact "
          f"{pca['exact']['time_s']:.2f} s, randomized {pca['randomized']['time_s']:.2f} s")

    # ---- part 3: products against ray tracing -------------------------------------------------
    axes = _axes_local()
    lam = np.asarray(SHARPNESS)
    axes_all = np.broadcast_to(axes, (vertices.size, axes.shape[0], 3)).copy()
    t = time.perf_counter()
    truth = ssdf.trace_lobe_visibility(scene, args.frame, axes_all, lam, samples=ORACLE_SAMPLES, vertices=vertices, device=args.device)
    oracle_s = time.perf_counter() - t
    flat_axes = np.tile(axes, (vertices.size, 1))  # (V * A, 3), vertex-major
    flat_maps = np.repeat(maps, axes.shape[0], axis=0)
    theta_full = ssdf_products.sample_maps(flat_maps, flat_axes).reshape(vertices.size, axes.shape[0])
    elevation = np.arcsin(axes[:, 2])[None, :]
    pole = sg.hemisphere_integral(0.5 * np.pi, lam)
    fig7 = {"sharpness": lam.tolist(), "axes_deg": AXES_DEG, "oracle_samples": ORACLE_SAMPLES, "oracle_s": oracle_s,
            "ssdf": [], "ssdf_horizon": [], "horizon_only": [], "pca": {}}
    for k, l in enumerate(lam):
        tr = truth[:, :, k]
        fig7["ssdf"].append(_errors(sg.hemisphere_integral(theta_full, l), tr, pole[k]))
        fig7["ssdf_horizon"].append(_errors(sg.hemisphere_integral(np.minimum(theta_full, elevation), l), tr, pole[k]))
        fig7["horizon_only"].append(_errors(np.full_like(tr, pole[k]),
                                            np.broadcast_to(sg.hemisphere_integral(elevation, l, method="quadrature"), tr.shape),
                                            pole[k]))
    terms_curve = []
    full = ssdf_pca.compress_ssdf(maps, error_budget=1e-12, max_terms=max_terms, method="exact")
    for n in TERMS:
        if n > models["exact"].error_curve.shape[0]:
            break
        if n > full.terms:
            break
        m_n = ssdf_pca.SSDFModel(full.mean, full.basis[:n], full.coeffs[:, :n], full.resolution, full.error_curve, 0.0)
        theta = ssdf_products.ssdf_lookup(m_n, np.repeat(m_n.coeffs, axes.shape[0], axis=0), flat_axes).reshape(vertices.size, -1)
        per_l = [_errors(sg.hemisphere_integral(np.clip(theta, -0.5 * np.pi, 0.5 * np.pi), l), truth[:, :, k], pole[k])
                 for k, l in enumerate(lam)]
        fig7["pca"][str(n)] = per_l
        terms_curve.append({"terms": n, "rms_rad": float(m_n.error_curve[n - 1]),
                            "product_mean_abs_fraction": [e["mean_abs_fraction"] for e in per_l],
                            "product_rel_rms": [e["rel_rms"] for e in per_l]})
    report["fig7"] = fig7
    report["fig9"] = terms_curve
    for k, l in enumerate(lam):
        e = fig7["ssdf"][k]
        print(f"lambda {l:6.0f}: SSDF product mean |err| {e['mean_abs_fraction']:.4f} of f_h(pi/2), rel RMS {e['rel_rms']:.4f}; "
              f"horizon-aware {fig7['ssdf_horizon'][k]['mean_abs_fraction']:.4f}; open-sky horizon error "
              f"{fig7['horizon_only'][k]['mean_abs_fraction']:.4f}")

    # ---- outputs ------------------------------------------------------------------------------
    tag = f"ssdf-{report['date']}-cpu" + ("-quick" if args.quick else "")
    json_path = out_dir / f"{tag}.json"
    write_json_atomic(json_path, report)
    _charts(out_dir, tag, report, maps, model, vis, resolution)
    print(f"wrote {json_path}")
    return 0


def _charts(out: Path, tag: str, report: dict, maps, model, vis, resolution: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from warpshade._fileio import atomic_path

    fig7 = report["fig7"]
    lam = fig7["sharpness"]
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for name, label in (("ssdf", "SSDF (uncompressed)"), ("ssdf_horizon", "SSDF, theta_d <= elevation"),
                        ("horizon_only", "open sky: horizon error alone")):
        ax[0].plot(lam, [e["mean_abs_fraction"] for e in fig7[name]], "o-", label=label)
        ax[1].plot(lam, [e["rel_rms"] for e in fig7[name]], "o-", label=label)
    n = str(report["pca"]["exact"]["terms"])
    if n in fig7["pca"]:
        ax[0].plot(lam, [e["mean_abs_fraction"] for e in fig7["pca"][n]], "s--", label=f"PCA, {n} terms")
        ax[1].plot(lam, [e["rel_rms"] for e in fig7["pca"][n]], "s--", label=f"PCA, {n} terms")
    for a, title in ((ax[0], "mean |error| / f_h(pi/2, lambda)"), (ax[1], "relative RMS over vertices x axes")):
        a.set_xscale("log")
        a.set_xlabel("lobe sharpness lambda")
        a.set_title(title)
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=8)
    fig.suptitle(f"SG x SSDF product vs ray tracing ({report['vertices']} vertices, {len(fig7['axes_deg'])} axes)")
    fig.tight_layout()
    with atomic_path(out / f"{tag}-fig7.png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)

    curve = report["fig9"]
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    terms = [c["terms"] for c in curve]
    full = report["pca"]["exact"]["error_curve_rad"]
    ax[0].semilogy(np.arange(1, len(full) + 1), full, "-", label="RMS reconstruction error")
    ax[0].axhline(report["pca"]["budget_rad"], color="k", ls=":", label="budget")
    ax[0].axvline(report["pca"]["exact"]["terms"], color="r", ls=":", label="chosen N")
    ax[0].set_xlabel("PCA terms N")
    ax[0].set_ylabel("radians")
    ax[0].legend(fontsize=8)
    for k, l in enumerate(lam):
        ax[1].semilogx(terms, [c["product_mean_abs_fraction"][k] for c in curve], "o-", label=f"lambda {l:g}")
    ax[1].set_xlabel("PCA terms N")
    ax[1].set_ylabel("product mean |error| / f_h(pi/2)")
    ax[1].legend(fontsize=8)
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle("PCA compression of SSDFs")
    fig.tight_layout()
    with atomic_path(out / f"{tag}-fig9.png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)

    # a few vertices: fine visibility, SSDF, PCA reconstruction
    pick = [i for i in range(min(4, vis.shape[0]))]
    fig, ax = plt.subplots(3, len(pick), figsize=(3 * len(pick), 8.5), squeeze=False)
    recon = model.reconstruct(pick)
    for j, i in enumerate(pick):
        ax[0, j].imshow(vis[i].T, origin="lower", cmap="gray", vmin=0, vmax=1)
        ax[1, j].imshow(maps[i].T, origin="lower", cmap="RdBu", vmin=-np.pi / 2, vmax=np.pi / 2)
        ax[2, j].imshow(recon[j].T, origin="lower", cmap="RdBu", vmin=-np.pi / 2, vmax=np.pi / 2)
        for r in range(3):
            ax[r, j].set_xticks([])
            ax[r, j].set_yticks([])
    ax[0, 0].set_ylabel("visibility (fine)")
    ax[1, 0].set_ylabel(f"SSDF {resolution}^2")
    ax[2, 0].set_ylabel(f"PCA, {model.terms} terms")
    fig.tight_layout()
    with atomic_path(out / f"{tag}-maps.png") as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
