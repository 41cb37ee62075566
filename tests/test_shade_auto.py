"""`warpshade shade`: the choice of a method for a user's scene (warpshade/measure/_auto.py).

The rule of the choice on measured rows (cheapest meeting a target, most accurate within a
budget, the nearest when nothing qualifies, every candidate's verdict), the split of the frames
into training and held-out ones, the graph file it writes (read back by the graph loader), and
the whole command on a small animated scene and a static one written here.
"""

import json
import math

import numpy as np
import pytest

from warpshade.graph import load
from warpshade.measure._auto import CHOICE_FRAMES, QUICK_CHOICE_FRAMES, TIMING_PASSES, choose, graph_toml, shade_scene, split_frames


def _row(label, err, ms, status="ok"):
    return {"method": label.split()[0], "label": label, "facts": {}, "baseline": False, "status": status,
            "reason": "" if status == "ok" else "StageError: no closed mesh", "rel_rms": err, "rel_rms_debiased": err,
            "frame_ms": ms}


def _rows():
    return [_row("trace K256", 0.03, 90.0), _row("hybrid K16", 0.08, 9.0), _row("hybrid K64", 0.05, 30.0),
            _row("unshadowed n3", 0.2, 0.1), _row("shexp n4", math.nan, math.nan, status="failed")]


def test_a_target_takes_the_cheapest_that_meets_it():
    rows = _rows()
    chosen, met, why = choose(rows, target_error=0.06)
    assert chosen["label"] == "hybrid K64" and met and "cheapest" in why
    verdicts = {r["label"]: r["verdict"] for r in rows}
    assert verdicts["trace K256"].startswith("meets the target but costs 90.00 ms")
    assert verdicts["hybrid K16"].startswith("error 0.0800 above the target")
    assert verdicts["shexp n4"].startswith("could not run: StageError")


def test_a_budget_takes_the_most_accurate_within_it():
    rows = _rows()
    chosen, met, _ = choose(rows, budget_ms=40.0)
    assert chosen["label"] == "hybrid K64" and met
    chosen, met, _ = choose(_rows(), target_error=0.06, budget_ms=20.0)  # nothing meets both: the nearest within the budget
    assert not met and chosen["label"] == "hybrid K16"


def test_nothing_meeting_the_request_gives_the_nearest_and_says_so():
    chosen, met, why = choose(_rows(), target_error=0.01)
    assert not met and chosen["label"] == "trace K256" and "no candidate meets" in why
    chosen, met, why = choose(_rows(), budget_ms=0.01)
    assert not met and chosen["label"] == "unshadowed n3" and "fastest" in why
    chosen, met, why = choose([_row("shexp n4", math.nan, math.nan, status="failed")], target_error=0.1)
    assert chosen is None and not met and "no candidate could run" in why


class _Frames:
    def __init__(self, n):
        self.frames = np.arange(n, dtype=np.float64)


@pytest.mark.parametrize("quick", [False, True])
@pytest.mark.parametrize("count", [1, 2, 3, 6, 10, 60])
def test_training_and_held_out_frames_are_apart(count, quick):
    per_set = QUICK_CHOICE_FRAMES if quick else CHOICE_FRAMES
    train, held, note = split_frames(_Frames(count), quick=quick)
    if count >= 2 * per_set:
        assert train.size == held.size == per_set
    assert train.size >= 1 and held.size >= 1
    if count == 1:
        assert "same frame" in note
    elif count >= 2:
        assert not set(train) & set(held)
    if count >= 2 * per_set + 2:  # the first and last frames are left out, the sets interleave
        assert 0.0 not in train and float(count - 1) not in held
        assert np.all(np.sort(np.r_[train, held])[::2] == np.sort(train))


def test_the_written_graph_reads_back(tmp_path):
    stages = [("trace", "hybrid.trace", {"order": 6, "samples": 16, "control": "previous"}, {}),
              ("shade", "prt.shade", {"order": 6}, {"transfer": "trace.transfer"})]
    path = tmp_path / "g.toml"
    path.write_text(graph_toml("g", 'a "quoted" description', "bundled:blockers", stages, [24.0, 47.0], 512))
    spec = load(path)
    assert [(s.name, s.type, s.params, s.inputs) for s in spec.stages] == [tuple(s) for s in stages]
    assert spec.scene == "bundled:blockers" and spec.name == "g"
    assert list(spec.validate_spec["frames"]) == [24, 47] and spec.validate_spec["samples"] == 512


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("WARPSHADE_CACHE", str(tmp_path / "cache"))


