"""Dynamic height fields with RPO shading (Nowrouzezahrai et al. 2009, Fig. 11): cost and error.

On the bundled water (``bundled:ripples``: 512 x 512 vertices, 48 frames), through the
stage-graph runtime on the CPU:

* time per frame (the recorded frame replayed, median over the clip) and per stage (a profile:
  scene evaluation, ``heightfield.visibility``, the shading) of the graph
  ``stages/ripples_height_rpo.toml`` (128^2 visibility texels, 512^2 shading) and of variants:
  other visibility resolutions (64^2, 256^2), n = 3, the horizon march settings, the generic
  path (per-vertex visibility + ``ldprt.tangents`` + ``rpo.shade``);
* error against the glossy ray-traced reference (same BRDF, eye and colour; MIS, ``--spp``
  samples) on ``--vertices`` random vertices of frames 0 and 24, for n = 3, 4 and k = 4, 8, 16
  (k <= n^2), the exact-BRDF table, and the variants above;
* a picture of frame 24 from the scene camera.

Writes ``heightfield-<date>-cpu.json`` and ``heightfield-<date>-cpu.png`` into ``--out``
(default ``benchmarks/results``).

``--compare-with TREE`` instead times the default graph of this tree against the same graph of
another checkout (e.g. the commit before a kernel change) side by side: interleaved child
processes (A, B, A, B, ...; ``--rounds``), each compiling the graph, replaying ``--frames``
recorded frames and profiling its kernels (the scene evaluation, the max pyramid, the texel
march, the lighting products, the vertex shading) and its two stages whole; the medians, the
ratios and each tree's absolute rate (Hz, with the load average of the runs) go to
``heightfield-compare-<date>-cpu.json`` / ``.png``. On a shared machine only the ratios mean much.

``--hz`` only times the default graph of this tree (well under two minutes): the recorded frame
replayed over the whole clip ``--passes`` times, the median frame in ms and Hz, the per-stage
profile, the load average before and after and the CPU threads, printed as one clear line and
written to ``heightfield-hz-<date>-cpu.json``. It is the absolute number of the goal (30 Hz);
run it on a quiet machine (the load average says how quiet it was).

Usage::

    python benchmarks/bench_heightfield.py [--spp 512] [--vertices 4096] [--frames 24] [--out DIR]
    python benchmarks/bench_heightfield.py --compare-with /path/to/other/checkout [--rounds 5] [--frames 24]
    python benchmarks/bench_heightfield.py --hz [--passes 3] [--out DIR]
"""

from __future__ import annotations

import argparse
import copy
import datetime
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

#: Smoke profile (tests/test_benchmarks.py): slow, kept out of the default suite (``-m "not slow"``):
#: 21 s, kept out so that the default suite stays within ten minutes on 2 CPU cores.
PROFILE = {"slow": True}

ROOT = Path(__file__).resolve().parent.parent

DATE = "2026-12-01"
COMPARE_DATE = "2026-12-02"

