"""Every ready-made stage graph runs headless from the CLI path; the demo writes USD + PNG + JSON."""

import json
from pathlib import Path

import numpy as np
import pytest

from warpshade import cli
from warpshade.graph import load, stage_types
from warpshade.measure import write_usd
from warpshade.scene import Environment, LightingSource, SphereLight, up_rotation

from goldens import golden_mismatch, golden_path, write_golden

STAGES = sorted((Path(__file__).resolve().parent.parent / "stages").glob("*.toml"))
#: Environments of more texels than the bundled scenes' 64 x 128 sky are replaced by a small sky.
QUICK_SKY_TEXELS = 64 * 128


@pytest.fixture(autouse=True)
def _private_cache(tmp_path_factory, monkeypatch):
    # precompute artifacts of these runs go to a per-session cache, never the user's
    monkeypatch.setenv("WARPSHADE_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def test_stage_folder_is_not_empty():
    assert len(STAGES) >= 5


@pytest.mark.parametrize("graph_file", STAGES, ids=[p.stem for p in STAGES])
def test_stage_graph_runs(device, graph_file, tmp_path, update_goldens):
    spec = load(graph_file)
    types = stage_types()
    for st in spec.stages:
        # each stage type's quick settings (Stage.quick_params): the same stages, seconds instead of minutes
        st.params.update(types[st.type].quick_params(st.params))
    scene = spec.load_scene()
    lighting = None
    if any(types[st.type].quick_sky for st in spec.stages) or any(
            isinstance(light, Environment) and light.image.shape[0] * light.image.shape[1] > QUICK_SKY_TEXELS
            for light in scene.lights):
        # a prefiltered table over the scene's sky, or a large sky, takes minutes: a small procedural sky (plus
        # the scene's lamps, unless the graph takes distant lights only) runs the same stages
        lamps = [light for light in scene.lights if isinstance(light, SphereLight)]
        if (spec.lighting or {}).get("source") == "distant":
            lamps = []
        lighting = LightingSource.fixed([Environment.sky(height=16, width=32, to_world=up_rotation(scene.up_axis)), *lamps],
                                        scene.up_axis)
    rt = spec.compile(scene, device=device, progress=False, scheduler="serial", lighting=lighting)
    frames = rt.scene.frames[:2]
    rt.run(list(frames), warmup=False)
    for f in frames:
        out = rt.results[float(f)]
        assert out.shape == (rt.scene.vertex_count, 3)
        assert np.all(np.isfinite(out)), f"{graph_file.name}: NaN/inf radiance at frame {f}"
        assert out.min() >= -1e-3 * max(1.0, out.max()), f"{graph_file.name}: negative radiance"
    results = {float(f): rt.results[float(f)] for f in frames}
    if update_goldens or not golden_path(spec.name).exists():
        write_golden(spec.name, results)
        if not update_goldens:
            pytest.fail(f"{graph_file.name}: no golden output yet; wrote tests/golden/{spec.name}.npz (commit it)")
    else:
        problem = golden_mismatch(spec.name, results)
        assert problem is None, problem
    usd = write_usd(rt, tmp_path / f"{spec.name}.usda")
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(usd))
    # the meshes shaded per frame (time-sampled colours; a source preview mesh keeps its own constant colour)
    colored = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh) and UsdGeom.PrimvarsAPI(p).HasPrimvar("displayColor")
               and UsdGeom.PrimvarsAPI(p).GetPrimvar("displayColor").GetAttr().GetNumTimeSamples() > 0]
    assert len(colored) == len(rt.scene.meshes)


def test_demo_writes_usd_png_and_report(device, tmp_path, capsys):
    assert cli.main(["demo", "--device", device, "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "USD" in printed and "PNG" in printed and "report" in printed
    report = json.loads((tmp_path / "demo.json").read_text())
    assert report["error"]["mean"]["rel_rms"] < 0.5  # static PRT of a smooth sky: a sane error
    assert len(report["frames_run"]) == 24
    assert list(tmp_path.glob("demo_*.png"))
    assert list(tmp_path.glob("demo_*_vs_reference.png")), "a validated run pictures its error"
    assert (tmp_path / "demo.usda").exists()


def test_run_reports_bad_graph(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[graph]\nname = "bad"\noutput = "x.radiance"\nscene = "warp-example:bunny"\n'
                   '[[stage]]\nname = "x"\ntype = "prt.nonexistent"\n')
    assert cli.main(["run", str(bad)]) == 2
    assert "unknown stage type 'prt.nonexistent'" in capsys.readouterr().err


def test_list_stages(capsys):
    assert cli.main(["list-stages"]) == 0
    out = capsys.readouterr().out
    assert "demo.toml" in out and "prt.transfer" in out
