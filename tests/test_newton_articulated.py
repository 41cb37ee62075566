"""examples/newton_articulated.py: a Newton articulated body of implicit shapes, shaded live.

The example runs headless in a subprocess, small (15 frames -- the ant drops and lands --, 8
segments per circle, 16 rays per vertex, one frame measured with 64 ground-truth rays; about 10 s
on two CPU cores once Newton's kernels are cached). The test reads what it wrote: the USD layer's
points and colours are finite, the body falls *and* bends (its shapes do not move as one rigid
piece), the ground under the body is darker than the ground far from it (a shadow), and the JSON
report has the time per frame and an error against ray tracing. Usage errors run in-process with
the simulation replaced by one that fails the test: each ends in exit status 2 naming the flag.
"""

import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hang import HANG_S

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "newton_articulated.py"
FRAMES = 15  # 0.5 s: the ant, dropped from 1 m, is on the ground from frame 10
LUMA = np.array([0.2126, 0.7152, 0.0722])
#: Ground within this distance (m, horizontally) of the body's centre is "under" it (the ant's
#: torso is a sphere of radius 0.25), and beyond FAR_M "far" (its legs reach about 0.8 m).
UNDER_M, FAR_M = 0.3, 2.0
#: Under the landed ant the ground gets at most this fraction of the far ground's luminance (0.53
#: measured at these settings; an unshadowed ground would be 1 up to the 16-ray noise, ~0.05 here).
SHADOW_RATIO = 0.75
#: The body bends: after the best rigid fit of the last frame's points onto the first's, the RMS
#: residual is above this (m); the legs' swing gives ~0.1 m, one rigid piece gives float noise.
BEND_M = 0.02
#: Relative RMS error against ray tracing with the reference's noise removed: 0.08 measured at
#: these settings (order-3 SH smooths the contact shadows); twice that is a real regression.
ERROR_DEBIASED = 0.16


def _rigid_residual(a: np.ndarray, b: np.ndarray) -> float:
    """RMS distance (m) between ``b`` and the best rotation + translation of ``a`` onto it (Kabsch)."""
    ca, cb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(u @ vt))
    rot = u @ np.diag([1.0, 1.0, d]) @ vt
    return float(np.sqrt(np.mean(np.sum(((a - ca) @ rot + cb - b) ** 2, axis=1))))


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    pytest.importorskip("newton", reason="the Newton example needs the [sim] extra")
    tmp = tmp_path_factory.mktemp("articulated")
    out = tmp / "out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run(
        [sys.executable, str(EXAMPLE), "--frames", str(FRAMES), "--segments", "8", "--samples", "16",
         "--truth-samples", "64", "--measure", "1", "--out", str(out), "--device", "cpu"],
        cwd=tmp, env=env, capture_output=True, text=True, timeout=HANG_S,
    )
    assert done.returncode == 0, f"examples/newton_articulated.py failed:\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    return out, done


def test_outputs_are_written_and_recorded(small_run):
    out, done = small_run
    assert "per frame after it: simulation" in done.stdout, done.stdout
    last = f"{FRAMES - 1:04d}"
    assert sorted(p.name for p in out.glob("*.png")) == sorted(
        ["newton_articulated_0000.png", f"newton_articulated_{FRAMES // 2:04d}.png", f"newton_articulated_{last}.png",
         f"newton_articulated_{last}_vs_reference.png"])
    assert all(p.stat().st_size > 1000 for p in out.glob("*.png"))
    # recorded in the folder's manifest, so that a rerun replaces them
    written = json.loads((out / ".warpshade-outputs.json").read_text())["written"]
    assert sorted(written) == sorted(p.name for p in out.iterdir() if not p.name.startswith("."))


def _layer(out):
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(out / "newton_articulated.usda"))
    body = UsdGeom.Mesh(stage.GetPrimAtPath("/Shaded/World_Body"))
    ground = UsdGeom.Mesh(stage.GetPrimAtPath("/Shaded/World_Ground"))
    assert body and ground, [str(p.GetPath()) for p in stage.Traverse()]
    return stage, body, ground, UsdGeom.PrimvarsAPI


def test_the_body_falls_and_bends_with_finite_radiance(small_run):
    out, _ = small_run
    _stage, body, ground, primvars = _layer(out)  # the stage keeps its prims valid
    assert body.GetPointsAttr().GetTimeSamples() == list(range(FRAMES))
    points = [np.asarray(body.GetPointsAttr().Get(f), np.float64) for f in range(FRAMES)]
    for f in range(FRAMES):
        for mesh in (body, ground):
            rgb = np.asarray(primvars(mesh).GetPrimvar("displayColor").Get(f))
            assert np.all(np.isfinite(rgb)) and np.all(rgb >= 0.0), f"frame {f}: NaN, infinite or negative radiance"
            assert rgb.max() > 0.0, f"frame {f}: black"
        assert np.all(np.isfinite(points[f])) and points[f].shape == points[0].shape
    assert np.any(np.abs(points[1] - points[0]) > 1e-4), "the body does not move between consecutive frames"
    drop = points[0][:, 2].mean() - points[-1][:, 2].mean()
    assert drop > 0.3, f"the body, dropped from 1 m, falls only {drop:.3f} m"
    assert points[-1][:, 2].min() > -0.05, "the body sinks through the ground"
    bend = _rigid_residual(points[0], points[-1])
    assert bend > BEND_M, f"the shapes move as one rigid piece (residual {bend:.4f} m): the joints do not move"


