"""Frame rate of the data-driven visibility graphs against RPO over per-frame ray tracing.

Issue goals this measures (Nowrouzezahrai et al. 2009, sec. 5, on this CPU): the wanderer's
data-driven frame at >= 100 Hz, and the data-driven frame at least 30x faster than the frame of
its baseline graph (``stages/<scene>_rpo_traced.toml``: the same shading over visibility ray
traced every frame).

Each measurement is a child process that compiles every graph (precomputed artifacts from the
cache: run the graphs once first, e.g. ``warpshade run stages/figure_visibility.toml``), steps one
warm-up frame twice (compile, record), then times ``--frames`` recorded frames and reports their
median (``Runtime.timing_summary``) and the per-stage profile. With ``--before COMMIT`` the same
child runs on that commit's library (a temporary git worktree on ``PYTHONPATH``), alternating
with this checkout for ``--rounds`` rounds, so the ratio is side by side on this shared machine;
the load average is recorded around every child.

Writes ``visibility-frame-<date>-<device>[-tag].json`` and ``.png`` into ``--out``.

Usage::

    python benchmarks/bench_visibility_frame.py [--graphs figure_visibility,figure_rpo_traced]
        [--before 9fb9145] [--rounds 3] [--frames 48] [--tag quiet]
    python benchmarks/bench_visibility_frame.py --quick --out DIR   # smoke profile
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: Smoke profile (tests/test_benchmarks.py): slow, kept out of the default suite (``-m "not slow"``):
#: a visibility training trace and fit in a fresh cache, then the figure's frame and
#: its traced baseline.
PROFILE = {"slow": True}

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
GRAPHS = ("figure_visibility", "figure_rpo_traced", "wanderer_visibility", "wanderer_rpo_traced")
#: Frames of a traced baseline timed at most (a traced wanderer frame takes about a second).
TRACED_FRAMES = 8
#: ``--quick``: the figure's pair in a fresh cache, trained on every 60th frame at 16 rays with one
#: small network, 3 frames timed, one round, no earlier commit.
QUICK = {"graphs": "figure_visibility,figure_rpo_traced", "frames": 3,
         "params": {"visibility.data": {"samples": 16, "frames": "0:600:60"},
                    "visibility.fit": {"hidden": (4,), "max_iterations": 10},
                    "rpo.visibility_traced": {"samples": 16}}}


def measure(graphs, device: str, frames: int, cache_dir: str | None, quick: bool = False) -> dict:
    """Median recorded frame and per-stage profile of each graph in this process."""
    from warpshade.graph import load

    rows = {}
    for name in graphs:
        spec = load(ROOT / "stages" / f"{name}.toml")
        if quick:
            for st in spec.stages:
                st.params.update(QUICK["params"].get(st.type, {}))
        rt = spec.compile(device=device, progress=False, **({"cache_dir": cache_dir} if cache_dir else {}))
        count = min(frames, TRACED_FRAMES) if name.endswith("_traced") else frames
        sel = [float(rt.scene.frames[i % len(rt.scene.frames)]) for i in range(count)]
        rt.run(sel, record=True, warmup=True)
        t = rt.timing_summary()
        rows[name] = {"vertices": int(rt.scene.vertex_count), "frames_timed": count,
                      "frame_ms": 1e3 * float(t["median_frame_s"]),
                      "profile_ms": {k: 1e3 * v for k, v in rt.profile(sel[:4]).items()}}
    return rows


@contextlib.contextmanager
def _tree(commit: str | None):
    """This checkout (``None``) or a temporary worktree of ``commit``."""
    if commit is None:
        yield ROOT
        return
    with tempfile.TemporaryDirectory(prefix="warpshade-before-") as tmp:
        tree = Path(tmp) / "tree"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), commit], check=True,
                       capture_output=True)
        try:
            yield tree
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False,
                           capture_output=True)


def child(tree: Path, graphs, args) -> dict:
    """One measurement in a child process importing the library of ``tree``."""
    with tempfile.TemporaryDirectory() as tmp:
        res = Path(tmp) / "rows.json"
        env = dict(os.environ, PYTHONPATH=str(tree))
        load0 = os.getloadavg()[0]
        cmd = [sys.executable, __file__, "--inner", str(res), "--graphs", ",".join(graphs), "--device", args.device,
               "--frames", str(args.frames)] + (["--cache", args.cache] if args.cache else []) + \
            (["--quick-params"] if args.quick else [])
        subprocess.run(cmd, check=True, env=env, cwd=str(ROOT))
        return {"rows": json.loads(res.read_text()), "load": [load0, os.getloadavg()[0]]}


def summarise(runs: list[dict], graphs) -> dict:
    """Median over rounds of each graph's frame time, and the data-driven / traced ratios."""
    out = {}
    for g in graphs:
        ms = [r["rows"][g]["frame_ms"] for r in runs]
        out[g] = {"frame_ms": float(np.median(ms)), "frame_ms_rounds": ms, "hz": 1e3 / float(np.median(ms)),
                  "vertices": runs[0]["rows"][g]["vertices"], "profile_ms": runs[-1]["rows"][g]["profile_ms"]}
    for g in graphs:
        traced = g.replace("_visibility", "_rpo_traced")
        if g.endswith("_visibility") and traced in out:
            ratios = [r["rows"][traced]["frame_ms"] / r["rows"][g]["frame_ms"] for r in runs]
            out[g]["traced_over_this"] = float(np.median(ratios))
            out[g]["traced_over_this_rounds"] = ratios
    return out


