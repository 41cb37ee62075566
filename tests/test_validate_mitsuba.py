"""Runs benchmarks/validate_mitsuba.py --quick when Mitsuba 3 is installed (the `validate` extra)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hang import HANG_S

from warpshade.io import bundled_asset_directory

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
        capture_output=True, text=True, timeout=HANG_S, cwd=ROOT,
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


# ---- the glossy per-pixel reference (validate_mitsuba.py --glossy) ---------------------------------
# Our Microfacet(f0=1) and Mitsuba's roughconductor(material="none") are the same function: their
# evaluations differ by float32 rounding only (measured: at most 2.3e-6 relative where the value
# exceeds 1e-3 of its maximum, over alpha 0.12..0.45).
GLOSSY_BSDF_RTOL = 1e-5
# Whole image (64 x 48, 2 x 2 rays per pixel, 64 samples; 2 x 64 spp): the noise explains the
# difference except at edges (silhouettes, hard point-light shadows, where our fixed sub-pixel
# grid and Mitsuba's random box-filter positions integrate a pixel differently; measured with the
# point light: 0.020 against a noise of 0.0085 at this resolution, shrinking with the supersampling).
GLOSSY_EDGE_SLACK = 0.03
# Away from edges the difference must be the noise alone (measured: 0.0020 against 0.0012 with
# the point light, 0.056 against 0.055 under the environment): 1.3x plus 0.002 for the lobe's
# average over the sphere light's cone (radius 1 % of its distance) vs Mitsuba's point.
GLOSSY_CONE_SLACK = 0.002
# Mean over the compared pixels (measured: at most 0.003).
GLOSSY_MAX_MEAN_DIFFERENCE = 0.01


def test_quick_glossy_validation_agrees_with_mitsuba(tmp_path):
    run = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "validate_mitsuba.py"), "--quick", "--glossy", "beckmann", "ggx",
         "--point-light", "--scene", str(Path(bundled_asset_directory()) / "blockers.usda"), "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=HANG_S, cwd=ROOT,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    reports = list(tmp_path.glob("mitsuba-glossy-*-quick.json"))
    assert len(reports) == 1
    report = json.loads(reports[0].read_text())
    for distribution in ("beckmann", "ggx"):
        for check in report["bsdf_isolation"][distribution].values():
            assert check["max_relative_difference_where_significant"] < GLOSSY_BSDF_RTOL
    cases = report["cases"]
    assert sorted((c["distribution"], c["light"]) for c in cases) == [
        ("beckmann", "environment"), ("beckmann", "point"), ("ggx", "environment"), ("ggx", "point")]
    for case in cases:
        assert (tmp_path / case["png"]).exists()
        assert case["pixels_compared"] > 500
        assert case["relative_rms"] < NOISE_FACTOR * case["relative_rms_expected_from_noise"] + GLOSSY_EDGE_SLACK, case
        smooth = case["away_from_edges"]
        assert smooth["relative_rms"] < NOISE_FACTOR * smooth["relative_rms_expected_from_noise"] + GLOSSY_CONE_SLACK, case
        assert abs(case["relative_mean_difference"]) < GLOSSY_MAX_MEAN_DIFFERENCE, case


# ---- the anisotropic per-pixel reference (validate_mitsuba_aniso.py) ------------------------------
# Our AnisotropicMicrofacet(f0=1) and Mitsuba's anisotropic roughconductor (beckmann, material none)
# are the same function in the same tangent frame (measured: 2.4e-6 relative where significant).
ANISO_BSDF_RTOL = 1e-5
# The ground's pixels (a plane: both tangents are the exact dp/du) under the sky and the point
# light: within the noise, plus the point light's hard shadow and highlight edges at this tiny
# resolution (48 x 36, 1 ray per pixel; measured 0.103 against a noise of 0.096 under the sky,
# 0.126 against 0.036 with the point light; at 160 x 120 x 4 rays: 0.029 against 0.030, 0.023
# against 0.006, and 0.0009 against 0.0002 away from edges).
ANISO_EDGE_SLACK = 0.12
# Mean over the compared pixels (measured quick: +0.007, -0.016).
ANISO_MAX_MEAN_DIFFERENCE = 0.04


def test_quick_anisotropic_validation_agrees_with_mitsuba(tmp_path):
    run = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "validate_mitsuba_aniso.py"), "--quick", "--point-light",
         "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=HANG_S, cwd=ROOT,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    report = json.loads(next(tmp_path.glob("mitsuba-aniso-*-quick.json")).read_text())
    assert report["bsdf_isolation"]["max_relative_difference_where_significant"] < ANISO_BSDF_RTOL
    assert sorted(c["light"] for c in report["cases"]) == ["environment", "point"]
    for case in report["cases"]:
        ground = case["ground_only"]
        assert ground["pixels_compared"] > 200, case
        assert ground["relative_rms"] < NOISE_FACTOR * ground["relative_rms_expected_from_noise"] + ANISO_EDGE_SLACK, case
        assert abs(case["relative_mean_difference"]) < ANISO_MAX_MEAN_DIFFERENCE, case
