"""Per-frame tracing with few rays and a control variate (``hybrid.trace``) against per-frame
tracing with 1024 rays (``prt.trace``): error, time per frame, noise and lag, side by side.

For each scene and setting, in one run on one device:

* the clip is stepped once from its start (every frame, so that reuse over frames works as in
  use) up to its last measured frame; the error against ray-traced ground truth (relative RMS)
  on the 3 fastest-moving frames and 4 frames spread over the clip: ``error`` = their mean,
  ``lag`` = mean on the fast frames / ``error`` (:func:`warpshade.measure.lag`); the time per frame
  is the median of those steps after the first two (compilation, recording);
* ``noise``: per-vertex relative standard deviation over 8 seeds at frame index ``--noise-frame``,
  each seed's run stepped from the clip's start (:func:`warpshade.measure.noise`); a comma list
  of frame indices measures it at each (``noise_at``, ``noise_ratio_at``): the first frames of a
  clip show the history's warm-up, later ones the reuse while the scene moves;
* ratios against ``prt.trace`` at 1024 rays (same order) measured in the same run.

Settings: ``prt.trace`` n6 1024 rays; ``hybrid.trace`` n6 with K in {8, 16, 32, 64} and each
applicable control (none, previous, ldprt; datadriven on the figure, trained on figure_train with
``--training-frames`` and ``--training-samples``; visibility on the figure and the wanderer: the
data-driven visibility model as control (``stages_for("visibility", ...)``), trained on the scene's
clip, frames and rays of :data:`VISIBILITY_TRAINING` -- figure_train every third frame at 128 rays,
wanderer_train every eighth frame at 64 rays, the selections of the visibility graphs, so that the
traced training data is shared with them -- or on ``--visibility-training-frames`` and
``--visibility-training-samples`` when given).

Usage::

    python benchmarks/bench_hybrid.py [--scenes blockers,cloth,bend,figure] [--device cpu]
    python benchmarks/bench_hybrid.py --quick --out /tmp/hy
    python benchmarks/bench_hybrid.py --scenes cloth --samples 64 --controls previous \
        --variants 'old={"cycle": 1};new={}' --suffix cycle     # parameter sets side by side

``--variants`` runs each named set of ``hybrid.trace`` parameters for every ray count and
control (methods ``hybrid <control> <name>``); ``--no-baseline`` leaves out ``prt.trace`` (no
ratios; for settings compared with each other only). The machine's load average at the start
and the end is in ``meta``.

Writes ``benchmarks/results/hybrid-<date>-<device>.json`` and ``.png`` (error, time per frame and noise
against rays per vertex, per scene), the JSON rewritten after every setting.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

from warpshade._fileio import atomic_path, write_json_atomic  # noqa: E402
from warpshade._wp import cpu_workers  # noqa: E402
from warpshade.measure import ground_truth, lag, load_bench_scene, noise  # noqa: E402
from warpshade.methods.hybrid import stages_for  # noqa: E402
from warpshade.methods.hybrid._rows import VISIBILITY_TRAINING  # noqa: E402
from warpshade.tasks import progress_bar  # noqa: E402

SCENES = ("blockers", "cloth", "bend", "figure")
TRAINING = {"figure": "bundled:figure_train", "figure_walk": "bundled:figure_train"}
# Visibility control: per scene the training clip, frames and rays per vertex per training frame,
# warpshade.methods.hybrid._rows.VISIBILITY_TRAINING (as warpshade.methods.visibility._rows.TRAINING_CLIPS /
# TRAINING_RAYS and the scenes' stages/*_visibility*.toml: a traced wanderer frame costs ~4x a figure
# frame, hence every eighth of its 1000 frames at 64 rays).


def settings(scene_key, order, samples_list, controls, reference_rays, training_frames, training_samples,
             variants=None, baseline=True, visibility_training=(None, None)):
    """The rows of a scene: ``(method, rays, stages)``; ``variants`` ``{name: hybrid.trace parameters}``
    (None: the defaults, unnamed) are run for every ray count and control. ``visibility_training``
    ``(frames, samples)`` overrides the scene's :data:`VISIBILITY_TRAINING` where not None."""
    out = [("traced", reference_rays, (("shade", "prt.trace", {"order": order, "samples": reference_rays}, {}),))] if baseline else []
    for k in samples_list:
        for control in controls:
            for name, trace in (variants or {"": {}}).items():
                if control == "datadriven":
                    if scene_key not in TRAINING:
                        continue
                    st = stages_for(control, k, order, training=TRAINING[scene_key], frames=training_frames,
                                    training_samples=training_samples, trace=trace)
                elif control == "visibility":
                    if scene_key not in VISIBILITY_TRAINING:
                        continue
                    clip, tf, ts = visibility_settings(scene_key, *visibility_training)
                    st = stages_for(control, k, order, training=clip, frames=tf, training_samples=ts, trace=trace)
                else:
                    st = stages_for(control, k, order, trace=trace)
                out.append((f"hybrid {control}" + (f" {name}" if name else ""), k, st))
    return out


