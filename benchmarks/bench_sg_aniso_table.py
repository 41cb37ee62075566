"""The measured anisotropic dish (``stages/dish_sg_aniso_measured.toml``) per pixel against its
ray-traced reference, against the analytic model the table was written from, and against the best
isotropic approximation of the same measured material.

One run of the graph, frame 0, rendered per pixel by ``sg.shade``
(:func:`warpshade.measure._pixels.render_frame`): eq. 13's 2-D NDF and 1-D shadowing extracted from
the bundled ``brushed_aniso.anisobrdf``, the NDF as free-axis SG lobes warped per lobe in each
pixel's UV tangent frame. References (:func:`warpshade.reference.reference_image`, ``samples`` rays
per pixel, the same UV tangents at each hit):

* the table itself ("linear"), what ``--validate`` measures against;
* the analytic model the generator tabulated (:func:`warpshade.usd_assets.generator.aniso_table.aniso_model`,
  anisotropic Beckmann with Smith masking): the SG image against it, and the table's reference
  against it (what the table's resolution alone costs).

The same stage with the analytic model's own eq.-13 factors instead of the extracted ones (the model
through the same SG path, as far as eq. 13 can hold it: ``D = pi D_B / 4`` on the table's (theta_h,
phi_h) cells, ``S`` the model's Smith factor averaged over the azimuth, the Fresnel index whose
normal reflectance is the model's f0) against the analytic model's reference: what the SG shading
costs when nothing is extracted.

Isotropic approximations of the same material: the same stage with the extracted NDF replaced by an
isotropic one -- its azimuthal average (the L2-closest isotropic NDF), and normalised isotropic
Beckmann NDFs of slope ``a`` for a sweep of ``a`` between the two slopes of the model (geometric
spacing) with the same projected area as the extracted NDF -- each shaded with the same extracted
shadowing and Fresnel index, against the table's reference; the best of them is "the best isotropic
approximation". Errors: relative RMS (``sqrt(mean |d|^2) / sqrt(mean |ref|^2)`` over RGB) over the
pixels fully covered by the DISH, and over every covered pixel.

Writes ``sg-aniso-table-<date>-cpu[-quick].json`` and ``.png`` (SG | table reference, best
isotropic | table reference, error of the anisotropic SG) into ``--out`` (default
benchmarks/results). ``--quick``: 48 x 36 pixels, 64 samples, SSDF 16^2, 3 NDF lobes, two
isotropic slopes.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

import warpshade.graph as graph
from warpshade.measure._pixels import pixel_stage, render_frame
from warpshade.methods.sg import _measured_aniso as measured_aniso
from warpshade.usd_assets.generator.aniso_table import ANISO_ROUGHNESS, ANISO_ROUGHNESS_Y, aniso_model

from _dish import (best_isotropic, pixel_masks, quick_overrides, rel_rms, relative_noise, render_and_reference,
                   write_aniso_outputs)

ROOT = Path(__file__).resolve().parents[1]
GRAPH = ROOT / "stages" / "dish_sg_aniso_measured.toml"
ISO_SWEEP = 7


def projected_area(m) -> float:
    """``integral D(h) h_z dh`` of an extracted NDF (quadrature over the hemisphere)."""
    x, w = np.polynomial.legendre.leggauss(256)
    z = 0.5 * (x + 1.0)
    phi = (np.arange(256) + 0.5) * 2 * np.pi / 256
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - zz * zz)
    h = np.stack([r * np.cos(pp), r * np.sin(pp), zz], -1)
    return float(np.sum(m.ndf(h) * zz * (0.5 * w)[:, None]) * 2 * np.pi / 256)


def isotropic_variants(m, slopes):
    """(name, AnisotropicMeasured) isotropic NDFs with the extraction's S and eta."""
    out = [("azimuthal average", dataclasses.replace(m, ndf_values=np.repeat(m.ndf_values.mean(1, keepdims=True),
                                                                                m.ndf_values.shape[1], 1), _fits={}))]
    area = projected_area(m)
    c = np.cos(m.theta_h)
    for a in slopes:
        d = np.exp(-(1 - c * c) / (c * c * a * a)) / (np.pi * a * a * c**4)
        iso = dataclasses.replace(m, ndf_values=np.repeat(d[:, None], m.ndf_values.shape[1], 1), _fits={})
        iso = dataclasses.replace(iso, ndf_values=iso.ndf_values * area / projected_area(iso), _fits={})
        out.append((f"Beckmann {a:.3f}", iso))
    return out


