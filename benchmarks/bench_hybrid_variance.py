"""The variance ``hybrid.trace`` tracks for its history against the history's actual variance over seeds.

The stage's one-frame variance is the formula for independent samples (``residual_kernel``); the
rays of a frame are a randomly rotated spherical Fibonacci set and the frames of a cycle are
stratified together, so the actual spread can be smaller. What reads the tracked variance -- the
variance test, the soft reset's bias estimate, the history-aware filter's least-squares limit --
sees the difference. For each scene: ``--seeds`` runs stepped from the clip's start, at the frame
indices ``--frames`` the per-vertex variance of the transfer over the seeds (trace over the
coefficients) against the mean over seeds of the tracked variance (``state.variance``); their
ratio over all vertices and its median per vertex.

Settings: the visibility control with ``REPROJECT_SOFT`` on the figure (as stages/figure_hybrid.toml),
LDPRT's transfer with ``LDPRT_TRACE`` without the history-aware filter elsewhere; 64 rays.

Usage::

    python benchmarks/bench_hybrid_variance.py [--scenes figure,bend] [--frames 1,8,24] [--seeds 6]
    python benchmarks/bench_hybrid_variance.py --quick --out /tmp/hv

Writes ``benchmarks/results/hybrid-variance-<date>-<device>.json``.
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from warpshade._fileio import write_json_atomic  # noqa: E402
from warpshade.graph import GraphSpec, StageSpec  # noqa: E402
from warpshade.measure import load_bench_scene  # noqa: E402
from warpshade.methods.hybrid import stages_for  # noqa: E402
from warpshade.methods.hybrid._rows import LDPRT_TRACE, REPROJECT_SOFT  # noqa: E402


def scene_stages(key: str, samples: int, order: int) -> tuple:
    if key == "figure":
        return stages_for("visibility", samples, order, training="bundled:figure_train", frames="0:600:3",
                          training_samples=128, trace=REPROJECT_SOFT)
    trace = {k: v for k, v in LDPRT_TRACE.items() if not k.startswith("warmup")}
    return stages_for("ldprt", samples, order, trace=trace)


def measure(key: str, frames_at: list[int], seeds: int, samples: int, order: int, device: str) -> dict:
    scene, lighting = load_bench_scene(key)
    frames = np.asarray(scene.frames, np.float64)
    stages = scene_stages(key, samples, order)
    runs = {k: ([], [], []) for k in frames_at}
    for s in range(seeds):
        st = [StageSpec(n, t, {**p, "seed": 1000 + s} if t == "hybrid.trace" else dict(p), dict(i)) for n, t, p, i in stages]
        rt = GraphSpec(st, "trace.transfer", name=f"hybrid-variance-{s}").compile(
            scene, device=device, progress=False, lighting=lighting)
        trace = next(x for x in rt.frame_stages if x.type_name == "hybrid.trace")
        for k in range(max(frames_at) + 1):
            out = rt.step(float(frames[k])).numpy().astype(np.float64)
            if k in runs:
                runs[k][0].append(out.copy())
                runs[k][1].append(trace._state.variance.numpy().astype(np.float64))
                runs[k][2].append(trace._state.frames.numpy().astype(np.float64))
    rows = []
    for k, (outs, tracked, count) in runs.items():
        actual = np.stack(outs).var(axis=0, ddof=1).sum(axis=1)
        tr = np.mean(tracked, axis=0)
        ok = actual > 0
        rows.append({"scene": key, "frame_index": k, "effective_frames_mean": float(np.mean(count)),
                     "actual_variance_mean": float(actual.mean()), "tracked_variance_mean": float(tr.mean()),
                     "tracked_over_actual": float(tr.mean() / actual.mean()) if actual.mean() > 0 else None,
                     "tracked_over_actual_median": float(np.median(tr[ok] / actual[ok])) if ok.any() else None})
        print(f"{key} frame {k}: effective frames {rows[-1]['effective_frames_mean']:.2f}, tracked / actual "
              f"{rows[-1]['tracked_over_actual']:.2f} (median per vertex {rows[-1]['tracked_over_actual_median']:.2f})",
              flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smoke profile: bend, frame 1, 2 seeds, 8 rays, order 3")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    ap.add_argument("--scenes", default="figure,bend")
    ap.add_argument("--frames", default="1,8,24", help="frame indices (each run stepped from the clip's start)")
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--order", type=int, default=6)
    ap.add_argument("--device", default="cpu")
    args = ap.parse_args(argv)
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    if args.quick:
        args.scenes, args.frames, args.seeds, args.samples, args.order = "bend", "1", 2, 8, 3
    out_dir = Path(args.out or ROOT / "benchmarks" / "results")
    out_dir.mkdir(parents=True, exist_ok=True)
    date = datetime.date.today().isoformat()
    tag = "cpu" if args.device == "cpu" else args.device.replace(":", "")
    path = out_dir / (f"hybrid-variance-{date}-{tag}" + ("-quick" if args.quick else "") + ".json")
    meta = {"date": date, "device": args.device, "seeds": args.seeds, "samples": args.samples, "order": args.order,
            "load_average": os.getloadavg(),
            "command": " ".join(["python", "benchmarks/bench_hybrid_variance.py", *(argv if argv is not None else sys.argv[1:])])}
    t0 = time.perf_counter()
    results = []
    for key in args.scenes.split(","):
        results += measure(key, [int(x) for x in args.frames.split(",")], args.seeds, args.samples, args.order, args.device)
    meta["seconds"] = time.perf_counter() - t0
    meta["load_average_end"] = os.getloadavg()
    write_json_atomic(path, {"meta": meta, "results": results}, indent=1)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
