"""The runnable examples (STYLE.md item 9) run headless with few frames and pass a NaN check.

Each example runs in a subprocess from a temporary folder with the checkout on ``PYTHONPATH``;
the test checks the exit status, that the USD layer and PNG previews exist, and that every
time-sampled point and colour of the layer is finite. Newton's kernels compile for about 90 s on
a CPU the first time (Warp caches them); later runs take seconds.
"""

import os
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
