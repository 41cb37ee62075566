"""The bundled ``sunlit`` scene: a glossy torus knot with a roughness texture on a textured ground
plane, an HDR sky with a small, very bright sun, and a moving tinted sphere light."""

import os

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from warpshade.basis import quadrature
from warpshade.io import bundled_asset_directory, load_usd
from warpshade.scene import Environment, SphereLight
from warpshade.scene import Texture
from warpshade.usd_assets import generator
from warpshade.usd_assets.generator import sunlit

from asset_compare import asset_differences

ASSETS = bundled_asset_directory()
SUNLIT_FILES = ["sunlit.usda", "sunlit_sky.hdr", "sunlit_knot_roughness.png", "sunlit_ground_diffuse.png",
                "sunlit_ground_roughness.png"]
MAX_TOTAL_BYTES = 1_500_000
#: Texels brighter than this multiple of the median sky radiance are the sun's.
SUN_THRESHOLD = 1000.0
#: RGBE stores 8-bit mantissas (relative error < 2**-8 per texel), and the sun covers a handful of
#: texels: its irradiance ratio to the sky is reproduced to ~1 %.
RTOL_RGBE_IRRADIANCE = 0.02


@pytest.fixture(scope="module")
def scene():
    return load_usd("bundled:sunlit")


def _mesh(scene, name):
    return next(m for m in scene.meshes if m.path == f"/World/{name}")


def test_generator_reproduces_the_bundled_files(tmp_path):
    written = generator.generate(str(tmp_path), scenes=["sunlit"])
    assert set(SUNLIT_FILES) <= {os.path.basename(p) for p in written}
    total = 0
    for name in SUNLIT_FILES:
        total += os.path.getsize(os.path.join(ASSETS, name))
        differences = asset_differences(os.path.join(ASSETS, name), tmp_path / name)  # values, not bytes
        assert not differences, (f"{name} differs: rerun python -m warpshade.usd_assets.generator --scenes sunlit\n"
                                 + "\n".join(differences))
    assert total < MAX_TOTAL_BYTES, f"sunlit files total {total} bytes"
    assert "sunlit" not in generator.SCENES  # regenerated explicitly, like ripples


def test_meshes_uvs_and_surface_maps(scene):
    assert scene.up_axis == "Z" and len(scene.frames) == 48 and scene.fps == 24.0 and scene.camera is not None
    knot, ground = _mesh(scene, "Knot"), _mesh(scene, "Ground")
    assert 1500 <= knot.vertex_count <= 3000 and ground.vertex_count >= 40 * 40
    assert knot.normals is not None and knot.uvs.shape == (knot.vertex_count, 2) and ground.uvs is not None
    # smooth authored normals agree with the triangles' orientation; the knot rests on the ground
    p, f = knot.points, knot.faces
    face_normal = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    assert np.all(np.sum(face_normal * knot.normals[f].mean(axis=1), axis=1) > 0)
    assert abs(p[:, 2].min()) < 1e-3 and np.ptp(ground.points[:, 0]) == pytest.approx(6.0)
    # spatially varying roughness in the texture and at the vertices, specular workflow on the knot
    rough = knot.surface.roughness
    assert isinstance(rough, Texture) and rough.channels == 1 and rough.wrap_s == "repeat"
    lo, hi = sunlit.SUNLIT_KNOT_ROUGHNESS
    assert rough.value_range[0] == pytest.approx(lo, abs=1 / 255) and rough.value_range[1] == pytest.approx(hi, abs=1 / 255)
    at = knot.surface.at_vertices(knot.uvs)
    assert at["roughness"].min() < 0.12 and at["roughness"].max() > 0.45
    assert knot.surface.use_specular_workflow and np.all(at["specular"] > at["diffuse"])
    # the ground: sRGB diffuse texture (two tile colours), raw roughness noise, dielectric F0
    g = ground.surface.at_vertices(ground.uvs)
    assert set(ground.surface.textures) == {"diffuse", "roughness"}
    assert np.ptp(g["diffuse"][:, 0]) > 0.3 and np.ptp(g["roughness"]) > 0.2
    np.testing.assert_allclose(g["specular"], 0.04)
    np.testing.assert_allclose(ground.albedo, g["diffuse"], atol=1e-6)


