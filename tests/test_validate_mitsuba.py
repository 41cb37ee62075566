"""Runs benchmarks/validate_mitsuba.py --quick when Mitsuba 3 is installed (the `validate` extra)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("mitsuba", reason="Mitsuba 3 not installed (pip install -e '.[validate]')")

ROOT = Path(__file__).resolve().parents[1]
# Shadow rays that may disagree between our float32 watertight test and Embree: only rays that
# hit a triangle edge/vertex, graze a plane or start on a surface; the quick run traces ~2e4 rays.
MAX_RAY_DISAGREEMENT = 1e-3
# Image: the relative RMS difference must be explained by the two Monte Carlo estimators' noise
# (64 samples per sub-pixel for ours, 2 x 64 spp for Mitsuba at 64 x 48): at most 1.3x the
# noise-only expectation plus 0.01 for pixel-filter differences along shading discontinuities.
NOISE_FACTOR = 1.3
FILTER_SLACK = 0.01
# Mean over all compared pixels: a bias in either estimator would show here first.
MAX_MEAN_DIFFERENCE = 0.01
# Mitsuba's envmap must reproduce our lat-long lookup to float32 precision.
MAX_ENVMAP_MAPPING_ERROR = 1e-4


def test_quick_validation_agrees_with_mitsuba(tmp_path):
    run = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "validate_mitsuba.py"), "--quick", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=600, cwd=ROOT,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    reports = list(tmp_path.glob("mitsuba-*-quick.json"))
    assert len(reports) == 1 and list(tmp_path.glob("mitsuba-*-quick.png"))
    report = json.loads(reports[0].read_text())
    vis = report["visibility"]
    assert vis["fraction_disagreeing"] <= MAX_RAY_DISAGREEMENT
    assert vis["disagreement_kinds"]["unexplained"] == 0
    img = report["image"]
    assert img["envmap_mapping_max_relative_error"] < MAX_ENVMAP_MAPPING_ERROR
    assert img["relative_rms"] < NOISE_FACTOR * img["relative_rms_expected_from_noise"] + FILTER_SLACK
    assert abs(img["relative_mean_difference"]) < MAX_MEAN_DIFFERENCE
