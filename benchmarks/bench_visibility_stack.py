"""Stacked regression against the per-cluster selection of stages/figure_visibility_diffuse.toml.

The graph with its visibility.fit parameters overridden by each variant (``regressor = "auto"``: one
candidate per cluster; ``regressor = "stack"`` with ``stack_top`` / ``stack_total``:
methods/visibility/stack.py), on the held-out figure clip (the graph's [validate] frames) and on
figure_walk (the frames of stages/figure_walk_datadriven.toml), against the same diffuse ray-traced
references as ``--validate``; the fits are made on the training clip only and cached like the
graph's. Records each variant's relative RMS, its fit report's cross-validation error (for a stack
the weighted out-of-fold error, in-sample for the weights), the fit time (when fitted in this run)
and the load average.

Writes ``visibility-stack-<date>-cpu.json`` into ``--out`` (default benchmarks/results).

Usage::

    python benchmarks/bench_visibility_stack.py [--clips figure,figure_walk] [--out DIR]
    python benchmarks/bench_visibility_stack.py --quick --out /tmp/vs      # smoke profile
"""

from __future__ import annotations

import argparse
import datetime
import os
import time
from pathlib import Path

#: Smoke profile (tests/test_benchmarks.py): slow, kept out of the default suite (``-m "not slow"``):
#: a training trace and references as bench_visibility_clusters, the auto and
#: stacked fits.
PROFILE = {"slow": True}

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
GRAPH = ROOT / "stages" / "figure_visibility_diffuse.toml"
#: visibility.fit overrides measured.
VARIANTS = {
    "auto": {"regressor": "auto"},
    "stack": {"regressor": "stack", "stack_top": 0, "stack_total": "one"},
    "stack top 8": {"regressor": "stack", "stack_top": 8, "stack_total": "one"},
    "stack free": {"regressor": "stack", "stack_top": 0, "stack_total": "free"},
    "stack equal top 3": {"regressor": "stack", "stack_top": 3, "stack_total": "equal"},
}
#: Held-out clips: scene (None: the graph's) and the graph whose [validate] frames are used.
CLIPS = {"figure": (None, None), "figure_walk": ("bundled:figure_walk", "figure_walk_datadriven")}


def run(variant: dict, clip: str, quick: bool = False) -> dict:
    from warpshade.graph import load
    from warpshade.measure import measure_error

    spec = load(GRAPH)
    if quick:  # smoke profile: 30 training frames at 16 rays, 64-ray references
        spec.validate_spec["samples"] = 64
        for st in spec.stages:
            if st.type == "visibility.data":
                st.params.update(frames="0:600:20", samples=16)
    scene, frames_of = CLIPS[clip]
    if scene is not None:
        spec.scene = scene
        spec.validate_spec["frames"] = list(load(ROOT / "stages" / f"{frames_of}.toml").validate_spec["frames"])
    if quick:
        spec.validate_spec["frames"] = spec.validate_spec["frames"][:1]
    for st in spec.stages:
        if st.type == "visibility.fit":
            st.params.update(variant)
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    rt = spec.compile(None, device="cpu", progress=False, scheduler="serial")
    compile_s = time.perf_counter() - t0
    m = measure_error(rt, [float(f) for f in spec.validate_spec["frames"]])
    fit = next(st for st in rt.stages if st.type_name == "visibility.fit")
    rep = getattr(fit, "report", None) or {}
    timing = rt.timings.get(fit.name) if isinstance(getattr(rt, "timings", None), dict) else None
    return {"rel_rms": float(m.error["mean"]["rel_rms"]), "frames": spec.validate_spec["frames"],
            "cv_error": rep.get("cv_error"), "fit_s": rep.get("total_fit_s"), "compile_s": compile_s,
            "fit_cache": getattr(timing, "cache", None), "input_components": rep.get("input_components"),
            "load_average": [load0, os.getloadavg()]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--clips", default="figure,figure_walk", help="held-out clips (figure, figure_walk)")
    ap.add_argument("--variants", default=",".join(VARIANTS), help="variants measured (names of VARIANTS)")
    ap.add_argument("--quick", action="store_true", help="smoke profile: the figure, 'auto' and 'stack', 30 training "
                    "frames at 16 rays, one frame against a 64-ray reference")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    args = ap.parse_args(argv)
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    if args.quick:
        args.clips, args.variants = "figure", "auto,stack"
    clips = [c for c in args.clips.split(",") if c]
    names = [v for v in args.variants.split(",") if v]
    bad = [c for c in clips if c not in CLIPS] + [v for v in names if v not in VARIANTS]
    if bad:
        ap.error(f"unknown clips or variants {bad}: clips {list(CLIPS)}, variants {list(VARIANTS)}")
    out = {"graph": str(GRAPH.relative_to(ROOT)), "variants": {v: VARIANTS[v] for v in names}, "results": {}}
    for clip in clips:
        for name in names:
            r = run(VARIANTS[name], clip, quick=args.quick)
            out["results"].setdefault(clip, {})[name] = r
            print(f"{clip:12s} {name:18s} rel_rms {r['rel_rms']:.4f}  cv {r['cv_error'] or float('nan'):.4f}  "
                  f"load {r['load_average'][1][0]:.2f}", flush=True)
    out_dir = Path(args.out or RESULTS)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"visibility-stack-{datetime.date.today().isoformat()}-cpu.json"
    from warpshade._fileio import write_json_atomic

    write_json_atomic(path, out, indent=1)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
