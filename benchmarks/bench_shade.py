"""``warpshade shade``'s automatic choice against the hand-made graphs of the bundled animated scenes.

For each scene, in one run on one device, on the same held-out frames (those ``warpshade shade``
holds out: :func:`warpshade.measure._auto.split_frames`) against the same ray-traced ground truth:

1. every hand-made diffuse graph of the scene (``stages/*.toml`` whose ``scene`` is it; glossy
   graphs, which shade another quantity, are left out) measured as ``warpshade shade`` measures a
   candidate (:func:`warpshade.measure._auto.measure`: stepped through the frames before each
   held-out frame; error with the reference's noise removed; median time per frame);
2. ``warpshade shade`` with ``--budget-ms`` the time per frame of the most accurate hand-made graph
   times ``--slack`` (default :data:`SLACK`: repeated timings of one graph on this shared machine
   spread by that much, so "the same time" is that close), its choice made on the training frames
   only (reuse settings tuned there), and its held-out error; ``ratio`` = that error over the best
   hand-made graph's.

The scenes with a character take the training clip their hand-made data-driven graphs train on
(``--training`` of ``warpshade shade``). Times come from one shared machine: the budget is the
hand-made graph's time measured in the same run.

With ``--assets``, the breadth check instead: ``warpshade shade --quick`` (one size per method, few
ground-truth rays: :data:`ASSET_CHOICE_SAMPLES`, :data:`ASSET_VALIDATE_SAMPLES`) on every bundled
scene and every USD asset shipped in the installed warp-lang and newton wheels (loaded from the
packages, never copied), each reported with its choice, held-out error and time per frame, or why it
could not run (``shade-assets-<date>-<device>.json``).

Usage::

    python benchmarks/bench_shade.py [--scenes blockers,cloth,bend,figure,figure_walk,wanderer_test]
    python benchmarks/bench_shade.py --assets
    python benchmarks/bench_shade.py --quick --out /tmp/shade

Writes ``benchmarks/results/shade-<date>-<device>.json`` and ``.png`` (held-out error against time
per frame: the hand-made graphs and the automatic choice, per scene), the JSON rewritten after
every scene.
"""

from __future__ import annotations

import argparse
import copy
import datetime
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from warpshade._fileio import atomic_path, write_json_atomic
from warpshade.graph import load
from warpshade.io import load_scene
from warpshade.measure import ground_truth
from warpshade.measure._auto import VALIDATE_SAMPLES, choose, default_lighting, measure, shade_scene, split_frames

ROOT = Path(__file__).resolve().parents[1]
#: The bundled animated scenes and the training clip of their character (None: no character).
SCENES = {"blockers": None, "cloth": None, "bend": None, "figure": "bundled:figure_train",
          "figure_walk": "bundled:figure_train", "wanderer_test": "bundled:wanderer_train"}
#: The budget given to ``warpshade shade``: the best hand-made graph's time per frame times this.
SLACK = 1.1
#: Stage types of graphs that shade glossy (another quantity than the diffuse choice).
GLOSSY_TYPES = ("rpo.shade", "sg.shade", "ldprt.shade_glossy", "visibility.shade_glossy")


#: Ground-truth rays of the breadth check (the choice; the held-out validation).
ASSET_CHOICE_SAMPLES = 64
ASSET_VALIDATE_SAMPLES = 128


def shipped_assets() -> list[str]:
    """Scene specs of every bundled scene and every USD file in the installed warp-lang and newton
    wheels' example assets."""
    import importlib.util

    from warpshade.io import bundled_asset_directory

    out = sorted({f"bundled:{p.stem}" for p in Path(bundled_asset_directory()).glob("*.usd*")})
    import warp.examples

    d = Path(warp.examples.get_asset_directory())
    out += [str(p) for p in sorted(d.glob("*.usd*"))]
    if importlib.util.find_spec("newton") is not None:
        import newton

        out += [str(p) for p in sorted((Path(newton.__file__).parent / "examples" / "assets").glob("*.usd*"))]
    return out


