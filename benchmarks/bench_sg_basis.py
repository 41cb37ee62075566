"""Accuracy of the spherical-Gaussian basis (warpshade.basis.sg): the goals of the SG issue.

* ``f_h`` (eq. 30): the erf form and the paper's sigmoid (eq. 46-49) against the quadrature oracle,
  worst error over theta_d in [-pi/2, pi/2] as a fraction of ``f_h(pi/2, lambda)`` and relative to
  the integral where it is at least 1 % of that, for lambda from 0.01 to 2000;
* the inner product (eq. 4) against a 400 x 800 product quadrature of the sphere, random lobes;
* the vector product (eq. 5) against direct multiplication;
* the clamped cosine lobes (the paper's and the L2 fit), relative L2 error over the sphere.

Writes ``benchmarks/results/sg-basis-<date>-cpu.json`` and ``-fh.png``. Float64, a few seconds.

    python benchmarks/bench_sg_basis.py
"""

from __future__ import annotations

import argparse
import datetime
import platform
from pathlib import Path

import numpy as np

from warpshade._fileio import write_json_atomic
from warpshade.basis import sg

RESULTS = Path(__file__).resolve().parent / "results"


def fh_errors(lams, method: str) -> dict:
    t = np.linspace(-np.pi / 2, np.pi / 2, 241)
    of_pole, relative = [], []
    for lam in lams:
        exact = sg.hemisphere_integral(t, lam, "quadrature")
        approx = sg.hemisphere_integral(t, lam, method)
        pole = exact[-1]
        of_pole.append(float(np.max(np.abs(approx - exact)) / pole))
        big = exact >= 0.01 * pole
        relative.append(float(np.max(np.abs(approx[big] - exact[big]) / exact[big])))
    return {"of_pole": of_pole, "relative": relative}


def sphere_rule(nt=400, nphi=800):
    x, w = np.polynomial.legendre.leggauss(nt)
    phi = (np.arange(nphi) + 0.5) * 2 * np.pi / nphi
    ct, ph = np.meshgrid(x, phi, indexing="ij")
    st = np.sqrt(1 - ct**2)
    dirs = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3)
    return dirs, (w[:, None] * np.full(nphi, 2 * np.pi / nphi)[None]).reshape(-1)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smoke profile: 12 sharpnesses, 8 lobe pairs, a 100 x 200 sphere rule")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = ap.parse_args(argv)
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    rng = np.random.default_rng(0)
    lams = np.geomspace(0.01, 2000.0, 12 if args.quick else 60)
    fh = {m: fh_errors(lams, m) for m in ("erf", "paper")}
    goal = (lams >= 1.0) & (lams <= 400.0)
    dirs, w = sphere_rule(*((100, 200) if args.quick else ()))
    pairs = 8 if args.quick else 40
    inner = []
    product = []
    for _ in range(pairs):
        a1, a2 = (v / np.linalg.norm(v) for v in rng.normal(size=(2, 3)))
        l1, l2 = rng.uniform(0.5, 100.0, 2)
        g1, g2 = sg.evaluate(dirs, a1, l1), sg.evaluate(dirs, a2, l2)
        q = float(np.sum(w * g1 * g2))
        inner.append(abs(float(sg.inner_product(a1, l1, 1.0, a2, l2, 1.0)) - q) / max(q, 1e-300))
        axis, lam, amp = sg.product(a1, l1, 1.0, a2, l2, 1.0)
        direct = g1 * g2
        product.append(float(np.max(np.abs(sg.evaluate(dirs, axis, lam, amp) - direct)) / direct.max()))
    x, wx = np.polynomial.legendre.leggauss(400)
    target = np.maximum(x, 0.0)
    cosine = {}
    for fit in ("paper", "l2"):
        _, lam, mu = sg.clamped_cosine(np.array([0.0, 0.0, 1.0]), fit)
        err = np.sqrt(np.sum(wx * (mu * np.exp(lam * (x - 1)) - target) ** 2) / np.sum(wx * target**2))
        cosine[fit] = {"sharpness": float(lam), "amplitude": float(mu), "relative_l2": float(err),
                       "hemisphere_integral_over_pi": float(mu * sg.hemisphere_integral(np.pi / 2, lam) / np.pi)}
    out = {
        "date": datetime.date.today().isoformat(), "machine": platform.machine(), "device": "cpu (float64 NumPy)",
        "fh": {"lambda": lams.tolist(), **fh,
               "goal_lambda_1_400": {m: {"max_of_pole": float(np.max(np.array(fh[m]["of_pole"])[goal])),
                                         "max_relative": float(np.max(np.array(fh[m]["relative"])[goal]))} for m in fh},
               "all_lambda": {m: float(np.max(fh[m]["of_pole"])) for m in fh}},
        "inner_product": {"lobes": pairs, "max_relative_error": float(np.max(inner)),
                          "quadrature": "100 x 200" if args.quick else "400 x 800"},
        "product": {"lobes": pairs, "max_error_of_peak": float(np.max(product))},
        "clamped_cosine": cosine,
    }
    stem = Path(args.out or RESULTS) / f"sg-basis-{out['date']}-cpu{'-quick' if args.quick else ''}"
    write_json_atomic(stem.with_suffix(".json"), out)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for m, style in (("erf", "-"), ("paper", "--")):
        ax.loglog(lams, fh[m]["of_pole"], style, label=f"{m} (max |err| / f_h(pi/2))")
    ax.axhline(0.01, color="grey", lw=0.8, ls=":")
    ax.axvspan(1, 400, color="0.92", zorder=0)
    ax.set_xlabel("sharpness lambda")
    ax.set_ylabel("worst error over theta_d")
    ax.set_title("hemisphere integral f_h: closed forms vs quadrature")
    ax.legend()
    fig.tight_layout()
    tmp = stem.parent / (stem.name + "-fh.tmp.png")
    fig.savefig(tmp, dpi=120)
    tmp.replace(stem.parent / (stem.name + "-fh.png"))
    print({k: v for k, v in out["fh"].items() if k.startswith("goal") or k == "all_lambda"})
    print(out["inner_product"], out["product"], out["clamped_cosine"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
