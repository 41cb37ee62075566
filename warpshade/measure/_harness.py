"""One method setting on one scene, timed and measured: what the harness, the error budgets and
the benchmarks all do.

:func:`run_setting` compiles a graph of ``(name, type, params, inputs)`` stage tuples on a
scene, steps the timing frames through the recorded frame (after a warm-up), profiles each
stage, and returns the radiance of the error frames; :func:`setting_error` compares that
radiance with ground truth (:func:`warpshade.measure._truth.ground_truth`).
"""

from __future__ import annotations

import time

__all__: list[str] = []


def run_setting(scene, lighting, stages, frames, output: str = "shade.radiance", timing_frames=None, device="cpu",
                cache_dir="default", name: str = "setting", profile: bool = True, progress: bool = False) -> dict:
    """Run one graph: radiance on ``frames``, time per frame, per-stage time, model size.

    Args:
        scene, lighting: the scene and its :class:`~warpshade.scene.LightingSource`.
        stages: ``(name, type, params, inputs)`` tuples.
        frames: frames whose radiance is returned.
        output: the output port ``"stage.port"``.
        timing_frames: frames stepped (replayed) for timing after a warm-up (default ``frames``).
        device: Warp device; cache_dir: the artifact cache (None: no cache).
        profile: also time the scene evaluation and each stage separately
            (:meth:`~warpshade.graph.Runtime.profile`).

    Returns:
        dict: ``runtime``, ``radiance`` {frame: (V, 3)}, ``frame_ms`` and ``host_ms`` (medians of
        the replayed frames), ``stage_ms`` {stage: ms} (profiled), ``compile_s`` (precompute and
        set-up), ``model_bytes``, ``reports`` {stage: precompute report}, ``diagnostics``.
    """
    from ..graph import GraphSpec, StageSpec

    spec = GraphSpec([StageSpec(n, t, dict(p), dict(i)) for (n, t, p, i) in stages], output, name=name)
    t0 = time.perf_counter()
    rt = spec.compile(scene, device=device, cache_dir=cache_dir, progress=progress, lighting=lighting)
    compile_s = time.perf_counter() - t0
    timing_frames = list(frames if timing_frames is None else timing_frames)
    rt.run(timing_frames, record=True, warmup=True)
    timing = rt.timing_summary()
    radiance = {}
    for f in frames:
        rec = rt.results.get(float(f))
        radiance[float(f)] = rec if rec is not None else rt.step(f).numpy().copy()
    stage_ms = {}
    if profile:
        stage_ms = {k: 1e3 * v for k, v in rt.profile(timing_frames[: max(1, min(4, len(timing_frames)))]).items()}
    described = rt.describe()
    return {
        "runtime": rt,
        "radiance": radiance,
        "frame_ms": 1e3 * timing["median_frame_s"],
        "host_ms": 1e3 * timing["median_host_s"],
        "stage_ms": stage_ms,
        "compile_s": compile_s,
        "model_bytes": rt.model_bytes(),
        "frames_timed": timing["frames_timed"],
        "uncaptured": timing["uncaptured"],
        "reports": {s["name"]: s["report"] for s in described["stages"] if "report" in s},
        "diagnostics": described["diagnostics"],
    }


def setting_error(radiance: dict, truth: dict) -> dict:
    """Error metrics of ``radiance`` {frame: (V, 3)} against ``truth`` (:func:`ground_truth`),
    combined over the frames, with ``per_frame`` metrics."""
    from ._metrics import combine_metrics, error_metrics

    per_frame = []
    for f, ref in truth.items():
        m = error_metrics(radiance[float(f)], ref["radiance"], ref["stderr"])
        m["frame"] = float(f)
        per_frame.append(m)
    out = combine_metrics(per_frame)
    out["per_frame"] = per_frame
    return out
