"""The anisotropic brushed-metal dish (``stages/dish_sg_aniso.toml``) per pixel against its ray-traced
reference, and the best isotropic approximation of the same material beside it.

One run of the graph (SSDFs and the sky's SG mixture and prefiltered table precomputed, cached),
frame 0, rendered per pixel by ``sg.shade`` (:func:`warpshade.measure.pixels.render_frame`): the
anisotropic Ward dish (NDF lobes warped per lobe in each pixel's UV tangent frame). The reference
is :func:`warpshade.reference.reference_image` with the stage's per-pixel reference model (the
same Ward BRDF, eye and specular colour, the same UV tangents at each hit, ``samples`` rays per
pixel). Then the same stage with ISOTROPIC Ward of alpha ``a`` for each ``a`` of a sweep between
the two anisotropic alphas (geometric spacing; each one re-set by ``Runtime.set_parameter`` on
the same run, nothing recomputed) against the same anisotropic reference; the best of them is
"the best isotropic approximation". Errors: relative RMS (``sqrt(mean |d|^2) / sqrt(mean |ref|^2)``
over RGB) over the pixels fully covered by the DISH (every ray of the pixel hits one of its
triangles), and over every covered pixel; the reference's own noise on the same pixels.

Goal (issue 27): the dish within 0.25 relative RMS of its reference, and at most 0.5 times the
error of the best isotropic approximation.

Writes ``sg-aniso-<date>-cpu[-quick].json`` and ``.png`` (SG anisotropic | reference | best
isotropic | error of the anisotropic, on the dish) into ``--out`` (default benchmarks/results).
``--quick``: 48 x 36 pixels, 64 samples, SSDF 16^2, 2 NDF lobes, two isotropic alphas.
"""

from __future__ import annotations

import argparse
import datetime
import sys
import time
from pathlib import Path

import numpy as np

import warpshade.graph as graph
from warpshade._fileio import write_json_atomic
from warpshade.measure import ground_truth_model
from warpshade.measure.pictures import ERROR_LIMIT, write_panels
from warpshade.measure.pixels import exposure_for, pixel_stage, render_frame
from warpshade.reference import reference_image
from warpshade.render import tonemap_f64

ROOT = Path(__file__).resolve().parents[1]
GRAPH = ROOT / "stages" / "dish_sg_aniso.toml"
#: Isotropic alphas tried, as fractions of the way from alpha_x to alpha_y in log space.
ISO_SWEEP = 7


