"""Where a frame's time goes: the recorded frame against a bare shading kernel, and host time.

For a few ready-made graphs (the demo, LDPRT and SHEXP on the skinned figure) this measures,
in one run on one machine:

* the median time per frame of ``Runtime.step`` (after warm-up), and the host-side Python time
  of a step (everything before the recorded frame is replayed);
* for the demo, the time of one bare order-4 PRT shading kernel over the same vertices and the
  ratio frame / bare kernel (what the frame adds on top of the one kernel that shades);
* the per-stage profile (scene evaluation and each stage launched and synchronised alone);
* variants of the frame: recorded with chunked multi-core CPU launches between segments (the
  default), recorded as one single-threaded replay (``WARPSHADE_THREADS=1``), and not recorded
  (every launch from Python).

``--before COMMIT`` runs the same measurement on an earlier commit of this repository (checked
out into a temporary git worktree, imported through ``PYTHONPATH``) right before, so the two
are side by side on the same machine; only what both versions have is measured there.

Writes ``benchmarks/results/frame-<date>-<device>.json`` and a chart ``...-frame.png``.

Usage::

    python benchmarks/bench_frame.py [--device cpu] [--frames 48] [--before 6d29463]
"""

from __future__ import annotations

import argparse
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

from warpshade._wp import wp

ROOT = Path(__file__).resolve().parent.parent
GRAPHS = ("demo", "figure_ldprt", "figure_shexp")
RESULTS = ROOT / "benchmarks" / "results"
#: Caps on the graphs' stage parameters in the ``--quick`` smoke profile (rays per vertex, ZH
#: lobes, blocker spheres): the precompute of a fresh cache in seconds.
QUICK_CAPS = {"samples": 16, "lobes": 1, "budget": 4}


def _median_ms(xs) -> float:
    return float(1e3 * np.median(xs)) if len(xs) else float("nan")


def bare_kernel_ms(rt, repeats: int = 200) -> float:
    """One order-4 ``shade_transfer_kernel`` launch over the run's vertices, synchronised."""
    try:
        from warpshade.methods.prt import _kernels as kernels
    except ImportError:  # --before a commit whose modules were not yet _-prefixed
        from warpshade.methods.prt import kernels

    v = rt.scene.vertex_count
    dev = rt.device
    transfer = wp.array(np.random.default_rng(0).normal(size=(v, 16)).astype(np.float32), device=dev)
    light = wp.array(np.ones((3, 16), np.float32), device=dev)
    albedo = wp.full((v, 3), 0.5, dtype=wp.float32, device=dev)
    out = wp.zeros((v, 3), dtype=wp.float32, device=dev)
    times = []
    for i in range(repeats + 5):
        t0 = time.perf_counter()
        wp.launch(kernels.shade_transfer_kernel, dim=v, inputs=[transfer, light, albedo, out], device=dev)
        wp.synchronize_device(dev)
        if i >= 5:
            times.append(time.perf_counter() - t0)
    return _median_ms(times)


def load_graph(name: str, quick: bool = False):
    """The graph ``stages/<name>.toml``; ``quick``: its stage parameters capped by :data:`QUICK_CAPS`."""
    from warpshade.graph import load

    spec = load(ROOT / "stages" / f"{name}.toml")
    if quick:
        for stage in spec.stages:
            stage.params.update({k: min(v, QUICK_CAPS[k]) for k, v in stage.params.items() if k in QUICK_CAPS})
    return spec