def chart(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from warpshade._fileio import atomic_path

    graphs = list(result["this"])
    series = [("this checkout", result["this"])]
    if "before" in result:
        series.insert(0, (f"before ({result['meta']['before']})", result["before"]))
    fig, ax = plt.subplots(figsize=(8, 4))
    width = 0.8 / len(series)
    for i, (label, rows) in enumerate(series):
        vals = [rows[g]["frame_ms"] for g in graphs]
        xs = np.arange(len(graphs)) + (i - (len(series) - 1) / 2) * width
        ax.bar(xs, vals, width, label=label)
        for x, v in zip(xs, vals):
            ax.annotate(f"{v:.1f} ms\n{1e3 / v:.0f} Hz", (x, v), ha="center", va="bottom", fontsize=7)
    ax.set_xticks(np.arange(len(graphs)), [f"{g}\n({result['this'][g]['vertices']:,} v)" for g in graphs], fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel("median time per recorded frame (ms)")
    ratios = ", ".join(f"{g.split('_')[0]} traced/data-driven {r['traced_over_this']:.0f}x"
                       for g, r in result["this"].items() if "traced_over_this" in r)
    ax.set_title(f"{result['meta']['machine']}, {result['meta']['device']}: {ratios}", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--graphs", default=",".join(GRAPHS), help="graphs of stages/ to time (comma-separated)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--frames", type=int, default=48, help=f"recorded frames timed per graph (traced: at most {TRACED_FRAMES})")
    ap.add_argument("--rounds", type=int, default=1, help="alternating rounds (with --before: before, this, before, ...)")
    ap.add_argument("--before", default=None, metavar="COMMIT", help="also time this earlier commit, side by side")
    ap.add_argument("--cache", default=None, help="artifact cache (default: the user cache, where the graphs' runs put it)")
    ap.add_argument("--tag", default="", help="suffix of the output names")
    ap.add_argument("--out", default=str(RESULTS), help="output directory")
    ap.add_argument("--quick", action="store_true",
                    help="smoke profile: the figure's pair, a fresh cache, few training frames and rays, 3 frames")
    ap.add_argument("--inner", default=None, help=argparse.SUPPRESS)  # child process: write rows here
    ap.add_argument("--quick-params", action="store_true", help=argparse.SUPPRESS)  # child of --quick
    args = ap.parse_args(argv)
    if args.quick and args.out == str(RESULTS):
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    own_cache = None
    if args.quick:
        args.graphs, args.frames, args.rounds, args.before = QUICK["graphs"], QUICK["frames"], 1, None
        own_cache = tempfile.TemporaryDirectory(prefix="warpshade-visframe-")
        args.cache = own_cache.name
    graphs = [g for g in args.graphs.split(",") if g]
    for g in graphs:
        if not (ROOT / "stages" / f"{g}.toml").is_file():
            ap.error(f"--graphs: no stages/{g}.toml")
    if args.inner:
        Path(args.inner).write_text(json.dumps(measure(graphs, args.device, args.frames, args.cache, args.quick_params)))
        return 0
    from warpshade._fileio import write_json_atomic

    this_runs, before_runs = [], []
    t0 = time.perf_counter()
    with _tree(args.before) as before_tree:
        for r in range(max(1, args.rounds)):
            if args.before:
                before_runs.append(child(before_tree, graphs, args))
                print(f"round {r + 1} before: " + ", ".join(f"{g} {before_runs[-1]['rows'][g]['frame_ms']:.2f} ms"
                                                           for g in graphs), flush=True)
            this_runs.append(child(ROOT, graphs, args))
            print(f"round {r + 1} this:   " + ", ".join(f"{g} {this_runs[-1]['rows'][g]['frame_ms']:.2f} ms"
                                                      for g in graphs) + f"  (load {this_runs[-1]['load']})", flush=True)
    result = {"meta": {"date": datetime.date.today().isoformat(), "device": args.device,
                       "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
                       "frames_timed": args.frames, "rounds": args.rounds, "before": args.before,
                       "load": [r["load"] for r in before_runs + this_runs], "wall_s": time.perf_counter() - t0,
                       "command": "python benchmarks/bench_visibility_frame.py " + " ".join(argv or sys.argv[1:])},
              "this": summarise(this_runs, graphs)}
    if args.before:
        result["before"] = summarise(before_runs, graphs)
        result["speedup"] = {g: float(np.median([b["rows"][g]["frame_ms"] / t["rows"][g]["frame_ms"]
                                                 for b, t in zip(before_runs, this_runs)])) for g in graphs}
    for g, row in result["this"].items():
        extra = f", traced/this {row['traced_over_this']:.1f}x" if "traced_over_this" in row else ""
        sp = f", {result['speedup'][g]:.2f}x faster than {args.before}" if args.before else ""
        print(f"{g:22s} {row['frame_ms']:8.2f} ms ({row['hz']:.0f} Hz){extra}{sp}")
    stem = f"visibility-frame-{result['meta']['date']}-{args.device.replace(':', '')}" + ("-quick" if args.quick else "") + \
        (f"-{args.tag}" if args.tag else "")
    out = Path(args.out)
    write_json_atomic(out / f"{stem}.json", result, indent=1)
    chart(result, out / f"{stem}.png")
    print(f"wrote {out / stem}.json and .png")
    if own_cache is not None:
        own_cache.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
