"""Where the SG shading of ``stages/dish_sg_svbrdf.toml`` departs from the ray-traced reference of
its texture of eq.-13 materials: a float64 split at a random subset of the dish's vertices.

One run of the graph, frame 0. The reference is the graph's own ``--validate`` ground truth (the
cached one: ``[validate]`` samples, the validate seed; :func:`warpshade.measure._truth.ground_truth`
of the stage's reference model, :class:`~warpshade.scene._svbrdf.SVBRDFMaterial`).
At the subset, :func:`warpshade.methods.sg._svbrdf.eq13_quadrature_f64` (Gauss-Legendre x uniform
nodes over each vertex's hemisphere, every node ray traced for visibility against the frame's BVH
from the reference's shadow-ray origin) of the texture with, in turn:

* ``exact``: each texel's EXACT analytic material (the asset generator's);
* ``file``: the file's curves as the reference reads them (D log-linear in cos, S linear in theta);
* ``fit_ndf``: the NDF replaced by the stage's SG lobes (S still the file's);
* ``fit_ndf_pca``: the shadowing too replaced by the stage's PCA decode (the method's material);

and the same ``fit_ndf_pca`` without visibility (``fit_open``). The SG shading is the stage's kernel
output and its float64 mirror (:func:`warpshade.methods.sg.shade_f64`) with the SSDFs, and the
mirror with every SSDF fully visible (``sg_open``). Each row is a relative RMS over the subset's
vertices and RGB (``sqrt(mean |a - b|^2) / sqrt(mean |b|^2)``): the reference against ``file`` (its
own correctness, next to its noise), ``file`` against ``exact`` (the 91 samples), ``fit_ndf``
against ``file`` (the NDF's SG fit), ``fit_ndf_pca`` against ``fit_ndf`` (the shadowing PCA),
``sg_open`` against ``fit_open`` (the SG shading of the method's own material without visibility:
the per-lobe warp, the lobe-cosine product, the prefiltered environment), the visibility's part
(``(sg - sg_open) - (fit_ndf_pca - fit_open)``, the SSDF's visibility against the ray-traced one,
relative to ``fit_ndf_pca``), and the SG output against the reference (the total). The texels of
the method and the reference are the same (one look-up function), so the look-up adds nothing.

Writes ``svbrdf-reference-<date>-cpu[-quick].json`` into ``--out`` (default benchmarks/results).
``--quick``: SSDF 8^2, 30 vertices, 64 reference samples (not cached), a coarse quadrature.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import warpshade.graph as graph
from warpshade._fileio import write_json_atomic
from warpshade.geometry._bvh import Visibility
from warpshade.measure import VALIDATE_SEED, ground_truth, reference_model
from warpshade.methods.sg import decode_maps, shade_f64
from warpshade.methods.sg._slices import duff_frame_f64
from warpshade.methods.sg._svbrdf import eq13_quadrature_f64, svbrdf_slices_f64
from warpshade.reference._svbrdf_warp import vertex_texels
from warpshade.scene import SphereLight
from warpshade.scene._materials import hemisphere_quadrature
from warpshade.scene._svbrdf import scene_uvs
from warpshade.usd_assets.generator.svbrdf import texel_material

from _dish import dated_stem, quick_overrides, rel_rms, relative_noise, sole_environment

ROOT = Path(__file__).resolve().parents[1]
GRAPH = ROOT / "stages" / "dish_sg_svbrdf.toml"


def _mirror(rt, idx, open_sky: bool, texels):
    """:func:`shade_f64` of the stage at vertices ``idx`` (the SSDFs, or fully visible)."""
    st = rt.output_stage()
    p = st.params
    fl = rt.state.lighting
    env = st.environment
    spheres = [SphereLight(pos, float(r), rad) for pos, r, rad in
               zip(fl.sphere_position.numpy(), fl.sphere_radius.numpy(), fl.sphere_radiance.numpy())]
    e2w = fl.environment_to_world.numpy()[0].astype(np.float64)
    maps = decode_maps(st.model)
    if open_sky:
        maps = np.full_like(maps, np.pi)  # every direction at the largest angular distance from occluders
    corners = np.repeat(idx[:, None], 3, 1)
    weights = np.tile([1.0, 0.0, 0.0], (idx.size, 1))
    pts = rt.state.points.numpy().astype(np.float64)
    nrm = rt.state.normals.numpy().astype(np.float64)

    def rows(buf):
        return buf.numpy().astype(np.float64)[idx]

    return shade_f64(pts[idx], nrm[idx], st._eye.numpy()[0], rows(st._albedo), rows(st._spec), np.zeros(idx.size), maps,
                     rt.frame_outputs["tangents"]["tangents"].numpy().astype(np.float64), "beckmann", p["f0"], env.mixture,
                     env.table, e2w, spheres, component=p["component"], cosine=p["cosine"], corners=corners,
                     weights=weights, horizon=p["horizon"], narrow_lights=p["narrow_lights"], svbrdf=(st.svbrdf, texels))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--vertices", type=int, default=300, help="dish vertices of the split")
    parser.add_argument("--z-nodes", type=int, default=96)
    parser.add_argument("--phi-nodes", type=int, default=192)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="small settings for a fast check")
    parser.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = parser.parse_args(argv)
    if args.quick and args.out is None:
        parser.error("--quick writes only into --out DIR (never benchmarks/results)")
    out = Path(args.out or ROOT / "benchmarks" / "results")
    out.mkdir(parents=True, exist_ok=True)
    spec = graph.load(GRAPH)
    samples = int(spec.validate_spec.get("samples", 1024))
    cache = "default"
    if args.quick:
        args.vertices, args.z_nodes, args.phi_nodes, samples, cache = 30, 32, 64, 64, None
        quick_overrides(spec, resolution=8)
    rt = spec.compile(device=args.device, progress=not args.quick)
    frame = float(rt.scene.frames[0])
    rt.run([frame])
    sg = rt.results[frame].astype(np.float64)
    model = reference_model(rt, frame)
    material = model["brdf"]
    t0 = time.perf_counter()
    truth = ground_truth(rt.scene, rt.lighting, [frame], samples, rt.device, cache, model, VALIDATE_SEED)[frame]
    truth_s = time.perf_counter() - t0
    reference, stderr = truth["radiance"].astype(np.float64), truth["stderr"].astype(np.float64)
    env = sole_environment(rt, frame, GRAPH)

    pts = rt.state.points.numpy().astype(np.float64)
    nrm = rt.state.normals.numpy().astype(np.float64)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    eye = np.asarray(model["eye"], np.float64)
    views = eye[None] - pts
    views /= np.linalg.norm(views, axis=1, keepdims=True)
    facing = np.flatnonzero(np.sum(views * nrm, axis=1) > 0.0)
    rng = np.random.default_rng(args.seed)
    idx = np.sort(rng.choice(facing, size=min(args.vertices, facing.size), replace=False))
    flat = vertex_texels(material, rt.scene, rt.device).numpy()[idx]
    rc = np.stack(np.divmod(flat, material.shape[1]), -1)
    texture = rt.output_stage().svbrdf
    texel_mismatch = int(np.sum(np.any(rc != texture.texel_of(scene_uvs(rt.scene)[idx]), axis=1)))  # float32 vs float64

    bvh = Visibility.from_scene(rt.scene, device=rt.device)
    bvh.update(rt.state.points)
    blocked = {}

    def occluded(p, dirs):
        if p not in blocked:
            origins = np.repeat((pts[idx[p]] + bvh.offset * nrm[idx[p]])[None], len(dirs), 0)
            blocked[p] = bvh.occluded(origins.astype(np.float32), dirs.astype(np.float32)).numpy().astype(bool)
        return blocked[p]

    def curves(kind):
        out = []
        for r, c in rc:
            t = np.array([r, c])
            exact_d, exact_s = texel_material(r, c)
            file_d = lambda th, t=t: material.ndf_at(np.broadcast_to(t, np.shape(th) + (2,)), np.cos(th))  # noqa: E731
            file_s = lambda th, t=t: material.shadow_at(np.broadcast_to(t, np.shape(th) + (2,)), np.cos(th))  # noqa: E731
            fit_d = lambda th, t=t: texture.ndf_at(np.broadcast_to(t, np.shape(th) + (2,)), np.cos(th))  # noqa: E731
            pca_s = lambda th, t=t: texture.shadow_at(np.broadcast_to(t, np.shape(th) + (2,)), np.cos(th))  # noqa: E731
            out.append({"exact": (exact_d, exact_s), "file": (file_d, file_s), "fit_ndf": (fit_d, file_s),
                        "fit_ndf_pca": (fit_d, pca_s)}[kind])
        return out

    color = np.asarray(model["color"], np.float64).reshape(-1, 3)
    color = color[idx] if color.shape[0] > 1 else color
    t0 = time.perf_counter()
    quad = {kind: color * eq13_quadrature_f64(nrm[idx], views[idx], curves(kind), material.eta, env.radiance, occluded,
                                              args.z_nodes, args.phi_nodes)
            for kind in ("exact", "file", "fit_ndf", "fit_ndf_pca")}
    quad["fit_open"] = color * eq13_quadrature_f64(nrm[idx], views[idx], curves("fit_ndf_pca"), material.eta, env.radiance,
                                                   None, args.z_nodes, args.phi_nodes)
    # the method's warped lobes (eq. 18-22, float64) against the sky map and the exact clamped cosine, no visibility
    dirs, wq = hemisphere_quadrature(args.z_nodes, args.phi_nodes)
    lobes_open = np.zeros((idx.size, 3))
    for p, (r, c) in enumerate(rc):
        frame = duff_frame_f64(nrm[idx[p]])
        axes, lam, amp = svbrdf_slices_f64(texture, np.array([[r, c]]), (frame @ views[idx[p]])[None])
        g = np.sum(amp[0][:, None] * np.exp(lam[0][:, None] * (axes[0] @ dirs.T - 1.0)), axis=0)
        lobes_open[p] = (wq * g * dirs[:, 2]) @ env.radiance(dirs @ frame)
    lobes_open *= color
    quad_s = time.perf_counter() - t0
    mirror = _mirror(rt, idx, False, rc)
    mirror_open = _mirror(rt, idx, True, rc)
    ref = reference[idx]
    vis_sg = mirror - mirror_open
    vis_true = quad["fit_ndf_pca"] - quad["fit_open"]
    split = {
        "reference_vs_file_quadrature": rel_rms(ref, quad["file"]),
        "reference_noise": relative_noise(stderr, reference, idx),
        "file_vs_exact": rel_rms(quad["file"], quad["exact"]),
        "ndf_fit": rel_rms(quad["fit_ndf"], quad["file"]),
        "shadowing_pca": rel_rms(quad["fit_ndf_pca"], quad["fit_ndf"]),
        "method_material_vs_file": rel_rms(quad["fit_ndf_pca"], quad["file"]),
        "sg_shading_open": rel_rms(mirror_open, quad["fit_open"]),
        "lobe_warp_open": rel_rms(lobes_open, quad["fit_open"]),
        "sg_lighting_open": rel_rms(mirror_open, lobes_open),
        "visibility": float(np.sqrt(np.mean((vis_sg - vis_true) ** 2)) / np.sqrt(np.mean(quad["fit_ndf_pca"] ** 2))),
        "visibility_share_of_radiance": float(np.sqrt(np.mean(vis_true**2)) / np.sqrt(np.mean(quad["fit_ndf_pca"] ** 2))),
        "sg_vs_method_material": rel_rms(mirror, quad["fit_ndf_pca"]),
        "sg_vs_reference": rel_rms(sg[idx], ref),
        "sg_mean_over_reference": float(sg[idx].sum() / max(ref.sum(), 1e-30)),
        "mirror_vs_kernel": float(np.abs(mirror - sg[idx]).max() / max(np.abs(sg[idx]).max(), 1e-30)),
        "sg_vs_reference_all_vertices": rel_rms(sg, reference),
    }
    # the SG shading without visibility by the view's angle from the normal (grazing views are where the warp is worst)
    angle = np.degrees(np.arccos(np.clip(np.sum(views[idx] * nrm[idx], axis=1), -1.0, 1.0)))
    by_view = []
    for lo, hi in ((0, 40), (40, 60), (60, 75), (75, 90)):
        sel = (angle >= lo) & (angle < hi)
        if sel.sum() >= 3:
            by_view.append({"view_deg": [lo, hi], "vertices": int(sel.sum()),
                            "sg_shading_open": rel_rms(mirror_open[sel], quad["fit_open"][sel]),
                            "sg_open_mean_over_quadrature": float(mirror_open[sel].sum() / max(quad["fit_open"][sel].sum(), 1e-30)),
                            "lobe_warp_open": rel_rms(lobes_open[sel], quad["fit_open"][sel]),
                            "warped_lobes_mean_over_quadrature": float(lobes_open[sel].sum() / max(quad["fit_open"][sel].sum(), 1e-30)),
                            "sg_vs_reference": rel_rms(sg[idx][sel], ref[sel])})
    print("dish_sg_svbrdf, float64 split at", idx.size, "vertices (relative RMS):")
    for k, v in split.items():
        print(f"  {k:32s} {v:.4f}")
    date, stem = dated_stem("svbrdf-reference", args.quick)
    report = {"date": date, "device": str(rt.device), "quick": args.quick, "graph": str(GRAPH.relative_to(ROOT)),
              "vertices": int(idx.size), "texel_mismatch_float64": texel_mismatch, "facing_vertices": int(facing.size), "samples": samples,
              "quadrature": [args.z_nodes, args.phi_nodes], "seed": args.seed, "split": split,
              "svbrdf": rt.output_stage().diagnostics()["svbrdf"], "truth_s": truth_s, "quadrature_s": quad_s}
    for row in by_view:
        print(f"  views {row['view_deg'][0]}-{row['view_deg'][1]} deg ({row['vertices']} vertices): SG open "
              f"{row['sg_shading_open']:.4f} (mean ratio {row['sg_open_mean_over_quadrature']:.3f}; warped lobes "
              f"{row['lobe_warp_open']:.4f}, ratio {row['warped_lobes_mean_over_quadrature']:.3f}), SG vs reference "
              f"{row['sg_vs_reference']:.4f}")
    report["by_view"] = by_view
    path = write_json_atomic(out / f"{stem}.json", report)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
