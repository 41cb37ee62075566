"""The viewer of the glossy stages (rpo.shade, sg.shade, ldprt.glossy_shade; methods/viewer.py):
with no 'eye' and no scene camera they shade toward the framing camera of the scene's bounds over
its frames, in the scene's up axis (a y-up scene gets a viewer above its ground); the scene's
camera when it has one; Runtime.set_eye moves it; the diagnostics say which; an explicit eye
below the scene is warned about before any precompute."""

import numpy as np
import pytest

from warpshade.graph import GraphSpec, StageError, StageSpec
from warpshade.measure import reference_model
from warpshade.render import frame_camera
from warpshade.scene import Camera, Environment, LightingSource, Mesh, Scene, up_rotation

from grids import ground_grid

#: The state's eye and the stage's are float32 copies of the float64 framing position.
RTOL_FLOAT32_POSITION = 1e-6
#: The hard-coded z-up eye the RPO graphs of stages/ once had (figure_rpo_traced.toml).
Z_UP_EYE = (1.2, -3.8, 1.6)
BOX_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                      [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
GROUND = 49  # vertices of the 7 x 7 ground grid, first in the scene


def _y_up(points):
    """z-up (x, y, z) -> y-up (x, z, -y): a proper rotation, so the grid's +z normals become +y."""
    p = np.asarray(points, np.float64)
    return np.stack([p[:, 0], p[:, 2], -p[:, 1]], 1)


def _box(lo, hi):
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], np.float64)


def _scene(camera=None):
    """A y-up ground (7 x 7, y = 0, normals +y) under a box that rises over 3 frames (rigid), so
    the bounds over the frames differ from the first frame's."""
    pts, faces = ground_grid(np.linspace(-1.0, 1.0, 7))
    rise = np.tile(np.eye(4), (3, 1, 1))
    rise[:, 3, 1] = [0.0, 0.5, 1.0]  # row-vector convention: the translation is the last row
    box = Mesh("/box", _box((-0.3, 0.3, -0.3), (0.3, 0.6, 0.3)), BOX_FACES, animation="rigid", transforms=rise)
    return Scene.from_meshes([Mesh("/ground", _y_up(pts), faces), box], frames=np.arange(3.0), up_axis="Y",
                             camera=camera)


def _lighting(scene):
    return LightingSource.fixed([Environment.sky(height=16, width=32, to_world=up_rotation(scene.up_axis))], scene.up_axis)


def _rpo(shade=None):
    return GraphSpec(stages=[
        StageSpec("vis", "rpo.visibility_traced", {"order": 3, "samples": 32}),
        StageSpec("shade", "rpo.shade", {"order": 3, "rank": 4, "view_order": 4, **(shade or {})}),
    ], output="shade.radiance", name="viewer-rpo")


def _sg(shade=None):
    return GraphSpec(stages=[
        StageSpec("ssdf", "sg.ssdf", {"resolution": 8, "supersample": 2}),
        StageSpec("environment", "sg.environment", {"lobes": 3}),
        StageSpec("tangents", "ldprt.tangents"),
        StageSpec("shade", "sg.shade", dict(shade or {})),
    ], output="shade.radiance", name="viewer-sg")


def _ldprt():
    return GraphSpec(stages=[
        StageSpec("fit", "ldprt.glossy_fit", {"order": 2, "lobes": 1, "rank": 2, "samples": 16, "view_resolution": 4}),
        StageSpec("tangents", "ldprt.tangents"),
        StageSpec("shade", "ldprt.glossy_shade", {"order": 2, "lobes": 1, "rank": 2, "view_resolution": 4}),
    ], output="shade.radiance", name="viewer-ldprt")


def _compile(spec, scene, device):
    return spec.compile(scene, device=device, cache_dir=None, progress=False, lighting=_lighting(scene))


def _framing(scene):
    return np.asarray(frame_camera(*scene.bounds_over_frames(), scene.up_axis).position, np.float64)


@pytest.fixture(scope="module")
def y_up():
    return _scene()


def test_framing_viewer_is_frame_camera_of_the_bounds_over_the_frames(y_up):
    from warpshade.methods._viewer import scene_viewer

    viewer = scene_viewer(y_up)
    assert viewer.source == "framing" and "up axis Y" in viewer.note
    np.testing.assert_allclose(viewer.position, _framing(y_up), rtol=1e-12)
    first = frame_camera(*y_up.bounds(0.0), "Y").position
    assert not np.allclose(viewer.position, first), "the rising box widens the bounds over the frames"
    lo, hi = y_up.bounds_over_frames()
    # above the ground and the whole scene, on the +y side of the y-up world
    assert viewer.position[1] > hi[1] > lo[1]


