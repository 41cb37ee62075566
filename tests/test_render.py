"""Preview renderer: pixel values of a known per-vertex colour field against float64 ray-plane
intersection, backgrounds, tone mapping vs its reference, framing, and atomic PNG output."""

import math
import os

import numpy as np
import pytest
from grids import ground_grid
from PIL import Image

from warpshade._wp import wp
from warpshade.measure._pictures import ERROR_COLORMAP
from warpshade.measure import comparison_figure, error_colors
from warpshade.render import camera_basis, frame_camera, render, tonemap_f64, write_png
from warpshade.render import tonemap
from warpshade.scene import Camera, Environment, Mesh, Scene

from tolerances import ATOL_FLOAT32

# Tone-mapped 8-bit values may differ by one level where float32 rounding crosses a .5 step.
MAX_LEVEL_DIFFERENCE = 1
# Pixels closer than this (in plane units) to the plane's border are not compared (the
# float32 ray may land on the other side of the border than the float64 one).
BORDER = 1e-3

WIDTH, HEIGHT = 32, 24


def _field(p):
    """A colour field linear in position (so per-vertex interpolation reproduces it exactly)."""
    return np.stack([0.25 + 0.2 * p[..., 0], 0.5 + 0.2 * p[..., 1], np.full(p.shape[:-1], 0.3)], -1)


@pytest.fixture(scope="module")
def plane_scene():
    points, faces = ground_grid(np.linspace(-1, 1, 5))
    return Scene.from_meshes([Mesh("plane", points, faces)])


CAMERA = Camera(position=np.array([0.2, -0.9, 2.5]), target=np.array([0.05, 0.0, 0.0]), up=np.array([0.0, 1.0, 0.0]), vertical_fov=50.0)


def _pixel_rays(camera, width, height):
    """Float64 pixel-centre rays of the documented camera convention, shape (H, W, 3)."""
    forward, right, up = camera_basis(camera)
    tan_v = math.tan(math.radians(camera.vertical_fov) / 2)
    cols = (2 * (np.arange(width) + 0.5) / width - 1) * tan_v * width / height
    rows = (1 - 2 * (np.arange(height) + 0.5) / height) * tan_v
    d = forward + cols[None, :, None] * right + rows[:, None, None] * up
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def test_vertex_colours_match_ray_plane_oracle(device, plane_scene):
    colours = _field(plane_scene.points_at(0.0))
    res = render(plane_scene, colors=colours, camera=CAMERA, width=WIDTH, height=HEIGHT, device=device)
    rays = _pixel_rays(CAMERA, WIDTH, HEIGHT)
    t = -CAMERA.position[2] / rays[..., 2]
    hit_point = CAMERA.position + t[..., None] * rays
    inside = np.all(np.abs(hit_point[..., :2]) < 1 - BORDER, axis=-1)
    outside = np.any(np.abs(hit_point[..., :2]) > 1 + BORDER, axis=-1)
    assert inside.sum() > 100 and outside.sum() > 50
    np.testing.assert_allclose(res.linear[inside], _field(hit_point[inside]), atol=ATOL_FLOAT32)
    assert np.all(res.coverage[inside] == 1.0) and np.all(res.coverage[outside] == 0.0)
    assert np.all(res.image[outside] == 128)  # neutral grey background
    expected = tonemap_f64(res.linear, 1.0 - res.coverage)
    assert np.abs(res.image.astype(int) - expected.astype(int)).max() <= MAX_LEVEL_DIFFERENCE


def test_environment_background_and_pixel_callback(device, plane_scene):
    sky = Environment.sky(height=16, width=32)
    res = render(plane_scene, shade=lambda gb: gb.normal, camera=CAMERA, width=WIDTH, height=HEIGHT, environment=sky, device=device)
    rays = _pixel_rays(CAMERA, WIDTH, HEIGHT)
    hit = res.coverage == 1.0
    miss = res.coverage == 0.0
    # the callback saw camera-facing shading normals: +z for the plane seen from above
    np.testing.assert_allclose(res.linear[hit], np.tile([0.0, 0.0, 1.0], (hit.sum(), 1)), atol=ATOL_FLOAT32)
    ref = sky.radiance(rays[miss])
    np.testing.assert_allclose(res.linear[miss], ref, atol=1e-4 * np.abs(sky.image).max())