def analytic_factors(m):
    """The analytic model's eq.-13 factors on the grid of the extraction ``m`` (module docstring)."""
    from warpshade.methods.sg._brdf import eta_from_f0

    model = aniso_model()
    tt, pp = np.meshgrid(m.theta_h, m.phi_h, indexing="ij")
    h = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], -1)
    phi = (np.arange(360) + 0.5) * 2 * np.pi / 360
    th = np.minimum(m.theta, 0.5 * np.pi - 1e-6)
    w = np.stack([np.sin(th)[:, None] * np.cos(phi), np.sin(th)[:, None] * np.sin(phi),
                  np.broadcast_to(np.cos(th)[:, None], (th.size, phi.size))], -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        shadow = np.mean(1.0 / (1.0 + np.nan_to_num(model._lambda(w))), axis=1)
    return dataclasses.replace(m, ndf_values=0.25 * np.pi * model._d(h), shadow=np.clip(shadow, 0.0, 1.0),
                               eta=float(eta_from_f0(model.f0)), _fits={})


def render_with(spec, scene, device, material, frame, w, h):
    """The graph's per-pixel image with the stage's measured material replaced by ``material``."""
    original = measured_aniso.stage_material
    measured_aniso.stage_material = lambda brdf, path, eta: material
    try:
        rt = spec.compile(scene=scene, device=device, progress=False)
        rt.step(frame)
        return render_frame(rt, frame, w, h), pixel_stage(rt).diagnostics().get("ndf_lobes")
    finally:
        measured_aniso.stage_material = original


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--width", type=int, default=160)
    parser.add_argument("--height", type=int, default=120)
    parser.add_argument("--samples", type=int, default=512, help="reference rays per pixel")
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
        quick_overrides(spec, resolution=16, lobes=3)
    run = render_and_reference(spec, args.device, args.width, args.height, args.samples, args.seed, not args.quick,
                               brdfs={"table": None, "analytic": aniso_model()})
    rt, frame, st, im = run.rt, run.frame, run.stage, run.image
    refs, compile_s, sg_s, ref_s = run.references, run.compile_s, run.sg_s, run.reference_s
    ref = refs["table"]
    mask, covered = pixel_masks(rt.scene, ref, im, args.width, args.height)
    ana = refs["analytic"].radiance
    result = {"rel_rms_dish": rel_rms(im.linear, ref.radiance, mask), "rel_rms_all": rel_rms(im.linear, ref.radiance, covered),
              "reference_noise_dish": relative_noise(ref.stderr, ref.radiance, mask),
              "vs_analytic_rel_rms_dish": rel_rms(im.linear, ana, mask),
              "vs_analytic_rel_rms_all": rel_rms(im.linear, ana, covered),
              "table_reference_vs_analytic_reference_dish": rel_rms(ref.radiance, ana, mask),
              "dish_pixels": int(mask.sum()), "covered_pixels": int(covered.sum()), "ndf_lobes": st.diagnostics().get("ndf_lobes")}
    print(f"anisotropic SG from the table: dish rel RMS {result['rel_rms_dish']:.4f} vs the table's reference (noise "
          f"{result['reference_noise_dish']:.4f}), {result['vs_analytic_rel_rms_dish']:.4f} vs the analytic model's; the "
          f"table's reference vs the model's {result['table_reference_vs_analytic_reference_dish']:.4f}", flush=True)
    scene = rt.scene
    exact_im, exact_lobes = render_with(spec, scene, args.device, analytic_factors(st.measured), frame, args.width,
                                        args.height)
    result["analytic_factors"] = {"rel_rms_dish_vs_analytic": rel_rms(exact_im.linear, ana, mask),
                                  "rel_rms_all_vs_analytic": rel_rms(exact_im.linear, ana, covered),
                                  "rel_rms_dish_vs_table": rel_rms(exact_im.linear, ref.radiance, mask),
                                  "ndf_lobes": exact_lobes}
    print(f"SG with the analytic model's eq.-13 factors: dish rel RMS "
          f"{result['analytic_factors']['rel_rms_dish_vs_analytic']:.4f} vs the analytic model's reference "
          f"({exact_lobes['lobes'] if exact_lobes else '?'} lobes)", flush=True)
    iso, images = [], []
    for name, material in isotropic_variants(st.measured, np.geomspace(ANISO_ROUGHNESS, ANISO_ROUGHNESS_Y, sweep)):
        iso_im, lobes = render_with(spec, scene, args.device, material, frame, args.width, args.height)
        iso.append({"ndf": name, "rel_rms_dish": rel_rms(iso_im.linear, ref.radiance, mask),
                    "rel_rms_all": rel_rms(iso_im.linear, ref.radiance, covered),
                    "lobes": None if lobes is None else lobes["lobes"]})
        images.append(iso_im.linear)
        print(f"isotropic {name}: dish rel RMS {iso[-1]['rel_rms_dish']:.4f}", flush=True)
    best, best_image, ratio = best_isotropic(result, iso, images, lambda row: row["ndf"])
    write_aniso_outputs(out, "sg-aniso-table", __file__, argv, args, GRAPH, ROOT, rt, im.linear, ref.radiance, mask,
                        titles=("SG, anisotropic table | reference", f"SG, isotropic ({best['ndf']}) | ref."),
                        material={"table": str(st.measured_path), "analytic": aniso_model().describe(),
                                  "eta": st.measured.eta, "extraction_residual": st.measured.residual},
                        result=result, iso_key="isotropic", iso=iso, best=best, best_image=best_image, ratio=ratio,
                        seconds={"compile": compile_s, "sg_frame": sg_s, "references": ref_s})
    return 0


if __name__ == "__main__":
    sys.exit(main())
