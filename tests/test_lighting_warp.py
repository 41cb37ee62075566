"""Device-side environment maps: bilinear lookup vs Environment.radiance (float64), and the
importance sampler's pdf vs its histogram and vs quadrature."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from warpshade.basis import quadrature
from warpshade.scene import Environment
from warpshade.scene._lighting_warp import (
    LUMINANCE_FLOOR,
    disabled_environment,
    env_texel_pdf_f64,
    lookup_environment,
    sample_environment,
    upload_environment,
)

# float32 bilinear lookup vs float64, relative to the largest radiance in the map (~40 for the
# sun): direction rotation, acos/atan2 and the interpolation weights in float32.
RTOL_LOOKUP = 5e-6
# A correct sampler fails the chi-square histogram test with probability 1e-6.
CHI2_FALSE_ALARM = 1e-6
# Unbiasedness of E[L / pdf]: within this many standard errors of the quadrature value.
Z_SCORE = 5.0
SAMPLE_COUNT = 200_000


@pytest.fixture(scope="module")
def sky():
    rot = Rotation.from_euler("xyz", [0.3, -0.5, 1.1]).as_matrix()
    return Environment.sky(height=16, width=32, sun_angle_deg=15.0, to_world=rot)


def _texel_of(env, dirs):
    local = dirs @ env.to_world
    theta = np.arccos(np.clip(local[:, 2], -1, 1))
    phi = np.mod(np.arctan2(local[:, 1], local[:, 0]), 2 * np.pi)
    row = np.clip((theta / np.pi * env.height).astype(int), 0, env.height - 1)
    col = np.clip((phi / (2 * np.pi) * env.width).astype(int), 0, env.width - 1)
    return row, col


def test_lookup_matches_float64_reference(device, sky, rng):
    dirs = rng.normal(size=(4000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    # poles, the azimuth seam and texel centres of the map frame, taken to world space
    special_map = np.concatenate(
        [[[0, 0, 1], [0, 0, -1], [1, 0, 0], [1, -1e-7, 0.3], [1, 1e-7, -0.3]], quadrature.latlong_directions(4, 8).reshape(-1, 3)]
    )
    special = special_map @ sky.to_world.T
    dirs = np.concatenate([dirs, special / np.linalg.norm(special, axis=1, keepdims=True)])
    env_map = upload_environment(sky, device)
    got = lookup_environment(env_map, dirs, device)
    ref = sky.radiance(dirs)
    np.testing.assert_allclose(got, ref, atol=RTOL_LOOKUP * np.abs(sky.image).max())


def test_sampler_histogram_matches_its_pdf(device, sky):
    env_map = upload_environment(sky, device)
    dirs, pdf, pdf_lookup = sample_environment(env_map, SAMPLE_COUNT, seed=3, device=device)
    prob, texel_pdf = env_texel_pdf_f64(sky)
    np.testing.assert_allclose(prob.sum(), 1.0, rtol=1e-12)
    # the pdf integrates to one over the sphere (texel pdf times exact texel solid angle)
    solid = quadrature.latlong(sky.height, sky.width).weights.reshape(prob.shape)
    np.testing.assert_allclose((texel_pdf * solid).sum(), 1.0, rtol=1e-12)
    row, col = _texel_of(sky, dirs.astype(np.float64))
    # the reported pdf is the texel's pdf, and env_pdf() agrees with the sampler
    inside = pdf == pdf_lookup
    assert inside.mean() > 0.999  # only draws landing exactly on a texel edge may differ
    np.testing.assert_allclose(pdf[inside], texel_pdf[row, col][inside], rtol=1e-5)
    counts = np.zeros(prob.shape)
    np.add.at(counts, (row, col), 1)
    expected = prob * SAMPLE_COUNT
    statistic = ((counts - expected) ** 2 / expected).sum()
    assert statistic < chi2.ppf(1.0 - CHI2_FALSE_ALARM, prob.size - 1)


def test_radiance_over_pdf_is_unbiased(device, sky):
    env_map = upload_environment(sky, device)
    dirs, pdf, _ = sample_environment(env_map, SAMPLE_COUNT, seed=5, device=device)
    values = sky.radiance(dirs.astype(np.float64)) / pdf[:, None]
    estimate = values.mean(0)
    stderr = values.std(0, ddof=1) / np.sqrt(SAMPLE_COUNT)
    q = quadrature.latlong(256, 512)  # fine midpoint rule over the bilinear map
    exact = (sky.radiance(q.directions @ sky.to_world.T) * q.weights[:, None]).sum(0)
    assert np.all(np.abs(estimate - exact) < Z_SCORE * stderr)
    # importance sampling helps: far below the variance of uniform sampling
    uniform = sky.radiance(q.directions @ sky.to_world.T) * 4 * np.pi
    assert np.all(values.var(0) < 0.5 * np.average((uniform - exact) ** 2, axis=0, weights=q.weights))


def test_black_map_samples_uniformly_and_disabled_is_zero(device):
    black = Environment.constant((0.0, 0.0, 0.0), height=4, width=8)
    env_map = upload_environment(black, device)
    _, pdf, _ = sample_environment(env_map, 1000, device=device)
    np.testing.assert_allclose(pdf, 1.0 / (4 * np.pi), rtol=1e-6)
    off = disabled_environment(device)
    np.testing.assert_array_equal(lookup_environment(off, [[0, 0, 1], [1, 0, 0]], device), 0.0)
    with pytest.raises(ValueError, match="disabled"):
        sample_environment(off, 10, device=device)


def test_floor_keeps_every_texel_reachable():
    img = np.zeros((8, 16, 3), np.float32)
    img[2, 5] = 100.0
    prob, pdf = env_texel_pdf_f64(Environment(img))
    assert prob.min() > 0.0
    # density = luminance (or 1/2 an edge neighbour's, 1/4 a corner's) + LUMINANCE_FLOOR * (its mean)
    lum = 100.0  # Rec. 709 weights sum to 1
    solid = quadrature.latlong(8, 16).weights.reshape(8, 16)
    spread = np.array([[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]])
    mean = lum * (spread * solid[1:4, 4:7]).sum() / (4 * np.pi)
    floor = LUMINANCE_FLOOR * mean
    assert pdf[2, 5] / pdf[0, 0] == pytest.approx((lum + floor) / floor, rel=1e-9)
    # the bilinear skirt of the bright texel is sampled with its largest bilinear weight
    np.testing.assert_allclose(pdf[1:4, 4:7], (lum * spread + floor) / floor * pdf[0, 0], rtol=1e-9)
    assert pdf[2, 7] == pytest.approx(pdf[0, 0], rel=1e-12)
