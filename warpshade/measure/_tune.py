"""The few-ray tracer's reuse settings chosen on the scene's own training frames (``warpshade shade``).

``hybrid.trace`` reuses its rays over frames and mesh neighbours; how far is a trade between noise
and lag that depends on the scene (how fast it moves, how smooth its shadows are) and on the
control (how much residual it leaves). Those settings are not read from a per-scene table: they
are chosen by measuring, on the training frames only, the same way the chooser measures every
candidate (:func:`warpshade.measure._auto.measure`: the candidate stepped through the frames before
each training frame, its radiance against ray-traced ground truth with the reference's noise
removed). The held-out frames the graph is validated on play no part.

**The rule** (:func:`tune_trace`): a coordinate search over :data:`STEPS`, in order, from the
stage's defaults. Each step tries its options with the settings kept so far and keeps the one of
least training error; an option replaces the incumbent only when it lowers the error by more than
:data:`KEEP_MARGIN` of it, so that noise in the measurement does not pick a setting, and a tie
keeps the simpler (earlier) option. The steps:

1. ``history``: reproject the history by the surface's turn and cut it on motion only (a turning
   surface keeps its history), or cut it where a normal turns (the default); world frame only;
2. ``reset``: fade the history where the fresh frame disagrees with it (hard) or blend by the
   bias estimated over 4 frames (soft);
3. ``alpha``: the least weight of a new frame, 0.1 to 0.5 (how long the history is);
4. ``filter``: passes of the edge-aware filter over mesh neighbours, 1 to 4;
5. ``warmup``: the history-aware filter where a vertex's history is short (off, 12 or 24 frames);
6. ``warmup_noise`` (with the history-aware filter on): the history's actual variance as a fraction
   of the tracked one (1, 0.33, 0.1), which sets how far that filter may go.

At most 1 + 12 measurements per candidate. The search's every measurement is kept in the report
(``tuning``), so a user sees what each setting cost on their scene.
"""

from __future__ import annotations

import json
import math

__all__ = ["KEEP_MARGIN", "STEPS", "tune_trace"]

#: An option is kept only when it lowers the training error by more than this fraction.
KEEP_MARGIN = 0.01
#: The coordinate search: (step, options), each option a change of ``hybrid.trace`` parameters
#: (the empty change: the stage's default).
STEPS = (
    ("history", ({}, {"reproject": True, "normal_turn": 180.0, "motion": 4.0})),
    ("reset", ({}, {"reset": "soft", "threshold": 8.0, "bias_frames": 4})),
    ("alpha", ({}, {"alpha": 0.2}, {"alpha": 0.3}, {"alpha": 0.5})),
    ("filter", ({}, {"filter_iterations": 2}, {"filter_iterations": 3}, {"filter_iterations": 4})),
    ("warmup", ({}, {"warmup_frames": 12.0}, {"warmup_frames": 24.0})),
    ("warmup_noise", ({}, {"warmup_noise": 0.33}, {"warmup_noise": 0.1})),
)
#: Steps that apply to the world frame only (the tangent frames turn with the surface already).
WORLD_ONLY = ("history",)
#: Steps that apply only with the history-aware filter on (the stage refuses them otherwise).
NEEDS_WARMUP = ("warmup_noise",)


def _key(settings: dict) -> str:
    return json.dumps(settings, sort_keys=True)


def _error(row: dict) -> float:
    e = row.get("rel_rms_debiased", math.nan) if row.get("status") == "ok" else math.nan
    return float(e) if e is not None and math.isfinite(e) else math.inf


def tune_trace(build, evaluate, *, local: bool = False, steps=None, margin: float = KEEP_MARGIN, log=None) -> dict:
    """Choose ``hybrid.trace`` reuse settings by the rule above.

    Args:
        build: ``build(settings) -> candidate``: the candidate graph with ``settings`` (a dict of
            ``hybrid.trace`` parameters) applied.
        evaluate: ``evaluate(candidate) -> row``: a measured row (``status``, ``rel_rms_debiased``,
            ``frame_ms``) on the training frames.
        local: the trace runs in the tangent frames (the world-frame-only steps are skipped).
        steps: the search (None: :data:`STEPS`).
        margin: :data:`KEEP_MARGIN`.
        log: a callable printing one line per measurement, or None.

    Returns:
        ``{"settings", "row", "candidate", "tuning"}``: the chosen settings, their measured row and
        candidate, and every measurement (``step``, ``settings``, ``rel_rms_debiased``,
        ``frame_ms``, ``kept``).
    """
    if not 0.0 <= margin < 1.0:
        raise ValueError(f"tune_trace: margin must be in [0, 1), got {margin!r}")
    steps = STEPS if steps is None else steps
    seen: dict[str, dict] = {}
    tuning = []

    def run(step, settings):
        k = _key(settings)
        if k not in seen:
            cand = build(dict(settings))
            row = evaluate(cand)
            seen[k] = {"row": row, "candidate": cand}
            tuning.append({"step": step, "settings": dict(settings), "status": row.get("status"),
                           "rel_rms_debiased": row.get("rel_rms_debiased"), "frame_ms": row.get("frame_ms"),
                           "kept": False})
            if log is not None:
                state = (f"error {row['rel_rms_debiased']:.4f}  {row['frame_ms']:8.2f} ms/frame" if row.get("status") == "ok"
                         else f"failed: {str(row.get('reason', ''))[:80]}")
                log(f"    tune {step:12s} {_key(settings)[:70]:70s} {state}")
        return seen[k]

    settings: dict = {}
    best = run("start", settings)
    tuning[-1]["kept"] = True
    for step, options in steps:
        if local and step in WORLD_ONLY:
            continue
        if step in NEEDS_WARMUP and not settings.get("warmup_frames"):
            continue
        incumbent, incumbent_settings = best, settings
        for option in options:
            if not option:  # the step's default: the settings kept so far, measured already
                continue
            trial = {**settings, **option}
            got = run(step, trial)
            if _error(got["row"]) < _error(incumbent["row"]) * (1.0 - margin):
                incumbent, incumbent_settings = got, trial
        if incumbent is not best:
            best, settings = incumbent, incumbent_settings
            for t in tuning:
                if _key(t["settings"]) == _key(settings):
                    t["kept"] = True
    return {"settings": settings, "row": best["row"], "candidate": best["candidate"], "tuning": tuning}
