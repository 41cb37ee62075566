"""One frame = one recorded replay: replayed frames equal cold, unrecorded stepping; the frame
state's lighting on the device against the float64 lighting; change notifications.

Rigid (moving blockers), skinned (figure) and deforming (cloth) scenes, with graphs that use
every per-frame input: normals (unshadowed), tangent frames (LDPRT), sphere sets (SHEXP) and a
BVH refit inside the recorded frame (per-frame ray tracing).
"""

import numpy as np
import pytest
import warp

from warpshade._wp import record_program
from warpshade.graph import GraphError, GraphSpec, StageSpec
from warpshade.io import load_scene
from warpshade.scene import DistantLight, Environment, FrameEvaluator, LightingSource, LightTrack, SphereLight
from warpshade.scene._state import CPU_REFIT_NOTE

from tolerances import REPLAY_RTOL

#: Warp zxzxz float32 SH rotation of a light's projection vs the float64 Ivanic-Ruedenberg
#: rotation: a few float32 roundings per coefficient, relative to the largest coefficient.
LIGHTING_RTOL = 2e-6
#: Frames stepped in an order that revisits and jumps (state must not leak between frames).
FRAME_ORDER = (0.0, 30.0, 59.0, 30.0, 1.0, 45.0)

SHEXP_FIT = {"grid_cells": 4000, "teleports": 1}
GRAPHS = {
    "unshadowed": [("shade", "prt.unshadowed", {"order": 3})],
    "ldprt": [("fit", "ldprt.fit", {"order": 3, "lobes": 2, "samples": 32, "restarts": 0}), ("tangents", "ldprt.tangents", {}),
              ("shade", "ldprt.shade", {"order": 3, "lobes": 2})],
    "shexp": [("tables", "shexp.tables", {"order": 3}), ("blockers", "shexp.blockers", {"budget": 6, **SHEXP_FIT}),
              ("shade", "shexp.shade", {"order": 3})],
    "traced": [("shade", "prt.trace", {"order": 3, "samples": 16})],
    # UV tangents accumulated per frame from the points (atomic adds), then the patch per vertex
    "patch": [("patch", "ldprt.patch", {"resolution": 8, "samples": 16, "order": 3, "lobes": 2}),
              ("shade", "ldprt.patch_shade", {"tiling": 4.0})],
}
CASES = [
    ("blockers", "unshadowed"), ("blockers", "traced"), ("blockers", "shexp"),
    ("figure", "ldprt"), ("figure", "shexp"), ("figure", "traced"),
    ("cloth", "unshadowed"), ("cloth", "traced"), ("cloth", "patch"),
]


@pytest.fixture(scope="module")
def scenes():
    return {name: load_scene(f"bundled:{name}") for name in ("blockers", "figure", "cloth")}


def _runtime(scene, graph, capture, tmp_path, device, lighting=None):
    stages = [StageSpec(n, t, dict(p)) for (n, t, p) in GRAPHS[graph]]
    lighting = lighting or LightingSource(scene.lights, scene.up_axis, 6.0, float(scene.frames[0]))
    return GraphSpec(stages, "shade.radiance", name=graph).compile(scene, device=device, cache_dir=tmp_path, progress=False,
                                                                    capture=capture, lighting=lighting)


class _LaunchCounter:
    def __init__(self, monkeypatch):
        self.count = 0
        original = warp.launch

        def counting(*args, **kwargs):
            self.count += 1
            return original(*args, **kwargs)

        monkeypatch.setattr(warp, "launch", counting)


