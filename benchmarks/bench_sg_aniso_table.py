"""The measured anisotropic dish (``stages/dish_sg_aniso_measured.toml``) per pixel against its
ray-traced reference, against the analytic model the table was written from, and against the best
isotropic approximation of the same measured material.

One run of the graph, frame 0, rendered per pixel by ``sg.shade``
(:func:`warpshade.measure.pixels.render_frame`): eq. 13's 2-D NDF and 1-D shadowing extracted from
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
from warpshade.methods.sg import measured_aniso
from warpshade.reference import reference_image
from warpshade.render import tonemap_f64
from warpshade.usd_assets.generator.aniso_table import ANISO_ROUGHNESS, ANISO_ROUGHNESS_Y, aniso_model

ROOT = Path(__file__).resolve().parents[1]
GRAPH = ROOT / "stages" / "dish_sg_aniso_measured.toml"
ISO_SWEEP = 7


def rel_rms(est, ref, mask):
    d = (est - ref)[mask]
    r = ref[mask]
    return float(np.sqrt(np.mean(d * d)) / np.sqrt(np.mean(r * r)))


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
    from warpshade.methods.sg.brdf import eta_from_f0

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
        for st in spec.stages:
            if st.type == "sg.ssdf":
                st.params.update(resolution=16, supersample=1)
            if st.type == "sg.shade":
                st.params.update(lobes=3)
    t0 = time.perf_counter()
    rt = spec.compile(device=args.device, progress=not args.quick)
    compile_s = time.perf_counter() - t0
    frame = float(rt.scene.frames[0])
    rt.step(frame)
    st = pixel_stage(rt)
    t0 = time.perf_counter()
    im = render_frame(rt, frame, args.width, args.height)
    sg_s = time.perf_counter() - t0
    model = ground_truth_model(st, rt.state.materials, rt.state.eye.numpy()[0], per_pixel=True)
    refs, ref_s = {}, {}
    for name, brdf in (("table", model["brdf"]), ("analytic", aniso_model())):
        t0 = time.perf_counter()
        refs[name] = reference_image(rt.scene, frame, brdf, camera=im.camera, width=args.width, height=args.height,
                                     samples=args.samples, eye=model["eye"], lighting=rt.lighting.lights_at(frame),
                                     specular=im.materials["specular"], include=("specular",), seed=args.seed,
                                     device=rt.device, tangents=model["tangents"])
        ref_s[name] = time.perf_counter() - t0
    ref = refs["table"]
    dish = next(k for k, m in enumerate(rt.scene.meshes) if m.path.endswith("Dish"))
    start = sum(m.triangle_count for m in rt.scene.meshes[:dish])
    tri = ref.hits.triangles.reshape(args.height, args.width)
    on_dish = (tri >= start) & (tri < start + rt.scene.meshes[dish].triangle_count)
    mask = ref.mask & on_dish & (im.coverage >= 1.0)
    covered = ref.mask & (im.coverage >= 1.0)
    scale = np.sqrt(np.mean(ref.radiance[mask] ** 2))
    ana = refs["analytic"].radiance
    result = {"rel_rms_dish": rel_rms(im.linear, ref.radiance, mask), "rel_rms_all": rel_rms(im.linear, ref.radiance, covered),
              "reference_noise_dish": float(np.sqrt(np.mean(ref.stderr[mask] ** 2)) / scale),
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
    iso, best = [], None
    for name, material in isotropic_variants(st.measured, np.geomspace(ANISO_ROUGHNESS, ANISO_ROUGHNESS_Y, sweep)):
        iso_im, lobes = render_with(spec, scene, args.device, material, frame, args.width, args.height)
        row = {"ndf": name, "rel_rms_dish": rel_rms(iso_im.linear, ref.radiance, mask),
               "rel_rms_all": rel_rms(iso_im.linear, ref.radiance, covered),
               "lobes": None if lobes is None else lobes["lobes"]}
        iso.append(row)
        print(f"isotropic {name}: dish rel RMS {row['rel_rms_dish']:.4f}", flush=True)
        if best is None or row["rel_rms_dish"] < best[0]["rel_rms_dish"]:
            best = (row, iso_im.linear)
    ratio = result["rel_rms_dish"] / best[0]["rel_rms_dish"]
    print(f"best isotropic: {best[0]['ndf']}, dish rel RMS {best[0]['rel_rms_dish']:.4f}; anisotropic / best isotropic = "
          f"{ratio:.3f}", flush=True)
    date = datetime.date.today().isoformat()
    stem = f"sg-aniso-table-{date}-cpu" + ("-quick" if args.quick else "")
    exposure = exposure_for(ref.radiance[mask].reshape(-1, 3))
    y_scale = float(np.mean(ref.radiance[mask].sum(-1))) if mask.any() else 1.0
    err = np.where(mask, (im.linear - ref.radiance).sum(-1) / max(y_scale, 1e-30), 0.0)
    import matplotlib

    from warpshade.measure.pictures import ERROR_COLORMAP

    err_rgb = matplotlib.colormaps[ERROR_COLORMAP](np.clip(0.5 + 0.5 * err / ERROR_LIMIT, 0, 1))[..., :3]
    err_u8 = np.clip(np.where(mask[..., None], err_rgb, 0.5) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    sg_img, ref_img, iso_img = (tonemap_f64(x, exposure=exposure) for x in (im.linear, ref.radiance, best[1]))
    png = write_panels(out / f"{stem}.png",
                       [np.concatenate([sg_img, ref_img], 1), np.concatenate([iso_img, ref_img], 1),
                        np.concatenate([err_u8, np.full_like(err_u8, 128)], 1)],
                       [f"SG, anisotropic table | reference\ndish rel RMS {result['rel_rms_dish']:.3f}",
                        f"SG, isotropic ({best[0]['ndf']}) | ref.\ndish rel RMS {best[0]['rel_rms_dish']:.3f}",
                        "error (anisotropic SG)"],
                       ERROR_LIMIT, f"{args.width}x{args.height} pixels, reference {args.samples} spp; "
                                    f"anisotropic / best isotropic = {ratio:.2f}")
    report = {"date": date, "device": str(rt.device), "quick": args.quick, "graph": str(GRAPH.relative_to(ROOT)),
              "width": args.width, "height": args.height, "reference_samples": args.samples,
              "material": {"table": str(st.measured_path), "analytic": aniso_model().describe(),
                           "eta": st.measured.eta, "extraction_residual": st.measured.residual},
              "anisotropic": result, "isotropic": iso, "best_isotropic": best[0],
              "ratio_anisotropic_to_best_isotropic": ratio,
              "goals": {"rel_rms_dish_below_0.25": result["rel_rms_dish"] < 0.25, "ratio_below_0.5": ratio <= 0.5},
              "seconds": {"compile": compile_s, "sg_frame": sg_s, "references": ref_s},
              "png": png.name, "command": "python benchmarks/bench_sg_aniso_table.py " + " ".join(argv if argv is not None else sys.argv[1:])}
    path = write_json_atomic(out / f"{stem}.json", report)
    print(f"wrote {path} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