def measure_graph(name: str, device: str, frame_count: int, cache_dir: str, quick: bool = False) -> dict:
    spec = load_graph(name, quick)
    t0 = time.perf_counter()
    rt = spec.compile(device=device, progress=False, cache_dir=cache_dir)
    setup_s = time.perf_counter() - t0
    frames = rt.scene.frames
    sel = [float(frames[i % len(frames)]) for i in range(frame_count)]
    rt.run(sel[:1], record=False)  # warm-up: compile (and record)
    rt.reset_timings()
    rt.run(sel, record=False, warmup=False)
    t = rt.timing_summary()
    out = {"graph": name, "vertices": rt.scene.vertex_count, "frames_timed": len(sel), "setup_s": setup_s,
           "frame_ms": 1e3 * t["median_frame_s"], "host_ms": 1e3 * t["median_host_s"],
           "recorded": bool(t.get("captured")), "uncaptured": t.get("uncaptured", [])}
    if hasattr(rt, "profile"):
        out["profile_ms"] = {k: 1e3 * v for k, v in rt.profile(sel[:8]).items()}
    if name == "demo":
        out["bare_kernel_ms"] = bare_kernel_ms(rt)
        out["frame_over_bare_kernel"] = out["frame_ms"] / out["bare_kernel_ms"]
    return out


def measure_variants(device: str, frame_count: int, cache_dir: str, variants: bool, quick: bool = False) -> dict:
    rows = {}
    for name in GRAPHS:
        rows[name] = {"default": measure_graph(name, device, frame_count, cache_dir, quick)}
        print(f"  {name:14s} {rows[name]['default']['frame_ms']:8.3f} ms/frame, host {rows[name]['default']['host_ms']:.4f} ms",
              flush=True)
    if variants:
        from warpshade.graph import load

        for name in GRAPHS:
            # not recorded: every launch from Python, chunked CPU launches on every core
            spec = load(ROOT / "stages" / f"{name}.toml")
            rt = spec.compile(device=device, progress=False, cache_dir=cache_dir, capture=False)
            sel = [float(rt.scene.frames[i % len(rt.scene.frames)]) for i in range(frame_count)]
            rt.run(sel[:1], record=False)
            rt.reset_timings()
            rt.run(sel, record=False, warmup=False)
            t = rt.timing_summary()
            rows[name]["not_recorded"] = {"frame_ms": 1e3 * t["median_frame_s"], "host_ms": 1e3 * t["median_host_s"]}
        # one single-threaded replay per frame: a child process with WARPSHADE_THREADS=1
        env = dict(os.environ, WARPSHADE_THREADS="1")
        with tempfile.TemporaryDirectory() as tmp:
            res = Path(tmp) / "single.json"
            subprocess.run([sys.executable, __file__, "--device", device, "--frames", str(frame_count), "--inner", str(res),
                            "--cache", cache_dir], check=True, env=env)
            single = json.loads(res.read_text())["rows"]
        for name in GRAPHS:
            rows[name]["single_replay"] = {k: single[name]["default"][k] for k in ("frame_ms", "host_ms", "uncaptured")}
        for name in GRAPHS:
            r = rows[name]
            print(f"  {name:14s} recorded+chunked {r['default']['frame_ms']:.3f} ms, single replay "
                  f"{r['single_replay']['frame_ms']:.3f} ms, not recorded {r['not_recorded']['frame_ms']:.3f} ms", flush=True)
    return rows


def run_before(commit: str, device: str, frame_count: int, cache_dir: str) -> dict:
    """The default measurement on an earlier commit (temporary worktree, same interpreter)."""
    with tempfile.TemporaryDirectory(prefix="warpshade-before-") as tmp:
        tree = Path(tmp) / "tree"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), commit], check=True,
                       capture_output=True)
        try:
            res = Path(tmp) / "before.json"
            env = dict(os.environ, PYTHONPATH=str(tree))
            subprocess.run([sys.executable, __file__, "--device", device, "--frames", str(frame_count), "--inner", str(res),
                            "--cache", cache_dir], check=True, env=env, cwd=str(tree))
            out = json.loads(res.read_text())
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=False, capture_output=True)
    out["commit"] = commit
    return out