#: Child process of ``--compare-with``: times the default graph of the tree on its PYTHONPATH
#: and prints one JSON line (replayed frame median; per-kernel medians, synchronised launches).
_CHILD = r"""
import json, sys, time
import numpy as np
import warpshade.methods.heightfield._kernels as K
import warpshade.methods.heightfield, warpshade.methods.rpo._stages
from warpshade._wp import wp, launch_parallel
from warpshade.graph import load
frames = int(sys.argv[1])
rt = load(sys.argv[2]).compile(device="cpu", progress=False)
rt.run([0.0, 1.0], record=False)
rt.run([float(f) for f in range(frames)], record=True)
frame_ms = float(np.median(rt.frame_s) * 1e3)
vis, shade = rt.frame_stages
cpu = {}
def tm(fn, n=9, name=None):
    ts, cs = [], []
    for _ in range(n):
        c0, t0 = time.process_time(), time.perf_counter()
        fn(); wp.synchronize_device("cpu")
        ts.append(time.perf_counter() - t0); cs.append(time.process_time() - c0)
    cpu[name] = float(np.median(cs) * 1e3)
    return float(np.median(ts) * 1e3)
g, r = vis.layout.size, vis.params["resolution"]
if hasattr(vis, "launch_parts"):
    # the stages name their kernels (whatever each tree launches): time each and the stages whole
    vp, sp = vis.launch_parts(), shade.launch_parts()
    kern = {"scene": tm(rt.evaluator.launch, name="scene"), "pyramid": tm(vp["pyramid"], name="pyramid"),
            "texels": tm(vp["texels"], name="texels"),
            "products": tm(lambda: [sp[k]() for k in sp if k != "shading"], name="products"),
            "shading": tm(sp["shading"], name="shading")}
else:
    def pyramid():
        wp.launch(K.heights_kernel, dim=g * g, inputs=[vis._points, vis._pyr], device="cpu")
        for k in range(1, len(vis._sizes)):
            s = vis._sizes[k]
            wp.launch(K.reduce_kernel, dim=s * s, inputs=[vis._pyr, int(vis._offs[k - 1]), vis._sizes[k - 1],
                                                         int(vis._offs[k]), s], device="cpu")
    vertices, texels, out = shade._shade_args
    kern = {"scene": tm(rt.evaluator.launch, name="scene"), "pyramid": tm(pyramid, name="pyramid"),
            "texels": tm(lambda: launch_parallel(vis._texel_kernel, r * r, lambda a, b: [vis._march, vis._texel_args, a],
                                                 "cpu"), name="texels"),
            "products": tm(lambda: launch_parallel(shade._product, r * r,
                                                   lambda a, b: [shade._texels, shade._lighting.light, a, shade._g], "cpu"),
                           name="products"),
            "shading": tm(lambda: launch_parallel(shade._shade, g * g, lambda a, b: [vertices, texels, a, out], "cpu"),
                          name="shading")}
# whole stages as the frame runs them (whatever kernels each tree launches)
kern["vis stage"] = tm(lambda: vis.launch(rt.state), name="vis stage")
kern["shade stage"] = tm(lambda: shade.launch(rt.state), name="shade stage")
import os
radiance = rt.step(24.0).numpy()
if len(sys.argv) > 3:
    np.save(sys.argv[3], radiance)  # frame 24, for the per-vertex comparison of the two trees
print("RESULT " + json.dumps({"frame_ms": frame_ms, "kernel_ms": kern, "kernel_cpu_ms": cpu, "load_average": os.getloadavg()[0],
                              "radiance_sum": float(radiance.astype(np.float64).sum())}))
"""


