"""Environment and light SH projections against exact SH of analytic radiance."""

import math

import numpy as np
import pytest

from warpshade.basis import sh
from warpshade.scene import DistantLight, Environment, SphereLight, sky_radiance, up_rotation

#: Pixel-centre (midpoint) quadrature of a smooth function on a 64 x 128 lat-long grid with
#: exact pixel solid angles: second order in the row height pi/64, error ~ (pi/64)**2 / 12 of
#: the function's scale ~ 2e-4; 1e-3 leaves margin.
LATLONG_64_RTOL = 1e-3
#: Coefficients that are exactly zero analytically come out at the same quadrature level.
LATLONG_64_ATOL = 1e-3
#: The delta limit of a narrow disc light: relative difference ~ (angle)**2 l(l+1) / 16.
NARROW_DISC_RTOL = 1e-4

SQRT_4PI = math.sqrt(4 * math.pi)
SQRT_4PI_3 = math.sqrt(4 * math.pi / 3)


def _linear_env(a, b, height=64, width=128, to_world=None):
    """Map-frame radiance a + b * z per RGB channel, as a lat-long image."""
    from warpshade.basis import quadrature

    z = quadrature.latlong_directions(height, width)[..., 2:3]
    img = np.asarray(a)[None, None, :] + np.asarray(b)[None, None, :] * z
    return Environment(img.astype(np.float64), np.eye(3) if to_world is None else to_world)


def _exact_linear_sh(a, b, axis, order):
    """Exact SH of a + b (d . axis) in Sloan's convention: only bands 0 and 1."""
    c = np.zeros((3, order * order))
    c[:, 0] = np.asarray(a) * SQRT_4PI
    nx, ny, nz = axis
    c[:, 1] = -np.asarray(b) * SQRT_4PI_3 * ny
    c[:, 2] = np.asarray(b) * SQRT_4PI_3 * nz
    c[:, 3] = -np.asarray(b) * SQRT_4PI_3 * nx
    return c


A = (1.0, 0.5, 0.25)
B = (0.6, -0.3, 0.2)


def test_linear_environment_projects_to_exact_sh():
    env = _linear_env(A, B)
    got = env.to_sh(4)
    exact = _exact_linear_sh(A, B, (0.0, 0.0, 1.0), 4)
    scale = np.abs(exact).max()
    np.testing.assert_allclose(got, exact, atol=LATLONG_64_ATOL * scale, rtol=LATLONG_64_RTOL)


def test_projection_error_shrinks_quadratically_with_resolution():
    errors = []
    for h in (16, 32, 64):
        env = _linear_env(A, B, height=h, width=2 * h)
        errors.append(np.abs(env.to_sh(3) - _exact_linear_sh(A, B, (0, 0, 1), 3)).max())
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all(ratios > 3.5), ratios  # midpoint rule: error / 4 per halving of the pixel size


def test_rotated_environment(rng):
    rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    rot *= np.linalg.det(rot)
    env = _linear_env(A, B, to_world=rot)
    exact = _exact_linear_sh(A, B, rot[:, 2], 3)  # map +z ends up at world rot @ e_z
    np.testing.assert_allclose(env.to_sh(3), exact, atol=LATLONG_64_ATOL * np.abs(exact).max())
    # rotating the environment again is the same as building it with the composed rotation
    extra = up_rotation("Y")
    np.testing.assert_allclose(env.rotated(extra).to_sh(3), _linear_env(A, B, to_world=extra @ rot).to_sh(3), atol=1e-12)


def test_windowed_projection():
    strength = 0.05
    got = _linear_env(A, B).to_sh(3, window="gaussian", strength=strength)
    exact = _exact_linear_sh(A, B, (0, 0, 1), 3)
    exact[:, 1:4] *= math.exp(-strength * 2)  # heat-kernel window: exp(-s l (l + 1)) on band 1
    np.testing.assert_allclose(got, exact, atol=LATLONG_64_ATOL * np.abs(exact).max())
    from warpshade.basis.sh import window  # noqa: F401  (the windowing API this relies on)


def test_constant_environment_dc_and_band_one_are_exact():
    # exact pixel solid angles make the DC term exact; band 1 vanishes by the grid's symmetry
    got = Environment.constant((2.0, 1.0, 0.5)).to_sh(2)
    expected = np.zeros((3, 4))
    expected[:, 0] = np.array([2.0, 1.0, 0.5]) * SQRT_4PI
    np.testing.assert_allclose(got, expected, atol=1e-12)


def test_distant_light_sh_is_the_delta_limit(rng):
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    irradiance = np.array([3.0, 2.0, 1.0])
    delta = DistantLight(direction, irradiance, angle_deg=0.0).to_sh(4)
    expected = irradiance[:, None] * sh.basis(direction, 4)[None, :]
    np.testing.assert_allclose(delta, expected, rtol=1e-10, atol=1e-12)
    narrow = DistantLight(direction, irradiance, angle_deg=0.5).to_sh(4)
    np.testing.assert_allclose(narrow, expected, rtol=NARROW_DISC_RTOL, atol=NARROW_DISC_RTOL * np.abs(expected).max())


def test_sphere_light_dc_term_is_its_solid_angle():
    light = SphereLight(position=(0.0, 0.0, 2.0), radius=1.0, radiance=(1.0, 2.0, 3.0))
    c = light.to_sh_at((0.0, 0.0, 0.0), 2)
    solid_angle = 2 * math.pi * (1 - math.cos(math.asin(0.5)))
    np.testing.assert_allclose(c[:, 0], np.array([1.0, 2.0, 3.0]) * solid_angle / SQRT_4PI, rtol=1e-10)
    with pytest.raises(ValueError, match="radius must be > 0"):
        SphereLight(position=(0, 0, 0), radius=0.0, radiance=(1, 1, 1))


def test_sky_environment_matches_sky_radiance():
    from warpshade.basis import quadrature

    env = Environment.sky(height=8, width=16)
    np.testing.assert_allclose(env.image, sky_radiance(quadrature.latlong_directions(8, 16)), rtol=1e-6)
    assert np.linalg.det(up_rotation("Y")) == pytest.approx(1.0)
    np.testing.assert_allclose(up_rotation("Y") @ [0, 0, 1], [0, 1, 0])


def test_environment_values_and_sizes_are_checked():
    """Negative radiance in a map, and map sizes below one texel, are named errors (a negative
    texel would shade negative light; a zero size once divided by zero)."""
    img = np.ones((4, 8, 3), np.float32)
    img[1, 2, 0] = -0.5
    with pytest.raises(ValueError, match=r"environment <array>: image has 1 negative values .* \(1, 2, 0\)"):
        Environment(img)
    for kw in ({"height": 0, "width": 8}, {"height": 4, "width": -1}, {"height": 2.5, "width": 8}):
        with pytest.raises(ValueError, match=r"Environment.sky: (height|width) must be an integer >= 1"):
            Environment.sky(**kw)
    with pytest.raises(ValueError, match=r"Environment.constant: height must be an integer >= 1"):
        Environment.constant(height=0)