@pytest.mark.parametrize("scene_name, graph", CASES, ids=[f"{s}-{g}" for s, g in CASES])
def test_replayed_frames_equal_cold_stepping(scenes, scene_name, graph, tmp_path, monkeypatch, device):
    monkeypatch.setenv("WARPSHADE_THREADS", "1")  # no chunked CPU launches: the frame is one replay
    scene = scenes[scene_name]
    frames = [f for f in FRAME_ORDER if f in scene.frames]
    cold = _runtime(scene, graph, False, tmp_path, device)
    replay = _runtime(scene, graph, True, tmp_path, device)
    want = [cold.step(f).numpy().copy() for f in frames]
    replay.step(frames[0])  # compiles, launched from Python
    replay.step(frames[0])  # recorded, then replayed
    program = replay.program
    assert program is not None and program.graph_count >= 1
    # the only Python call a recorded CPU frame may make here: the BVH refit Warp's CPU capture
    # does not record (a refit, no kernel launch); on CUDA nothing
    allowed = [CPU_REFIT_NOTE] if graph == "traced" and device == "cpu" else []
    assert program.uncaptured == allowed, f"Python calls in the recorded frame: {program.uncaptured}"
    counter = _LaunchCounter(monkeypatch)
    got = [replay.step(f).numpy().copy() for f in frames]
    assert counter.count == 0, "a replayed frame makes no kernel launches from Python"
    size = max(np.abs(w).max() for w in want)
    for f, a, b in zip(frames, got, want):
        assert np.all(np.isfinite(a))
        np.testing.assert_allclose(a, b, rtol=0, atol=REPLAY_RTOL * size, err_msg=f"frame {f}")
    assert not np.allclose(want[0], want[2]), "the frames differ (the test sees the animation)"


def test_chunked_cpu_launches_run_between_recorded_segments(scenes, tmp_path, monkeypatch, device):
    """A launch big enough to be split over the CPU cores becomes a Python call of the program:
    still every core, and still the cold result. On CUDA the same frame is recorded whole."""
    scene = scenes["blockers"]
    graph = [StageSpec("shade", "prt.trace", {"order": 3, "samples": 256})]  # 2.4k vertices x 256 rays: chunked
    rts = [GraphSpec(graph, "shade.radiance").compile(scene, device=device, cache_dir=None, progress=False, capture=c)
           for c in (False, True)]
    want = rts[0].step(10.0).numpy().copy()
    rts[1].step(10.0)
    got = rts[1].step(10.0).numpy().copy()
    if device == "cpu":
        assert rts[1].program.uncaptured == [CPU_REFIT_NOTE, "chunked CPU launch"] and rts[1].program.graph_count == 3
    else:
        assert rts[1].program.uncaptured == [] and rts[1].program.graph_count == 1
    np.testing.assert_allclose(got, want, rtol=0, atol=REPLAY_RTOL * np.abs(want).max())


def test_frame_lighting_matches_float64_lighting(scenes, device):
    """Rotation about the up axis, a tracked distant light, a tracked environment and a moving
    sphere light, evaluated on the device from the frame index."""
    scene = scenes["blockers"]
    times = np.array([0.0, 20.0, 59.0])
    turns = np.stack([np.eye(4)] * 3)
    for i, deg in enumerate((0.0, 50.0, 140.0)):
        c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        turns[i, :3, :3] = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])  # row-vector rotation about z
        turns[i, 3, :3] = (0.1 * i, 0.0, 0.2 * i)
    env = Environment.sky()
    env.track = LightTrack(times, turns)
    lights = [env, DistantLight((0.2, 0.5, 1.0), (3.0, 2.0, 1.0), angle_deg=4.0, track=LightTrack(times, turns)),
              SphereLight((0.5, 0.5, 1.5), 0.2, (8.0, 8.0, 8.0), track=LightTrack(times, turns))]
    source = LightingSource(lights, scene.up_axis, 7.0, 0.0)
    ev = FrameEvaluator(scene, device, lighting=source)
    lighting = ev.state.lighting
    l3, l6 = lighting.sh(3), lighting.sh(6)
    for f in (0.0, 13.0, 40.0, 59.0):
        ev.evaluate(f)
        ref = source.sh(6, f)
        scale = np.abs(ref).max()
        np.testing.assert_allclose(l6.numpy(), ref, rtol=0, atol=LIGHTING_RTOL * scale)
        np.testing.assert_allclose(l3.numpy(), ref[:, :9], rtol=0, atol=LIGHTING_RTOL * scale)
        posed = source.lights_at(f)
        np.testing.assert_allclose(lighting.environment_to_world.numpy()[0], posed[0].to_world, atol=1e-6)
        np.testing.assert_allclose(lighting.distant_direction.numpy()[0], posed[1].direction, atol=1e-6)
        np.testing.assert_allclose(lighting.sphere_position.numpy()[0], posed[2].position, atol=1e-6)
    assert lighting.changed.numpy()[0] == 1
    ev.evaluate(59.0)
    assert lighting.changed.numpy()[0] == 0, "the same frame again: the lighting did not change"


