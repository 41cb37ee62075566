"""Speed-vs-accuracy harness: every method x setting on every bundled scene, in one run.

For each scene and device it measures, side by side:

* time per frame (median over the timed frames, after a warm-up frame), host-side time too;
* precompute time (each artifact computed once per harness run in a private cache and charged at
  its real cost to every row that uses it) and model memory;
* error against ray-traced ground truth on sampled frames: relative RMS over vertices, the
  99th percentile, and the ground truth's own Monte Carlo noise (differences below it are not
  resolved; ``rel_rms_debiased`` removes the ground truth's variance from the squared error).

Writes ``benchmarks/results/<date>-<device>.json``, a Pareto chart ``...-pareto.png`` (time per
frame vs error, log axes, one marker per method/setting, one panel per scene) and a Markdown
table, and refreshes ``benchmarks/results/latest-<device>.{json,png,md}``.

Usage::

    python benchmarks/run.py [--quick] [--scenes bunny,blockers] [--methods prt,shexp] [--device cpu]
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: Smoke profile (tests/test_benchmarks.py): slow, kept out of the default suite (``-m "not slow"``):
#: 41 s: one row of every method, SG's environment included.
PROFILE = {"slow": True}

ROOT = Path(__file__).resolve().parent.parent

from warpshade._fileio import atomic_path, write_json_atomic, write_text_atomic  # noqa: E402
from warpshade._wp import cpu_workers, wp  # noqa: E402
from warpshade.graph import ArtifactCache
from warpshade.measure import (  # noqa: E402
    BENCH_SCENES,
    ground_truth,
    lag,
    load_bench_scene,
    noise,
    pick_frames,
    reference_model,
    run_setting,
    scene_kinds,
    setting_error,
)
from warpshade.measure._scenes import ROTATE_DEGREES_PER_FRAME  # noqa: E402
from warpshade.methods._rows import all_rows  # noqa: E402

from _checkout import checkout_commit  # noqa: E402  (a sibling module: benchmarks/_checkout.py)

RESULTS = ROOT / "benchmarks" / "results"
SCENES = BENCH_SCENES
#: The ``--quick`` smoke profile: its default scene, and caps on the rows' stage parameters
#: (rays per vertex, SSDF resolution, blocker-sphere budget, lobe counts, BRDF ranks).
QUICK_SCENES = "bend"
QUICK_CAPS = {"samples": 16, "resolution": 8, "budget": 2, "lobes": 1, "rank": 2}


def coarse_lighting(scene):
    """``(scene, lighting)`` with the scene's environments box-filtered down to about 32 texel rows
    (``--quick``: SG's prefiltered table of a full-size sky takes tens of seconds to build)."""
    from warpshade.scene import Environment, LightingSource

    def coarse(env, rows=32):
        img = np.asarray(env.image, np.float32)
        f = max(1, img.shape[0] // rows)
        h, w = img.shape[0] // f * f, img.shape[1] // f * f
        return dataclasses.replace(env, image=img[:h, :w].reshape(h // f, f, w // f, f, 3).mean(axis=(1, 3)))

    scene.lights = [coarse(light) if isinstance(light, Environment) else light for light in scene.lights]
    return scene, LightingSource(scene.lights, scene.up_axis, ROTATE_DEGREES_PER_FRAME, float(scene.frames[0]))


def smoke_rows(rows) -> list:
    """The first row of each method, its stage parameters capped by :data:`QUICK_CAPS` (``--quick``)."""
    out, seen = [], set()
    for row in rows:
        if row.method in seen:
            continue
        seen.add(row.method)
        stages = tuple((n, t, {k: min(v, QUICK_CAPS[k]) if k in QUICK_CAPS else v for k, v in p.items()}, i)
                       for (n, t, p, i) in row.stages)
        out.append(dataclasses.replace(row, stages=stages))
    return out


def run_row(row, scene, lighting, device, timing_frames, gt_frames, truth_for, precompute_cache, progress=False):
    """Run one row; ``truth_for(model)`` gives the (cached) ground truth the row's output is
    measured against; ``precompute_cache`` = (ArtifactCache private to this harness run, dict of
    artifact key -> seconds it took when it was computed), so rows sharing a precompute (the
    same sphere set, the same transfer) compute it once and all report its real cost."""
    cache, seconds_by_key = precompute_cache
    res = run_setting(scene, lighting, row.stages, gt_frames, output=row.output, timing_frames=timing_frames, device=device,
                      cache_dir=cache.root, name=f"{row.method}-{row.setting}".replace(" ", "-"), progress=progress)
    rt = res["runtime"]
    precompute_s = 0.0
    for name, timing in rt.timings.items():
        key = rt.artifact_keys.get(name)
        if key is None:
            continue
        if timing.cache == "miss":
            seconds_by_key[key] = timing.precompute_s
        precompute_s += seconds_by_key.get(key, timing.precompute_s)
    model = reference_model(rt)
    reference = "diffuse" if model is None else f"glossy {model['brdf'].name}"  # e.g. glossy LDPRT
    err = setting_error(res["radiance"], truth_for(model))
    per_frame = err.pop("per_frame")
    return {
        "method": row.method,
        "setting": row.setting,
        "params": [dict(name=n, type=t, **p) for (n, t, p, _) in row.stages],
        "notes": row.notes,
        "median_frame_ms": res["frame_ms"],
        "median_host_ms": res["host_ms"],
        "stage_ms": res["stage_ms"],
        "uncaptured": res["uncaptured"],
        "precompute_s": precompute_s,
        "compile_and_setup_s": res["compile_s"],
        "model_bytes": res["model_bytes"],
        "frames_timed": res["frames_timed"],
        "error": err,
        "error_per_frame": per_frame,
        "reference": reference,
    }


def temporal_metrics(row, scene, lighting, device, gt_samples, cache_root, reference: str) -> dict:
    """``--temporal``: noise over 8 seeds at a held frame and lag on the fastest-moving frames of
    the clip (:func:`warpshade.measure.noise`, :func:`warpshade.measure.lag`); lag is measured
    against the diffuse reference only (None for rows measured against a glossy one)."""
    out = {"noise": noise(scene, lighting, row.stages, output=row.output, device=device, cache_dir=cache_root)}
    if reference == "diffuse":
        lg = lag(scene, lighting, row.stages, lambda frames: ground_truth(scene, lighting, frames, gt_samples, device),
                 output=row.output, device=device, cache_dir=cache_root)
        lg.pop("diagnostics", None)
        out["lag"] = lg
    else:
        out["lag"] = {"lag": None, "lag_note": f"measured against the diffuse reference only, the row's is {reference}"}
    return out


def _vs_diffuse(r) -> bool:
    """Whether a result row was measured against the diffuse reference (rows before the field: yes)."""
    return r.get("reference", "diffuse") == "diffuse"


def _front(points):
    """The lower-left envelope (Pareto front) of ``(time, error)`` points, fastest first."""
    front, best = [], np.inf
    for x, y in sorted(points):
        if y < best:
            front.append((x, y))
            best = y
    return front


def _labelled(sub) -> list:
    """The rows of one scene's panel that get a text label: the Pareto front (among rows measured
    against the diffuse reference), each method's most accurate row and the per-frame ray tracer's
    rows, skipping any whose label would land on one already placed (the table names every row)."""
    front = set(_front([(r["median_frame_ms"], r["error"]["rel_rms"]) for r in sub if _vs_diffuse(r)]))
    best = {}
    for r in sub:
        if r["method"] not in best or r["error"]["rel_rms"] < best[r["method"]]["error"]["rel_rms"]:
            best[r["method"]] = r
    wanted = [r for r in sub if (r["median_frame_ms"], r["error"]["rel_rms"]) in front or best[r["method"]] is r
              or r["method"] == "traced"]  # the per-frame ray tracer: the baseline to beat
    placed, out = [], []
    for r in sorted(wanted, key=lambda r: r["error"]["rel_rms"]):
        lx, ly = np.log10(r["median_frame_ms"]), np.log10(max(r["error"]["rel_rms"], 1e-4))
        if all(abs(lx - px) > 0.35 or abs(ly - py) > 0.06 for px, py in placed):
            placed.append((lx, ly))
            out.append(r)
    return out


def pareto_chart(results, path, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = sorted({r["scene"] for r in results})
    methods = sorted({r["method"] for r in results})
    cmap = plt.get_cmap("tab20" if len(methods) > 10 else "tab10")
    colors = {m: cmap(i % cmap.N) for i, m in enumerate(methods)}
    cols = min(3, len(scenes))
    rows = (len(scenes) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(5.6 * cols, 4.4 * rows), squeeze=False)
    for ax, sc in zip(axes.flat, scenes):
        sub = [r for r in results if r["scene"] == sc]
        for r in sub:
            x, y = r["median_frame_ms"], max(r["error"]["rel_rms"], 1e-4)
            other = not _vs_diffuse(r)  # measured against another reference
            ax.scatter(x, y, s=28, zorder=3, marker="D" if other else "o",
                       facecolors="none" if other else colors[r["method"]], edgecolors=colors[r["method"]])
        for r in _labelled(sub):
            ax.annotate(f"{r['method']} {r['setting']}", (r["median_frame_ms"], max(r["error"]["rel_rms"], 1e-4)),
                        fontsize=6.5, xytext=(4, 3), textcoords="offset points", color="0.15")
        # Pareto front per scene (lower-left envelope) over the rows that share the diffuse reference
        front = _front([(r["median_frame_ms"], r["error"]["rel_rms"]) for r in sub if _vs_diffuse(r)])
        if len(front) > 1:
            ax.plot(*zip(*front), color="0.6", lw=1, ls="--", zorder=1)
        noise = np.mean([r["error"].get("noise_rel_rms", np.nan) for r in sub if _vs_diffuse(r)])
        if np.isfinite(noise):
            ax.axhline(noise, color="0.3", lw=0.8, ls=":", label="ground-truth noise")
        vc = sub[0]["vertex_count"]
        ax.set_title(f"{sc} ({vc:,} vertices, {len(sub)} rows)", fontsize=10)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("time per frame (ms)")
        ax.set_ylabel("relative RMS error vs ray traced")
        ax.grid(True, which="both", alpha=0.25)
    for ax in list(axes.flat)[len(scenes):]:
        ax.axis("off")
    glossy = {r["method"] for r in results if not _vs_diffuse(r)}
    handles = [plt.Line2D([], [], marker="D" if m in glossy else "o", ls="", color=colors[m],
                          markerfacecolor="none" if m in glossy else colors[m],
                          label=f"{m} (vs glossy reference)" if m in glossy else m) for m in methods]
    handles.append(plt.Line2D([], [], ls=":", color="0.3", label="ground-truth noise"))
    fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 7), fontsize=9, frameon=False)
    fig.suptitle(title + " -- labels: the Pareto front, each method's most accurate row, the ray tracer; "
                 "the table lists all",
                 fontsize=11)
    legend_rows = (len(handles) + 6) // 7
    fig.tight_layout(rect=(0, 0.025 + 0.03 * legend_rows / rows, 1, 0.96))
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def markdown_table(results, meta) -> str:
    lines = [f"# Speed vs accuracy ({meta['date']}, {meta['device']})", "",
             f"{meta['machine']}; Warp {meta['warp']}; ground truth {meta['gt_samples']} spp on frames per scene; "
             f"timed frames per row: {meta['timing_frames']}. Reproduce: `{meta['command']}`. Error is "
             "against the diffuse ray-traced reference unless the method cell names another (e.g. the glossy one: "
             "same BRDF, towards the scene camera).", ""]
    for sc in sorted({r["scene"] for r in results}):
        sub = [r for r in results if r["scene"] == sc]
        lines += [f"## {sc} ({sub[0]['vertex_count']:,} vertices, ground-truth noise "
                  f"{np.mean([r['error'].get('noise_rel_rms', np.nan) for r in sub if _vs_diffuse(r)]):.4f})", "",
                  "| method | setting | ms/frame | precompute s | model MB | rel RMS | rel RMS (debiased) | p99 |",
                  "|---|---|---:|---:|---:|---:|---:|---:|"]
        for r in sorted(sub, key=lambda r: (r["method"], r["median_frame_ms"])):
            e = r["error"]
            lines.append(
                f"| {r['method'] if _vs_diffuse(r) else r['method'] + ' (vs ' + r['reference'] + ')'} | {r['setting']} | {r['median_frame_ms']:.2f} | {r['precompute_s']:.2f} | "
                f"{r['model_bytes'] / 2**20:.2f} | {e['rel_rms']:.4f} | {e.get('rel_rms_debiased', float('nan')):.4f} | "
                f"{e['rel_p99']:.4f} |"
            )
        lines.append("")
    return "\n".join(lines)


def replot(path: Path) -> int:
    """Chart and Markdown table again from a results JSON (e.g. after a change to the chart)."""
    import json

    try:
        data = json.loads(path.read_text())
        meta, results = data["meta"], data["results"]
    except (OSError, ValueError, KeyError) as exc:
        raise SystemExit(f"--replot {path}: not a harness results file ({exc})")
    ok = [r for r in results if "failed" not in r]
    stem = path.name[: -len(".json")]
    pareto_chart(ok, path.parent / f"{stem}-pareto.png",
                 f"warpshade: time per frame vs error ({meta['device']}, {meta['date']})")
    write_text_atomic(path.parent / f"{stem}.md", markdown_table(ok, meta))
    print(f"redrew {path.parent / stem}-pareto.png and .md")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="smoke profile: the bend, one row per method with few rays, 2 timed frames, 32-ray truth")
    ap.add_argument("--scenes", default=None, help="comma-separated scene keys (default: all; quick: bend)")
    ap.add_argument("--methods", default=None, help="comma-separated method names (default: all)")
    ap.add_argument("--device", action="append", default=None, help="device(s); default: cpu and cuda:0 if present")
    ap.add_argument("--exclude", default=None,
                    help="comma-separated row labels to leave out (e.g. \"ldprt-glossy n6 b12 N4\")")
    ap.add_argument("--gt-samples", type=int, default=None, help="ground-truth samples per vertex")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results; required with --quick)")
    ap.add_argument("--temporal", action="store_true",
                    help="also measure noise (8 seeds at a held frame) and lag (error on the fastest-moving frames "
                         "relative to the clip's mean) for every row")
    ap.add_argument("--resume", default=None, metavar="JSON",
                    help="go on with an interrupted run: the scenes already in JSON (written after each scene) are "
                         "kept and skipped, the rest measured and added to the same file")
    ap.add_argument("--replot", default=None, metavar="JSON",
                    help="redraw the chart and table of an earlier results JSON (next to it) without measuring")
    args = ap.parse_args(argv)
    if args.replot:
        return replot(Path(args.replot))
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    if args.quick and args.scenes is None:
        args.scenes = QUICK_SCENES

    devices = args.device or (["cpu"] + (["cuda:0"] if wp.is_cuda_available() else []))
    scene_keys = args.scenes.split(",") if args.scenes else list(SCENES)
    for k in scene_keys:
        if k not in SCENES:
            ap.error(f"unknown scene {k!r}; known: {sorted(SCENES)}")
    rows = all_rows(quick=args.quick)
    if args.quick:
        rows = smoke_rows(rows)
    if args.methods:
        wanted = set(args.methods.split(","))
        rows = [r for r in rows if r.method in wanted]
    if args.exclude:
        drop = {x.strip() for x in args.exclude.split(",")}
        rows = [r for r in rows if r.label not in drop]
    gt_samples = args.gt_samples or (32 if args.quick else 2048)
    timing_frames = 2 if args.quick else 12
    gt_count = 1 if args.quick else 2
    out_dir = Path(args.out or RESULTS)
    out_dir.mkdir(parents=True, exist_ok=True)
    date = datetime.date.today().isoformat()

    earlier = None
    if args.resume:
        try:
            earlier = json.loads(Path(args.resume).read_text())
            earlier["meta"], earlier["results"]  # noqa: B018 -- both keys must be there
        except (OSError, ValueError, KeyError) as exc:
            ap.error(f"--resume {args.resume}: not a harness results file ({exc})")
        if len(devices) != 1 or earlier["meta"]["device"] != devices[0]:
            ap.error(f"--resume {args.resume}: it holds device {earlier['meta']['device']!r}; pass --device "
                     f"{earlier['meta']['device']}")
        out_dir = Path(args.resume).parent

    for device in devices:
        tag = "cpu" if device == "cpu" else device.replace(":", "")
        results = list(earlier["results"]) if earlier else []
        done = {r["scene"] for r in results}
        stem = Path(args.resume).name[: -len(".json")] if earlier else f"{date}-{tag}" + ("-quick" if args.quick else "")
        seconds_before = earlier["meta"].get("seconds", 0.0) if earlier else 0.0
        command = " ".join(["python", "benchmarks/run.py", *(argv if argv is not None else sys.argv[1:])])
        meta = {
            "date": earlier["meta"]["date"] if earlier else date, "device": device,
            "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
            "warp": wp.config.version, "gt_samples": gt_samples, "timing_frames": timing_frames, "quick": args.quick,
            "rotate_degrees_per_frame": ROTATE_DEGREES_PER_FRAME,
            "threads": cpu_workers() if device == "cpu" else None,
            "command": earlier["meta"]["command"] if earlier else command,
            "commit": earlier["meta"].get("commit") if earlier else checkout_commit(ROOT),
            "resumed_by": (earlier["meta"].get("resumed_by", []) + [f"{command} (at {checkout_commit(ROOT)})"]) if earlier else [],
            "seconds": seconds_before,
            "temporal": args.temporal,
            "scenes_done": sorted(done),
        }
        scratch = tempfile.TemporaryDirectory(prefix="warpshade-harness-")
        precompute_cache = (ArtifactCache(scratch.name), {})  # ground truth stays in the shared truth cache
        t_all = time.perf_counter()
        for key in scene_keys:
            if key in done:
                print(f"[{device}] {key}: kept from {args.resume}", flush=True)
                continue
            scene, lighting = load_bench_scene(key)
            if args.quick:
                scene, lighting = coarse_lighting(scene)
            kinds = scene_kinds(scene) | {key}
            applicable = [r for r in rows if kinds & set(r.scenes)]
            if not applicable:
                continue
            print(f"[{device}] {key}: {scene.vertex_count:,} vertices, {len(scene.frames)} frames, {len(applicable)} rows", flush=True)
            gt_frames = pick_frames(scene, gt_count + 2)[1:-1] if gt_count < len(scene.frames) else scene.frames
            ground_truth(scene, lighting, gt_frames, gt_samples, device, progress=True)  # diffuse, computed up front
            t_frames = pick_frames(scene, timing_frames)
            for row in applicable:
                try:
                    r = run_row(row, scene, lighting, device, t_frames, gt_frames,
                                lambda model: ground_truth(scene, lighting, gt_frames, gt_samples, device, model=model,
                                                           progress=True), precompute_cache)
                except Exception as exc:  # a failing row is reported, never silently dropped
                    print(f"    {row.label:28s} FAILED: {exc}", flush=True)
                    results.append({"scene": key, "device": device, "method": row.method, "setting": row.setting,
                                    "failed": repr(exc)})
                    continue
                r.update(scene=key, device=device, vertex_count=scene.vertex_count)
                results.append(r)
                e = r["error"]
                print(f"    {row.label:28s} {r['median_frame_ms']:9.2f} ms/frame  precompute {r['precompute_s']:7.2f} s  "
                      f"rel RMS {e['rel_rms']:.4f} (noise {e.get('noise_rel_rms', float('nan')):.4f})  p99 {e['rel_p99']:.4f}",
                      flush=True)
                if args.temporal:
                    try:
                        r["temporal"] = temporal_metrics(row, scene, lighting, device, gt_samples, precompute_cache[0].root,
                                                         r["reference"])
                        print(f"    {'':28s} noise {r['temporal']['noise']['noise_rel']:.4f}  lag {r['temporal']['lag']['lag']}",
                              flush=True)
                    except Exception as exc:  # reported with the row, the row's other numbers kept
                        r["temporal"] = {"failed": repr(exc)}
            # each finished scene is on disk: an interrupted run goes on with --resume and loses only its current scene
            meta.update(seconds=seconds_before + time.perf_counter() - t_all, scenes_done=sorted(done | {key}))
            done.add(key)
            write_json_atomic(out_dir / f"{stem}.json", {"meta": meta, "results": results}, indent=1)
        ok = [r for r in results if "failed" not in r]
        meta["seconds"] = seconds_before + time.perf_counter() - t_all
        write_json_atomic(out_dir / f"{stem}.json", {"meta": meta, "results": results}, indent=1)
        if ok:
            pareto_chart(ok, out_dir / f"{stem}-pareto.png", f"warpshade: time per frame vs error ({device}, {meta['date']})")
            write_text_atomic(out_dir / f"{stem}.md", markdown_table(ok, meta))
            # benchmarks/results/latest-* is a run over every scene; another --out directory keeps its own latest-*
            if out_dir.resolve() != RESULTS.resolve() or done >= set(SCENES):
                for ext, src in (("json", f"{stem}.json"), ("png", f"{stem}-pareto.png"), ("md", f"{stem}.md")):
                    shutil.copyfile(out_dir / src, out_dir / f"latest-{tag}.{ext}")
        scratch.cleanup()
        print(f"[{device}] wrote {out_dir / stem}.json/.md and -pareto.png in {meta['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
