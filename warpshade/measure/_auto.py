"""Pick, size and validate a method for a user's own scene (``warpshade shade SCENE``).

Model no more than the scene needs, chosen on the scene itself:

1. **Inspect** the stage: static / rigid / skinned / deforming meshes, frames, lights, camera,
   up axis, what was skipped (:func:`inspect_scene`).
2. **Split its frames** (:func:`split_frames`): ``2 n`` frames (``n`` = :data:`CHOICE_FRAMES`)
   spread inside the scene's range,
   alternately *training* frames (the choice is made on them) and *held-out* frames (the chosen
   graph is validated on them and on nothing else). A static scene has one frame: it is both,
   and the report says so.
3. **Candidates** (:func:`candidates_for`): every method that applies to the scene's kind, each at
   a few sizes (SH order, rays per frame, sphere budget, ZH lobes), and the brute-force per-frame
   ray tracer (``prt.trace``) as the baseline to beat. Glossy candidates (RPO over traced or
   static visibility) are measured against the glossy ray-traced reference.
4. **Measure** each candidate on the training frames (:func:`measure`): its radiance against
   ray-traced ground truth (the relative RMS error with the reference's own noise removed,
   ``rel_rms_debiased``), and its median time per frame (the lowest median of
   :data:`TIMING_PASSES` passes). A method with a history (the few-ray
   tracer) is stepped through :data:`WARM_FRAMES` frames before each measured frame, as a user's
   frame loop would. A candidate that cannot run on the scene (SHEXP without a closed mesh, ...)
   is kept in the report with the reason.
5. **Choose** (:func:`choose`): with ``target_error``, the cheapest candidate meeting it; with
   ``budget_ms``, the most accurate within it; with both, the cheapest meeting the target within
   the budget. Where none qualifies the nearest is taken and the report says that no method met
   the request. The report says why each candidate won or lost.
6. **Write** the chosen graph as TOML next to the outputs (``<name>_auto.toml``: rerun or edit it
   with ``warpshade run``), with the held-out frames as its ``[validate]`` frames; the report of
   the choice (``<name>_auto_choice.json``) and a time-vs-error chart of every candidate
   (``<name>_auto_choice.png``). ``warpshade shade`` then runs the graph (USD layer, previews, its
   own report, validated on the held-out frames).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

__all__ = ["CHOICE_FRAMES", "QUICK_CHOICE_FRAMES", "TIMING_PASSES", "WARM_FRAMES", "candidates_for", "choose", "default_lighting", "inspect_scene", "measure", "split_frames", "graph_toml", "plot_candidates",
           "run_frames", "shade_outputs", "shade_scene", "training_selection", "tuned_candidate"]

#: Frames a candidate is stepped through before each measured frame (a method with a history
#: -- the few-ray tracer's running estimate -- is measured as a frame loop would run it).
WARM_FRAMES = 8
#: The error target when neither a target nor a budget is given (relative RMS error).
DEFAULT_TARGET = 0.1
#: Ground-truth rays per vertex of the choice (training frames) and of the held-out validation.
CHOICE_SAMPLES = 256
VALIDATE_SAMPLES = 512
#: Timing passes over a candidate's frames: its time per frame is the lowest of the passes'
#: medians (a shared machine's load only ever adds time; one slow pass must not decide a close
#: call). Passes after the first run only while one pass takes under
#: :data:`TIMING_PASS_LIMIT_S` seconds.
TIMING_PASSES = 3
TIMING_PASS_LIMIT_S = 5.0
#: SHEXP candidates (SH order, sphere budget); more spheres than 16 are fitted as a hierarchy.
SHEXP_SIZES = ((4, 8), (4, 16), (4, 48), (6, 8), (6, 48))
#: ``--glossy auto`` shades glossy when a mesh's UsdPreviewSurface roughness is below this.
GLOSSY_ROUGHNESS = 0.4


# ---- the scene ---------------------------------------------------------------------------------
def inspect_scene(scene) -> dict:
    """What the scene is, as the chooser sees it."""
    kinds = sorted({m.animation for m in scene.meshes})
    if scene.is_static:
        kind = "static"
    elif "deforming" in kinds:
        kind = "deforming"
    elif "skinned" in kinds:
        kind = "skinned"
    else:
        kind = "rigid"
    lo, hi = scene.bounds_over_frames()
    return {
        "source": str(scene.source),
        "kind": kind,
        "mesh_animation": {m.path: m.animation for m in scene.meshes},
        "meshes": len(scene.meshes),
        "vertices": int(scene.vertex_count),
        "triangles": int(scene.triangle_count),
        "frames": len(scene.frames),
        "first_frame": float(scene.frames[0]),
        "last_frame": float(scene.frames[-1]),
        "fps": float(scene.fps),
        "up_axis": scene.up_axis,
        "camera": scene.camera is not None,
        "lights": [type(light).__name__ for light in scene.lights],
        "skipped": [list(s) for s in getattr(scene, "skipped", [])],
        "glossy_meshes": sum(1 for m in scene.meshes if _glossy(m)),
        "bounds": [np.asarray(lo).tolist(), np.asarray(hi).tolist()],
    }


def _glossy(mesh) -> bool:
    """A mesh whose UsdPreviewSurface has a uniform roughness below :data:`GLOSSY_ROUGHNESS`
    (a visible highlight: a diffuse method would miss it)."""
    surface = getattr(mesh, "surface", None)
    rough = getattr(surface, "roughness", None)
    return isinstance(rough, (int, float)) and float(rough) < GLOSSY_ROUGHNESS


#: Frames of each set (training, held out) of :func:`split_frames`: two frames of a walk cycle can
#: rank two methods the other way round from the clip (on the bundled wanderer, 2 frames put LDPRT
#: ahead of data-driven transfer, 8 frames put it 12% behind, as on the held-out frames).
CHOICE_FRAMES = 4
#: The same with ``--quick`` (a first look).
QUICK_CHOICE_FRAMES = 2


def split_frames(scene, per_set: int | None = None, quick: bool = False) -> tuple[np.ndarray, np.ndarray, str]:
    """(training frames, held-out frames, note): ``2 per_set`` frames (``per_set`` default
    :data:`CHOICE_FRAMES`, :data:`QUICK_CHOICE_FRAMES` with ``quick``) spread inside the scene's
    range (its first and last frames left out when it has more than ``2 per_set + 2``),
    alternately training and held-out; a scene with fewer frames splits what it has, and a
    one-frame scene uses its frame for both (the note says so)."""
    if per_set is None:
        per_set = QUICK_CHOICE_FRAMES if quick else CHOICE_FRAMES
    if int(per_set) < 1:
        raise ValueError(f"split_frames: per_set must be >= 1, got {per_set!r}")
    f = np.asarray(scene.frames, np.float64)
    if f.size == 1:
        return f.copy(), f.copy(), "one frame: the choice and the validation use the same frame (different rays)"
    want = 2 * per_set
    if f.size >= want + 2:
        idx = np.unique(np.linspace(0, f.size - 1, want + 2).round().astype(int))[1:-1]
    else:
        idx = np.arange(f.size)
    train, held = f[idx[0::2]], f[idx[1::2]]
    if held.size == 0:
        held = train.copy()
        return train, held, "too few frames to hold any out: validated on the training frames"
    return train, held, ""


#: The most training-clip frames a data-driven candidate traces (evenly spaced over the clip).
TRAINING_FRAMES = 200
#: Rays per vertex of a data-driven candidate's training frames.
TRAINING_SAMPLES = 128


def training_selection(clip_frames: int, most: int = TRAINING_FRAMES) -> str:
    """The ``frames`` selection of a training clip of ``clip_frames`` frames: every ``s``-th frame,
    ``s`` the least stride that keeps at most ``most`` of them."""
    if clip_frames < 1:
        raise ValueError("shade: the training clip has no frames")
    stride = max(1, math.ceil(clip_frames / most))
    return f"0:{int(clip_frames)}:{stride}"


def _hybrid(add, control: str, samples: int, order: int = 6, **kw):
    """A hybrid candidate whose reuse settings :func:`warpshade.measure._tune.tune_trace` chooses."""
    from ..methods.hybrid._rows import stages_for

    facts = {"order": order, "samples": samples, "control": control}
    tune = {"control": control, "samples": samples, "order": order, **kw}
    add("hybrid", f"n{order} K{samples} {control}", stages_for(control, samples, order=order, **kw), facts, tune=tune)


def tuned_candidate(cand: dict, settings: dict) -> dict:
    """``cand`` (a tunable hybrid candidate) with ``hybrid.trace`` ``settings`` applied."""
    from ..methods.hybrid._rows import stages_for

    t = cand["tune"]
    kw = {k: v for k, v in t.items() if k not in ("control", "samples", "order")}
    stages = stages_for(t["control"], t["samples"], order=t["order"], trace=dict(settings), **kw)
    return {**cand, "stages": tuple(stages), "facts": {**cand["facts"], "trace": dict(settings)}}


def candidates_for(scene, glossy: bool = False, quick: bool = False, training: dict | None = None) -> list[dict]:
    """The settings worth trying on ``scene``: ``{"method", "label", "stages", "facts",
    "timed_stage"}`` (``timed_stage`` None: the whole frame counts), the per-frame ray tracer
    among them (``"baseline": True``). A hybrid candidate carries ``"tune"`` (its reuse settings
    are chosen on the training frames, :mod:`._tune`). With ``training`` (``{"clip": spec,
    "frames": selection}``, a clip of the same character) the data-driven methods join."""
    from ..methods.prt._budget import candidates as prt_candidates
    from ..methods.shexp._rows import graph_stages

    kind = inspect_scene(scene)["kind"]
    out = []

    def add(method, label, stages, facts, baseline=False, tune=None):
        out.append({"method": method, "label": f"{method} {label}", "stages": tuple(stages), "facts": dict(facts),
                    "timed_stage": None, "baseline": baseline, "tune": tune})

    if glossy:
        from ..methods.rpo._rows import rpo_stages

        for order, rank in ((4, 4), (4, 8)) if not quick else ((4, 4),):
            vis = "static" if kind == "static" else "traced"
            add("rpo", f"{vis} n{order} k{rank}", rpo_stages(vis, order, rank, samples=256),
                {"visibility": vis, "order": order, "rank": rank})
        return out
    trace_counts = (64,) if quick else (64, 256)
    for k in trace_counts:  # the brute-force baseline: the frame's transfer ray traced anew
        add("prt.trace", f"n6 K{k}", (("shade", "prt.trace", {"order": 6, "samples": k}, {}),), {"order": 6, "samples": k},
            baseline=True)
    add("unshadowed", "n3", (("shade", "prt.unshadowed", {"order": 3}, {}),), {"order": 3})
    if kind == "static":
        for c in prt_candidates(orders=(4,) if quick else (3, 4, 6), samples=(256,)):
            add("prt", c["label"], c["stages"], c["facts"])
        return out
    rays = (16,) if quick else (16, 64)
    for k in rays:
        _hybrid(add, "previous", k)
    # the sphere budget is not monotone in error (overlapping spheres over-darken: on the blockers
    # 8 spheres give 0.078, 16 give 0.14, 48 give 0.16), so a few budgets are measured
    for order, spheres in ((4, 8),) if quick else SHEXP_SIZES:
        add("shexp", f"n{order} {spheres} spheres", graph_stages(order, "hyb", spheres, hierarchy=spheres > 16),
            {"order": order, "spheres": spheres})
    if kind == "rigid" and not quick:
        for k in rays:  # the blocker spheres' visibility as control (needs closed meshes)
            _hybrid(add, "shexp", k)
    if kind in ("skinned", "deforming"):
        for lobes in (1,) if quick else (1, 4):
            fit = {"order": 4, "lobes": lobes, "samples": 256, "target_error": 0.05}
            add("ldprt", f"n4 N<={lobes}", (("fit", "ldprt.fit", fit, {}), ("tangents", "ldprt.tangents", {}, {}),
                                             ("shade", "ldprt.shade", {"order": 4, "lobes": lobes}, {})),
                {"order": 4, "lobes": lobes})
        if not quick:
            for k in rays:  # the rest pose's local transfer, rotated with the surface, as control
                _hybrid(add, "ldprt", k)
    if training is not None and kind != "static":
        clip, frames = training["clip"], training["frames"]
        data = {"training": clip, "frames": frames, "order": 6, "samples": TRAINING_SAMPLES}
        from ..methods.hybrid._rows import VISIBILITY_FIT

        add("visibility", "n6 diffuse", (("data", "visibility.data", dict(data), {}),
                                         ("fit", "visibility.fit", dict(VISIBILITY_FIT), {"data": "data.data"}),
                                         ("predict", "visibility.predict", {"order": 6}, {"model": "fit.model"}),
                                         ("shade", "visibility.diffuse", {"order": 6}, {})),
            {"order": 6, "training": clip, "frames": frames})
        add("datadriven", "n6 reduced", (("data", "datadriven.data", {**data, "samples": 2 * TRAINING_SAMPLES}, {}),
                                         ("fit", "datadriven.fit", {"reduction": "reduced", "pose": "quaternion"}, {"data": "data.data"}),
                                         ("transfer", "datadriven.transfer", {"order": 6}, {"model": "fit.model"}),
                                         ("shade", "prt.shade", {"order": 6}, {"transfer": "transfer.transfer"})),
            {"order": 6, "training": clip, "frames": frames})
        for k in rays:
            _hybrid(add, "visibility", k, training=clip, frames=frames, training_samples=TRAINING_SAMPLES)
    return out


# ---- measuring -----------------------------------------------------------------------------------
def _windows(scene, frames, warm: int) -> list[list[float]]:
    """For each frame, the frames stepped up to it (``warm`` before it, within the scene)."""
    f = np.asarray(scene.frames, np.float64)
    out = []
    for t in frames:
        i = int(np.flatnonzero(f == float(t))[0])
        out.append([float(x) for x in f[max(0, i - warm):i + 1]])
    return out


def measure(scene, lighting, cand: dict, frames, truth: dict, *, device="cpu", cache_dir="default",
            warm: int = WARM_FRAMES, glossy_truth=None) -> dict:
    """One candidate on ``frames``: ``{"rel_rms", "rel_rms_debiased", "frame_ms", "compile_s",
    "status", "reason"}`` (``status`` "ok" or "failed", with the reason)."""
    from ..graph import GraphSpec, StageSpec
    from ._harness import setting_error
    from ._truth import reference_model

    row = {k: cand[k] for k in ("method", "label", "facts", "baseline")}
    row["stages"] = [list(s) for s in cand["stages"]]
    t0 = time.perf_counter()
    try:
        spec = GraphSpec([StageSpec(n, t, dict(p), dict(i)) for (n, t, p, i) in cand["stages"]], "shade.radiance",
                         name=cand["label"].replace(" ", "-"))
        rt = spec.compile(scene, device=device, cache_dir=cache_dir, progress=False, lighting=lighting)
        compile_s = time.perf_counter() - t0
        radiance, medians, t_pass = {}, [], 0.0
        windows = _windows(scene, frames, warm)
        while not medians or (len(medians) < TIMING_PASSES and t_pass < TIMING_PASS_LIMIT_S):
            start, t0 = len(rt.frame_s), time.perf_counter()
            for window in windows:
                rt.run(window, record=True, warmup=False)
                if not medians:  # the first pass's radiance is the one measured
                    radiance[window[-1]] = np.array(rt.results[window[-1]], copy=True)
            medians.append(float(np.median(rt.frame_s[start:])))
            t_pass = time.perf_counter() - t0
        model = reference_model(rt)
        ref = truth if model is None else glossy_truth(model)
        err = setting_error(radiance, ref)
    except Exception as exc:  # a candidate that cannot run on this scene is reported, not fatal
        row.update(status="failed", reason=f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}",
                   rel_rms=math.nan, rel_rms_debiased=math.nan, frame_ms=math.nan,
                   compile_s=time.perf_counter() - t0)
        return row
    debiased = err.get("rel_rms_debiased", err["rel_rms"])
    row.update(status="ok", reason="", rel_rms=float(err["rel_rms"]), rel_rms_debiased=float(debiased),
               frame_ms=1e3 * min(medians), frame_ms_passes=[1e3 * m for m in medians], compile_s=compile_s,
               glossy=model is not None)
    if not np.isfinite(row["rel_rms"]):
        row.update(status="failed", reason="its radiance is not finite")
    return row


def choose(rows: list[dict], target_error: float | None = None, budget_ms: float | None = None) -> tuple[dict | None, bool, str]:
    """(the chosen row, whether it meets the request, why) from measured ``rows``; each row gets
    a ``"verdict"`` saying why it won or lost. The error compared is ``rel_rms_debiased``."""
    ok = [r for r in rows if r["status"] == "ok"]
    for r in rows:
        if r["status"] != "ok":
            r["verdict"] = f"could not run: {r['reason']}"
    if not ok:
        return None, False, "no candidate could run on this scene"
    if target_error is None and budget_ms is None:
        target_error = DEFAULT_TARGET
    err = lambda r: r["rel_rms_debiased"]  # noqa: E731
    meets_t = (lambda r: err(r) <= target_error) if target_error is not None else (lambda r: True)
    meets_b = (lambda r: r["frame_ms"] <= budget_ms) if budget_ms is not None else (lambda r: True)
    good = [r for r in ok if meets_t(r) and meets_b(r)]
    if good:
        chosen = min(good, key=lambda r: (r["frame_ms"], err(r))) if target_error is not None else min(good, key=err)
        met = True
        why = (f"the cheapest meeting the error target {target_error:g}" if target_error is not None else
               f"the most accurate within {budget_ms:g} ms per frame")
        if target_error is not None and budget_ms is not None:
            why += f" within {budget_ms:g} ms per frame"
    else:
        met = False
        if budget_ms is not None and target_error is None:
            chosen = min(ok, key=lambda r: r["frame_ms"])
            why = f"no candidate runs within {budget_ms:g} ms per frame: the fastest is the nearest"
        else:
            within = [r for r in ok if meets_b(r)] or ok
            chosen = min(within, key=err)
            why = f"no candidate meets the error target {target_error:g}: the most accurate is the nearest"
            if budget_ms is not None:
                why += f" (within {budget_ms:g} ms per frame where any is)"
    for r in ok:
        if r is chosen:
            r["verdict"] = "chosen: " + why
        elif not meets_t(r):
            r["verdict"] = f"error {err(r):.4f} above the target {target_error:g}"
        elif not meets_b(r):
            r["verdict"] = f"{r['frame_ms']:.2f} ms per frame, above the budget {budget_ms:g}"
        elif target_error is not None:
            r["verdict"] = f"meets the target but costs {r['frame_ms']:.2f} ms against {chosen['frame_ms']:.2f}"
        else:
            r["verdict"] = f"within the budget but less accurate ({err(r):.4f} against {err(chosen):.4f})"
    return chosen, met, why


# ---- outputs ---------------------------------------------------------------------------------------
def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise ValueError(f"shade: cannot write parameter value {v!r} to TOML")


def graph_toml(name: str, description: str, scene: str, stages, validate_frames, samples: int) -> str:
    """A stage graph file (``warpshade run`` reads it) of ``(name, type, params, inputs)`` tuples."""
    lines = ["# written by `warpshade shade`: the method it chose for this scene; edit and rerun with `warpshade run`",
             "[graph]", f"name = {_toml_value(name)}", f"description = {_toml_value(description)}",
             f"scene = {_toml_value(scene)}", 'output = "shade.radiance"', "",
             "[lighting]  # the scene's environments and distant lights (a sky where it has none)", 'source = "distant"', "",
             "[validate]",
             f"frames = {_toml_value([int(f) if float(f).is_integer() else float(f) for f in validate_frames])}",
             f"samples = {int(samples)}"]
    for sname, stype, params, inputs in stages:
        lines += ["", "[[stage]]", f"name = {_toml_value(sname)}", f"type = {_toml_value(stype)}"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in params.items()]
        if inputs:
            lines.append("inputs = { " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in inputs.items()) + " }")
    return "\n".join(lines) + "\n"


def plot_candidates(rows: list[dict], chosen: dict | None, path, title: str, target_error=None, budget_ms=None) -> Path:
    """Time per frame against error of every candidate that ran (the ray tracer marked as the
    baseline, the choice circled), written as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._fileio import atomic_path

    fig, ax = plt.subplots(figsize=(7.5, 5.0), dpi=110)
    methods = sorted({r["method"] for r in rows if r["status"] == "ok"})
    colors = {m: plt.cm.tab10(i % 10) for i, m in enumerate(methods)}
    for m in methods:
        rs = [r for r in rows if r["status"] == "ok" and r["method"] == m]
        ax.scatter([r["frame_ms"] for r in rs], [r["rel_rms_debiased"] for r in rs], color=colors[m],
                   marker="s" if rs[0].get("baseline") else "o", s=36,
                   label=f"{m} (per-frame ray tracing: the baseline)" if rs[0].get("baseline") else m)
        for r in rs:
            ax.annotate(r["label"].split(" ", 1)[1], (r["frame_ms"], r["rel_rms_debiased"]), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
    if chosen is not None:
        ax.scatter([chosen["frame_ms"]], [chosen["rel_rms_debiased"]], s=220, facecolors="none", edgecolors="k",
                   linewidths=1.5, label=f"chosen: {chosen['label']}")
    if target_error is not None:
        ax.axhline(target_error, color="0.5", ls="--", lw=1, label=f"error target {target_error:g}")
    if budget_ms is not None:
        ax.axvline(budget_ms, color="0.5", ls=":", lw=1, label=f"budget {budget_ms:g} ms")
    ax.set_xscale("log")
    ax.set_xlabel("time per frame (ms, median; whole frame)")
    ax.set_ylabel("relative RMS error vs ray-traced truth (noise removed)")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path


# ---- the whole command -------------------------------------------------------------------------------
def shade_scene(scene_spec: str, out_dir, *, target_error: float | None = None, budget_ms: float | None = None,
                glossy: str = "auto", device="cpu", cache_dir="default", choice_samples: int = CHOICE_SAMPLES,
                validate_samples: int = VALIDATE_SAMPLES, quick: bool = False, training: str | None = None,
                tune: bool = True, log=print) -> dict:
    """Inspect ``scene_spec``, measure the candidates on its training frames, choose, write the
    chosen graph, its report and chart into ``out_dir``, and validate the choice on the held-out
    frames. ``training``: a training clip of the same character (scene spec) for the data-driven
    candidates; ``tune``: choose the few-ray tracer's reuse settings on the training frames
    (:mod:`._tune`; off with ``quick``). Returns the report (also written as ``<name>_auto.json``)."""
    from .._fileio import write_json_atomic, write_text_atomic
    from ..io import load_scene
    from ._truth import ground_truth
    from ._tune import tune_trace

    if target_error is not None and not (isinstance(target_error, (int, float)) and target_error > 0):
        raise ValueError(f"--target-error must be a number > 0, got {target_error!r}")
    if budget_ms is not None and not (isinstance(budget_ms, (int, float)) and budget_ms > 0):
        raise ValueError(f"--budget-ms must be a number > 0, got {budget_ms!r}")
    if glossy not in ("auto", "on", "off"):
        raise ValueError(f"--glossy must be auto, on or off, got {glossy!r}")
    t_start = time.perf_counter()
    scene = load_scene(scene_spec)
    info = inspect_scene(scene)
    train_clip = None
    if training is not None:
        try:
            clip = load_scene(training)
        except Exception as exc:
            raise ValueError(f"--training {training}: {exc}") from None
        if info["kind"] == "static":
            raise ValueError(f"--training {training}: the scene {scene_spec} is static; a training clip of poses "
                             "applies to an animated character")
        if clip.vertex_count != scene.vertex_count or clip.triangle_count != scene.triangle_count:
            raise ValueError(f"--training {training}: not the same character as {scene_spec} ({clip.vertex_count:,} "
                             f"vertices and {clip.triangle_count:,} triangles against {scene.vertex_count:,} and "
                             f"{scene.triangle_count:,})")
        train_clip = {"clip": str(Path(training).resolve()) if Path(str(training)).exists() else str(training),
                      "frames": training_selection(len(clip.frames))}
    name = Path(str(scene_spec).split(":", 1)[-1]).stem or "scene"
    out_dir = Path(out_dir)
    log(f"scene   {info['source']}: {info['kind']}, {info['meshes']} mesh(es), {info['vertices']:,} vertices, "
        f"{info['frames']} frame(s), up {info['up_axis']}, {'a camera' if info['camera'] else 'no camera'}, "
        f"{len(info['lights'])} light(s)" + (f"; skipped: {', '.join(p for p, _ in info['skipped'])}" if info["skipped"] else ""))
    if train_clip is not None:
        log(f"training clip {train_clip['clip']}, frames {train_clip['frames']} (data-driven candidates)")
    use_glossy = glossy == "on" or (glossy == "auto" and info["glossy_meshes"] > 0)
    if glossy == "auto":
        log(f"glossy  {'on' if use_glossy else 'off'}: {info['glossy_meshes']} mesh(es) with a UsdPreviewSurface "
            f"roughness below {GLOSSY_ROUGHNESS} (--glossy on|off decides instead)")
    lighting = default_lighting(scene)
    left_out = left_out_lights(scene)
    if left_out:
        under = "the scene's distant lights" if len(left_out) < len(scene.lights) else "a procedural sky"
        log(f"lights  sphere light(s) {', '.join(left_out)} left out: the methods compared shade distant lighting "
            f"(SH); measured under {under}")
    stem = f"{name}_auto"
    plan = shade_outputs(out_dir, stem, scene)
    plan.check()  # before any work: nothing is written over a file warpshade did not write
    train, held, note = split_frames(scene, quick=quick)
    log(f"frames  training {[float(f) for f in train]} (the choice), held out {[float(f) for f in held]} (the validation)"
        + (f"; {note}" if note else ""))
    cands = candidates_for(scene, glossy=use_glossy, quick=quick, training=train_clip)
    truth = ground_truth(scene, lighting, train, choice_samples, device, cache_dir)
    glossy_truth = lambda model: ground_truth(scene, lighting, train, choice_samples, device, cache_dir, model=model)  # noqa: E731
    evaluate = lambda c: measure(scene, lighting, c, train, truth, device=device, cache_dir=cache_dir,  # noqa: E731
                                 glossy_truth=glossy_truth)
    rows = []
    for i, cand in enumerate(cands):
        tuning = None
        if cand.get("tune") and tune and not quick:
            log(f"  [{i + 1}/{len(cands)}] {cand['label']}: reuse settings chosen on the training frames")
            tuned = tune_trace(lambda settings, c=cand: tuned_candidate(c, settings), evaluate,
                               local=cand["tune"]["control"] == "ldprt", log=log)
            cands[i] = cand = tuned["candidate"]
            row, tuning = tuned["row"], tuned["tuning"]
            row["facts"] = dict(cand["facts"])
            row["stages"] = [list(st) for st in cand["stages"]]
            row["tuning"] = tuning
        else:
            row = evaluate(cand)
        rows.append(row)
        state = (f"error {row['rel_rms_debiased']:.4f}  {row['frame_ms']:8.2f} ms/frame" if row["status"] == "ok"
                 else f"failed: {row['reason'][:90]}")
        log(f"  [{i + 1}/{len(cands)}] {row['label']:28s} {state}" + (f"  (reuse {cand['facts']['trace']})" if tuning else ""))
    chosen, met, why = choose(rows, target_error, budget_ms)
    report = {"scene": info, "request": {"target_error": target_error, "budget_ms": budget_ms, "glossy": glossy,
                                         "default_target": DEFAULT_TARGET if target_error is None and budget_ms is None else None},
              "training_frames": [float(f) for f in train], "held_out_frames": [float(f) for f in held], "frames_note": note,
              "choice_samples": int(choice_samples), "validate_samples": int(validate_samples), "warm_frames": WARM_FRAMES,
              "training_clip": train_clip, "tuned": bool(tune and not quick), "left_out_lights": left_out,
              "candidates": rows, "met": bool(met), "why": why, "chosen": None, "held_out": None,
              "scene_frames": [float(f) for f in scene.frames]}
    if chosen is not None:
        plan.check()  # again: minutes may have passed
        scene_ref = str(Path(scene_spec).resolve()) if Path(str(scene_spec)).exists() else str(scene_spec)
        stages = [tuple(s) for s in chosen["stages"]]
        toml = graph_toml(stem, f"{info['kind']} scene: {chosen['label']} ({why})", scene_ref, stages, held, validate_samples)
        graph_path = write_text_atomic(plan.extra[0], toml)
        plan.record([graph_path])
        held_truth = ground_truth(scene, lighting, held, validate_samples, device, cache_dir)
        held_glossy = lambda model: ground_truth(scene, lighting, held, validate_samples, device, cache_dir, model=model)  # noqa: E731
        cand = next(c for c in cands if c["label"] == chosen["label"])
        val = measure(scene, lighting, cand, held, held_truth, device=device, cache_dir=cache_dir, glossy_truth=held_glossy)
        report["chosen"] = {"label": chosen["label"], "method": chosen["method"], "facts": chosen["facts"], "graph": str(graph_path)}
        report["held_out"] = {k: val[k] for k in ("status", "reason", "rel_rms", "rel_rms_debiased", "frame_ms")}
        log(f"chosen  {chosen['label']}: {why}")
        log(f"held out error {val['rel_rms_debiased']:.4f} (relative RMS, the reference's noise removed; "
            f"{val['rel_rms']:.4f} with it), {val['frame_ms']:.2f} ms/frame on {device}")
        log(f"graph   {graph_path}  (rerun: warpshade run {graph_path} --validate)")
    else:
        log(f"no method could run on this scene: {why}")
    chart = plot_candidates(rows, chosen, plan.extra[2], f"{name}: candidates on the training frames",
                            target_error if target_error is not None or budget_ms is not None else DEFAULT_TARGET, budget_ms)
    report["chart"] = str(chart)
    report["seconds"] = time.perf_counter() - t_start
    path = write_json_atomic(plan.extra[1], report)
    plan.record([chart, path])
    log(f"report  {path}\nchart   {chart}")
    return report


def run_frames(frames, held) -> str:
    """The ``--frames`` span a run of the chosen graph covers: from :data:`WARM_FRAMES` frames before
    the first held-out frame to the last (as ``A:B``, ``B`` exclusive), so that a method with a
    history reaches every held-out frame as the choice measured it."""
    f = np.asarray(frames, np.float64)
    lo = int(np.flatnonzero(f == float(min(held)))[0])
    hi = int(np.flatnonzero(f == float(max(held)))[0])
    start = f[max(0, lo - WARM_FRAMES)]
    end = "" if hi + 1 >= f.size else f"{f[hi + 1]:g}"
    return f"{start:g}:{end}"


def shade_outputs(out_dir, stem: str, scene):
    """The files of ``warpshade shade`` in ``out_dir`` (:class:`~warpshade.measure._outputs.OutputPlan`
    ``extra``: the chosen graph ``<stem>.toml``, the choice's report ``<stem>_choice.json`` and
    chart ``<stem>_choice.png``), never over a file warpshade did not write or the scene."""
    from ._outputs import OutputPlan

    d = Path(out_dir)
    protected = {Path(scene.source).resolve(): "the scene"} if scene.source and Path(str(scene.source)).exists() else {}
    return OutputPlan(directory=d, usd=None, report=None, protected=protected,
                      extra=(d / f"{stem}.toml", d / f"{stem}_choice.json", d / f"{stem}_choice.png"))


def default_lighting(scene):
    """The lighting ``warpshade shade`` measures under: the scene's distant lights (environments and
    distant lights), or where it has none a procedural sky about its up axis -- the ``[lighting]
    source = "distant"`` of the graph it writes. Its sphere lights are left out (the diffuse
    methods shade distant lighting in SH); :func:`shade_scene` says so, naming them."""
    from ..graph._scene_inputs import lighting_from_spec

    return lighting_from_spec({"source": "distant"}, scene)


def left_out_lights(scene) -> list[str]:
    """The paths of the scene's sphere lights (what :func:`default_lighting` leaves out)."""
    from ..scene import SphereLight

    return [light.path or "<array>" for light in scene.lights if isinstance(light, SphereLight)]
