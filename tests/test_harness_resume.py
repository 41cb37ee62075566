"""The speed-vs-accuracy harness (``benchmarks/run.py``) without measuring: its chart's Pareto
front and labels, and ``--resume`` (scenes already in a results file are kept, not measured
again; a file of another device or not a results file is refused by name)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def harness():
    # the script imports its sibling module as ``python benchmarks/run.py`` finds it
    sibling = importlib.util.spec_from_file_location("_checkout", ROOT / "benchmarks" / "_checkout.py")
    checkout = importlib.util.module_from_spec(sibling)
    sibling.loader.exec_module(checkout)
    sys.modules.setdefault("_checkout", checkout)
    spec = importlib.util.spec_from_file_location("warpshade_harness", ROOT / "benchmarks" / "run.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _row(method, setting, ms, err, scene="bend", reference="diffuse"):
    return {"scene": scene, "device": "cpu", "method": method, "setting": setting, "params": [], "notes": "",
            "median_frame_ms": ms, "median_host_ms": 0.0, "stage_ms": {}, "uncaptured": [], "precompute_s": 0.5,
            "compile_and_setup_s": 0.1, "model_bytes": 1024, "frames_timed": 12, "reference": reference,
            "error": {"rel_rms": err, "rel_p99": 2 * err, "noise_rel_rms": 0.01, "rel_rms_debiased": err},
            "error_per_frame": [], "vertex_count": 792}


def test_front_is_the_lower_left_envelope(harness):
    pts = [(1.0, 0.5), (2.0, 0.3), (3.0, 0.4), (0.5, 0.9), (10.0, 0.1)]
    assert harness._front(pts) == [(0.5, 0.9), (1.0, 0.5), (2.0, 0.3), (10.0, 0.1)]


def test_labels_are_the_front_each_methods_best_and_the_tracer(harness):
    rows = [_row("prt", "n2", 0.05, 0.30), _row("prt", "n6", 0.3, 0.08), _row("prt", "n4", 0.25, 0.35),
            _row("shexp", "n4", 5.0, 0.15), _row("shexp", "n6", 20.0, 0.09),
            _row("traced", "n4 s256", 100.0, 0.05),
            _row("prt", "n6 s64", 0.31, 0.081)]  # on top of prt n6: its label would overlap
    labelled = {(r["method"], r["setting"]) for r in harness._labelled(rows)}
    assert {("prt", "n2"), ("prt", "n6"), ("traced", "n4 s256"), ("shexp", "n6")} <= labelled
    assert ("prt", "n4") not in labelled and ("shexp", "n4") not in labelled  # neither on the front nor a best
    assert not {("prt", "n6"), ("prt", "n6 s64")} <= labelled  # overlapping labels: one is drawn


def test_resume_keeps_finished_scenes_and_redraws(harness, tmp_path):
    earlier = tmp_path / "2026-12-01-cpu.json"
    meta = {"date": "2026-12-01", "device": "cpu", "machine": "x", "warp": "1", "gt_samples": 2048, "timing_frames": 12,
            "quick": False, "command": "python benchmarks/run.py", "seconds": 12.0}
    earlier.write_text(json.dumps({"meta": meta, "results": [_row("prt", "n2", 0.05, 0.3), _row("traced", "s64", 9.0, 0.1)]}))
    assert harness.main(["--scenes", "bend", "--device", "cpu", "--resume", str(earlier)]) == 0
    data = json.loads(earlier.read_text())
    assert len(data["results"]) == 2 and data["meta"]["scenes_done"] == ["bend"]
    assert data["meta"]["date"] == "2026-12-01" and data["meta"]["seconds"] >= 12.0
    assert data["meta"]["resumed_by"] and "--resume" in data["meta"]["resumed_by"][0]
    assert (tmp_path / "2026-12-01-cpu-pareto.png").stat().st_size > 0 and (tmp_path / "2026-12-01-cpu.md").exists()
    assert (tmp_path / "latest-cpu.json").exists()  # another --out directory keeps its own latest-*


def test_resume_refuses_what_it_cannot_go_on_with(harness, tmp_path, capsys):
    bad = tmp_path / "notes.json"
    bad.write_text("{}")
    with pytest.raises(SystemExit):
        harness.main(["--scenes", "bend", "--device", "cpu", "--resume", str(bad)])
    assert "notes.json" in capsys.readouterr().err
    other = tmp_path / "2026-12-01-cuda0.json"
    other.write_text(json.dumps({"meta": {"device": "cuda:0"}, "results": []}))
    with pytest.raises(SystemExit):
        harness.main(["--scenes", "bend", "--device", "cpu", "--resume", str(other)])
    assert "cuda:0" in capsys.readouterr().err