def run_assets(specs, out: Path, device: str, cache_dir) -> list[dict]:
    rows = []
    for spec in specs:
        name = Path(spec.split(":", 1)[-1]).stem
        t0 = time.perf_counter()
        row = {"scene": spec}
        try:
            rep = shade_scene(spec, out / "assets" / name, device=device, cache_dir=cache_dir, quick=True,
                              choice_samples=ASSET_CHOICE_SAMPLES, validate_samples=ASSET_VALIDATE_SAMPLES,
                              log=lambda s: None)
            row.update(kind=rep["scene"]["kind"], vertices=rep["scene"]["vertices"], frames=rep["scene"]["frames"],
                       skipped=len(rep["scene"]["skipped"]), met=rep["met"])
            if rep["chosen"] is not None:
                row.update(status="ok", chosen=rep["chosen"]["label"], held_out=rep["held_out"]["rel_rms_debiased"],
                           frame_ms=rep["held_out"]["frame_ms"])
            else:
                row.update(status="no method", reason=rep["why"])
        except Exception as exc:  # reported per asset: the breadth check goes on
            row.update(status="refused", reason=f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
        row["seconds"] = time.perf_counter() - t0
        rows.append(row)
        state = (f"{row['chosen']:28s} held-out {row['held_out']:.4f} {row['frame_ms']:8.2f} ms/frame"
                 if row["status"] == "ok" else f"{row['status']}: {row.get('reason', '')[:100]}")
        print(f"  {spec.split('/')[-1]:32s} {state}  ({row['seconds']:.0f} s)", flush=True)
    return rows


def hand_made(scene_key: str) -> list[Path]:
    """The diffuse graphs in ``stages/`` over ``bundled:<scene_key>``."""
    out = []
    for path in sorted((ROOT / "stages").glob("*.toml")):
        spec = load(path)
        if spec.scene != f"bundled:{scene_key}":
            continue
        if any(st.type in GLOSSY_TYPES or "glossy" in st.type for st in spec.stages):
            continue
        out.append(path)
    return out


def measure_graph(path: Path, scene, lighting, held, truth, device, cache_dir) -> dict:
    spec = load(path)
    cand = {"method": "graph", "label": f"graph {spec.name}", "baseline": False, "facts": {"graph": spec.name},
            "stages": tuple((st.name, st.type, dict(st.params), dict(st.inputs)) for st in spec.stages)}
    row = measure(scene, lighting, cand, held, truth, device=device, cache_dir=cache_dir)
    row["graph"] = spec.name
    return row


def run_scene(key: str, training, out: Path, device: str, cache_dir, samples: int, choice_samples: int,
              quick: bool, slack: float = SLACK, reuse: bool = False) -> dict:
    scene = load_scene(f"bundled:{key}")
    lighting = default_lighting(scene)
    train, held, _ = split_frames(scene, quick=quick)
    truth = ground_truth(scene, lighting, held, samples, device, cache_dir)
    graphs = hand_made(key)
    if quick:
        graphs = [g for g in graphs if "unshadowed" in g.stem][:1] or graphs[:1]
    rows = []
    for g in graphs:
        t0 = time.perf_counter()
        row = measure_graph(g, scene, lighting, held, truth, device, cache_dir)
        rows.append(row)
        state = (f"error {row['rel_rms_debiased']:.4f} {row['frame_ms']:8.2f} ms/frame" if row["status"] == "ok"
                 else f"failed: {row['reason'][:80]}")
        print(f"  {key}: {row['graph']:28s} {state}  ({time.perf_counter() - t0:.0f} s)", flush=True)
    ok = [r for r in rows if r["status"] == "ok"]
    best = min(ok, key=lambda r: r["rel_rms_debiased"]) if ok else None
    budget = slack * best["frame_ms"] if best is not None else None
    choice_file = out / f"{key}_auto" / f"{key}_auto_choice.json"
    if reuse and choice_file.exists():  # the choice of an earlier run (its candidates' training rows)
        report = json.loads(choice_file.read_text())
        print(f"  {key}: the choice of {choice_file} (--reuse)", flush=True)
    else:
        report = shade_scene(f"bundled:{key}", out / f"{key}_auto", budget_ms=budget, device=device, cache_dir=cache_dir,
                             choice_samples=choice_samples, validate_samples=samples, quick=quick,
                             training=None if quick else training, log=lambda s: print(f"  {key}: {s}", flush=True))
    auto = None
    if report["chosen"] is not None:
        h = report["held_out"]
        auto = {"label": report["chosen"]["label"], "facts": report["chosen"]["facts"],
                "rel_rms_debiased": h["rel_rms_debiased"], "rel_rms": h["rel_rms"], "frame_ms": h["frame_ms"],
                "met": report["met"], "why": report["why"]}
    ratio = (auto["rel_rms_debiased"] / best["rel_rms_debiased"]) if auto and best else None
    at_each = pareto_choices(report["candidates"], ok, slack, scene, lighting, held, truth, device, cache_dir, key)
    return {"scene": key, "training": training, "slack": slack, "training_frames": [float(f) for f in train],
            "held_out_frames": [float(f) for f in held], "hand_made": rows,
            "best_hand_made": best["graph"] if best else None, "budget_ms": budget, "auto": auto, "ratio": ratio,
            "at_each_pareto_graph": at_each, "shade_report": str(choice_file)}


def pareto(rows: list[dict]) -> list[dict]:
    """The hand-made graphs no other is both faster and more accurate than."""
    return [r for r in rows if not any(o is not r and o["frame_ms"] <= r["frame_ms"] and
                                       o["rel_rms_debiased"] < r["rel_rms_debiased"] for o in rows)]


def pareto_choices(candidates, hand_rows, slack, scene, lighting, held, truth, device, cache_dir, key) -> list[dict]:
    """At each Pareto hand-made graph's time (times ``slack``): what ``warpshade shade``'s rule picks
    from its measured candidates (:func:`warpshade.measure._auto.choose` on the training rows), that
    choice measured on the held-out frames, and the ratio of errors."""
    out, measured = [], {}
    for g in sorted(pareto(hand_rows), key=lambda r: r["frame_ms"]):
        chosen, _, why = choose(copy.deepcopy(candidates), budget_ms=slack * g["frame_ms"])
        if chosen is None:
            continue
        if chosen["label"] not in measured:
            cand = {k: chosen[k] for k in ("method", "label", "facts", "baseline")}
            cand["stages"] = tuple(tuple(st) for st in chosen["stages"])
            measured[chosen["label"]] = measure(scene, lighting, cand, held, truth, device=device, cache_dir=cache_dir)
        m = measured[chosen["label"]]
        out.append({"graph": g["graph"], "graph_error": g["rel_rms_debiased"], "graph_ms": g["frame_ms"],
                    "budget_ms": slack * g["frame_ms"], "chosen": chosen["label"], "why": why,
                    "error": m["rel_rms_debiased"], "frame_ms": m["frame_ms"],
                    "ratio": m["rel_rms_debiased"] / g["rel_rms_debiased"]})
        print(f"  {key}: at {g['graph']} ({g['frame_ms']:.2f} ms, error {g['rel_rms_debiased']:.4f}): {chosen['label']} "
              f"error {m['rel_rms_debiased']:.4f} {m['frame_ms']:.2f} ms, ratio {out[-1]['ratio']:.2f}", flush=True)
    return out


def plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(results)
    cols = min(3, n)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(5.0 * cols, 4.0 * rows), dpi=100, squeeze=False)
    for ax, res in zip(axes.ravel(), results):
        ok = [r for r in res["hand_made"] if r["status"] == "ok"]
        ax.scatter([r["frame_ms"] for r in ok], [r["rel_rms_debiased"] for r in ok], color="tab:blue", s=30,
                   label="hand-made graphs")
        for r in ok:
            ax.annotate(r["graph"].replace(res["scene"] + "_", ""), (r["frame_ms"], r["rel_rms_debiased"]), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
        if res["auto"] is not None:
            a = res["auto"]
            ax.scatter([a["frame_ms"]], [a["rel_rms_debiased"]], color="tab:red", marker="*", s=140,
                       label=f"shade: {a['label']}")
        if res["budget_ms"] is not None:
            ax.axvline(res["budget_ms"], color="0.5", ls=":", lw=1,
                       label=f"budget: best hand-made graph's time x {res.get('slack', 1.0):g}")
        ax.set_xscale("log")
        ax.set_title(f"{res['scene']}" + (f": ratio {res['ratio']:.2f}" if res["ratio"] is not None else ""), fontsize=10)
        ax.set_xlabel("time per frame (ms)")
        ax.set_ylabel("held-out relative RMS error")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    for ax in axes.ravel()[n:]:
        ax.set_visible(False)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default=",".join(SCENES), help="comma-separated bundled scene keys")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--samples", type=int, default=VALIDATE_SAMPLES, help="ground-truth rays of the held-out frames")
    ap.add_argument("--choice-samples", type=int, default=256, help="ground-truth rays of the training frames")
    ap.add_argument("--out", default=None, help="output directory (default benchmarks/results)")
    ap.add_argument("--suffix", default="", help="appended to the result file names")
    ap.add_argument("--slack", type=float, default=SLACK, help="budget = best hand-made graph's time times this")
    ap.add_argument("--reuse", action="store_true",
                    help="take the choice of an earlier run in --out where there is one (the hand-made graphs are measured again)")
    ap.add_argument("--assets", action="store_true", help="the breadth check: shade --quick on every shipped asset")
    ap.add_argument("--quick", action="store_true", help="smoke profile: the blockers, one graph, shade --quick, few rays")
    args = ap.parse_args(argv)
    if args.quick and args.out is None:
        ap.error("--quick writes only into --out DIR (never benchmarks/results)")
    keys = [k.strip() for k in args.scenes.split(",") if k.strip()]
    unknown = [k for k in keys if k not in SCENES]
    if unknown:
        ap.error(f"--scenes: unknown scene(s) {', '.join(unknown)}; known: {', '.join(SCENES)}")
    if args.quick:
        keys, args.samples, args.choice_samples = ["blockers"], 32, 32
    out = Path(args.out) if args.out else ROOT / "benchmarks" / "results"
    out.mkdir(parents=True, exist_ok=True)
    cache_dir = Path(out) / "cache" if args.quick else "default"
    stamp = datetime.date.today().isoformat()
    stem = f"shade-{stamp}-{args.device}" + (f"-{args.suffix}" if args.suffix else "") + ("-quick" if args.quick else "")
    meta = {"device": args.device, "machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
            "load_start": os.getloadavg()[0], "samples": args.samples, "choice_samples": args.choice_samples,
            "command": "python benchmarks/bench_shade.py " + " ".join(argv or [])}
    if args.assets:
        specs = shipped_assets()
        if args.quick:
            specs = ["bundled:blockers"]
        stem = stem.replace("shade-", "shade-assets-", 1)
        rows = run_assets(specs, out / "shade", args.device, cache_dir)
        write_json_atomic(out / f"{stem}.json", {"meta": meta, "assets": rows})
        print(f"wrote {out / (stem + '.json')}: {sum(r['status'] == 'ok' for r in rows)} of {len(rows)} chose a method")
        return 0
    results = []
    for key in keys:
        t0 = time.perf_counter()
        results.append(run_scene(key, SCENES[key], out / "shade", args.device, cache_dir, args.samples,
                                 args.choice_samples, args.quick, args.slack, args.reuse))
        results[-1]["seconds"] = time.perf_counter() - t0
        meta["load_end"] = os.getloadavg()[0]
        write_json_atomic(out / f"{stem}.json", {"meta": meta, "scenes": results})
        r = results[-1]
        if r["auto"] is not None and r["ratio"] is not None:
            print(f"{key}: shade chose {r['auto']['label']} error {r['auto']['rel_rms_debiased']:.4f} "
                  f"{r['auto']['frame_ms']:.2f} ms/frame; best hand-made {r['best_hand_made']} ratio {r['ratio']:.2f}",
                  flush=True)
    plot(results, out / f"{stem}.png")
    print(f"wrote {out / (stem + '.json')} and .png")
    return 0 if all(np.isfinite(r["ratio"]) for r in results if r["ratio"] is not None) else 1


if __name__ == "__main__":
    raise SystemExit(main())
