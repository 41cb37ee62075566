"""Run-time changes batched into one update: each stage told once and set up at most once, the
frame recorded once, the result the same as the changes made one by one; bad values refused at
the setter; a refused update puts every change of the batch back.

Graph: ``shade`` (``prt.unshadowed``) -> ``tint`` (a gain on its radiance), and ``side``, a
frame stage that reads the scene's points only (no change here concerns it).
"""

import contextlib

import numpy as np
import pytest

from warpshade._wp import wp
from warpshade.graph import FrameStage, GraphError, GraphSpec, Param, Port, StageError, StageSpec, register_stage
from warpshade.io import load_scene
from warpshade.scene import Environment, LightingSource

#: Frames compared between runs (one revisited: nothing may leak between frames).
FRAMES = (0.0, 5.0, 0.0)
#: tint's set-up refuses a gain above this (a value its parameter accepts: refused at update).
MAX_GAIN = 100.0


@wp.kernel
def _tint_kernel(gain: wp.array(dtype=wp.float32), shaded: wp.array2d(dtype=wp.float32), out: wp.array2d(dtype=wp.float32)):
    v, c = wp.tid()
    out[v, c] = gain[0] * shaded[v, c]


@wp.kernel
def _height_kernel(points: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.float32)):
    v = wp.tid()
    out[v] = points[v][2]


@register_stage
class _Tint(FrameStage):
    """Frame stage: radiance = gain * shaded radiance; a new gain needs a new set-up (the gain is
    uploaded there), and the set-up refuses a gain above :data:`MAX_GAIN`."""

    type_name = "test.batch_tint"
    parameters = {"gain": Param(1.0, float, minimum=0.0)}

    def input_ports(self):
        return {"shaded": Port("float32", ("V", 3))}

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3))}

    def setup(self, ctx, inputs):
        if self.params["gain"] > MAX_GAIN:
            raise StageError(f"stage {self.name!r}: parameter 'gain' {self.params['gain']} is above {MAX_GAIN} (refused in set-up)")
        self.shaded = inputs["shaded"]
        self.gain = wp.array([self.params["gain"]], dtype=wp.float32, device=ctx.device)
        self.out = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=ctx.device)
        return {"radiance": self.out}

    def launch(self, state):
        wp.launch(_tint_kernel, dim=self.out.shape, inputs=[self.gain, self.shaded, self.out], device=state.device)


@register_stage
class _Side(FrameStage):
    """Frame stage reading the scene's points only: the height of each vertex."""

    type_name = "test.batch_side"

    def input_ports(self):
        return {"points": Port("vec3", ("V",))}

    def output_ports(self):
        return {"height": Port("float32", ("V",))}

    def setup(self, ctx, inputs):
        self.points = inputs["points"]
        self.out = wp.zeros(ctx.dims["V"], dtype=wp.float32, device=ctx.device)
        return {"height": self.out}

    def launch(self, state):
        wp.launch(_height_kernel, dim=self.out.shape[0], inputs=[self.points, self.out], device=state.device)


@pytest.fixture(scope="module")
def scene():
    return load_scene("bundled:blockers")


def _compile(scene, device):
    spec = GraphSpec([StageSpec("side", "test.batch_side"),
                      StageSpec("shade", "prt.unshadowed", {"order": 3}),
                      StageSpec("tint", "test.batch_tint", inputs={"shaded": "shade.radiance"})],
                     "tint.radiance", name="batched-changes")
    lighting = LightingSource(scene.lights, scene.up_axis, 6.0, float(scene.frames[0]))
    return spec.compile(scene, device=device, cache_dir=None, progress=False, lighting=lighting)