def visibility_settings(scene_key, frames=None, samples=None):
    """The visibility control's training ``(clip, frames, samples)`` of a scene: its
    :data:`VISIBILITY_TRAINING` entry, ``frames``/``samples`` replacing it where not None."""
    clip, tf, ts = VISIBILITY_TRAINING[scene_key]
    return clip, (tf if frames is None else frames), (ts if samples is None else samples)


def parse_variants(text):
    """``"old={...};new={...}"`` (JSON objects of hybrid.trace parameters) as ``{name: dict}``."""
    import json

    if not text:
        return None
    out = {}
    for part in text.split(";"):
        name, sep, body = part.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"--variants: {part!r} is not NAME=JSON")
        params = json.loads(body)
        if not isinstance(params, dict):
            raise ValueError(f"--variants: {name!r} must be a JSON object of hybrid.trace parameters")
        out[name.strip()] = params
    return out


#: Line styles of the named variants (in name order).
STYLES = ("s--", "^:", "v-.", "D-")
#: One colour per setting family in every panel.
COLORS = {"hybrid none": "C1", "hybrid previous": "C2", "hybrid ldprt": "C0", "hybrid datadriven": "C3",
          "hybrid visibility": "C4", "hybrid shexp": "C5"}


def chart(results, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = sorted({r["scene"] for r in results})
    variants = sorted({" ".join(r["method"].split()[2:]) for r in results} - {""})
    fig, axes = plt.subplots(3, len(scenes), figsize=(4.2 * len(scenes), 10), squeeze=False)
    for j, s in enumerate(scenes):
        rs = [r for r in results if r["scene"] == s]
        ref = next((r for r in rs if r["method"] == "traced"), None)
        for method in sorted({r["method"] for r in rs if r["method"] != "traced"}):
            m = sorted((r for r in rs if r["method"] == method), key=lambda r: r["rays"])
            family = " ".join(method.split()[:2])
            color = COLORS.get(family)
            variant = method[len(family):].strip()
            style = "o-" if not variant else STYLES[variants.index(variant) % len(STYLES)]
            axes[0, j].plot([r["rays"] for r in m], [r["error"] for r in m], style, color=color, label=method)
            axes[1, j].plot([r["rays"] for r in m], [r["frame_ms"] for r in m], style, color=color, label=method)
            axes[2, j].plot([r["rays"] for r in m], [r["noise"] for r in m], style, color=color, label=method)
        if ref is not None:
            axes[0, j].axhline(ref["error"], color="k", ls="--", label=f"prt.trace {ref['rays']} rays")
            axes[0, j].axhline(1.2 * ref["error"], color="k", ls=":", label="1.2x prt.trace")
            axes[1, j].axhline(ref["frame_ms"], color="k", ls="--", label=f"prt.trace {ref['rays']} rays")
            axes[1, j].axhline(ref["frame_ms"] / 8, color="k", ls=":", label="1/8 of prt.trace")
            axes[2, j].axhline(ref["noise"], color="k", ls="--", label=f"prt.trace {ref['rays']} rays")
        axes[0, j].set_title(s)
        axes[0, j].set_xscale("log", base=2)
        axes[1, j].set_xscale("log", base=2)
        axes[1, j].set_yscale("log")
        axes[2, j].set_xscale("log", base=2)
        axes[2, j].set_yscale("log")
        axes[2, j].set_xlabel("rays per vertex per frame")
        axes[2, j].set_ylabel("noise over seeds (relative, first --noise-frame)")
        axes[0, j].set_ylabel("relative RMS error (clip mean)")
        axes[1, j].set_ylabel("ms per frame")
    for ax in axes[0]:
        ax.legend(fontsize=6)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=90)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smoke profile: bend, K 8, control none, 64-ray baseline, order 3")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--samples", default="8,16,32,64", help="rays per vertex per frame of hybrid.trace")
    ap.add_argument("--controls", default="none,previous,ldprt,datadriven")
    ap.add_argument("--order", type=int, default=6)
    ap.add_argument("--reference-rays", type=int, default=1024, help="rays per vertex of the prt.trace baseline")
    ap.add_argument("--gt-samples", type=int, default=1024, help="ground-truth samples per vertex")
    ap.add_argument("--noise-frame", default="12", help="frame index of the noise metric; a comma list measures it at "
                    "each (the first is the row's 'noise'; all in 'noise_at')")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--training-frames", default="0:600:20", help="data-driven control: training frames")
    ap.add_argument("--training-samples", type=int, default=32, help="data-driven control: rays per training frame")
    ap.add_argument("--visibility-training-frames", default=None,
                    help="visibility control: training frames of every scene (default: the scene's VISIBILITY_TRAINING)")
    ap.add_argument("--visibility-training-samples", type=int, default=None,
                    help="visibility control: rays per training frame of every scene (default: the scene's VISIBILITY_TRAINING)")
    ap.add_argument("--variants", default=None, metavar="NAME=JSON;...",
                    help='hybrid.trace parameter sets run side by side, e.g. \'old={"threshold": 2};new={}\'')
    ap.add_argument("--suffix", default="", help="added to the results' file name (hybrid-<date>-<device>-SUFFIX)")
    ap.add_argument("--no-baseline", action="store_true", help="leave out the prt.trace row (no ratios)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--replot", default=None, metavar="JSON", help="redraw the chart of an earlier results JSON")
    args = ap.parse_args(argv)
    if args.replot:
        import json

        data = json.loads(Path(args.replot).read_text())
        chart([r for r in data["results"] if "failed" not in r], Path(args.replot).with_suffix(".png"))
        return 0
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    if args.quick:
        args.scenes, args.samples, args.controls, args.reference_rays = "bend", "8", "none", 64
        args.gt_samples, args.noise_frame, args.seeds, args.order = 32, "2", 2, 3
    out_dir = Path(args.out or ROOT / "benchmarks" / "results")
    out_dir.mkdir(parents=True, exist_ok=True)
    date = datetime.date.today().isoformat()
    tag = "cpu" if args.device == "cpu" else args.device.replace(":", "")
    stem = out_dir / (f"hybrid-{date}-{tag}" + ("-quick" if args.quick else "") + (f"-{args.suffix}" if args.suffix else ""))
    meta = {"date": date, "device": args.device, "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
            "threads": cpu_workers() if args.device == "cpu" else None, "order": args.order,
            "gt_samples": args.gt_samples, "noise_seeds": args.seeds, "noise_frame_index": args.noise_frame,
            "training_frames": args.training_frames, "training_samples": args.training_samples,
            "visibility_training": {s: visibility_settings(s, args.visibility_training_frames, args.visibility_training_samples)
                                    for s in args.scenes.split(",") if s in VISIBILITY_TRAINING} or None,
            "variants": parse_variants(args.variants), "load_average": os.getloadavg(),
            "command": " ".join(["python", "benchmarks/bench_hybrid.py", *(argv if argv is not None else sys.argv[1:])])}
    results = []
    t_all = time.perf_counter()
    samples = [int(x) for x in args.samples.split(",")]
    controls = args.controls.split(",")
    for key in args.scenes.split(","):
        scene, lighting = load_bench_scene(key)
        print(f"{key}: {scene.vertex_count:,} vertices, {len(scene.frames)} frames", flush=True)

        def truth_for(frames, scene=scene, lighting=lighting):
            return ground_truth(scene, lighting, frames, args.gt_samples, args.device, progress=True)

        noise_frames = [float(scene.frames[min(int(i), len(scene.frames) - 1)]) for i in str(args.noise_frame).split(",")]
        rows = settings(key, args.order, samples, controls, args.reference_rays, args.training_frames, args.training_samples,
                        parse_variants(args.variants), baseline=not args.no_baseline,
                        visibility_training=(args.visibility_training_frames, args.visibility_training_samples))
        for method, rays, stages in progress_bar(rows, desc=f"{key}: settings", unit="setting"):
            t0 = time.perf_counter()
            try:
                lg = lag(scene, lighting, stages, truth_for, device=args.device)
                nzs = {f: noise(scene, lighting, stages, frame=f, seeds=args.seeds, device=args.device) for f in noise_frames}
                nz = nzs[noise_frames[0]]
            except Exception as exc:  # reported, never dropped
                print(f"  {method} K{rays}: FAILED {exc!r}", flush=True)
                results.append({"scene": key, "method": method, "rays": rays, "failed": repr(exc)})
                continue
            r = {"scene": key, "method": method, "rays": rays, "error": lg["lag_mean_error"], "lag": lg["lag"],
                 "fast_error": lg["lag_fast_error"], "frame_ms": lg["frame_ms"], "noise": nz["noise_rel"],
                 "noise_p99": nz["noise_rel_p99"], "noise_at": {str(int(f)): x["noise_rel"] for f, x in nzs.items()},
                 "lag_frames": lg["lag_frames"], "lag_errors": lg["lag_errors"], "fast_frames": lg["lag_fast_frames"],
                 "diagnostics": lg.get("diagnostics"), "seconds": time.perf_counter() - t0,
                 "stages": [dict(name=n, type=t, **p) for (n, t, p, _) in stages]}
            results.append(r)
            print(f"  {method:28s} K{rays:<5d} error {r['error']:.4f}  lag {r['lag']:.3f}  noise {r['noise']:.4f}  "
                  f"{r['frame_ms']:9.2f} ms/frame", flush=True)
            ref = next((x for x in results if x["scene"] == key and x["method"] == "traced" and "failed" not in x), None)
            for x in results:
                if ref is not None and x["scene"] == key and "failed" not in x:
                    x["error_ratio"] = x["error"] / ref["error"]
                    x["speedup"] = ref["frame_ms"] / x["frame_ms"]
                    x["noise_ratio"] = x["noise"] / ref["noise"] if ref["noise"] > 0 else None
                    x["noise_ratio_at"] = {f: (x["noise_at"][f] / ref["noise_at"][f] if ref["noise_at"].get(f) else None)
                                           for f in x["noise_at"]}
            meta["seconds"] = time.perf_counter() - t_all
            write_json_atomic(Path(f"{stem}.json"), {"meta": meta, "results": results}, indent=1)
    ok = [r for r in results if "failed" not in r]
    if ok:
        chart(ok, Path(f"{stem}.png"))
    meta["load_average_end"] = os.getloadavg()
    write_json_atomic(Path(f"{stem}.json"), {"meta": meta, "results": results}, indent=1)
    print(f"wrote {stem}.json/.png in {time.perf_counter() - t_all:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
