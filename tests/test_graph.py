"""Stage-graph runtime: validation errors, artifact caching, stepping and outputs."""

import json

import numpy as np
import pytest
import trimesh

from warpshade._wp import wp
from warpshade.graph import FrameStage, GraphError, GraphSpec, Param, Port, PrecomputeStage, StageSpec, load, register_stage
from warpshade.measure import measure_error, render_comparisons, write_report, write_usd
from warpshade.scene import Environment, Mesh, Scene

CALLS = {"const": 0}


@register_stage
class _Const(PrecomputeStage):
    """Precompute: a (V, K) array filled with ``value`` (counts its invocations)."""

    type_name = "test.const"
    parameters = {"k": Param(2, int), "value": Param(1.0, float)}

    def dims(self):
        return {"K": self.params["k"]}

    def output_ports(self):
        return {"values": Port("float32", ("V", "K"))}

    def precompute(self, ctx, inputs):
        CALLS["const"] += 1
        self.report = {"value": self.params["value"], "histogram": np.array([3, 1])}
        return {"values": np.full((ctx.dims["V"], self.params["k"]), self.params["value"], np.float32)}

    def check_artifact(self, outputs):
        if np.abs(outputs["values"]).max() > 1e6:
            raise ValueError("implausible values (an older artifact format)")


@wp.kernel
def _sum_rows(values: wp.array2d(dtype=wp.float32), points: wp.array(dtype=wp.vec3), out: wp.array2d(dtype=wp.float32)):
    v = wp.tid()
    s = float(0.0)
    for i in range(values.shape[1]):
        s += values[v, i]
    out[v, 0] = s
    out[v, 1] = points[v][2]
    out[v, 2] = 0.0


@register_stage
class _Sum(FrameStage):
    """Frame stage: radiance = (row sum of values, point z, 0)."""

    type_name = "test.sum"
    parameters = {"k": Param(2, int)}

    def dims(self):
        return {"K": self.params["k"]}

    def input_ports(self):
        return {"values": Port("float32", ("V", "K")), "points": Port("vec3", ("V",))}

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3))}

    def setup(self, ctx, inputs):
        self.inputs = inputs
        self.out = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self.out}

    def launch(self, state):
        wp.launch(_sum_rows, dim=state.vertex_count, inputs=[self.inputs["values"], self.inputs["points"], self.out],
                  device=state.device)


@register_stage
class _Loop(FrameStage):
    type_name = "test.loop"

    def input_ports(self):
        return {"radiance": Port("float32", ("V", 3))}

    def output_ports(self):
        return {"radiance2": Port("float32", ("V", 3))}


@pytest.fixture
def moving_scene():
    plane = trimesh.creation.box(extents=(1.0, 1.0, 0.1))
    frames = np.arange(4, dtype=np.float64)
    xf = np.tile(np.eye(4), (4, 1, 1))
    xf[:, 3, 2] = frames * 0.5  # rises 0.5 per frame (row-vector translation)
    mesh = Mesh("/box", plane.vertices, plane.faces, animation="rigid", transforms=xf)
    return Scene.from_meshes([mesh], frames=frames, lights=[Environment.constant((1.0, 1.0, 1.0))])


def _spec(k_const=2, k_sum=2, value=1.0, extra=(), inputs=None):
    stages = [
        StageSpec("bake", "test.const", {"k": k_const, "value": value}),
        StageSpec("shade", "test.sum", {"k": k_sum}, inputs or {}),
        *extra,
    ]
    return GraphSpec(stages=stages, output="shade.radiance", name="t")


def test_runs_and_steps(moving_scene, tmp_path, device):
    rt = _spec(value=0.25).compile(moving_scene, device=device, cache_dir=tmp_path, progress=False)
    out = rt.step(2.0).numpy()
    assert np.allclose(out[:, 0], 0.5)  # 2 columns of 0.25
    expected_z = moving_scene.points_at(2.0)[:, 2]
    assert np.allclose(out[:, 1], expected_z, atol=1e-6)
    frames = rt.run("1:3")
    assert list(frames) == [1.0, 2.0]
    assert sorted(rt.results) == [1.0, 2.0]
    summary = rt.timing_summary()
    assert summary["captured"] and summary["median_frame_s"] is not None
    assert summary["stages"]["bake"]["cache"] == "miss"
    assert summary["stages"]["shade"]["median_frame_s"] is None, "per-stage times come from profile()"
    profile = rt.profile("0:2")
    assert set(profile) == {"scene", "shade"} and all(v > 0 for v in profile.values())
    assert rt.timing_summary()["stages"]["shade"]["median_frame_s"] is not None