def test_the_body_shadows_the_ground_under_it(small_run):
    out, _ = small_run
    _stage, body, ground, primvars = _layer(out)  # the stage keeps its prims valid
    last = FRAMES - 1
    centre = np.asarray(body.GetPointsAttr().Get(last), np.float64).mean(0)
    ground_xy = np.asarray(ground.GetPointsAttr().Get(last), np.float64)[:, :2]
    lum = np.asarray(primvars(ground).GetPrimvar("displayColor").Get(last), np.float64) @ LUMA
    dist = np.linalg.norm(ground_xy - centre[:2], axis=1)
    under, far = lum[dist < UNDER_M], lum[dist > FAR_M]
    assert under.size >= 10 and far.size >= 100, (under.size, far.size)
    ratio = under.mean() / far.mean()
    assert ratio < SHADOW_RATIO, f"no shadow under the body: the ground there is {ratio:.2f} of the far ground"


def test_the_report_has_time_per_frame_and_error(small_run):
    out, _ = small_run
    report = json.loads((out / "newton_articulated.json").read_text())
    assert report["robot"] == "ant" and report["device"] == "cpu" and report["frames"] == FRAMES
    assert report["shapes"] == ["12 CAPSULE", "1 SPHERE"], report["shapes"]
    timing = report["ms_per_frame"]
    assert timing["frames_timed"] == FRAMES - 1
    assert all(np.isfinite(timing[k]) and timing[k] > 0 for k in ("simulation", "shading", "total"))
    (frame,) = report["error"]["per_frame"]
    assert frame["frame"] == FRAMES - 1
    assert all(np.isfinite(frame[k]) and frame[k] >= 0 for k in ("rel_rms", "rel_rms_debiased", "noise_rel_rms"))
    assert frame["rel_rms_debiased"] < ERROR_DEBIASED, frame


# ---- usage errors: exit status 2, named by flag, before the simulation ----------------------------------
def _example(monkeypatch):
    """examples/newton_articulated.py as a module, its simulation replaced by one that fails the test."""
    spec = importlib.util.spec_from_file_location("newton_articulated_example", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)

    def simulate(*args, **kwargs):
        raise AssertionError("the simulation started")

    monkeypatch.setattr(module, "ArticulatedSim", simulate)
    return module


@pytest.mark.parametrize("argv, message", [
    (["--frames", "0"], "argument --frames: must be >= 1, got 0"),
    (["--segments", "2"], "argument --segments: must be >= 3, got 2"),
    (["--measure", "4"], "argument --measure: must be 0 to 3 .*got 4"),
    (["--truth-samples", "8"], "argument --truth-samples: must be >= 16, got 8"),
    (["--samples", "4"], "argument --samples: .*parameter 'samples' must be >= 16, got 4"),
    (["--robot", "cheetah"], "argument --robot: invalid choice: 'cheetah'"),
    (["--device", "cuda:99"], "argument --device: .*cuda:99"),
])
def test_usage_errors_exit_2_before_simulating(tmp_path, capsys, monkeypatch, argv, message):
    example = _example(monkeypatch)
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exited:
        example.main([*argv, "--out", str(out)])
    err = capsys.readouterr().err
    assert exited.value.code == 2 and re.search(rf": error: {message}", err), err
    assert not out.exists() or not list(out.iterdir())


def test_never_replaces_a_file_it_did_not_write(tmp_path, capsys, monkeypatch):
    example = _example(monkeypatch)
    out = tmp_path / "out"
    out.mkdir()
    (out / "newton_articulated.json").write_text("a user's notes")
    with pytest.raises(SystemExit) as exited:
        example.main(["--out", str(out), "--frames", "3", "--device", "cpu"])
    err = capsys.readouterr().err
    assert exited.value.code == 2 and "argument --out: output directory" in err, err
    assert "newton_articulated.json" in err, err
    assert (out / "newton_articulated.json").read_text() == "a user's notes"


def test_every_newton_shape_kind_tessellates_in_its_frame():
    """The shapes as Newton defines them: a capsule's radius and half height along local Z, a box's
    half extents; the tessellation's bounds are the analytic ones."""
    newton = pytest.importorskip("newton", reason="the shapes are Newton's")
    spec = importlib.util.spec_from_file_location("newton_articulated_example", EXAMPLE)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    cases = {
        newton.GeoType.SPHERE: ((0.3, 0.0, 0.0), (0.3, 0.3, 0.3)),
        newton.GeoType.CAPSULE: ((0.1, 0.4, 0.0), (0.1, 0.1, 0.5)),
        newton.GeoType.CYLINDER: ((0.2, 0.3, 0.0), (0.2, 0.2, 0.3)),
        newton.GeoType.CONE: ((0.2, 0.3, 0.0), (0.2, 0.2, 0.3)),
        newton.GeoType.BOX: ((0.1, 0.2, 0.3), (0.1, 0.2, 0.3)),
        newton.GeoType.ELLIPSOID: ((0.1, 0.2, 0.3), (0.1, 0.2, 0.3)),
    }
    for geo, (scale, half_extent) in cases.items():
        points, faces = example.shape_mesh(int(geo), scale, 32)
        assert faces.max() < len(points) and len(faces) > 0
        # 32 segments: the polygon's flats lie within 0.5 % of the radius inside the circle
        np.testing.assert_allclose(points.max(0), half_extent, rtol=6e-3, err_msg=str(geo))
        np.testing.assert_allclose(-points.min(0), half_extent, rtol=6e-3, err_msg=str(geo))
    assert example.shape_mesh(int(newton.GeoType.PLANE), (0.0, 0.0, 0.0), 32) is None
