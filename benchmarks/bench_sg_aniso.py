"""The anisotropic brushed-metal dish (``stages/dish_sg_aniso.toml``) per pixel against its ray-traced
reference, and the best isotropic approximation of the same material beside it.

One run of the graph (SSDFs and the sky's SG mixture and prefiltered table precomputed, cached),
frame 0, rendered per pixel by ``sg.shade`` (:func:`warpshade.measure._pixels.render_frame`): the
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
import sys
from pathlib import Path

import numpy as np

import warpshade.graph as graph
from warpshade.measure._pixels import render_frame

from _dish import (best_isotropic, pixel_masks, quick_overrides, rel_rms, relative_noise, render_and_reference,
                   write_aniso_outputs)

ROOT = Path(__file__).resolve().parents[1]
GRAPH = ROOT / "stages" / "dish_sg_aniso.toml"
#: Isotropic alphas tried, as fractions of the way from alpha_x to alpha_y in log space.
ISO_SWEEP = 7


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
        quick_overrides(spec, resolution=16, lobes=2)
    run = render_and_reference(spec, args.device, args.width, args.height, args.samples, args.seed, not args.quick)
    rt, frame, st, im = run.rt, run.frame, run.stage, run.image
    p = st.params
    ref, compile_s, sg_s, ref_s = run.references["reference"], run.compile_s, run.sg_s, run.reference_s["reference"]
    mask, covered = pixel_masks(rt.scene, ref, im, args.width, args.height)
    result = {"rel_rms_dish": rel_rms(im.linear, ref.radiance, mask), "rel_rms_all": rel_rms(im.linear, ref.radiance, covered),
              "reference_noise_dish": relative_noise(ref.stderr, ref.radiance, mask),
              "dish_pixels": int(mask.sum()), "covered_pixels": int(covered.sum()),
              "ndf_lobes": st.diagnostics().get("ndf_lobes")}
    print(f"anisotropic SG: dish rel RMS {result['rel_rms_dish']:.4f} (reference noise {result['reference_noise_dish']:.4f}, "
          f"{result['dish_pixels']} pixels), all {result['rel_rms_all']:.4f}; SG {sg_s:.2f} s, reference {ref_s:.1f} s", flush=True)
    ax, ay = float(p["roughness"]), float(p["roughness_y"])
    iso, images = [], []
    for a in np.geomspace(ax, ay, sweep):
        rt.set_parameter("shade", "roughness_y", None)
        rt.set_parameter("shade", "roughness", float(a))
        rt.step(frame)
        iso_im = render_frame(rt, frame, args.width, args.height)
        iso.append({"alpha": float(a), "rel_rms_dish": rel_rms(iso_im.linear, ref.radiance, mask),
                    "rel_rms_all": rel_rms(iso_im.linear, ref.radiance, covered)})
        images.append(iso_im.linear)
        print(f"isotropic Ward alpha {a:.3f}: dish rel RMS {iso[-1]['rel_rms_dish']:.4f}", flush=True)
    best, best_image, ratio = best_isotropic(result, iso, images, lambda row: f"alpha {row['alpha']:.3f}")
    write_aniso_outputs(out, "sg-aniso", __file__, argv, args, GRAPH, ROOT, rt, im.linear, ref.radiance, mask,
                        titles=(f"SG, Ward {ax:g} x {ay:g} | reference", f"SG, isotropic {best['alpha']:.3f} | ref."),
                        material={"model": "ward", "alpha_x": ax, "alpha_y": ay, "tangent": p["tangent"]},
                        result=result, iso_key="isotropic_sweep", iso=iso, best=best, best_image=best_image, ratio=ratio,
                        seconds={"compile": compile_s, "sg_frame": sg_s, "reference": ref_s})
    return 0


if __name__ == "__main__":
    sys.exit(main())