def test_cache_reuse_and_invalidation(moving_scene, tmp_path, device):
    CALLS["const"] = 0
    _spec(value=1.0).compile(moving_scene, device=device, cache_dir=tmp_path, progress=False)
    assert CALLS["const"] == 1
    rt = _spec(value=1.0).compile(moving_scene, device=device, cache_dir=tmp_path, progress=False)
    assert CALLS["const"] == 1, "unchanged inputs must reuse the cached artifact"
    assert rt.timings["bake"].cache == "hit"
    bake = next(s for s in rt.stages if s.name == "bake")
    assert bake.report == {"value": 1.0, "histogram": [3, 1]}, "a precompute report survives the cache"
    assert rt.describe()["stages"][0]["report"]["histogram"] == [3, 1]
    _spec(value=2.0).compile(moving_scene, device=device, cache_dir=tmp_path, progress=False)
    assert CALLS["const"] == 2, "a changed parameter must recompute"
    moved = Scene.from_meshes(
        [Mesh("/box", moving_scene.meshes[0].points * 2.0, moving_scene.meshes[0].faces, animation="rigid",
              transforms=moving_scene.meshes[0].transforms)],
        frames=moving_scene.frames, lights=moving_scene.lights,
    )
    _spec(value=2.0).compile(moved, device=device, cache_dir=tmp_path, progress=False)
    assert CALLS["const"] == 3, "a changed scene must recompute"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "no temporary files left behind"


def _entry(tmp_path):
    (artifact,) = tmp_path.glob("*.npz")
    return artifact