def test_sky_has_a_small_very_bright_sun(scene):
    env = next(light for light in scene.lights if isinstance(light, Environment))
    lum = env.image @ np.array([0.2126, 0.7152, 0.0722])
    sky_median = np.median(lum)
    sun = lum > SUN_THRESHOLD * sky_median
    assert 1 <= sun.sum() <= 12 and lum.max() > 1e4 * sky_median
    q = quadrature.latlong(env.height, env.width)
    dirs = q.directions @ env.to_world.T
    weight = (q.weights * np.maximum(dirs[:, 2], 0.0)).reshape(env.height, env.width)
    e_sun, e_sky = np.sum(lum * weight * sun), np.sum(lum * weight * ~sun)
    assert e_sun / e_sky == pytest.approx(sunlit.SUNLIT_SUN_TO_SKY, rel=RTOL_RGBE_IRRADIANCE)
    # the sun's solid angle is that of a 1.2 degree disc, and it sits where the generator put it
    solid = np.sum(lum * q.weights.reshape(lum.shape) * sun) / lum.max()
    assert np.pi * np.radians(0.5) ** 2 < solid < np.pi * np.radians(0.9) ** 2
    direction = np.sum(dirs.reshape(*lum.shape, 3) * (lum * sun)[..., None], axis=(0, 1))
    direction /= np.linalg.norm(direction)
    assert np.degrees(np.arccos(direction @ sunlit.sunlit_sun_direction())) < 0.7
    assert 35.0 <= np.degrees(np.arcsin(direction[2])) <= 45.0


def test_the_sun_casts_a_shadow_of_the_knot_in_view(scene, device):
    from warpshade.geometry._bvh import Visibility

    ground = _mesh(scene, "Ground")
    sun = sunlit.sunlit_sun_direction()
    vis = Visibility.from_scene(scene, frame=0.0, device=device)
    origins = ground.points + [0.0, 0.0, 1e-3]
    shadowed = vis.occluded(origins, np.tile(sun, (len(origins), 1))).numpy().astype(bool)
    assert 0.01 < shadowed.mean() < 0.2
    # the shadow lies away from the sun, next to the knot, and inside the camera's frame
    centre = ground.points[shadowed].mean(axis=0)
    assert centre[:2] @ sun[:2] < -0.2
    cam = scene.camera
    forward = (cam.target - cam.position) / np.linalg.norm(cam.target - cam.position)
    right = np.cross(forward, cam.up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    half = np.tan(np.radians(cam.vertical_fov) / 2.0)
    for points in (ground.points[shadowed], _mesh(scene, "Knot").points):
        rel = points - cam.position
        depth = rel @ forward
        x, y = (rel @ right) / depth / (1.5 * half), (rel @ up) / depth / half  # 36 x 24 mm aperture
        assert depth.min() > 0 and np.abs(x).max() < 0.95 and np.abs(y).max() < 0.95


def test_sphere_light_moves_outside_the_knot(scene):
    lamp = next(light for light in scene.lights if isinstance(light, SphereLight))
    assert 0.05 <= lamp.radius <= 0.1 and lamp.track is not None
    assert np.ptp(lamp.radiance) > 0.3 * lamp.radiance.max()  # tinted
    positions = np.stack([lamp.at(f).position for f in scene.frames])
    assert np.linalg.norm(positions - positions[0], axis=1).max() > 2.0
    hull = ConvexHull(_mesh(scene, "Knot").points)
    # signed distance to the hull's facet planes (outward normals): > radius for some facet means
    # a separating plane, so the whole sphere is outside the convex hull
    clearance = (positions @ hull.equations[:, :3].T + hull.equations[:, 3]).max(axis=1)
    assert clearance.min() > lamp.radius + 0.2
    assert (positions[:, 2] - lamp.radius).min() > 0.3  # above the ground plane
