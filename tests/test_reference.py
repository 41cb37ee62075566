"""Monte Carlo ground truth: white furnace, convex objects, a sphere occluder vs the analytic cap
integral, analytic lights, and the reported standard error vs the spread across seeds."""

import numpy as np
import pytest
import trimesh
from grids import ground_grid

from warpshade.basis import quadrature
from warpshade.reference import shade
from warpshade.scene import DistantLight, Environment, Mesh, Scene, SphereLight

# An estimate must lie within this many reported standard errors of the exact value.
Z_SCORE = 5.0
# float32 arithmetic on exactly representable estimates (white furnace with cosine sampling).
RTOL_FLOAT32 = 2e-6
# The faceted sphere (icosphere, 3 subdivisions) occludes up to ~1e-3 less than a true sphere;
# relative to the unoccluded radiance.
FACETING_BIAS = 2e-3
# Reported stderr^2 vs the observed variance across 16 seeds, pooled over receivers and channels:
# ~40 receivers x 15 degrees of freedom => the ratio has a relative spread of ~0.06; 5 sigma.
VARIANCE_RATIO_RANGE = (0.7, 1.4)

ALBEDO = np.array([0.9, 0.6, 0.3])
BALL_CENTRE = np.array([0.0, 0.0, 1.5])
BALL_RADIUS = 0.5


@pytest.fixture(scope="module")
def ball_scene():
    ball = trimesh.creation.icosphere(2, radius=1.0)
    return Scene.from_meshes([Mesh("ball", ball.vertices, ball.faces, albedo=ALBEDO)])


@pytest.fixture(scope="module")
def ground_scene():
    """A wide ground, fine in the middle, with a sphere hovering above its centre."""
    coords = np.concatenate([[-20.0, -8.0, -4.0], np.linspace(-2.0, 2.0, 9), [4.0, 8.0, 20.0]])
    ground_p, ground_f = ground_grid(coords)
    ball = trimesh.creation.icosphere(3, radius=BALL_RADIUS)
    scene = Scene.from_meshes(
        [Mesh("ground", ground_p, ground_f, albedo=ALBEDO), Mesh("ball", np.asarray(ball.vertices) + BALL_CENTRE, ball.faces)]
    )
    receivers = np.where((np.abs(ground_p[:, 0]) <= 1.5) & (np.abs(ground_p[:, 1]) <= 1.5))[0]
    return scene, receivers


@pytest.fixture(scope="module")
def sky():
    return Environment.sky(height=32, width=64, sun_angle_deg=20.0, sun_radiance=(8.0, 7.0, 6.0))


def _cap_cosine(points, centre, radius):
    """(1/pi) * integral of max(0, z.s) over the cap a sphere subtends from ground points whose
    normal is +z -- exact when the cap is wholly above the horizon: sin^2(alpha) cos(beta)."""
    offset = centre - points
    dist = np.linalg.norm(offset, axis=1)
    sin_a = radius / dist
    cos_b = offset[:, 2] / dist
    assert np.all(np.arccos(cos_b) + np.arcsin(sin_a) < np.pi / 2)
    return sin_a**2 * cos_b


def _within(result, exact, z=Z_SCORE, slack=0.0):
    err = np.abs(result.radiance - exact)
    return np.all(err <= z * result.stderr + slack + RTOL_FLOAT32 * np.abs(exact))


def test_white_furnace(device, ball_scene):
    env = Environment.constant((1.0, 0.5, 0.25))
    expected = ALBEDO * np.array([1.0, 0.5, 0.25])
    cos = shade(ball_scene, 0.0, env, 64, device=device, method="cosine")
    np.testing.assert_allclose(cos.radiance, np.tile(expected, (ball_scene.vertex_count, 1)), rtol=RTOL_FLOAT32)
    assert cos.stderr.max() < 1e-6
    for method in ("light", "mis"):
        res = shade(ball_scene, 0.0, env, 512, device=device, method=method)
        assert res.stderr.min() > 0.0  # light sampling of a constant sky is not exact
        assert _within(res, expected)


def test_convex_object_under_a_sky(device, ball_scene, sky):
    """No self-shadowing: radiance = albedo/pi * integral L max(0, n.s), by quadrature."""
    normals = ball_scene.evaluate(0.0, device=device).normals.numpy().astype(np.float64)
    q = quadrature.latlong(256, 512)
    radiance = sky.radiance(q.directions)
    cosine = np.maximum(normals @ q.directions.T, 0.0) * q.weights
    exact = ALBEDO / np.pi * (cosine @ radiance)
    for method in ("cosine", "light", "mis"):
        res = shade(ball_scene, 0.0, sky, 1024, device=device, method=method, seed=11)
        assert _within(res, exact, slack=1e-3 * exact.max()), method
    # the light-sampled estimates are tighter than the cosine ones on a sunny sky
    cos = shade(ball_scene, 0.0, sky, 1024, device=device, method="cosine")
    mis = shade(ball_scene, 0.0, sky, 1024, device=device, method="mis")
    assert np.median(mis.stderr) < np.median(cos.stderr)