class _Spy:
    """Counts set-ups per frame stage and frame recordings of one runtime."""

    def __init__(self, rt, monkeypatch):
        import warpshade.graph._frame as frame_module

        self.setups = {st.name: 0 for st in rt.frame_stages}
        self.records = 0
        for st in rt.frame_stages:
            monkeypatch.setattr(st, "setup", self._counting(st.name, st.setup))
        record = frame_module.record_program

        def counting_record(launch, *args, **kwargs):
            if getattr(launch, "__self__", None) is rt.frame:  # this runtime's frame only
                self.records += 1
            return record(launch, *args, **kwargs)

        monkeypatch.setattr(frame_module, "record_program", counting_record)

    def _counting(self, name, setup):
        def counted(ctx, inputs):
            self.setups[name] += 1
            return setup(ctx, inputs)

        return counted

    def reset(self):
        self.setups = dict.fromkeys(self.setups, 0)
        self.records = 0


def _warm(rt):
    """Step twice: kernels compiled, the frame recorded (what a running frame loop has)."""
    rt.step(0.0)
    rt.step(0.0)
    assert rt.program is not None


def _frames(rt) -> list:
    return [rt.step(f).numpy().copy() for f in FRAMES]


def _five_changes(rt, scene):
    mesh = scene.meshes[0]
    rt.set_parameter("shade", "window", "hanning")
    rt.set_albedo((0.2, 0.4, 0.6), prims=[mesh.path])
    rt.set_parameter("tint", "gain", 2.0)
    rt.set_eye((0.0, 4.0, 3.0))
    rt.set_parameter("shade", "window_size", 2.5)


def test_changes_in_a_batch_set_each_stage_up_once_and_record_once(scene, device, monkeypatch):
    one_by_one, batched = _compile(scene, device), _compile(scene, device)
    _warm(one_by_one)
    _warm(batched)
    spy_one, spy = _Spy(one_by_one, monkeypatch), _Spy(batched, monkeypatch)

    _five_changes(one_by_one, scene)
    assert spy_one.setups == {"side": 0, "shade": 2, "tint": 3}, "one by one: shade twice, tint after each"

    with batched.batch():
        _five_changes(batched, scene)
        assert batched.dirty == {("shade", "window"), "albedo", ("tint", "gain"), "eye", ("shade", "window_size")}
        assert spy.setups == {"side": 0, "shade": 0, "tint": 0}, "nothing applied inside the block"
    assert batched.dirty == frozenset()
    assert spy.setups == {"side": 0, "shade": 1, "tint": 1}, "each affected stage once; side untouched"
    assert batched.program is None
    first = batched.step(0.0).numpy().copy()
    assert spy.records == 1
    assert spy.setups == {"side": 0, "shade": 1, "tint": 1}

    spy.reset()
    got = _frames(batched)
    assert spy.records == 0 and sum(spy.setups.values()) == 0, "later frames replay the one recording"
    want = _frames(one_by_one)
    np.testing.assert_array_equal(first, want[0])
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)


def test_a_new_lighting_in_a_batch_sets_every_stage_up_once(scene, device, monkeypatch):
    one_by_one, batched = _compile(scene, device), _compile(scene, device)
    _warm(one_by_one)
    _warm(batched)
    spy = _Spy(batched, monkeypatch)
    sky = LightingSource.fixed([Environment.constant((0.5, 0.6, 0.7))], scene.up_axis)

    def changes(rt):
        rt.set_parameter("shade", "window", "lanczos")
        rt.set_lighting(sky)
        rt.set_parameter("tint", "gain", 0.5)

    changes(one_by_one)
    with batched.batch():
        changes(batched)
    assert spy.setups == {"side": 1, "shade": 1, "tint": 1}
    assert batched.lighting is sky and batched.ctx.lighting is sky
    for g, w in zip(_frames(batched), _frames(one_by_one)):
        np.testing.assert_array_equal(g, w)
    assert spy.records == 1


def test_step_inside_a_batch_applies_what_is_dirty_first(scene, device, monkeypatch):
    rt, fresh = _compile(scene, device), _compile(scene, device)
    _warm(rt)
    spy = _Spy(rt, monkeypatch)
    fresh.set_parameter("tint", "gain", 3.0)
    with rt.batch():
        rt.set_parameter("tint", "gain", 3.0)
        got = rt.step(5.0).numpy().copy()
        assert rt.dirty == frozenset()
    assert spy.setups == {"side": 0, "shade": 0, "tint": 1}
    np.testing.assert_array_equal(got, fresh.step(5.0).numpy())


