"""The few-ray tracer's reuse settings chosen on the training frames (warpshade/measure/_tune.py),
and ``warpshade shade --training`` (the data-driven candidates on a clip of the same character).

The search rule on a synthetic error surface whose minimum is known (each step keeps the least
error, an option must win by the stated margin, a tie keeps the default, failed measurements never
win, the world-frame-only and warm-up-only steps are skipped where they do not apply); one real
search on the blockers; the training clip's frame selection and its refusals.
"""

import math

import pytest

from warpshade.measure._auto import candidates_for, shade_scene, training_selection, tuned_candidate
from warpshade.measure._tune import KEEP_MARGIN, STEPS, tune_trace


def _surface(best: dict, failing=()):
    """An evaluate() whose error grows with each parameter's distance from ``best``'s value."""
    defaults = {"reproject": False, "reset": "hard", "alpha": 0.1, "filter_iterations": 1, "warmup_frames": 0.0,
                "warmup_noise": 1.0}
    calls = []

    def evaluate(settings):
        calls.append(dict(settings))
        if any(settings.get(k) == v for k, v in failing):
            return {"status": "failed", "reason": "StageError: test", "rel_rms_debiased": math.nan, "frame_ms": math.nan}
        err = 0.05
        for k, want in best.items():
            got = settings.get(k, defaults[k])
            err += 0.01 * (abs(float(got) - float(want)) if not isinstance(want, str) else float(got != want))
        return {"status": "ok", "rel_rms_debiased": err, "frame_ms": 1.0}

    return evaluate, calls


def test_the_search_finds_a_separable_minimum():
    evaluate, calls = _surface({"alpha": 0.3, "filter_iterations": 3, "warmup_frames": 12.0, "warmup_noise": 0.33})
    got = tune_trace(lambda s: s, evaluate)
    assert got["settings"] == {"alpha": 0.3, "filter_iterations": 3, "warmup_frames": 12.0, "warmup_noise": 0.33}
    assert got["row"]["rel_rms_debiased"] == pytest.approx(0.05)
    assert len(calls) == len({str(sorted(c.items())) for c in calls}), "no setting is measured twice"
    assert len(calls) <= 1 + sum(len(o) - 1 for _, o in STEPS)
    kept = [t for t in got["tuning"] if t["kept"]]
    assert kept[-1]["settings"] == got["settings"]


def test_a_gain_within_the_margin_keeps_the_default():
    base = 0.05

    def evaluate(settings):  # alpha 0.5 is better by less than the margin, filter 2 by more
        err = base
        if settings.get("alpha") == 0.5:
            err -= 0.5 * KEEP_MARGIN * base
        if settings.get("filter_iterations") == 2:
            err -= 3 * KEEP_MARGIN * base
        return {"status": "ok", "rel_rms_debiased": err, "frame_ms": 1.0}

    got = tune_trace(lambda s: s, evaluate)
    assert got["settings"] == {"filter_iterations": 2}


def test_failed_measurements_never_win_and_unfit_steps_are_skipped():
    evaluate, calls = _surface({"alpha": 0.5}, failing=(("alpha", 0.5),))
    got = tune_trace(lambda s: s, evaluate, local=True)
    assert "alpha" not in got["settings"] or got["settings"]["alpha"] != 0.5
    assert not any("reproject" in c for c in calls), "the tangent frames skip the world-frame history step"
    assert not any("warmup_noise" in c for c in calls), "no warm-up noise without the history-aware filter"
    with pytest.raises(ValueError, match="margin"):
        tune_trace(lambda s: s, evaluate, margin=1.5)


def test_a_real_search_on_the_blockers(tmp_path, monkeypatch):
    """Two steps on the blockers' two training frames: the kept setting is the least error measured,
    and the candidate returned runs those settings."""
    monkeypatch.setenv("WARPSHADE_CACHE", str(tmp_path / "cache"))
    from warpshade.io import load_scene
    from warpshade.measure import ground_truth
    from warpshade.measure._auto import default_lighting, measure, split_frames

    scene = load_scene("bundled:blockers")
    lighting = default_lighting(scene)
    train, _, _ = split_frames(scene, quick=True)
    truth = ground_truth(scene, lighting, train, 64, "cpu")
    cand = next(c for c in candidates_for(scene, quick=True) if c.get("tune"))
    steps = (("alpha", ({}, {"alpha": 0.5})), ("filter", ({}, {"filter_iterations": 2})))
    got = tune_trace(lambda s: tuned_candidate(cand, s), lambda c: measure(scene, lighting, c, train, truth), steps=steps)
    errors = [t["rel_rms_debiased"] for t in got["tuning"]]
    assert all(math.isfinite(e) for e in errors) and len(errors) == 3
    assert got["row"]["rel_rms_debiased"] == min(errors) or got["settings"] == {}
    trace = next(p for (n, t, p, i) in got["candidate"]["stages"] if t == "hybrid.trace")
    assert all(trace[k] == v for k, v in got["settings"].items())
    assert got["candidate"]["facts"]["trace"] == got["settings"]


@pytest.mark.parametrize("count, want", [(600, "0:600:3"), (1000, "0:1000:5"), (50, "0:50:1"), (201, "0:201:2")])
def test_training_frames_are_at_most_the_stated_number(count, want):
    assert training_selection(count) == want


def test_a_training_clip_adds_the_data_driven_candidates():
    from warpshade.io import load_scene

    scene = load_scene("bundled:bend")
    plain = {c["method"] for c in candidates_for(scene)}
    with_clip = candidates_for(scene, training={"clip": "bundled:bend", "frames": "0:60:1"})
    methods = {c["method"] for c in with_clip}
    assert {"visibility", "datadriven"} <= methods - plain
    vis = [c for c in with_clip if c.get("tune") and c["tune"]["control"] == "visibility"]
    assert vis and all(c["tune"]["training"] == "bundled:bend" for c in vis)


@pytest.mark.parametrize("training, match", [("bundled:figure_train", "not the same character"),
                                             ("bundled:no_such_scene", "--training bundled:no_such_scene")])
def test_a_wrong_training_clip_is_refused_before_any_work(tmp_path, training, match):
    with pytest.raises(ValueError, match=match):
        shade_scene("bundled:bend", tmp_path / "out", training=training, log=lambda *_: None)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