def test_shade_chooses_writes_and_validates_on_held_out_frames(tmp_path, cache):
    out = tmp_path / "out"
    lines = []
    report = shade_scene("bundled:blockers", out, target_error=0.1, quick=True, choice_samples=128, validate_samples=128,
                         log=lines.append)
    assert report["scene"]["kind"] == "rigid"
    assert not set(report["training_frames"]) & set(report["held_out_frames"])
    ran = [r for r in report["candidates"] if r["status"] == "ok"]
    assert any(r["baseline"] for r in ran), "the per-frame ray tracer is measured as the baseline"
    assert all(r["verdict"] for r in report["candidates"])
    for r in ran:  # time per frame: the lowest median of the timing passes (cheap candidates get them all)
        assert 1 <= len(r["frame_ms_passes"]) <= TIMING_PASSES and r["frame_ms"] == min(r["frame_ms_passes"])
    assert any(len(r["frame_ms_passes"]) == TIMING_PASSES for r in ran)
    chosen = report["chosen"]
    assert chosen is not None and np.isfinite(report["held_out"]["rel_rms_debiased"])
    assert report["held_out"]["frame_ms"] > 0
    spec = load(chosen["graph"])  # the chosen graph, runnable with `warpshade run`
    assert [float(f) for f in spec.validate_spec["frames"]] == report["held_out_frames"]
    assert json.loads((out / "blockers_auto_choice.json").read_text())["chosen"]["label"] == chosen["label"]
    assert (out / "blockers_auto_choice.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert any(line.startswith("held out error") for line in lines)


def _static_usd(path, sphere_light=False):
    """A sphere on a ground plane, no animation, no time codes, no camera (Y up); with ``sphere_light``, lit by one sphere light alone."""
    import trimesh
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    ground = trimesh.creation.box(extents=(4.0, 0.05, 4.0))
    for name, m, offset in (("Ball", ball, (0.0, 0.55, 0.0)), ("Ground", ground, (0.0, -0.025, 0.0))):
        mesh = UsdGeom.Mesh.Define(stage, f"/World/{name}")
        mesh.CreatePointsAttr([tuple(p) for p in (m.vertices + np.asarray(offset)).tolist()])
        mesh.CreateFaceVertexCountsAttr([3] * len(m.faces))
        mesh.CreateFaceVertexIndicesAttr(m.faces.ravel().tolist())
    if sphere_light:
        from pxr import UsdLux

        lamp = UsdLux.SphereLight.Define(stage, "/World/Lamp")
        lamp.CreateRadiusAttr(0.5)
        lamp.CreateIntensityAttr(20.0)
        UsdGeom.Xformable(lamp.GetPrim()).AddTranslateOp().Set((0.4, 1.4, 0.3))
    stage.GetRootLayer().Save()
    return path


def test_a_scene_lit_by_sphere_lights_alone_is_measured_under_a_sky_and_says_so(tmp_path, cache):
    """The diffuse methods shade distant lighting (SH): a scene whose only light is a sphere light
    is measured (and its graph written) under the distant lights -- a sky here -- with the left-out
    light named, not compared black against a reference lit by the lamp."""
    scene = _static_usd(tmp_path / "lamp.usda", sphere_light=True)
    lines = []
    report = shade_scene(str(scene), tmp_path / "out", target_error=0.5, quick=True, choice_samples=64, validate_samples=64,
                         log=lines.append)
    assert report["left_out_lights"] == ["/World/Lamp"]
    assert any("/World/Lamp left out" in line and "procedural sky" in line for line in lines)
    assert report["held_out"]["status"] == "ok" and report["held_out"]["rel_rms_debiased"] < 0.5
    assert 'source = "distant"' in (tmp_path / "out" / "lamp_auto.toml").read_text()


def test_a_stage_that_leaves_sphere_lights_out_says_so(tmp_path, cache):
    from warpshade.graph import GraphSpec, StageSpec
    from warpshade.io import load_scene

    scene = load_scene(str(_static_usd(tmp_path / "lamp.usda", sphere_light=True)))
    spec = GraphSpec([StageSpec("shade", "prt.unshadowed", {"order": 3})], "shade.radiance", name="lamp")
    with pytest.warns(UserWarning, match=r"'shade' \(prt.unshadowed\).*sphere light\(s\) /World/Lamp"):
        spec.compile(scene, device="cpu", progress=False)


def test_a_static_scene_is_one_frame_and_says_so(tmp_path, cache):
    scene = _static_usd(tmp_path / "ball.usda")
    report = shade_scene(str(scene), tmp_path / "out", target_error=0.5, quick=True, choice_samples=64, validate_samples=64,
                         log=lambda *_: None)
    assert report["scene"]["kind"] == "static" and report["scene"]["up_axis"] == "Y"
    assert report["training_frames"] == report["held_out_frames"] and "same frame" in report["frames_note"]
    assert report["met"] and report["chosen"]["method"] in ("prt", "unshadowed", "prt.trace")
    assert str(scene.resolve()) in (tmp_path / "out" / "ball_auto.toml").read_text()


@pytest.mark.parametrize("kwargs, flag", [({"target_error": 0.0}, "--target-error"), ({"budget_ms": -1.0}, "--budget-ms"),
                                          ({"glossy": "maybe"}, "--glossy")])
def test_bad_requests_name_their_flag(tmp_path, kwargs, flag):
    with pytest.raises(ValueError, match=flag):
        shade_scene("bundled:blockers", tmp_path, **kwargs)


def test_the_command_runs_the_chosen_graph_on_the_held_out_frames(tmp_path, cache, capsys):
    """`warpshade shade` end to end: the choice, then the chosen graph run from a few frames before
    the first held-out frame to the last, validated on the held-out frames; a second run into the
    same folder replaces only its own files, and a user's file of an output's name is refused."""
    from warpshade import cli

    out = tmp_path / "out"
    argv = ["shade", "bundled:blockers", "--quick", "--out", str(out), "--validate-samples", "64", "--device", "cpu"]
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert "chosen" in printed and "run     warpshade run" in printed
    choice = json.loads((out / "blockers_auto_choice.json").read_text())
    run = json.loads((out / "blockers_auto.json").read_text())  # the run's own report
    assert sorted(f["frame"] for f in run["error"]["per_frame"]) == choice["held_out_frames"]
    assert (out / "blockers_auto.usda").exists()
    assert cli.main(argv + ["--no-run"]) == 0  # its own files: replaced
    (out / "blockers_auto_choice.json").unlink()
    (out / "blockers_auto_choice.json").write_text("mine")
    assert cli.main(argv) == 2
    assert "blockers_auto_choice.json" in capsys.readouterr().err
    assert (out / "blockers_auto_choice.json").read_text() == "mine"
