"""A graph's recorded frame and the ground truth of one validated frame, timed side by side with an
earlier commit.

What ``warpshade run GRAPH --validate`` spends its time on beyond the precompute: the frames (for
``stages/figure_hybrid.toml`` the 64-ray ``hybrid.trace`` residual each frame) and the ray-traced
ground truth of the measured frames (:func:`warpshade.measure.ground_truth`: MIS with indirect
paths). Each measurement is a fresh process -- this checkout, and with ``--before COMMIT`` that
commit checked out into a temporary git worktree and imported through ``PYTHONPATH`` --
alternated ``--rounds`` times so both see the same machine; the medians and their ratio are
reported. The precompute comes from the artifact cache (it is not what is timed); the ground
truth is computed afresh (no cache).

Writes ``benchmarks/results/validate-<date>-<device>.json`` and a chart ``...png``.

Usage::

    python benchmarks/bench_validate.py --before 3f8606c            # figure_hybrid, 2 rounds
    python benchmarks/bench_validate.py --graph blockers_hybrid --gt-frame 30
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"


def measure(root: Path, graph: str, frames: int, gt_frame: float, samples: int, device: str) -> dict:
    """In this process, on whichever warpshade it imports: the median recorded frame over the
    scene's first ``frames`` time codes, and one ground-truth frame of ``samples`` rays a vertex."""
    import warpshade
    from warpshade.graph import load
    from warpshade.measure import ground_truth

    spec = load(root / "stages" / f"{graph}.toml")
    scene = spec.load_scene()
    rt = spec.compile(scene, device=device, progress=False)
    sel = [float(f) for f in scene.frames[:frames]]
    rt.run(sel)
    frame_ms = 1e3 * rt.timing_summary()["median_frame_s"]
    if float(gt_frame) not in {float(f) for f in scene.frames}:
        raise SystemExit(f"--gt-frame {gt_frame:g} is not a time code of {graph}'s scene")
    t0 = time.perf_counter()
    ground_truth(rt.scene, rt.lighting, [float(gt_frame)], samples=samples, device=device, cache_dir=None)
    return {"warpshade": str(Path(warpshade.__file__).parent), "frame_ms": frame_ms, "frames_timed": len(sel),
            "ground_truth_s": time.perf_counter() - t0}


def child(tree: Path, args) -> dict:
    """One measurement in a fresh process importing warpshade from ``tree``."""
    with tempfile.TemporaryDirectory(prefix="warpshade-validate-") as tmp:
        res = Path(tmp) / "row.json"
        env = dict(os.environ, PYTHONPATH=str(tree))
        subprocess.run([sys.executable, str(Path(__file__).resolve()), "--inner", str(res), "--tree", str(tree),
                        "--graph", args.graph, "--frames", str(args.frames), "--gt-frame", str(args.gt_frame),
                        "--samples", str(args.samples), "--device", args.device], check=True, env=env, cwd=str(tree))
        return json.loads(res.read_text())


def chart(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from warpshade._fileio import atomic_path

    sides = [s for s in ("before", "this") if s in result["median"]]
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.4))
    for ax, key, label in ((axes[0], "frame_ms", "median recorded frame (ms)"),
                           (axes[1], "ground_truth_s", f"ground truth, one frame, {result['meta']['samples']} rays (s)")):
        for i, side in enumerate(sides):
            vals = [r[key] for r in result["rounds"] if r["side"] == side]
            ax.bar(i, result["median"][side][key], 0.6, color="tab:gray" if side == "before" else "tab:blue")
            ax.plot([i] * len(vals), vals, "k.", ms=5)
        ax.set_xticks(range(len(sides)), [f"before\n{result['meta']['before']}" if s == "before" else "this checkout"
                                          for s in sides])
        ax.set_ylabel(label, fontsize=8)
        ax.grid(True, axis="y", alpha=0.3)
    fig.suptitle(f"{result['meta']['graph']} on {result['meta']['device']} (dots: rounds, bars: medians)", fontsize=9)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--graph", default="figure_hybrid", help="a graph of stages/ (default figure_hybrid)")
    ap.add_argument("--frames", type=int, default=24, help="frames timed (the scene's first time codes)")
    ap.add_argument("--gt-frame", type=float, default=30.0, help="the time code whose ground truth is timed")
    ap.add_argument("--samples", type=int, default=1024, help="ground-truth rays per vertex")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--before", default=None, metavar="COMMIT", help="also measure this earlier commit, alternated")
    ap.add_argument("--rounds", type=int, default=2, help="measurements per side")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    ap.add_argument("--quick", action="store_true", help="smoke profile: blockers_unshadowed, 3 frames, 16 rays, one round")
    ap.add_argument("--inner", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--tree", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.inner:
        row = measure(Path(args.tree), args.graph, args.frames, args.gt_frame, args.samples, args.device)
        Path(args.inner).write_text(json.dumps(row))
        return 0
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    if args.quick:
        args.graph, args.frames, args.gt_frame, args.samples, args.rounds = "blockers_unshadowed", 3, 0.0, 16, 1
    if not (ROOT / "stages" / f"{args.graph}.toml").is_file():
        ap.error(f"--graph: no stages/{args.graph}.toml")
    from warpshade._fileio import write_json_atomic

    trees = {"this": ROOT}
    tmp = None
    if args.before:
        tmp = tempfile.TemporaryDirectory(prefix="warpshade-before-")
        trees["before"] = Path(tmp.name) / "tree"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(trees["before"]), args.before],
                       check=True, capture_output=True)
    rounds = []
    try:
        for i in range(args.rounds):
            for side in [s for s in ("before", "this") if s in trees]:
                row = {"side": side, "round": i, **child(trees[side], args)}
                rounds.append(row)
                print(f"  round {i + 1} {side:6s} frame {row['frame_ms']:8.2f} ms  ground truth {row['ground_truth_s']:7.2f} s",
                      flush=True)
    finally:
        if tmp is not None:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(trees["before"])],
                           check=False, capture_output=True)
            tmp.cleanup()
    median = {side: {k: statistics.median(r[k] for r in rounds if r["side"] == side) for k in ("frame_ms", "ground_truth_s")}
              for side in trees}
    date = datetime.date.today().isoformat()
    from _checkout import checkout_commit  # a sibling module: benchmarks/_checkout.py

    result = {"meta": {"date": date, "device": args.device, "graph": args.graph, "commit": checkout_commit(ROOT),
                       "frames_timed": args.frames,
                       "gt_frame": args.gt_frame, "samples": args.samples, "before": args.before, "rounds": args.rounds,
                       "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
                       "command": "python benchmarks/bench_validate.py " + " ".join(argv if argv is not None else sys.argv[1:])},
              "rounds": rounds, "median": median}
    if "before" in median:
        result["this_over_before"] = {k: median["this"][k] / median["before"][k] for k in ("frame_ms", "ground_truth_s")}
        print(f"this / before: frame {result['this_over_before']['frame_ms']:.2f}x, "
              f"ground truth {result['this_over_before']['ground_truth_s']:.2f}x")
    out = Path(args.out or RESULTS)
    stem = f"validate-{date}-{args.device.replace(':', '')}" + ("-quick" if args.quick else "")
    write_json_atomic(out / f"{stem}.json", result, indent=1)
    chart(result, out / f"{stem}.png")
    print(f"wrote {out / stem}.json and .png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
