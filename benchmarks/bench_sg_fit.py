"""SG fit error per BRDF model against the exact BRDF (Wang et al. 2009, the Fig. 2 / 3 analogue).

1. Isotropic models with one closed-form lobe (Beckmann, Cook-Torrance eq. 12, Blinn-Phong,
   isotropic Ward) over a sweep of roughness / exponents: the NDF error (lobe against the exact
   NDF, relative L2 over the hemisphere of h) and the slice error of :func:`slices.slice_error`
   (the warped slice times the cosine against the exact BRDF times the cosine, relative L2 over
   the hemisphere of i) at view polar angles 0, 30, 60, 75 and 85 degrees (azimuth 0). Also the
   three closed forms of the Beckmann lobe (the measurement behind the default) and the analytic
   sharp-lobe limit of the slice error (:func:`slices.isotropic_warp_floor`).
2. Anisotropic models fitted with free axes by L-BFGS-B (Ashikhmin-Shirley nu = 75, nv = 1200 as
   in the paper's Fig. 2; anisotropic Ward alpha_x = 0.1, alpha_y = 0.4): lobe count 1..8 against
   the NDF fit error, the fit time and the slice error at views 0 / 30 / 60 degrees, azimuths 0 and
   90 degrees.

Writes ``sg-fit-<date>-cpu.json`` and ``sg-fit-<date>-cpu.png`` into ``--out`` (default
``benchmarks/results``).

Usage::

    python benchmarks/bench_sg_fit.py [--quick] [--out DIR]
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

from warpshade._fileio import atomic_path, write_json_atomic
from warpshade.methods.sg import _brdf as brdf, _slices as slices
from warpshade.methods.sg import _ndf as sg_ndf

RESULTS = ROOT / "benchmarks" / "results"
VIEW_THETAS = (0.0, 30.0, 60.0, 75.0, 85.0)
SWEEPS = {
    "beckmann": ("roughness", (0.05, 0.1, 0.2, 0.3, 0.5)),
    "cook-torrance": ("m", (0.045, 0.1, 0.2, 0.3, 0.5)),
    "blinn-phong": ("exponent", (1000.0, 300.0, 100.0, 30.0, 10.0)),
    "ward": ("alpha_x", (0.05, 0.1, 0.2, 0.3, 0.5)),
}
ANISOTROPIC = {
    "ashikhmin-shirley": {"nu": 75.0, "nv": 1200.0},
    "ward": {"alpha_x": 0.1, "alpha_y": 0.4},
}
ANISO_VIEWS = ((0.0, 0.0), (30.0, 0.0), (30.0, 90.0), (60.0, 0.0), (60.0, 90.0))
#: Views of the ``--quick`` smoke profile.
QUICK_VIEW_THETAS = (0.0, 60.0)
QUICK_ANISO_VIEWS = ((0.0, 0.0), (60.0, 90.0))


def view(theta_deg: float, phi_deg: float = 0.0) -> np.ndarray:
    t, p = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)])


def ndf_error_isotropic(model: str, params: dict, nodes: int = 800) -> float:
    """Relative L2 error of the closed-form lobe against the exact NDF over the hemisphere of h."""
    lobes = sg_ndf.ndf_lobes(model, **params)
    x, w = np.polynomial.legendre.leggauss(nodes)
    split = min(0.5 * np.pi, 12.0 / math.sqrt(max(lobes.sharpness[0], 1e-6)))
    t, wt = [], []
    for lo, hi in ((0.0, split), (split, 0.5 * np.pi)):
        if hi - lo > 1e-9:
            t.append(lo + 0.5 * (hi - lo) * (x + 1.0))
            wt.append(0.5 * (hi - lo) * w)
    t = np.concatenate(t)
    wt = np.concatenate(wt) * 2.0 * np.pi * np.sin(t)
    h = np.stack([np.sin(t), np.zeros_like(t), np.cos(t)], -1)
    d = brdf.ndf_exact(model, h, **params)
    return float(math.sqrt(wt @ (lobes.evaluate(h) - d) ** 2 / (wt @ d**2)))


def isotropic(quick: bool) -> dict:
    out = {}
    for model, (name, values) in SWEEPS.items():
        rows = []
        for value in values[2:3] if quick else values:
            params = {name: value}
            exact = brdf.microfacet_brdf(model, **params)
            lobes = sg_ndf.ndf_lobes(model, **params)
            errors = {f"{t:g}": slices.slice_error(exact, model, params, view(t))
                      for t in (QUICK_VIEW_THETAS if quick else VIEW_THETAS)}
            row = {name: value, "sharpness": float(lobes.sharpness[0]), "amplitude": float(lobes.amplitude[0]),
                   "ndf_error": ndf_error_isotropic(model, params), "slice_error": errors}
            rows.append(row)
            print(f"  {model:14s} {name}={value:<7g} NDF {row['ndf_error']:.4f}  slice " +
                  "  ".join(f"{t}deg {e:.4f}" for t, e in errors.items()), flush=True)
        out[model] = {"parameter": name, "rows": rows}
    forms = {}
    for a in SWEEPS["beckmann"][1][2:3] if quick else SWEEPS["beckmann"][1]:
        forms[f"{a:g}"] = {f: (ndf_error_isotropic("beckmann", {"roughness": a, "form": f})
                               if (f != "taylor" or a < 0.7) else None) for f in brdf.BECKMANN_FORMS}
        print(f"  beckmann forms a={a:g}: " + "  ".join(f"{k} {v:.4f}" for k, v in forms[f"{a:g}"].items()), flush=True)
    out["beckmann_forms"] = forms
    out["isotropic_warp_floor"] = {f"{t:g}": float(slices.isotropic_warp_floor(math.cos(math.radians(t))))
                                   for t in (QUICK_VIEW_THETAS if quick else VIEW_THETAS)}
    print("  isotropic-warp floor (sharp-lobe limit): " +
          "  ".join(f"{t}deg {e:.4f}" for t, e in out["isotropic_warp_floor"].items()), flush=True)
    return out


def anisotropic(quick: bool) -> dict:
    out = {}
    counts = (1, 2) if quick else tuple(range(1, 9))
    for model, params in ANISOTROPIC.items():
        exact = brdf.microfacet_brdf(model, **params)
        rows = []
        for k in counts:
            t0 = time.perf_counter()
            slice_params = {**params, "lobes": k}
            fit = sg_ndf.fit_model_ndf(model, **slice_params)  # cached: view_slice below reuses it
            seconds = time.perf_counter() - t0
            errors = {f"{t:g}/{p:g}": slices.slice_error(exact, model, slice_params, view(t, p))
                      for t, p in (QUICK_ANISO_VIEWS if quick else ANISO_VIEWS)}
            culled_85 = int(slices.view_slice(model, view(85.0), **slice_params).culled.sum())
            rows.append({"lobes": k, "ndf_error": fit.relative_error, "initial_error": fit.initial_error,
                         "fit_seconds": seconds, "iterations": fit.iterations, "converged": fit.success,
                         "slice_error": errors, "culled_at_85deg": culled_85})
            print(f"  {model:17s} lobes={k}: NDF {fit.relative_error:.4f} (start {fit.initial_error:.4f}), "
                  f"{seconds:.2f} s, {fit.iterations} it; slice " +
                  "  ".join(f"{v} {e:.4f}" for v, e in errors.items()) + f"; culled at 85deg: {culled_85}", flush=True)
        out[model] = {"params": params, "rows": rows}
    return out


def chart(result, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axs = plt.subplots(2, 3, figsize=(15, 8.5))
    for ax, model in zip(axs.ravel()[:4], SWEEPS):
        block = result["isotropic"][model]
        for row in block["rows"]:
            thetas = [float(t) for t in row["slice_error"]]
            ys = list(row["slice_error"].values())
            ax.semilogy(thetas, ys, "o-", label=f"{block['parameter']}={row[block['parameter']]:g}")
        floor = result["isotropic"]["isotropic_warp_floor"]
        ax.semilogy([float(t) for t in floor][1:], list(floor.values())[1:], "k:", lw=2,
                    label="isotropic-warp floor")
        ax.set_title(f"{model}: 1 SG lobe, warped slice")
        ax.set_xlabel("view polar angle (deg)")
        ax.set_ylabel("relative L2 error (slice x cos)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    for ax, model in zip(axs.ravel()[4:], ANISOTROPIC):
        rows = result["anisotropic"][model]["rows"]
        k = [r["lobes"] for r in rows]
        ax.semilogy(k, [r["ndf_error"] for r in rows], "ks-", label="NDF fit")
        for v in rows[0]["slice_error"]:
            ax.semilogy(k, [r["slice_error"][v] for r in rows], "o--", label=f"slice, view {v} deg")
        params = ", ".join(f"{a}={b:g}" for a, b in result["anisotropic"][model]["params"].items())
        ax.set_title(f"{model} ({params}): L-BFGS-B lobes")
        ax.set_xlabel("lobes")
        ax.set_ylabel("relative L2 error")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"SG BRDF fits against the exact models ({result['date']}, {result['machine']})")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="smoke profile: one roughness per model, 1 and 2 anisotropic lobes")
    ap.add_argument("--out", type=Path, default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = ap.parse_args(argv)
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    t0 = time.perf_counter()
    result = {"date": datetime.date.today().isoformat(), "machine": f"{platform.machine()}, {os.cpu_count()} cores",
              "view_polar_angles_deg": list(QUICK_VIEW_THETAS if args.quick else VIEW_THETAS),
              "metric": "relative L2 over the hemisphere of i of (rho_s*(i;o) max(0,i_z) - rho(o,i) i_z); "
                        "NDF: relative L2 over the hemisphere (isotropic) or fitting cap (anisotropic) of h"}
    print("isotropic closed forms:", flush=True)
    result["isotropic"] = isotropic(args.quick)
    print("anisotropic fits (L-BFGS-B, free axes):", flush=True)
    result["anisotropic"] = anisotropic(args.quick)
    result["seconds"] = time.perf_counter() - t0
    stem = (args.out or RESULTS) / f"sg-fit-{result['date']}-cpu{'-quick' if args.quick else ''}"
    write_json_atomic(f"{stem}.json", result, indent=1)
    chart(result, Path(f"{stem}.png"))
    print(f"wrote {stem}.json, {stem}.png ({result['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