def test_sphere_occluder_matches_cap_integral(device, ground_scene):
    scene, receivers = ground_scene
    env = Environment.constant((1.0, 1.0, 1.0))
    res = shade(scene, 0.0, env, 4096, device=device, method="mis", vertices=receivers)
    blocked = _cap_cosine(scene.points_at(0.0)[receivers], BALL_CENTRE, BALL_RADIUS)
    exact = ALBEDO * (1.0 - blocked)[:, None]
    assert blocked.max() > 0.08  # a visible shadow
    assert _within(res, exact, slack=FACETING_BIAS * ALBEDO.max())


def test_stderr_matches_spread_across_seeds(device, ground_scene, sky):
    scene, receivers = ground_scene
    runs = [shade(scene, 0.0, sky, 128, device=device, method="mis", seed=s, vertices=receivers) for s in range(16)]
    values = np.stack([r.radiance for r in runs]).astype(np.float64)
    reported = np.stack([r.stderr for r in runs]).astype(np.float64) ** 2
    ratio = values.var(axis=0, ddof=1).sum() / reported.mean(axis=0).sum()
    assert VARIANCE_RATIO_RANGE[0] < ratio < VARIANCE_RATIO_RANGE[1]


def test_delta_distant_light_casts_a_sharp_shadow(device, ground_scene):
    scene, receivers = ground_scene
    direction = np.array([0.3, 0.0, 1.0]) / np.linalg.norm([0.3, 0.0, 1.0])
    irradiance = np.array([2.0, 1.0, 3.0])
    res = shade(scene, 0.0, DistantLight(direction, irradiance, angle_deg=0.0), 8, device=device, vertices=receivers)
    assert res.stderr.max() == 0.0
    p = scene.points_at(0.0)[receivers]
    # distance from the ball's centre to the shadow ray toward the light
    along = (BALL_CENTRE - p) @ direction
    miss = np.linalg.norm(BALL_CENTRE - p - along[:, None] * direction, axis=1)
    lit, dark = miss > 1.05 * BALL_RADIUS, miss < 0.95 * BALL_RADIUS  # clear of the facets
    assert lit.sum() > 10 and dark.sum() >= 2
    np.testing.assert_allclose(res.radiance[lit], np.tile(ALBEDO / np.pi * irradiance * direction[2], (lit.sum(), 1)), rtol=1e-5)
    assert np.all(res.radiance[dark] == 0.0)


def test_area_lights_match_their_cap_integrals(device):
    ground_p, ground_f = ground_grid(np.linspace(-1.0, 1.0, 5))
    scene = Scene.from_meshes([Mesh("ground", ground_p, ground_f, albedo=ALBEDO)])
    sphere = SphereLight(position=(0.5, 0.3, 2.0), radius=0.4, radiance=(5.0, 4.0, 3.0))
    res = shade(scene, 0.0, sphere, 256, device=device)
    exact = ALBEDO * np.asarray(sphere.radiance) * _cap_cosine(ground_p, sphere.position, sphere.radius)[:, None]
    assert _within(res, exact)
    # a distant disc: radiance E / Omega over a cap of half-angle a about its direction
    direction = np.array([0.2, -0.4, 1.0]) / np.linalg.norm([0.2, -0.4, 1.0])
    disc = DistantLight(direction, irradiance=(3.0, 3.0, 3.0), angle_deg=10.0)
    half = np.radians(5.0)
    omega = 2 * np.pi * (1 - np.cos(half))
    res = shade(scene, 0.0, disc, 64, device=device)
    exact = ALBEDO / np.pi * 3.0 / omega * np.pi * np.sin(half) ** 2 * direction[2]
    assert res.stderr.max() > 0.0 and _within(res, np.tile(exact, (scene.vertex_count, 1)))


def test_result_api_and_bad_input(device, ball_scene):
    env = Environment.constant((1.0, 1.0, 1.0))
    scene = Scene.from_meshes(ball_scene.meshes, lights=[env])
    res = shade(scene, 0.0, None, 8, device=device, method="cosine", vertices=[0, 5])
    assert np.asarray(res).shape == (2, 3) and res.stderr.shape == (2, 3)
    with pytest.raises(ValueError, match="at most one Environment"):
        shade(scene, 0.0, [env, env], 8, device=device)
    with pytest.raises(ValueError, match="unsupported light"):
        shade(scene, 0.0, ["sun"], 8, device=device)
    with pytest.raises(ValueError, match="method"):
        shade(scene, 0.0, env, 8, device=device, method="uniform")
    with pytest.raises(ValueError, match="samples"):
        shade(scene, 0.0, env, 1, device=device)
    with pytest.raises(ValueError, match="mis"):
        shade(scene, 0.0, env, 3, device=device, method="mis")


def test_chunked_launches_give_identical_results(device, ball_scene, sky):
    # 162 receivers x 512 rays is above CHUNK_MIN_RAYS, so workers=2 really splits the launch
    one = shade(ball_scene, 0.0, sky, 512, device=device, workers=1)
    two = shade(ball_scene, 0.0, sky, 512, device=device, workers=2)
    np.testing.assert_array_equal(one.radiance, two.radiance)
    np.testing.assert_array_equal(one.stderr, two.stderr)
