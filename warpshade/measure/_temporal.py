"""Temporal metrics of a method: noise over seeds at a held frame, and lag on the fastest frames.

* :func:`noise` -- the clip is stepped from its start up to a frame, once per seed (the ``seed``
  parameter of every frame stage that has one; a method without one is deterministic and has
  zero noise, measured with one run); per vertex, the standard deviation of the radiance over
  the seeds (RMS over channels, unbiased variance), reported relative to the RMS radiance of the
  seed mean: ``noise_rel`` (RMS over vertices) and ``noise_rel_p99``.
* :func:`motion_per_frame` -- RMS vertex displacement from the previous frame (0 for the first).
* :func:`lag` -- the clip is stepped from its start, every frame, once; the error against ground
  truth (relative RMS) on the ``fast`` frames of most motion and on ``spread`` frames spread over
  the clip; ``lag`` = mean error on the fast frames / mean error over all measured frames. A
  method that reuses work over frames and lags behind the motion shows ``lag > 1``.
"""

from __future__ import annotations

import numpy as np

__all__: list[str] = []

#: Seeds of the noise metric.
NOISE_SEEDS = 8


def seeded(stages, seed: int) -> tuple:
    """The stage tuples with ``seed`` set on every frame stage that has that parameter (None when
    none has one: the method is deterministic per frame)."""
    from ..graph import FrameStage, get_stage_type

    out, found = [], False
    for name, type_name, params, inputs in stages:
        cls = get_stage_type(type_name, name)
        if issubclass(cls, FrameStage) and "seed" in cls.parameters:
            params = {**params, "seed": int(seed)}
            found = True
        out.append((name, type_name, params, inputs))
    return tuple(out) if found else None


def _compile(scene, lighting, stages, output, device, cache_dir, name):
    from ..graph import GraphSpec, StageSpec

    spec = GraphSpec([StageSpec(n, t, dict(p), dict(i)) for (n, t, p, i) in stages], output, name=name)
    return spec.compile(scene, device=device, cache_dir=cache_dir, progress=False, lighting=lighting)


def noise(scene, lighting, stages, output: str = "shade.radiance", frame=None, seeds: int = NOISE_SEEDS, device="cpu",
          cache_dir="default", base_seed: int = 1000) -> dict:
    """Per-vertex relative standard deviation over ``seeds`` runs at ``frame`` (default: the
    frame a quarter into the clip), each stepped from the clip's start."""
    frames = np.asarray(scene.frames, np.float64)
    if frame is None:
        frame = frames[len(frames) // 4]
    stop = scene.frame_index(frame)
    deterministic = seeded(stages, 0) is None
    runs = []
    for k in range(1 if deterministic else seeds):
        st = tuple(stages) if deterministic else seeded(stages, base_seed + k)
        rt = _compile(scene, lighting, st, output, device, cache_dir, f"noise-{k}")
        for f in frames[:stop]:
            rt.step(float(f))
        runs.append(rt.step(float(frames[stop])).numpy().astype(np.float64).copy())
    x = np.stack(runs)  # (S, V, 3)
    mean = x.mean(axis=0)
    scale = float(np.sqrt(np.mean(mean**2))) or 1.0
    if x.shape[0] < 2:
        std = np.zeros(x.shape[1])
    else:
        std = np.sqrt(np.mean(x.var(axis=0, ddof=1), axis=1))
    return {"noise_rel": float(np.sqrt(np.mean(std**2))) / scale, "noise_rel_p99": float(np.percentile(std, 99)) / scale,
            "noise_frame": float(frames[stop]), "noise_seeds": int(x.shape[0]), "deterministic": x.shape[0] < 2}


def motion_per_frame(scene) -> np.ndarray:
    """RMS vertex displacement from the previous frame, per frame (0 for the first), float64."""
    frames = np.asarray(scene.frames, np.float64)
    out = np.zeros(len(frames))
    prev = scene.points_at(float(frames[0]))
    for i in range(1, len(frames)):
        cur = scene.points_at(float(frames[i]))
        out[i] = float(np.sqrt(np.mean(np.sum((cur - prev) ** 2, axis=1))))
        prev = cur
    return out


def lag_frames(scene, fast: int = 3, spread: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """``(fast frames, spread frames)``: the ``fast`` frames of most motion (not the first) and
    ``spread`` frames spread over the clip (first left out: nothing to lag behind there)."""
    frames = np.asarray(scene.frames, np.float64)
    motion = motion_per_frame(scene)
    order = np.argsort(-motion[1:], kind="stable")[:fast] + 1
    idx = np.unique(np.linspace(1, len(frames) - 1, spread).round().astype(int)) if len(frames) > 1 else np.zeros(1, int)
    return frames[np.sort(order)], frames[idx]


def lag(scene, lighting, stages, truth_for, output: str = "shade.radiance", fast: int = 3, spread: int = 4,
        device="cpu", cache_dir="default") -> dict:
    """Error on the fastest-moving frames relative to the clip's mean error (the clip stepped once
    from its start). ``truth_for(frames)`` returns :func:`~warpshade.measure.ground_truth` of
    those frames. Static scenes (no motion) give ``lag`` None. Also returns ``frame_ms``, the
    median time of the steps after the first two (compilation, recording), and the run's
    ``diagnostics`` after its last frame."""
    from ._metrics import error_metrics

    fast_f, spread_f = lag_frames(scene, fast, spread)
    if motion_per_frame(scene).max() == 0.0:
        return {"lag": None, "lag_note": "no geometry moves"}
    wanted = sorted(set(fast_f.tolist()) | set(spread_f.tolist()))
    truth = truth_for(wanted)
    rt = _compile(scene, lighting, stages, output, device, cache_dir, "lag")
    last = max(wanted)
    errors = {}
    for f in np.asarray(scene.frames, np.float64):
        if f > last:
            break
        out = rt.step(float(f))
        if float(f) in truth:
            ref = truth[float(f)]
            errors[float(f)] = error_metrics(out.numpy(), ref["radiance"], ref.get("stderr"))["rel_rms"]
    steps = list(rt.frame_s)[2:] or list(rt.frame_s)
    fast_e = float(np.mean([errors[float(f)] for f in fast_f]))
    mean_e = float(np.mean(list(errors.values())))
    return {"lag": fast_e / mean_e if mean_e > 0 else None, "lag_fast_error": fast_e, "lag_mean_error": mean_e,
            "lag_fast_frames": [float(f) for f in fast_f], "lag_frames": [float(f) for f in wanted],
            "lag_errors": [errors[float(f)] for f in wanted],
            "frame_ms": 1e3 * float(np.median(steps)), "diagnostics": rt.describe().get("diagnostics")}
