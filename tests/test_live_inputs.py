"""Live inputs: points and joint-local transforms fed from Python per frame
(``Runtime.step(frame, points=..., joints=...)``) flow through the recorded frame.

Stepping frame 0 with frame k's points (the cloth, deforming) or joints (the figure, skinned)
gives frame k's output, with per-frame ray tracing (``prt.trace``: the BVH refit is inside the
recorded frame). Bad feeds -- wrong shape, dtype or device, NaN, an unknown or static prim,
another thread stepping -- are clear errors naming the prim, and the next normal step is correct.
"""

import threading

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from warpshade._wp import wp
from warpshade.graph import GraphSpec, StageSpec
from warpshade.io import load_scene

CLOTH, FIGURE_BODY, SKELETON, GROUND = "/World/Cloth", "/World/Figure/Body", "/World/Figure/Skel", "/World/Ground"
K = 30


def _runtime(scene):
    graph = [StageSpec("shade", "prt.trace", {"order": 3, "samples": 16})]
    return GraphSpec(graph, "shade.radiance").compile(scene, cache_dir=None, progress=False)


@pytest.fixture(scope="module")
def cloth():
    scene = load_scene("bundled:cloth")
    rt = _runtime(scene)
    mesh = next(m for m in scene.meshes if m.path == CLOTH)
    frames = {f: rt.step(f).numpy().copy() for f in (0.0, float(K))}
    points_k = rt.state.points.numpy()[mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count].copy()
    return rt, frames, points_k


@pytest.fixture(scope="module")
def figure():
    scene = load_scene("bundled:figure")
    rt = _runtime(scene)
    frames = {f: rt.step(f).numpy().copy() for f in (0.0, float(K))}
    joints_k = np.asarray(scene.skeletons[0].local_transforms[K], np.float64)
    return rt, frames, joints_k


def test_cloth_fed_points_give_frame_k(cloth):
    rt, frames, points_k = cloth
    recordings = []
    for _ in range(3):  # first feed (new staging buffer: recorded anew), then replays
        out = rt.step(0, points={CLOTH: points_k}).numpy()
        recordings.append(rt.program)
        np.testing.assert_array_equal(out, frames[K])
    assert recordings[1] is recordings[2] is not None, "later feeds replay the same recording"
    np.testing.assert_array_equal(rt.step(0).numpy(), frames[0.0], "a step without points uses the time samples")
    fresh = _runtime(rt.scene)
    np.testing.assert_array_equal(fresh.step(K).numpy(), frames[K], "a fresh runtime agrees (same rays)")


def test_cloth_fed_device_array(cloth):
    rt, frames, points_k = cloth
    for value in (wp.array(points_k, dtype=wp.vec3, device=rt.device),
                  wp.array(points_k, dtype=wp.float32, device=rt.device)):
        np.testing.assert_array_equal(rt.step(0, points={CLOTH: value}).numpy(), frames[K])
    np.testing.assert_array_equal(rt.step(K).numpy(), frames[K])