def compare(other: str, rounds: int, frames: int, out_dir: Path, suffix: str = "") -> int:
    """Interleaved child runs of this tree and ``other`` (see the module docstring)."""
    import subprocess

    graph = str(ROOT / "stages" / "ripples_height_rpo.toml")
    trees = {"this": str(ROOT), "other": str(Path(other).resolve())}
    import tempfile

    runs = {k: [] for k in trees}
    scratch = tempfile.mkdtemp(prefix="bench_heightfield_")
    for i in range(rounds):
        for key, tree in trees.items():
            env = {**os.environ, "PYTHONPATH": tree}
            t0 = time.perf_counter()
            res = subprocess.run([sys.executable, "-c", _CHILD, str(frames), graph, os.path.join(scratch, f"{key}.npy")],
                                 env=env, cwd=tree, capture_output=True, text=True)
            line = [x for x in res.stdout.splitlines() if x.startswith("RESULT ")]
            if res.returncode != 0 or not line:
                print(res.stdout[-2000:], res.stderr[-4000:], file=sys.stderr)
                raise SystemExit(f"child run of {tree} failed")
            runs[key].append(json.loads(line[0][7:]))
            print(f"  round {i + 1}/{rounds} {key:5s}: {runs[key][-1]['frame_ms']:.1f} ms/frame "
                  f"{ {k: round(v, 1) for k, v in runs[key][-1]['kernel_ms'].items()} } ({time.perf_counter() - t0:.0f} s)",
                  flush=True)
    med = {k: {"frame_ms": float(np.median([r["frame_ms"] for r in v])),
               "kernel_ms": {n: float(np.median([r["kernel_ms"][n] for r in v])) for n in v[0]["kernel_ms"]},
               "kernel_cpu_ms": {n: float(np.median([r["kernel_cpu_ms"][n] for r in v])) for n in v[0]["kernel_cpu_ms"]}}
           for k, v in runs.items()}
    ratio = {"frame": med["this"]["frame_ms"] / med["other"]["frame_ms"],
             **{n: med["this"]["kernel_ms"][n] / med["other"]["kernel_ms"][n] for n in med["this"]["kernel_ms"]}}
    # CPU time (both threads' work) is far less sensitive to other processes than wall time
    cpu_ratio = {n: med["this"]["kernel_cpu_ms"][n] / med["other"]["kernel_cpu_ms"][n] for n in med["this"]["kernel_cpu_ms"]}
    this_cpu, other_cpu = (sum(v for n, v in med[k]["kernel_cpu_ms"].items() if not n.endswith(" stage"))
                           for k in ("this", "other"))
    cpu_ratio["frame (sum of kernels)"] = this_cpu / other_cpu
    # the same radiance (a sum over every vertex of frame 24) from both trees
    agree = abs(runs["this"][0]["radiance_sum"] - runs["other"][0]["radiance_sum"]) / abs(runs["other"][0]["radiance_sum"])
    rad = {k: np.load(os.path.join(scratch, f"{k}.npy")).astype(np.float64) for k in trees}
    per_vertex = float(np.abs(rad["this"] - rad["other"]).max() / np.abs(rad["other"]).max())
    import shutil

    shutil.rmtree(scratch, ignore_errors=True)
    report = {"benchmark": "bench_heightfield --compare-with", "date": COMPARE_DATE, "cpu_count": os.cpu_count(),
              "platform": platform.platform(), "graph": "stages/ripples_height_rpo.toml", "rounds": rounds,
              "frames": frames, "trees": trees, "median": med, "ratio_this_over_other": ratio,
              "cpu_time_ratio_this_over_other": cpu_ratio,
              "radiance_sum_relative_difference": agree,
              "radiance_max_abs_difference_over_max": per_vertex, "runs": runs,
              "note": "interleaved child processes on a shared 2-core machine: compare the ratios",
              "command": "python benchmarks/bench_heightfield.py " + " ".join(sys.argv[1:])}
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = out_dir / f"heightfield-compare-{COMPARE_DATE}-cpu{'-' + suffix if suffix else ''}"
    (Path(f"{stem}.json")).write_text(json.dumps(report, indent=1))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(med["this"]["kernel_cpu_ms"])
    other_ms = [med["other"]["kernel_cpu_ms"][n] for n in names]
    this_ms = [med["this"]["kernel_cpu_ms"][n] for n in names]
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.bar(x - 0.2, other_ms, 0.4, label=f"other ({Path(trees['other']).name})")
    ax.bar(x + 0.2, this_ms, 0.4, label=f"this ({Path(trees['this']).name})")
    for i, n in enumerate(names):
        ax.text(i, max(other_ms[i], this_ms[i]) * 1.02, f"{cpu_ratio[n]:.2f}x", ha="center", fontsize=8)
    ax.set_xticks(x, names)
    ax.set_ylabel("CPU ms per launch (median, all threads)")
    ax.set_title(f"ripples_height_rpo kernels, {rounds} interleaved rounds (ratio this/other)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(f"{stem}.png", dpi=110)
    plt.close(fig)
    loads = [r.get("load_average") for v in runs.values() for r in v if r.get("load_average") is not None]
    report["load_average_range"] = [min(loads), max(loads)] if loads else None
    (Path(f"{stem}.json")).write_text(json.dumps(report, indent=1))
    print(f"absolute: this {1e3 / med['this']['frame_ms']:.1f} Hz ({med['this']['frame_ms']:.1f} ms/frame), other "
          f"{1e3 / med['other']['frame_ms']:.1f} Hz ({med['other']['frame_ms']:.1f} ms/frame); load average "
          + (f"{min(loads):.2f}..{max(loads):.2f}" if loads else "unknown") + " during the runs")
    print(f"wall-time ratios this/other: { {k: round(v, 3) for k, v in ratio.items()} }; radiance agrees to {agree:.2e} (sum), "
          f"{per_vertex:.2e} (largest per-vertex difference over the largest radiance, frame 24)")
    print(f"CPU-time ratios this/other: { {k: round(v, 3) for k, v in cpu_ratio.items()} }")
    print(f"wrote {stem}.json, {stem}.png")
    return 0


def hz(passes: int, out_dir: Path, suffix: str = "") -> int:
    """Absolute frame rate of the default graph of this tree (see the module docstring)."""
    import warpshade.methods.heightfield  # noqa: F401  (the height-field stages)
    from warpshade._wp import cpu_workers
    from warpshade.graph import load

    load_before = os.getloadavg()
    t0 = time.perf_counter()
    graph = ROOT / "stages" / "ripples_height_rpo.toml"
    rt = load(graph).compile(device="cpu", progress=False)
    setup_s = time.perf_counter() - t0
    clip = [float(f) for f in rt.scene.frames]
    rt.run(clip[:2], record=False)  # compile, then record the frame
    frame_ms = []
    for _ in range(passes):
        rt.reset_timings()
        rt.run(clip, record=False, warmup=False)
        frame_ms += [t * 1e3 for t in rt.frame_s]
    prof = rt.profile(clip[:8])
    load_after = os.getloadavg()
    med = float(np.median(frame_ms))
    from _checkout import checkout_commit  # a sibling module: benchmarks/_checkout.py

    commit = checkout_commit(ROOT)
    today = datetime.date.today().isoformat()  # a re-run on a quiet machine gets its own file
    report = {"benchmark": "bench_heightfield --hz", "date": today, "graph": "stages/ripples_height_rpo.toml",
              "commit": commit, "cpu_count": os.cpu_count(), "threads": cpu_workers(), "platform": platform.platform(),
              "frames_timed": len(frame_ms), "passes": passes, "frame_ms_median": round(med, 2),
              "frame_ms_p10_p90": [round(float(x), 2) for x in np.percentile(frame_ms, [10, 90])],
              "hz": round(1e3 / med, 1), "goal_hz": 30.0,
              "stage_ms": {k: round(v * 1e3, 2) for k, v in prof.items()},
              "uncaptured": rt.program.uncaptured if rt.program is not None else [],
              "load_average_before": [round(x, 2) for x in load_before],
              "load_average_after": [round(x, 2) for x in load_after], "setup_s": round(setup_s, 1),
              "note": "frames of the recorded program replayed on the CPU; a load average above ~0.5 means other "
                      "processes shared the cores and the rate is a lower bound",
              "command": "python benchmarks/bench_heightfield.py " + " ".join(sys.argv[1:])}
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"heightfield-hz-{today}-cpu{'-' + suffix if suffix else ''}.json"
    path.write_text(json.dumps(report, indent=1))
    print(f"ripples_height_rpo on the CPU ({cpu_workers()} threads): {med:.1f} ms/frame = {1e3 / med:.1f} Hz "
          f"(median of {len(frame_ms)} replayed frames; goal 30 Hz); stages (profile, ms) {report['stage_ms']}; "
          f"load average {load_before[0]:.2f} before, {load_after[0]:.2f} after")
    print(f"wrote {path}")
    return 0


def _graph(vis=None, shade=None, generic=False):
    from warpshade.graph import StageSpec, load

    spec = load(ROOT / "stages" / "ripples_height_rpo.toml")
    spec = copy.deepcopy(spec)
    v, s = spec.stages
    v.params.update(vis or {})
    s.params.update(shade or {})
    if generic:
        v.params["per_vertex"] = True
        p = {k: s.params[k] for k in ("order", "rank", "brdf", "roughness", "specular") if k in s.params}
        spec.stages = [v, StageSpec("tangents", "ldprt.tangents"),
                       StageSpec("shade", "rpo.shade", {**p, "visibility_space": "world"}, {"visibility": "vis.visibility"})]
    return spec


def _measure(name, spec, scene, truth, idx, frames, timing_frames):
    from warpshade.measure import error_metrics

    t0 = time.perf_counter()
    rt = spec.compile(scene, device="cpu", progress=False)
    setup_s = time.perf_counter() - t0
    rt.run(timing_frames, record=False)
    frame_ms = float(np.median(rt.frame_s) * 1e3)
    prof = rt.profile(timing_frames[:8])
    errs = {}
    for f in frames:
        est = rt.step(f).numpy()[idx]
        m = error_metrics(est, truth[f]["radiance"], truth[f]["stderr"])
        errs[str(f)] = {k: float(m[k]) for k in ("rel_rms", "rel_rms_debiased") if k in m}
    row = {"name": name, "frame_ms": round(frame_ms, 2), "hz": round(1e3 / frame_ms, 1),
           "stage_ms": {k: round(v * 1e3, 2) for k, v in prof.items()}, "setup_s": round(setup_s, 2),
           "error": errs, "rel_rms_mean": float(np.mean([e["rel_rms"] for e in errs.values()])),
           "params": {st.name: dict(st.params) for st in spec.stages},
           "diagnostics": {st.name: st.diagnostics() for st in rt.stages if hasattr(st, "diagnostics")}}
    print(f"  {name:<34s} {frame_ms:7.1f} ms/frame ({row['hz']:5.1f} Hz)  stages {row['stage_ms']}  "
          f"rel RMS {row['rel_rms_mean']:.4f}", flush=True)
    return row, rt


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=512, help="glossy reference samples per vertex")
    ap.add_argument("--vertices", type=int, default=4096, help="random vertices measured against the reference")
    ap.add_argument("--frames", type=int, default=24, help="frames timed (the clip from 0)")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    ap.add_argument("--quick", action="store_true",
                    help="smoke profile: 16 samples, 128 vertices, 2 frames, the default and generic graphs only, a small picture")
    ap.add_argument("--compare-with", default=None, metavar="TREE",
                    help="time this tree's default graph against another checkout's, interleaved (see above)")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds of --compare-with")
    ap.add_argument("--hz", action="store_true", help="only the absolute frame rate of the default graph (see above)")
    ap.add_argument("--passes", type=int, default=3, help="passes over the clip of --hz")
    ap.add_argument("--suffix", default="", help="--compare-with, --hz: appended to the output's name (what was measured)")
    args = ap.parse_args(argv)
    if args.hz:
        return hz(args.passes, Path(args.out or ROOT / "benchmarks" / "results"), args.suffix)
    if args.compare_with:
        if args.quick and args.out is None:
            ap.error("--quick writes only into --out DIR (never benchmarks/results)")
        rounds, frames = (1, 4) if args.quick else (args.rounds, args.frames)
        return compare(args.compare_with, rounds, frames, Path(args.out or ROOT / "benchmarks" / "results"), args.suffix)
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    args.out = args.out or str(ROOT / "benchmarks" / "results")
    if args.quick:
        args.spp, args.vertices, args.frames = 16, 128, 2

    import warpshade.methods.ldprt._stages  # noqa: F401  (ldprt.tangents)
    import warpshade.methods.heightfield  # noqa: F401  (the height-field stages)
    import warpshade.methods.rpo._stages  # noqa: F401  (rpo.shade)
    from warpshade.reference import shade_glossy
    from warpshade.render import render

    base = _graph()
    scene = base.load_scene()
    lighting = base.lighting_source(scene)
    shade_p = base.stages[1].params
    model = base.compile(scene, device="cpu", progress=False).output_stage().reference_model()
    brdf = model["brdf"]
    idx = np.sort(np.random.default_rng(0).choice(scene.vertex_count, args.vertices, replace=False))
    frames = [0.0, 24.0]
    timing_frames = [float(f) for f in range(args.frames)]
    print(f"ripples: {scene.vertex_count} vertices, {len(scene.frames)} frames; glossy reference {args.spp} spp on "
          f"{idx.size} vertices", flush=True)
    truth = {}
    t0 = time.perf_counter()
    for f in frames:
        res = shade_glossy(scene, f, brdf, eye=model["eye"], lighting=lighting.lights_at(f), samples=args.spp,
                           color=model["color"], device="cpu", vertices=idx)
        truth[f] = {"radiance": np.asarray(res.radiance), "stderr": np.asarray(res.stderr)}
    ref_s = time.perf_counter() - t0
    print(f"  reference: {ref_s:.1f} s", flush=True)

    configs = [("default (n=4, k=8, 128^2 vis)", {}, {}, False)]
    for n, ks in ((3, (4, 8, 9)), (4, (4, 16))):
        for k in ks:
            configs.append((f"n={n}, k={k}", {"order": n}, {"order": n, "rank": k}, False))
    configs += [
        ("n=4, exact BRDF table", {}, {"factors": "exact"}, False),
        ("n=3, exact BRDF table", {"order": 3}, {"order": 3, "factors": "exact"}, False),
        ("vis 64^2", {"resolution": 64}, {}, False),
        ("vis 256^2", {"resolution": 256}, {}, False),
        ("vis 512^2 (full)", {"resolution": 512}, {}, False),
        ("below = blocked", {"below": "blocked"}, {}, False),
        ("march q=2", {"samples_per_octave": 2}, {}, False),
        ("march q=1, footprint 0.25", {"footprint": 0.25}, {}, False),
        ("march conservative (footprint 1)", {"footprint": 1.0}, {}, False),
        ("azimuths 8", {"azimuths": 8}, {}, False),
        ("azimuths 32", {"azimuths": 32}, {}, False),
        ("generic: per-vertex vis + rpo.shade", {}, {}, True),
    ]
    if args.quick:
        configs = [configs[0], configs[-1]]
    rows = []
    keep_rt = None
    for name, vis, shade, generic in configs:
        row, rt = _measure(name, _graph(vis, shade, generic), scene, truth, idx, frames, timing_frames)
        rows.append(row)
        if keep_rt is None:
            keep_rt = rt
    os.makedirs(args.out, exist_ok=True)
    out = Path(args.out)
    stem = f"heightfield-{DATE}-cpu" + ("-quick" if args.quick else "")
    png = out / f"{stem}.png"
    radiance = keep_rt.step(24.0).numpy().copy()
    width, height, supersample = (160, 90, 1) if args.quick else (800, 450, 2)
    render(scene, frame=24.0, colors=radiance, width=width, height=height, environment=scene.lights[0], exposure=0.5,
           path=str(png), device="cpu", supersample=supersample)
    report = {
        "benchmark": "bench_heightfield", "date": DATE, "device": "cpu", "cpu_count": os.cpu_count(),
        "platform": platform.platform(), "processor": platform.processor(),
        "scene": {"file": "bundled:ripples", "vertices": scene.vertex_count, "triangles": scene.triangle_count,
                  "frames": len(scene.frames)},
        "reference": {"spp": args.spp, "vertices": int(idx.size), "frames": frames, "seconds": round(ref_s, 1),
                      "brdf": brdf.describe(), "method": "mis"},
        "timing_frames": len(timing_frames), "goal": "30 Hz at 128^2 visibility / 512^2 shading (paper: 32 Hz, 8800 GTX)",
        "rows": rows, "picture": png.name,
    }
    (out / f"{stem}.json").write_text(json.dumps(report, indent=1, default=str))
    print(f"wrote {out / f'{stem}.json'} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
