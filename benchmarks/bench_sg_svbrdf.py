"""The dish with a spatially varying measured material (``stages/dish_sg_svbrdf.toml``) per pixel
against a float64 quadrature of the exact per-texel materials.

One run of the graph (SSDFs and the sky's SG mixture and prefiltered table precomputed), frame
0, rendered per pixel by ``sg.shade`` with ``brdf = "svbrdf"``: each pixel's texel (nearest, at
the UV interpolated at the hit) gives its NDF lobes and its shadowing decoded from the PCA. The
oracle here is :func:`warpshade.methods.sg._svbrdf.eq13_quadrature_f64` (the glossy ray-traced
reference shades the texture too: ``--validate`` and ``bench_svbrdf_reference.py``): for each pixel of a subset of the dish's
pixels, eq. 13 with the texel's EXACT analytic ``D`` and ``S``
(:func:`warpshade.usd_assets.generator.svbrdf.texel_material`) integrated against the sky
(bilinear radiance) over the hemisphere of the pixel's shading normal by Gauss-Legendre x uniform
quadrature, each quadrature direction ray traced for visibility against the scene's BVH (the SG
shading has the SSDFs instead). Errors: relative RMS (``sqrt(mean |d|^2) / sqrt(mean |ref|^2)``
over RGB) over those pixels, and the same without visibility in either (the SG specular with the
SSDF left out is not available from the stage, so that row compares the quadrature with and
without visibility: how much of the dish is self-shadowed).

Writes ``sg-svbrdf-<date>-cpu[-quick].json`` and ``.png`` (SG | quadrature at the sampled pixels,
grey elsewhere | error) into ``--out`` (default benchmarks/results). ``--quick``: 32 x 24 pixels,
SSDF 16^2, 40 oracle pixels on a coarse quadrature. By default the quadrature covers every
dish pixel of an 80 x 60 image (96 x 192 nodes).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import warpshade.graph as graph
from warpshade._fileio import write_json_atomic
from warpshade.measure._pictures import ERROR_COLORMAP, ERROR_LIMIT, write_panels
from warpshade.measure._pixels import exposure_for, pixel_bvh
from warpshade.methods.sg._svbrdf import eq13_quadrature_f64
from warpshade.render import render_gbuffer, tonemap_f64
from warpshade.scene._svbrdf import scene_uvs
from warpshade.usd_assets.generator.svbrdf import SVBRDF_ETA, texel_material

from _dish import dated_stem, dish_mask, quick_overrides, rel_rms, render_first_frame, sole_environment

#: Smoke profile (tests/test_benchmarks.py): slow, kept out of the default suite (``-m "not slow"``):
#: minutes on a loaded machine: the dish's SSDF bake and the sky's prefiltered table,
#: as bench_sg, then the quadrature with ray-traced visibility at 40 pixels.
PROFILE = {"slow": True}

ROOT = Path(__file__).resolve().parents[1]
GRAPH = ROOT / "stages" / "dish_sg_svbrdf.toml"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--width", type=int, default=80)
    parser.add_argument("--height", type=int, default=60)
    parser.add_argument("--pixels", type=int, default=0, help="dish pixels the quadrature is computed at (0: all)")
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
    if args.quick:
        args.width, args.height, args.pixels, args.z_nodes, args.phi_nodes = 32, 24, 40, 64, 128
        quick_overrides(spec, resolution=16)
    run = render_first_frame(spec, args.device, args.width, args.height, not args.quick)
    rt, frame, st, im, sg_s = run.rt, run.frame, run.stage, run.image, run.sg_s
    env = sole_environment(rt, frame, GRAPH)
    # the same rays as render_frame (supersample 1): which pixels are on the dish, and where
    bvh = pixel_bvh(rt)
    gb = render_gbuffer(bvh, rt.state.normals, im.camera, args.width, args.height)
    hit = gb.hit.numpy().astype(bool)
    face = gb.face.numpy()
    on_dish = hit & dish_mask(rt.scene, face)
    idx = np.flatnonzero(on_dish)
    rng = np.random.default_rng(args.seed)
    pick = np.sort(rng.choice(idx, size=idx.size if args.pixels <= 0 else min(args.pixels, idx.size), replace=False))
    b = gb.bary.numpy()[pick].astype(np.float64)
    w = np.stack([b[:, 0], b[:, 1], 1.0 - b[:, 0] - b[:, 1]], 1)
    corners = gb.faces.numpy()[face[pick]]
    uv = np.einsum("pk,pkc->pc", w, scene_uvs(rt.scene)[corners])
    texels = st.svbrdf.texel_of(uv)
    pos = gb.position.numpy()[pick].astype(np.float64)
    nrm = gb.normal.numpy()[pick].astype(np.float64)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    eye = rt.state.eye.numpy()[0].astype(np.float64)
    views = eye[None] - pos
    views /= np.linalg.norm(views, axis=1, keepdims=True)
    materials = [texel_material(r, c) for r, c in texels]

    def occluded(p, dirs):
        origins = np.repeat((pos[p] + bvh.offset * nrm[p])[None], len(dirs), 0)
        return bvh.occluded(origins.astype(np.float32), dirs.astype(np.float32)).numpy().astype(bool)

    t0 = time.perf_counter()
    oracle = eq13_quadrature_f64(nrm, views, materials, SVBRDF_ETA, env.radiance, occluded, args.z_nodes, args.phi_nodes)
    oracle_s = time.perf_counter() - t0
    open_sky = eq13_quadrature_f64(nrm, views, materials, SVBRDF_ETA, env.radiance, None, args.z_nodes, args.phi_nodes)
    sg = im.linear.reshape(-1, 3)[pick].astype(np.float64)
    result = {"rel_rms_dish": rel_rms(sg, oracle), "pixels": int(pick.size), "dish_pixels": int(idx.size),
              "rel_rms_visibility_effect": rel_rms(open_sky, oracle),
              "mean_ratio": float(sg.sum() / max(oracle.sum(), 1e-30)),
              "per_pixel_rel_error_median": float(np.median(np.linalg.norm(sg - oracle, axis=1)
                                                            / np.maximum(np.linalg.norm(oracle, axis=1), 1e-30))),
              "svbrdf": st.diagnostics()["svbrdf"], "sg_s": sg_s, "oracle_s": oracle_s}
    print(f"SVBRDF SG: dish rel RMS {result['rel_rms_dish']:.4f} against the quadrature at {result['pixels']} pixels "
          f"(visibility changes the quadrature by {result['rel_rms_visibility_effect']:.4f}; SG / quadrature "
          f"mean {result['mean_ratio']:.3f}); "
          f"{result['svbrdf']['lobes']} lobes (worst texel {result['svbrdf']['ndf_error_max']:.4f}), "
          f"{result['svbrdf']['shadow_terms']} shadowing terms (RMS {result['svbrdf']['shadow_rms']:.2e}); "
          f"SG {sg_s:.2f} s, quadrature {oracle_s:.1f} s", flush=True)
    date, stem = dated_stem("sg-svbrdf", args.quick)
    exposure = exposure_for(im.linear[on_dish.reshape(args.height, args.width)].reshape(-1, 3))
    ref_img = np.full((args.height * args.width, 3), 0.0)
    ref_img[pick] = oracle
    err = np.zeros(args.height * args.width)
    err[pick] = (sg - oracle).sum(-1) / max(float(np.mean(oracle.sum(-1))), 1e-30)
    import matplotlib

    err_rgb = matplotlib.colormaps[ERROR_COLORMAP](np.clip(0.5 + 0.5 * err / ERROR_LIMIT, 0, 1))[..., :3]
    sampled = np.zeros(args.height * args.width, bool)
    sampled[pick] = True
    err_u8 = np.clip(np.where(sampled[:, None], err_rgb, 0.5) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    sg_u8 = tonemap_f64(im.linear, exposure=exposure)
    ref_u8 = np.where(sampled.reshape(args.height, args.width, 1),
                      tonemap_f64(ref_img.reshape(args.height, args.width, 3), exposure=exposure), 128).astype(np.uint8)
    zoom = max(1, 320 // args.width)  # panels at least ~320 pixels wide, so their titles fit

    def big(img):
        return np.repeat(np.repeat(img, zoom, 0), zoom, 1)

    png = write_panels(out / f"{stem}.png", [big(sg_u8), big(ref_u8), big(err_u8.reshape(args.height, args.width, 3))],
                       ["SG, SVBRDF", f"quadrature ({pick.size} px)", f"rel RMS {result['rel_rms_dish']:.3f}"],
                       ERROR_LIMIT, f"{args.width}x{args.height} pixels; exact per-texel eq. 13, ray-traced visibility")
    report = {"date": date, "device": str(rt.device), "quick": args.quick, "graph": str(GRAPH.relative_to(ROOT)),
              "width": args.width, "height": args.height, "quadrature": [args.z_nodes, args.phi_nodes],
              "seed": args.seed, **result, "png": png.name}
    path = write_json_atomic(out / f"{stem}.json", report)
    print(f"wrote {path} and {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