def rel_rms(est, ref, mask):
    d = (est - ref)[mask]
    r = ref[mask]
    return float(np.sqrt(np.mean(d * d)) / np.sqrt(np.mean(r * r)))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--width", type=int, default=160)
    parser.add_argument("--height", type=int, default=120)
    parser.add_argument("--samples", type=int, default=1024, help="reference rays per pixel")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="small settings for a fast check")
    parser.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = parser.parse_args(argv)
    if args.quick and args.out is None:
        parser.error("--quick writes only into --out DIR (never benchmarks/results)")
    out = Path(args.out or ROOT / "benchmarks" / "results")
    out.mkdir(parents=True, exist_ok=True)
    sweep = ISO_SWEEP
    spec = graph.load(GRAPH)
    if args.quick:
        args.width, args.height, args.samples, sweep = 48, 36, 64, 2
        for st in spec.stages:
            if st.type == "sg.ssdf":
                st.params.update(resolution=16, supersample=1)
            if st.type == "sg.shade":
                st.params.update(lobes=2)
    t0 = time.perf_counter()
    rt = spec.compile(device=args.device, progress=not args.quick)
    compile_s = time.perf_counter() - t0
    frame = float(rt.scene.frames[0])
    rt.step(frame)
    st = pixel_stage(rt)
    p = st.params
    t0 = time.perf_counter()
    im = render_frame(rt, frame, args.width, args.height)
    sg_s = time.perf_counter() - t0
    model = ground_truth_model(st, rt.state.materials, rt.state.eye.numpy()[0], per_pixel=True)
    t0 = time.perf_counter()
    ref = reference_image(rt.scene, frame, model["brdf"], camera=im.camera, width=args.width, height=args.height,
                          samples=args.samples, eye=model["eye"], lighting=rt.lighting.lights_at(frame),
                          specular=im.materials["specular"], include=("specular",), seed=args.seed, device=rt.device,
                          tangents=model["tangents"])
    ref_s = time.perf_counter() - t0
    dish = next(k for k, m in enumerate(rt.scene.meshes) if m.path.endswith("Dish"))
    start = sum(m.triangle_count for m in rt.scene.meshes[:dish])
    tri = ref.hits.triangles.reshape(args.height, args.width)
    on_dish = (tri >= start) & (tri < start + rt.scene.meshes[dish].triangle_count)
    mask = ref.mask & on_dish & (im.coverage >= 1.0)
    covered = ref.mask & (im.coverage >= 1.0)
    scale = np.sqrt(np.mean(ref.radiance[mask] ** 2))
    result = {"rel_rms_dish": rel_rms(im.linear, ref.radiance, mask), "rel_rms_all": rel_rms(im.linear, ref.radiance, covered),
              "reference_noise_dish": float(np.sqrt(np.mean(ref.stderr[mask] ** 2)) / scale),
              "dish_pixels": int(mask.sum()), "covered_pixels": int(covered.sum()),
              "ndf_lobes": st.diagnostics().get("ndf_lobes")}
    print(f"anisotropic SG: dish rel RMS {result['rel_rms_dish']:.4f} (reference noise {result['reference_noise_dish']:.4f}, "
          f"{result['dish_pixels']} pixels), all {result['rel_rms_all']:.4f}; SG {sg_s:.2f} s, reference {ref_s:.1f} s", flush=True)
    ax, ay = float(p["roughness"]), float(p["roughness_y"])
    iso = []
    best = None
    for a in np.geomspace(ax, ay, sweep):
        rt.set_parameter("shade", "roughness_y", None)
        rt.set_parameter("shade", "roughness", float(a))
        rt.step(frame)
        iso_im = render_frame(rt, frame, args.width, args.height)
        row = {"alpha": float(a), "rel_rms_dish": rel_rms(iso_im.linear, ref.radiance, mask),
               "rel_rms_all": rel_rms(iso_im.linear, ref.radiance, covered)}
        iso.append(row)
        print(f"isotropic Ward alpha {a:.3f}: dish rel RMS {row['rel_rms_dish']:.4f}", flush=True)
        if best is None or row["rel_rms_dish"] < best[0]["rel_rms_dish"]:
            best = (row, iso_im.linear)
    ratio = result["rel_rms_dish"] / best[0]["rel_rms_dish"]
    print(f"best isotropic: alpha {best[0]['alpha']:.3f}, dish rel RMS {best[0]['rel_rms_dish']:.4f}; "
          f"anisotropic / best isotropic = {ratio:.3f}", flush=True)
    date = datetime.date.today().isoformat()
    stem = f"sg-aniso-{date}-cpu" + ("-quick" if args.quick else "")
    exposure = exposure_for(ref.radiance[mask].reshape(-1, 3))
    y_scale = float(np.mean(ref.radiance[mask].sum(-1))) if mask.any() else 1.0
    err = np.where(mask, (im.linear - ref.radiance).sum(-1) / max(y_scale, 1e-30), 0.0)
    import matplotlib

    from warpshade.measure.pictures import ERROR_COLORMAP

    err_rgb = matplotlib.colormaps[ERROR_COLORMAP](np.clip(0.5 + 0.5 * err / ERROR_LIMIT, 0, 1))[..., :3]
    err_img = np.where(mask[..., None], err_rgb, 0.5)
    sg_img, ref_img, iso_img = (tonemap_f64(x, exposure=exposure) for x in (im.linear, ref.radiance, best[1]))
    err_u8 = np.clip(err_img * 255.0 + 0.5, 0, 255).astype(np.uint8)
    grey = np.full_like(err_u8, 128)
    png = write_panels(out / f"{stem}.png",
                       [np.concatenate([sg_img, ref_img], 1), np.concatenate([iso_img, ref_img], 1),
                        np.concatenate([err_u8, grey], 1)],
                       [f"SG, Ward {ax:g} x {ay:g} | reference\ndish rel RMS {result['rel_rms_dish']:.3f}",
                        f"SG, isotropic {best[0]['alpha']:.3f} | ref.\ndish rel RMS {best[0]['rel_rms_dish']:.3f}",
                        "error (anisotropic SG)"],
                       ERROR_LIMIT, f"{args.width}x{args.height} pixels, reference {args.samples} spp; "
                                    f"anisotropic / best isotropic = {ratio:.2f}")
    report = {"date": date, "device": str(rt.device), "quick": args.quick, "graph": str(GRAPH.relative_to(ROOT)),
              "width": args.width, "height": args.height, "reference_samples": args.samples,
              "material": {"model": "ward", "alpha_x": ax, "alpha_y": ay, "tangent": p["tangent"]},
              "anisotropic": result, "isotropic_sweep": iso, "best_isotropic": best[0],
              "ratio_anisotropic_to_best_isotropic": ratio,
              "goals": {"rel_rms_dish_below_0.25": result["rel_rms_dish"] < 0.25, "ratio_below_0.5": ratio <= 0.5},
              "seconds": {"compile": compile_s, "sg_frame": sg_s, "reference": ref_s},
              "png": png.name, "command": "python benchmarks/bench_sg_aniso.py " + " ".join(argv if argv is not None else sys.argv[1:])}
    path = write_json_atomic(out / f"{stem}.json", report)
    print(f"wrote {path} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
