"""Animated cameras: read from USD, the eye followed per frame inside the recorded frame, and the
glossy reference of each frame taken from that frame's eye."""

import numpy as np
from grids import ground_grid

from warpshade.graph import GraphSpec, StageSpec
from warpshade.io import load_scene
from warpshade.measure import reference_model
from warpshade.scene import Camera, Environment, LightingSource, Mesh, Scene


def _sheet_with_camera(frames=4):
    pts, faces = ground_grid(np.linspace(-1.0, 1.0, 5))
    path = np.array([[3.0 * np.cos(t), 3.0 * np.sin(t), 2.0] for t in np.linspace(0.0, 1.5, frames)])
    cam = Camera(position=path[0], target=np.zeros(3), up=np.array([0.0, 0.0, 1.0]), positions=path)
    scene = Scene.from_meshes([Mesh("/sheet", pts, faces)], frames=np.arange(float(frames)))
    scene.camera = cam
    return scene, path


def test_bundled_orbit_camera_moves():
    scene = load_scene("bundled:figure_orbit")
    assert scene.camera.moving and scene.camera.positions.shape == (len(scene.frames), 3)
    assert np.linalg.norm(scene.camera.positions[-1] - scene.camera.positions[0]) > 1.0
    still = load_scene("bundled:figure")
    assert not still.camera.moving


def test_eye_follows_the_camera_in_the_recorded_frame_until_set(device):
    scene, path = _sheet_with_camera()
    spec = GraphSpec(stages=[StageSpec("vis", "rpo.visibility_traced", {"order": 3, "samples": 32}),
                             StageSpec("shade", "rpo.shade", {"order": 3, "rank": 4, "view_order": 4})],
                     output="shade.radiance")
    rt = spec.compile(scene, device=device, cache_dir=None, progress=False,
                      lighting=LightingSource.fixed([Environment.sky()], "Z"))
    outs = []
    for f in (0.0, 1.0, 0.0, 1.0, 2.0, 3.0):  # the frame is recorded after the first two steps
        outs.append(rt.step(f).numpy().copy())
        np.testing.assert_allclose(rt.state.eye.numpy()[0], path[int(f)], rtol=1e-6)
    np.testing.assert_array_equal(outs[0], outs[2])
    assert not np.allclose(outs[0], outs[1])
    for f in range(4):
        np.testing.assert_allclose(reference_model(rt, float(f))["eye"], path[f], rtol=1e-6)
    rt.set_eye([0.0, 0.0, 5.0])
    rt.step(3.0)
    np.testing.assert_allclose(rt.state.eye.numpy()[0], [0.0, 0.0, 5.0])
    np.testing.assert_allclose(reference_model(rt, 1.0)["eye"], [0.0, 0.0, 5.0])