def test_bad_values_are_refused_at_the_setter_with_nothing_marked(scene, device, monkeypatch):
    rt = _compile(scene, device)
    _warm(rt)
    spy = _Spy(rt, monkeypatch)
    shade = next(st for st in rt.frame_stages if st.name == "shade")
    albedo = rt.evaluator.albedo.numpy().copy()
    for outside_a_batch in (True, False):
        with contextlib.nullcontext() if outside_a_batch else rt.batch():
            with pytest.raises(StageError, match=r"stage 'shade': parameter 'window' must be one of"):
                rt.set_parameter("shade", "window", "square")
            with pytest.raises(StageError, match=r"stage 'tint': parameter 'gain' must be >= 0"):
                rt.set_parameter("tint", "gain", -1.0)
            with pytest.raises(GraphError, match=r"stage 'shade' has no parameter 'nope'"):
                rt.set_parameter("shade", "nope", 1)
            with pytest.raises(StageError, match=r"stage 'shade': parameter 'order' must be <= 10"):
                rt.set_parameter("shade", "order", 11)
            with pytest.raises(ValueError, match="eye"):
                rt.set_eye((0.0, np.nan, 1.0))
            with pytest.raises(ValueError, match="albedo"):
                rt.set_albedo([1.0, 2.0])
            assert rt.dirty == frozenset()
            assert shade.params["window"] is None and shade.params["order"] == 3
    np.testing.assert_array_equal(rt.evaluator.albedo.numpy(), albedo)
    assert sum(spy.setups.values()) == 0 and rt.program is not None


def test_update_with_nothing_dirty_does_nothing(scene, device, monkeypatch):
    rt = _compile(scene, device)
    _warm(rt)
    spy = _Spy(rt, monkeypatch)
    told = []
    for st in rt.frame_stages:
        monkeypatch.setattr(st, "notify_changed", lambda flags, keys=frozenset(), name=st.name: told.append(name))
    program = rt.program
    assert rt.update() == frozenset()
    with rt.batch():
        pass
    assert told == [] and sum(spy.setups.values()) == 0
    assert rt.program is program, "the recording stays"
    rt.step(0.0)
    assert spy.records == 0


def test_a_refused_update_puts_every_change_of_the_batch_back(scene, device, monkeypatch):
    rt, fresh = _compile(scene, device), _compile(scene, device)
    _warm(rt)
    mesh = scene.meshes[0]
    shade, tint = (next(st for st in rt.frame_stages if st.name == n) for n in ("shade", "tint"))
    albedo = rt.evaluator.albedo.numpy().copy()
    with pytest.raises(StageError, match="refused in set-up"):
        with rt.batch():
            rt.set_parameter("shade", "window", "hanning")
            rt.set_albedo((0.9, 0.1, 0.1), prims=[mesh.path])
            rt.set_parameter("tint", "gain", 2 * MAX_GAIN)  # accepted by the parameter, refused in set-up
    assert rt.dirty == frozenset()
    assert shade.params["window"] is None and tint.params["gain"] == 1.0
    np.testing.assert_array_equal(rt.evaluator.albedo.numpy(), albedo)
    for g, w in zip(_frames(rt), _frames(fresh)):
        np.testing.assert_array_equal(g, w)

    # an exception leaving the block puts back what was marked in it, unapplied
    spy = _Spy(rt, monkeypatch)
    with pytest.raises(KeyError):
        with rt.batch():
            rt.set_parameter("tint", "gain", 4.0)
            raise KeyError("the caller's own error")
    assert rt.dirty == frozenset() and tint.params["gain"] == 1.0
    for g, w in zip(_frames(rt), _frames(fresh)):
        np.testing.assert_array_equal(g, w)
    assert spy.setups["shade"] == 0