def test_figure_fed_joints_give_frame_k(figure):
    rt, frames, joints_k = figure
    for value in (joints_k, wp.array(joints_k.astype(np.float32), dtype=wp.mat44, device=rt.device)):
        np.testing.assert_allclose(rt.step(0, joints={SKELETON: value}).numpy(), frames[K], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(rt.step(0).numpy(), frames[0.0], "a step without joints uses the time samples")


def test_figure_fed_skinned_points(figure):
    rt, frames, _ = figure
    rt.step(K)
    mesh = next(m for m in rt.scene.meshes if m.path == FIGURE_BODY)
    points_k = rt.state.points.numpy()[mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count].copy()
    np.testing.assert_array_equal(rt.step(0, points={FIGURE_BODY: points_k}).numpy(), frames[K])
    np.testing.assert_array_equal(rt.step(0).numpy(), frames[0.0])


# ---- where it fails ---------------------------------------------------------------------------
def _rejected(rt, frames, match, **feed):
    with pytest.raises(ValueError, match=match):
        rt.step(K, **feed)
    np.testing.assert_array_equal(rt.step(0).numpy(), frames[0.0], "the next normal step is correct")


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rows=st.integers(0, 2000), cols=st.sampled_from([2, 3, 4]))
def test_wrong_shape_names_the_prim(cloth, rows, cols):
    rt, frames, points_k = cloth
    if (rows, cols) == points_k.shape:
        return
    _rejected(rt, frames, f"points of {CLOTH}: expected shape", points={CLOTH: np.zeros((rows, cols))})


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(bad=st.sampled_from([np.nan, np.inf, -np.inf, 1e39]), row=st.integers(0, 899), col=st.integers(0, 2))
def test_non_finite_points_are_refused(cloth, bad, row, col):
    rt, frames, points_k = cloth
    p = points_k.astype(np.float64)
    p[row, col] = bad
    _rejected(rt, frames, f"points of {CLOTH}: 1 value", points={CLOTH: p})
    with np.errstate(over="ignore"):
        device_points = wp.array(p.astype(np.float32), dtype=wp.vec3, device=rt.device)
    _rejected(rt, frames, f"points of {CLOTH}: 1 value", points={CLOTH: device_points})


def test_bad_dtype_device_and_prims(cloth, figure):
    rt, frames, points_k = cloth
    _rejected(rt, frames, "expected floating-point numbers, got dtype int64", points={CLOTH: points_k.astype(np.int64)})
    _rejected(rt, frames, "expected floating-point", points={CLOTH: np.full(points_k.shape, "x")})
    _rejected(rt, frames, "expected a wp.array of vec3",
              points={CLOTH: wp.array(points_k, dtype=wp.vec3d, device=rt.device)})
    _rejected(rt, frames, f"no mesh prim '/World/Nope'.*{CLOTH}", points={"/World/Nope": points_k})
    _rejected(rt, frames, f"mesh {GROUND} is static", points={GROUND: np.zeros((1600, 3))})
    _rejected(rt, frames, "no skeleton prim '/World/Skel'", joints={"/World/Skel": np.eye(4)[None]})
    _rejected(rt, frames, "expected a dict", points=points_k)
    if wp.get_cuda_device_count():
        other = "cpu" if rt.device.is_cuda else "cuda:0"
        _rejected(rt, frames, "the array is on", points={CLOTH: wp.array(points_k, dtype=wp.vec3, device=other)})
    frt, fframes, joints_k = figure
    _rejected(frt, fframes, f"joints of {SKELETON}: expected shape", joints={SKELETON: joints_k[:-1]})
    bad = joints_k.copy()
    bad[3, 0, 0] = np.nan
    _rejected(frt, fframes, f"joints of {SKELETON}: 1 value", joints={SKELETON: bad})


def test_a_bad_frame_with_a_feed_changes_nothing(cloth):
    rt, frames, points_k = cloth
    with pytest.raises(ValueError):
        rt.step(1e6, points={CLOTH: points_k})
    np.testing.assert_array_equal(rt.step(0).numpy(), frames[0.0])


def test_feeding_while_another_thread_steps(cloth, monkeypatch):
    rt, frames, points_k = cloth
    entered, leave, errors = threading.Event(), threading.Event(), []
    run = rt.frame.run

    def slow_run():
        entered.set()
        leave.wait(10)
        run()

    monkeypatch.setattr(rt.frame, "run", slow_run)
    worker = threading.Thread(target=lambda: rt.step(K))
    worker.start()
    entered.wait(10)
    try:
        rt.step(0, points={CLOTH: points_k})
    except RuntimeError as exc:
        errors.append(str(exc))
    leave.set()
    worker.join()
    assert errors and "another thread is stepping" in errors[0]
    np.testing.assert_array_equal(rt.output.numpy(), frames[K], "the other thread's frame is undisturbed")
    monkeypatch.undo()
    np.testing.assert_array_equal(rt.step(0).numpy(), frames[0.0])