def _flip_byte(data: bytes) -> bytes:
    b = bytearray(data)
    b[len(b) // 2] ^= 0x40
    return bytes(b)


@pytest.mark.parametrize("damage, reported", [
    (lambda data: b"garbage", "does not match its digest"),
    (lambda data: data[: len(data) // 2], "does not match its digest"),
    (lambda data: b"", "does not match its digest"),
    (_flip_byte, "does not match its digest"),
])
def test_damaged_cache_entry_is_reported_discarded_and_recomputed(moving_scene, tmp_path, damage, reported, device):
    CALLS["const"] = 0
    _spec(value=1.0).compile(moving_scene, device=device, cache_dir=tmp_path, progress=False)
    artifact = _entry(tmp_path)
    artifact.write_bytes(damage(artifact.read_bytes()))
    rt = _spec(value=1.0).compile(moving_scene, device=device, cache_dir=tmp_path, progress=False)
    assert CALLS["const"] == 2 and rt.timings["bake"].cache == "miss"
    assert len(rt.stale_artifacts) == 1 and reported in rt.stale_artifacts[0] and str(artifact) in rt.stale_artifacts[0]
    assert rt.describe()["stale_artifacts"] == rt.stale_artifacts
    assert np.allclose(rt.step(0.0).numpy()[:, 0], 2.0)
    rt = _spec(value=1.0).compile(moving_scene, device=device, cache_dir=tmp_path, progress=False)
    assert rt.timings["bake"].cache == "hit" and not rt.stale_artifacts


@pytest.mark.parametrize("contents, reported", [
    (lambda v: np.full_like(v, np.nan), "NaN or infinite"),
    (lambda v: v[:, :1], "has shape"),
    (lambda v: v[:0], "has shape"),
    (lambda v: v.astype(np.int64), "has dtype"),
    (lambda v: np.full_like(v, 1e7), "implausible"),
])
def test_cache_entry_not_matching_the_stage_is_recomputed(moving_scene, tmp_path, contents, reported, device):
    """Well-formed entries (the digest matches) whose arrays do not fit the stage's ports, or
    fail the stage's own check: reported, discarded, recomputed; never a crash or a wrong
    (e.g. all-black) result."""
    from warpshade.graph import ArtifactCache

    CALLS["const"] = 0
    rt = _spec(value=1.0).compile(moving_scene, device=device, cache_dir=tmp_path, progress=False)
    key = rt.artifact_keys["bake"]
    cache = ArtifactCache(tmp_path)
    arrays = cache.load(key)
    cache.store(key, {k: contents(v) if k == "values" else v for k, v in arrays.items()})
    rt = _spec(value=1.0).compile(moving_scene, device=device, cache_dir=tmp_path, progress=False)
    assert CALLS["const"] == 2 and rt.timings["bake"].cache == "miss"
    assert rt.stale_artifacts and reported in rt.stale_artifacts[0], rt.stale_artifacts
    assert np.allclose(rt.step(0.0).numpy()[:, 0], 2.0)
    rt = _spec(value=1.0).compile(moving_scene, device=device, cache_dir=tmp_path, progress=False)
    assert rt.timings["bake"].cache == "hit" and not rt.stale_artifacts, "the recomputed artifact replaced it"


@pytest.mark.filterwarnings("ignore:overflow encountered in cast")
def test_a_precompute_that_produces_nan_is_an_error_naming_the_stage(moving_scene, tmp_path, device):
    # 1e300 is a finite parameter that overflows the float32 artifact
    with pytest.raises(GraphError, match=r"stage 'bake' \(test.const\): its precompute produced an invalid artifact: "
                                         r"output 'values' has 16 NaN or infinite values"):
        _spec(value=1e300).compile(moving_scene, device=device, cache_dir=None, progress=False)
    with pytest.raises(GraphError, match="parameter 'value' must be finite"):
        _spec(value=float("nan")).build()


@pytest.mark.parametrize(
    "spec, message",
    [
        (GraphSpec([StageSpec("a", "no.such")], "a.x"), "unknown stage type 'no.such'"),
        (_spec(extra=[]).__class__([StageSpec("bake", "test.const", {"kk": 1}), StageSpec("shade", "test.sum")], "shade.radiance"),
         "unknown parameter"),
        (GraphSpec([StageSpec("shade", "test.sum")], "shade.radiance"), "input 'values' is not connected"),
        (_spec(extra=[StageSpec("bake2", "test.const")]), "input 'values' is ambiguous"),
        (_spec(inputs={"values": "scene.points"}), "expects dtype float32"),
        (_spec(k_const=3, k_sum=2), "expects shape"),
        (_spec(extra=[StageSpec("loop", "test.loop", {}, {"radiance": "loop2.radiance2"}),
                      StageSpec("loop2", "test.loop", {}, {"radiance": "loop.radiance2"})]), "cycle"),
        (_spec(inputs={"values": "nowhere.values"}), "unknown stage 'nowhere'"),
        (_spec(inputs={"values": "bake.nothing"}), "has no output 'nothing'"),
        (GraphSpec([StageSpec("bake", "test.const"), StageSpec("shade", "test.sum")], "bake.values"),
         "must come from a per-frame stage"),
    ],
)
def test_validation_errors(spec, message):
    with pytest.raises(GraphError, match=message) as info:
        spec.build({"V": 8, "T": 1, "F": 12})
    assert "stage" in str(info.value) or "graph" in str(info.value)


def test_toml_loading_errors(tmp_path):
    with pytest.raises(GraphError, match="does not exist"):
        load(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[graph\nname=")
    with pytest.raises(GraphError, match="invalid TOML"):
        load(bad)
    no_out = tmp_path / "noout.toml"
    no_out.write_text('[graph]\nname = "x"\n[[stage]]\nname = "a"\ntype = "test.const"\n')
    with pytest.raises(GraphError, match="output"):
        load(no_out)


def test_toml_roundtrip_and_outputs(moving_scene, tmp_path, device):
    path = tmp_path / "g.toml"
    path.write_text(
        '[graph]\nname = "toml-graph"\noutput = "shade.radiance"\nframes = "0:3"\n'
        '[[stage]]\nname = "bake"\ntype = "test.const"\nvalue = 0.5\n'
        '[[stage]]\nname = "shade"\ntype = "test.sum"\ninputs = { values = "bake.values" }\n'
    )
    spec = load(path)
    rt = spec.compile(moving_scene, device=device, cache_dir=None, progress=False)
    assert rt.timings["bake"].cache == "off"
    rt.run()
    report = json.loads(write_report(rt, tmp_path / "report.json").read_text())
    assert report["graph"] == "toml-graph" and report["frames_run"] == [0.0, 1.0, 2.0]
    usd_path = write_usd(rt, tmp_path / "out" / "shaded.usda")
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(usd_path))
    meshes = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    assert len(meshes) == 1
    pv = UsdGeom.PrimvarsAPI(meshes[0]).GetPrimvar("displayColor")
    assert pv.GetInterpolation() == UsdGeom.Tokens.vertex
    assert pv.GetAttr().GetTimeSamples() == [0.0, 1.0, 2.0]
    got = np.asarray(pv.Get(Usd.TimeCode(1.0)))
    assert np.allclose(got, rt.results[1.0])
    pts = np.asarray(UsdGeom.Mesh(meshes[0]).GetPointsAttr().Get(Usd.TimeCode(2.0)))
    assert np.allclose(pts, moving_scene.points_at(2.0), atol=1e-6)


def test_comparisons_need_a_measured_reference(moving_scene, tmp_path, device):
    rt = _spec().compile(moving_scene, device=device, cache_dir=None, progress=False)
    rt.run([0.0, 1.0], warmup=False)
    measured = measure_error(rt, [0.0], samples=16, cache_dir=None)
    with pytest.raises(ValueError, match=r"frame\(s\) \[1.0\] were not measured"):
        render_comparisons(rt, measured, tmp_path, frames=[1.0])
    (png,) = render_comparisons(rt, measured, tmp_path, width=48, height=36)
    assert png.name.endswith("_0000_vs_reference.png") and png.exists()


@wp.kernel
def _scale_rows(gain: wp.array(dtype=wp.float32), points: wp.array(dtype=wp.vec3), out: wp.array2d(dtype=wp.float32)):
    v = wp.tid()
    out[v, 0] = gain[0] * points[v][2]
    out[v, 1] = 0.0
    out[v, 2] = 0.0


@register_stage
class _Gain(FrameStage):
    """Frame stage: radiance = (gain * point z, 0, 0); absorbs a new ``gain`` (a device write),
    needs a new set-up for a new ``offset``."""

    type_name = "test.gain"
    parameters = {"gain": Param(1.0, float), "offset": Param(0.0, float)}
    built = 0

    def __init__(self, name, params=None):
        super().__init__(name, params)
        type(self).built += 1
        self.setups, self.told = 0, []

    def input_ports(self):
        return {"points": Port("vec3", ("V",))}

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3))}

    def setup(self, ctx, inputs):
        self.setups += 1
        self.points = inputs["points"]
        self.gain = wp.array([self.params["gain"]], dtype=wp.float32, device=ctx.device)
        self.out = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self.out}

    def notify_changed(self, flags, keys=frozenset()):
        self.told.append(set(keys))
        if keys == {"gain"}:
            self.gain.assign(np.array([self.params["gain"]], np.float32))
            return True
        return super().notify_changed(flags, keys)

    def launch(self, state):
        wp.launch(_scale_rows, dim=state.vertex_count, inputs=[self.gain, self.points, self.out], device=state.device)


def test_a_stage_told_which_parameter_changed_absorbs_it_without_a_new_setup(moving_scene, tmp_path, device):
    path = tmp_path / "g.toml"
    path.write_text('[graph]\noutput = "shade.radiance"\n[[stage]]\nname = "shade"\ntype = "test.gain"\n')
    before = _Gain.built
    rt = load(path).compile(moving_scene, device=device, cache_dir=None, progress=False)
    assert _Gain.built == before + 1, "load checks the stages, compile runs the same ones: each built once"
    st = rt.output_stage()
    rt.step(2.0)
    base = rt.step(2.0).numpy().copy()
    program = rt.program
    rt.set_parameter("shade", "gain", 3.0)
    assert st.told[-1] == {"gain"} and st.setups == 1
    np.testing.assert_allclose(rt.step(2.0).numpy()[:, 0], 3.0 * base[:, 0], rtol=1e-6)
    assert rt.program is program, "an absorbed parameter keeps the recording"
    rt.set_parameter("shade", "offset", 1.0)
    assert st.told[-1] == {"offset"} and st.setups == 2 and rt.program is None
    np.testing.assert_allclose(rt.step(2.0).numpy()[:, 0], 3.0 * base[:, 0], rtol=1e-6)