@pytest.mark.parametrize("graph", ["rpo", "sg", "ldprt"])
def test_y_up_scene_without_camera_is_shaded_toward_the_framing_camera(device, y_up, graph):
    rt = _compile({"rpo": _rpo, "sg": _sg, "ldprt": _ldprt}[graph](), y_up, device)
    out = rt.step(0.0).numpy()
    st = rt.output_stage()
    viewer = st.diagnostics()["viewer"]
    framing = _framing(y_up)
    assert viewer["source"] == "framing" and "up axis Y" in viewer["note"]
    np.testing.assert_allclose(viewer["position"], framing, rtol=RTOL_FLOAT32_POSITION)
    # one viewer for the run: the state's eye, which the references measure against
    np.testing.assert_allclose(rt.state.eye.numpy()[0], framing, rtol=RTOL_FLOAT32_POSITION)
    np.testing.assert_allclose(reference_model(rt, 0.0)["eye"], framing, rtol=RTOL_FLOAT32_POSITION)
    assert st.follows_state_eye
    # the ground faces +y and sees the viewer above its horizon: every ground vertex is lit
    assert np.all(np.isfinite(out)) and np.all(out[:GROUND].sum(axis=1) > 0.0)


def test_rpo_sees_nothing_from_a_z_up_eye_under_a_y_up_ground_and_is_warned(device, y_up):
    with pytest.warns(UserWarning, match=r"stage 'shade': parameter 'eye' .* below the scene's lowest y"):
        rt = _compile(_rpo({"eye": Z_UP_EYE}), y_up, device)
    out = rt.step(0.0).numpy()
    assert rt.output_stage().diagnostics()["viewer"]["source"] == "eye"
    assert not out[:GROUND].any(), "an eye under the ground sees every ground vertex below its horizon"


def test_scene_camera_is_the_viewer_and_set_eye_moves_it(device):
    camera = Camera(position=np.array([0.5, 2.5, 3.0]), target=np.zeros(3), up=np.array([0.0, 1.0, 0.0]),
                    path="/World/Camera")
    scene = _scene(camera)
    rt = _compile(_rpo(), scene, device)
    rt.step(0.0)
    viewer = rt.output_stage().diagnostics()["viewer"]
    assert viewer["source"] == "camera" and "/World/Camera" in viewer["note"]
    np.testing.assert_allclose(viewer["position"], camera.position, rtol=RTOL_FLOAT32_POSITION)
    rt.set_eye([1.0, 3.0, -2.0])
    moved = rt.step(0.0).numpy()
    viewer = rt.output_stage().diagnostics()["viewer"]
    assert viewer["source"] == "set_eye"
    np.testing.assert_allclose(viewer["position"], [1.0, 3.0, -2.0], rtol=RTOL_FLOAT32_POSITION)
    fixed = _compile(_rpo({"eye": (1.0, 3.0, -2.0)}), scene, device).step(0.0).numpy()
    np.testing.assert_array_equal(moved, fixed)


def test_set_eye_moves_the_framing_viewer(device, y_up):
    rt = _compile(_rpo(), y_up, device)
    rt.step(0.0)
    rt.set_eye([0.2, 4.0, 1.0])
    moved = rt.step(0.0).numpy()
    assert rt.output_stage().diagnostics()["viewer"]["source"] == "set_eye"
    np.testing.assert_array_equal(moved, _compile(_rpo({"eye": (0.2, 4.0, 1.0)}), y_up, device).step(0.0).numpy())


def test_explicit_eye_below_the_scene_is_warned_before_any_precompute(y_up, sg_bake_refused):
    Baked = sg_bake_refused
    with pytest.warns(UserWarning, match=r"stage 'shade': parameter 'eye' \[1\.2, -3\.8, 1\.6\]: its y = -3\.8 is below"):
        with pytest.raises(Baked):
            _compile(_sg({"eye": Z_UP_EYE}), y_up, "cpu")


@pytest.mark.parametrize("eye, message", [((1.0, 2.0), "three finite numbers"), ((0.0, float("nan"), 1.0), "finite")])
def test_bad_eye_is_refused_when_the_graph_is_built(eye, message):
    for spec in (_rpo({"eye": eye}), _sg({"eye": eye})):
        with pytest.raises(StageError, match=rf"stage 'shade': parameter 'eye' .*{message}"):
            spec.build({"V": 57, "T": 3, "F": 110})

