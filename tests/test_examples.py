"""The runnable examples (STYLE.md item 9) run headless with few frames and pass a NaN check.

Each example runs in a subprocess from a temporary folder with the checkout on ``PYTHONPATH``;
the test checks the exit status, that the USD layer and PNG previews exist, and that every
time-sampled point and colour of the layer is finite. Newton's kernels compile for about 90 s on
a CPU the first time (Warp caches them); later runs take seconds.

Usage errors (issue 39) are run in-process with the simulation replaced by one that fails the
test: each ends in exit status 2 and a message naming the flag before anything is simulated, and
a file in ``--out`` the example did not write is kept.
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


def test_newton_cloth_runs_headless(tmp_path):
    pytest.importorskip("newton", reason="the Newton example needs the [sim] extra")
    from pxr import Usd, UsdGeom

    frames, cells = 3, 4
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run(
        [sys.executable, str(ROOT / "examples" / "newton_cloth.py"), "--frames", str(frames), "--cells", str(cells),
         "--samples", "16", "--out", str(out), "--device", "cpu"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=HANG_S,
    )
    assert done.returncode == 0, f"examples/newton_cloth.py failed:\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    assert "per frame after it: simulation" in done.stdout, done.stdout
    assert sorted(p.name for p in out.glob("*.png")) == ["newton_cloth_0000.png", "newton_cloth_0001.png", "newton_cloth_0002.png"]
    # recorded in the folder's manifest, so that a rerun replaces them
    written = json.loads((out / ".warpshade-outputs.json").read_text())["written"]
    assert sorted(written) == sorted(p.name for p in out.iterdir() if not p.name.startswith("."))

    stage = Usd.Stage.Open(str(out / "newton_cloth.usda"))
    cloth = UsdGeom.Mesh(stage.GetPrimAtPath("/Shaded/World_Cloth"))
    colors = UsdGeom.PrimvarsAPI(cloth).GetPrimvar("displayColor")
    assert cloth.GetPointsAttr().GetTimeSamples() == list(range(frames))
    rest = np.asarray(cloth.GetPointsAttr().Get(0))
    assert rest.shape == ((cells + 1) ** 2, 3)
    for frame in range(frames):
        points = np.asarray(cloth.GetPointsAttr().Get(frame))
        rgb = np.asarray(colors.Get(frame))
        assert np.all(np.isfinite(points)) and np.all(np.isfinite(rgb)), f"frame {frame}: NaN or infinite values"
        assert rgb.shape == rest.shape and np.all(rgb >= 0.0)
    assert np.asarray(cloth.GetPointsAttr().Get(frames - 1))[:, 2].max() < rest[:, 2].max(), "the cloth falls"


# ---- usage errors: exit status 2, named by flag, before the simulation ----------------------------------
def _example(monkeypatch):
    """examples/newton_cloth.py as a module, its simulation replaced by one that fails the test."""
    spec = importlib.util.spec_from_file_location("newton_cloth_example", ROOT / "examples" / "newton_cloth.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)

    def simulate(*args, **kwargs):
        raise AssertionError("the simulation started")

    monkeypatch.setattr(module, "ClothSim", simulate)
    return module


@pytest.mark.parametrize("argv, message", [
    (["--frames", "0"], "argument --frames: must be >= 1, got 0"),
    (["--cells", "-2"], "argument --cells: must be >= 1, got -2"),
    (["--samples", "4"], "argument --samples: .*parameter 'samples' must be >= 16, got 4"),
    (["--device", "cuda:99"], "argument --device: .*cuda:99"),
    (["--device", "cuda:0"], "argument --device: .*cuda:0"),
])
def test_newton_cloth_usage_errors_exit_2_before_simulating(tmp_path, capsys, monkeypatch, argv, message):
    if argv == ["--device", "cuda:0"]:
        import warp as wp

        if wp.is_cuda_available():
            pytest.skip("this machine has CUDA")
    example = _example(monkeypatch)
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exited:
        example.main([*argv, "--out", str(out)])
    err = capsys.readouterr().err
    assert exited.value.code == 2 and re.search(rf": error: {message}", err), err
    assert not out.exists() or not list(out.iterdir())


def test_newton_cloth_refuses_an_out_onto_a_file(tmp_path, capsys, monkeypatch):
    example = _example(monkeypatch)
    a_file = tmp_path / "cloth.usda"
    a_file.write_text("a user's scene")
    with pytest.raises(SystemExit) as exited:
        example.main(["--out", str(a_file), "--device", "cpu"])
    err = capsys.readouterr().err
    assert exited.value.code == 2 and f"argument --out: {a_file} is an existing file, not a directory" in err, err
    assert a_file.read_text() == "a user's scene"


def test_newton_cloth_never_replaces_a_file_it_did_not_write(tmp_path, capsys, monkeypatch):
    """Its outputs are planned like the CLI's: a user's ``newton_cloth.usda`` (or a preview's
    name) in ``--out`` is named and kept, before the simulation."""
    example = _example(monkeypatch)
    out = tmp_path / "out"
    out.mkdir()
    (out / "newton_cloth.usda").write_text("a user's layer")
    (out / "newton_cloth_0001.png").write_bytes(b"a user's picture")
    with pytest.raises(SystemExit) as exited:
        example.main(["--out", str(out), "--frames", "3", "--device", "cpu"])
    err = capsys.readouterr().err
    assert exited.value.code == 2 and "argument --out: output directory" in err, err
    assert "already holds newton_cloth.usda, newton_cloth_0001.png" in err, err
    assert sorted(p.name for p in out.iterdir()) == ["newton_cloth.usda", "newton_cloth_0001.png"]
    assert (out / "newton_cloth.usda").read_text() == "a user's layer"