def test_scene_evaluation_records_and_replays(scenes, device):
    scene = scenes["figure"]
    ev = FrameEvaluator(scene, device)
    program = record_program(ev.launch, device)
    for f in (3.0, 40.0):
        ev.set_frame(f)
        program.replay()
        np.testing.assert_allclose(ev.state.points.numpy(), scene.points_at(f), atol=1e-5)
        np.testing.assert_allclose(ev.state.normals.numpy(), scene.normals_at(f), atol=1e-4)
    with pytest.raises(ValueError, match="not one of the sampled time codes"):
        ev.set_frame(3.5)


def test_changes_reach_the_next_frame_and_swapping_back_restores_it(scenes, tmp_path, device):
    scene = scenes["blockers"]
    rt = _runtime(scene, "unshadowed", True, tmp_path, device)
    rt.step(5.0)
    before = rt.step(5.0).numpy().copy()
    program = rt.program
    mesh = scene.meshes[0]
    rt.set_albedo((0.1, 0.2, 0.3), prims=[mesh.path])
    changed = rt.step(5.0).numpy().copy()
    assert rt.program is program, "an albedo change is a device write: the recording stays"
    sl = slice(mesh.vertex_offset, mesh.vertex_offset + mesh.vertex_count)
    ratio = changed[sl] / np.maximum(before[sl], 1e-12)
    lit = before[sl].max(axis=1) > 1e-3
    np.testing.assert_allclose(ratio[lit], (np.array([0.1, 0.2, 0.3]) / scene.albedo[sl][lit]), rtol=1e-5)
    np.testing.assert_array_equal(changed[mesh.vertex_count:], before[mesh.vertex_count:])
    rt.set_albedo(mesh.albedo, prims=[mesh.path])
    np.testing.assert_array_equal(rt.step(5.0).numpy(), before)
    # a parameter: the stage is set up again and the frame recorded anew
    rt.set_parameter("shade", "window", "hanning")
    windowed = rt.step(5.0).numpy().copy()
    assert not np.allclose(windowed, before)
    rt.set_parameter("shade", "window", None)
    rt.step(5.0)
    np.testing.assert_array_equal(rt.step(5.0).numpy(), before)
    with pytest.raises(GraphError, match="no parameter 'nope'"):
        rt.set_parameter("shade", "nope", 1)
    prt = GraphSpec([StageSpec("bake", "prt.transfer", {"order": 3, "samples": 16}), StageSpec("shade", "prt.shade", {"order": 3})],
                    "shade.radiance").compile(scene, device=device, cache_dir=tmp_path, progress=False)
    with pytest.raises(GraphError, match="changes the stage's ports"):
        prt.set_parameter("shade", "order", 4)
    with pytest.raises(GraphError, match="precompute stage"):
        prt.set_parameter("bake", "samples", 32)
    # a new lighting: the same as compiling with it
    sky = [Environment.constant((0.5, 0.6, 0.7))]
    rt.set_lighting(sky)
    fresh = _runtime(scene, "unshadowed", True, tmp_path, device, lighting=LightingSource.fixed(sky, scene.up_axis))
    np.testing.assert_allclose(rt.step(5.0).numpy(), fresh.step(5.0).numpy(), rtol=0, atol=1e-7)


def test_lighting_override_is_a_host_write_before_the_replay(scenes, tmp_path, device):
    scene = scenes["blockers"]
    rt = _runtime(scene, "unshadowed", True, tmp_path, device)
    rt.step(0.0)
    rt.step(0.0)
    program = rt.program
    coeffs = rt.lighting.sh(3, 0.0) * 0.5
    half = rt.step(0.0, lighting=coeffs).numpy().copy()
    assert rt.program is program
    full = rt.step(0.0).numpy().copy()
    np.testing.assert_allclose(half, 0.5 * full, rtol=1e-5, atol=1e-7)
    with pytest.raises(ValueError, match=r"needs \(3, 9\)"):
        rt.step(0.0, lighting=np.zeros((3, 4)))
    with pytest.raises(ValueError, match="set_lighting"):
        rt.step(0.0, lighting=[SphereLight((0, 0, 2), 0.1, (1, 1, 1))])