def test_supersampling_box_filters(device, plane_scene):
    colours = _field(plane_scene.points_at(0.0))
    big = render(plane_scene, colors=colours, camera=CAMERA, width=2 * WIDTH, height=2 * HEIGHT, device=device)
    small = render(plane_scene, colors=colours, camera=CAMERA, width=WIDTH, height=HEIGHT, supersample=2, device=device)
    pooled = big.linear.reshape(HEIGHT, 2, WIDTH, 2, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(small.linear, pooled, atol=ATOL_FLOAT32)
    np.testing.assert_allclose(small.coverage, big.coverage.reshape(HEIGHT, 2, WIDTH, 2).mean(axis=(1, 3)))


def test_tonemap_kernel_matches_reference(device, rng):
    linear = np.exp(rng.normal(size=(9, 7, 3)) * 2.0).astype(np.float32)
    grey = np.where(rng.uniform(size=(9, 7)) < 0.3, rng.uniform(size=(9, 7)), 0.0).astype(np.float32)
    for mode in ("srgb", "reinhard"):
        got = tonemap(
            wp.array(linear.reshape(-1, 3), dtype=wp.vec3, device=device),
            wp.array(grey.ravel(), dtype=wp.float32, device=device),
            7, 9, exposure=-1.5, mode=mode,
        )
        ref = tonemap_f64(linear, grey, exposure=-1.5, mode=mode)
        assert np.abs(got.astype(int) - ref.astype(int)).max() <= MAX_LEVEL_DIFFERENCE
    with pytest.raises(ValueError, match="mode"):
        tonemap_f64(linear, mode="filmic")


def test_frame_camera_keeps_the_bounds_in_view():
    lo, hi = np.array([-1.0, -2.0, 0.0]), np.array([3.0, 1.0, 0.5])
    for up_axis in ("Z", "Y"):
        cam = frame_camera(lo, hi, up_axis=up_axis, aspect=WIDTH / HEIGHT)
        forward, right, up = camera_basis(cam)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        rel = corners - cam.position
        depth = rel @ forward
        tan_v = math.tan(math.radians(cam.vertical_fov) / 2)
        assert np.all(depth > 0)
        assert np.all(np.abs(rel @ up / depth) < tan_v)
        assert np.all(np.abs(rel @ right / depth) < tan_v * WIDTH / HEIGHT)
        assert up[["X", "Y", "Z"].index(up_axis)] > 0.5  # upright


def test_png_written_atomically(device, plane_scene, tmp_path):
    path = tmp_path / "tiny.png"
    res = render(plane_scene, colors=_field(plane_scene.points_at(0.0)), camera=CAMERA, width=8, height=6, path=path, device=device)
    assert res.path == str(path)
    np.testing.assert_array_equal(np.asarray(Image.open(path)), res.image)
    before = path.read_bytes()
    with pytest.raises(ValueError, match="uint8"):
        write_png(path, res.image.astype(np.float32))
    assert path.read_bytes() == before  # a failed write leaves the old file alone
    with pytest.raises(ValueError, match="does not exist"):
        write_png(tmp_path / "missing" / "x.png", res.image)
    assert sorted(os.listdir(tmp_path)) == ["tiny.png"]  # no temporary files left behind
    with pytest.raises(ValueError, match="exactly one"):
        render(plane_scene, camera=CAMERA, width=8, height=6, device=device)


def test_error_colours_are_the_colour_map_at_the_signed_error():
    import matplotlib

    rng = np.random.default_rng(3)
    ref = rng.uniform(0.2, 1.0, (50, 3))
    cmap = matplotlib.colormaps[ERROR_COLORMAP]
    for scale, t in [(1.0, 0.5), (1.25, 0.75), (0.5, 0.0), (3.0, 1.0)]:
        # a uniform scale of every vertex: the error (Y_est - Y_ref) / mean Y_ref varies per
        # vertex, so compare against the colour map at each vertex's own error
        colours, err = error_colors(ref * scale, ref, limit=0.5)
        y = ref @ np.array([0.2126, 0.7152, 0.0722])
        assert np.allclose(err, (scale - 1.0) * y / y.mean(), atol=1e-12)
        expect = cmap(np.clip(0.5 + err, 0.0, 1.0))[:, :3]
        encoded = np.where(colours <= 0.0031308, 12.92 * colours, 1.055 * colours ** (1 / 2.4) - 0.055)
        assert np.allclose(encoded, expect, atol=1e-5), f"scale {scale} (t={t})"
    with pytest.raises(ValueError, match="must both be"):
        error_colors(ref[:, :2], ref[:, :2])
    with pytest.raises(ValueError, match="no positive mean"):
        error_colors(ref, np.zeros_like(ref))


def test_comparison_figure_is_written_atomically(device, plane_scene, tmp_path):
    ref = _field(plane_scene.points_at(0.0))
    path = comparison_figure(plane_scene, 0.0, ref * 0.9, ref, tmp_path / "sub" / "cmp.png", width=64, height=48,
                             supersample=1, device=device)
    with Image.open(path) as img:
        assert img.size[0] > 3 * 64 and img.size[1] > 48
    assert [p.name for p in path.parent.iterdir()] == ["cmp.png"], "no temporary files left behind"
    with pytest.raises(ValueError, match="must be"):
        comparison_figure(plane_scene, 0.0, ref[:3], ref, tmp_path / "bad.png", device=device)
    assert not (tmp_path / "bad.png").exists()