def chart(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from warpshade._fileio import atomic_path

    rows = result["rows"]
    series = [("before (commit %s)" % result["before"]["commit"], lambda n: result["before"]["rows"][n]["default"]["frame_ms"])
              if "before" in result else None,
              ("recorded, chunked CPU launches", lambda n: rows[n]["default"]["frame_ms"]),
              ("recorded, one replay", lambda n: rows[n].get("single_replay", {}).get("frame_ms", np.nan)),
              ("not recorded", lambda n: rows[n].get("not_recorded", {}).get("frame_ms", np.nan))]
    series = [s for s in series if s is not None]
    fig, ax = plt.subplots(figsize=(8, 4))
    width = 0.8 / len(series)
    for i, (label, get) in enumerate(series):
        vals = [get(n) for n in GRAPHS]
        ax.bar(np.arange(len(GRAPHS)) + (i - (len(series) - 1) / 2) * width, vals, width, label=label)
    ax.set_xticks(np.arange(len(GRAPHS)), [f"{n}\n({rows[n]['default']['vertices']:,} v)" for n in GRAPHS])
    ax.set_yscale("log")
    ax.set_ylabel("median time per frame (ms)")
    demo = rows["demo"]["default"]
    ax.set_title(f"{result['meta']['device']}: demo frame = {demo['frame_over_bare_kernel']:.2f} x one bare shading kernel",
                 fontsize=10)
    ax.legend(fontsize=8)
    ax.grid(True, axis="y", which="both", alpha=0.3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--frames", type=int, default=48, help="frames timed per graph")
    ap.add_argument("--before", default=None, metavar="COMMIT", help="also measure this earlier commit, side by side")
    ap.add_argument("--no-variants", action="store_true", help="only the default (recorded) frame")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    ap.add_argument("--cache", default=None, help="artifact cache directory (default: a temporary one)")
    ap.add_argument("--inner", default=None, help=argparse.SUPPRESS)  # child process: write rows here
    ap.add_argument("--quick", action="store_true",
                    help="smoke profile: 3 frames per graph, no variants, stage parameters capped (QUICK_CAPS)")
    args = ap.parse_args(argv)
    if args.quick and args.out is None and not args.inner:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    args.out = args.out or str(RESULTS)
    if args.quick:
        args.frames, args.no_variants = 3, True
    own_cache = tempfile.TemporaryDirectory(prefix="warpshade-frame-") if args.cache is None else None
    cache_dir = args.cache or own_cache.name
    if args.inner:
        rows = {n: {"default": measure_graph(n, args.device, args.frames, cache_dir)} for n in GRAPHS}
        Path(args.inner).write_text(json.dumps({"rows": rows}))
        return 0
    from warpshade._fileio import write_json_atomic

    result = {"meta": {"date": datetime.date.today().isoformat(), "device": args.device,
                       "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
                       "warp": wp.config.version, "frames_timed": args.frames,
                       "command": "python benchmarks/bench_frame.py" + (f" --before {args.before}" if args.before else "")}}
    if args.before:
        print(f"[before: {args.before}]", flush=True)
        result["before"] = run_before(args.before, args.device, args.frames, cache_dir)
        for n in GRAPHS:
            b = result["before"]["rows"][n]["default"]
            print(f"  {n:14s} {b['frame_ms']:8.3f} ms/frame, host {b['host_ms']:.4f} ms", flush=True)
    print("[this checkout]", flush=True)
    result["rows"] = measure_variants(args.device, args.frames, cache_dir, not args.no_variants, args.quick)
    demo = result["rows"]["demo"]["default"]
    print(f"  demo frame / bare order-4 shading kernel: {demo['frame_over_bare_kernel']:.2f} "
          f"({demo['frame_ms']:.3f} / {demo['bare_kernel_ms']:.3f} ms)", flush=True)
    if "before" in result:
        b = result["before"]["rows"]["demo"]["default"]
        print(f"  before: {b['frame_over_bare_kernel']:.2f} ({b['frame_ms']:.3f} / {b['bare_kernel_ms']:.3f} ms)", flush=True)
    tag = args.device.replace(":", "")
    out = Path(args.out)
    stem = f"frame-{result['meta']['date']}-{tag}" + ("-quick" if args.quick else "")
    write_json_atomic(out / f"{stem}.json", result, indent=1)
    chart(result, out / f"{stem}.png")
    print(f"wrote {out / stem}.json and .png")
    if own_cache is not None:
        own_cache.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
