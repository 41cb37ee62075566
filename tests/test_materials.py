"""BRDF models and their SVD view/light factorisation against quadrature and analytic oracles."""

import numpy as np
import pytest

from warpshade.basis import sh
from warpshade.scene import _materials as M

# Directional albedo by the (96 x 192) hemisphere rule: the peaked lobes (Phong 20, GGX 0.3) are
# resolved to better than this.
ATOL_ALBEDO = 2e-3
# Quadrature identities on smooth integrands.
ATOL_QUAD = 1e-6
# Full-rank factorisation at off-grid views: bilinear view interpolation on a 32 x 32 texture;
# measured 0.8-1.6 % relative RMS for Phong 20 / GGX 0.3 / Beckmann 0.3 under random order-4
# lighting.
RTOL_VIEW_INTERP_32 = 0.03

MODELS = [M.Lambert(0.7), M.Phong(20.0), M.BlinnPhong(40.0), M.Microfacet(0.3, "ggx", f0=1.0),
          M.Microfacet(0.3, "beckmann", f0=1.0)]


def _hemi(rng, count):
    d = rng.normal(size=(count, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.05
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@pytest.mark.parametrize("brdf", MODELS, ids=lambda b: f"{b.name}")
def test_reciprocity_horizon_and_energy(brdf, rng):
    v, s = _hemi(rng, 20), _hemi(rng, 20)
    np.testing.assert_allclose(brdf.evaluate(v, s), brdf.evaluate(s, v), rtol=1e-12)
    below = s * np.array([1.0, 1.0, -1.0])
    assert np.all(brdf.evaluate(v, below) == 0.0) and np.all(brdf.evaluate(below, v) == 0.0)
    dirs, w = M.hemisphere_quadrature(96, 192)
    albedo = (brdf.evaluate(v[:5, None, :], dirs[None]) * w * dirs[:, 2]).sum(axis=1)
    assert np.all(albedo <= 1.0 + ATOL_ALBEDO)
    if isinstance(brdf, M.Lambert):
        np.testing.assert_allclose(albedo, 0.7, atol=ATOL_QUAD)


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
def test_microfacet_distribution_is_normalised(distribution):
    """Projected microfacet area: integral D(h) (n.h) dh = 1."""
    dirs, w = M.hemisphere_quadrature(200, 8)
    brdf = M.Microfacet(0.4, distribution)
    assert np.sum(brdf._d(dirs[:, 2]) * dirs[:, 2] * w) == pytest.approx(1.0, abs=1e-4)
    assert M.Microfacet.from_glossiness(0.3).roughness == pytest.approx(0.7)


def test_concentric_map_roundtrip_and_area():
    g = (np.arange(200) + 0.5) / 200 * 2 - 1
    a, b = np.meshgrid(g, g, indexing="ij")
    ab = np.stack([a.ravel(), b.ravel()], -1)
    d = M.concentric_to_hemisphere(ab)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(M.hemisphere_to_concentric(d), ab, atol=1e-12)
    # equal-area: uniform texels sample the hemisphere uniformly (mean z = 1/2, mean z^2 = 1/3)
    assert d[:, 2].mean() == pytest.approx(0.5, abs=1e-4)
    assert (d[:, 2] ** 2).mean() == pytest.approx(1.0 / 3.0, abs=1e-4)


def test_lambert_b_matrix_is_the_clamped_cosine():
    order = 5
    views = M.view_grid(4)
    b = M.brdf_matrix(M.Lambert(), order, views)
    cosine = sh.zh_to_sh(np.array([0.0, 0.0, 1.0]), sh.clamped_cosine_zh(order, "zh"))
    np.testing.assert_allclose(b, np.broadcast_to(cosine / np.pi, b.shape), atol=1e-4)
    fac = M.factorize(M.Lambert(), order, 1, resolution=4)
    assert fac.truncation_error() < 1e-12


def test_factorisation_error_decreases_with_rank():
    order = 4
    brdf = M.Microfacet(0.5, "ggx")
    b = M.brdf_matrix(brdf, order, M.view_grid(8))
    errs = [M.factorize(brdf, order, k, resolution=8, matrix=b).truncation_error() for k in range(1, 17)]
    assert np.all(np.diff(errs) <= 1e-12) and errs[-1] < 1e-12 and errs[0] > 0.3
    # the reported truncation error is the Frobenius error of U~ S~ V~ against B
    fac = M.factorize(brdf, order, 3, resolution=8, matrix=b)
    approx = fac.view_factors.reshape(-1, 3) @ fac.rows
    assert np.linalg.norm(approx - b) / np.linalg.norm(b) == pytest.approx(fac.truncation_error(), rel=1e-9)


@pytest.mark.parametrize("brdf", MODELS[1:4], ids=lambda b: b.name)
def test_glossy_shading_vs_brute_force_quadrature(brdf, rng):
    """Unshadowed glossy shading r(v) = u(v) . (V~ e) against quadrature of b L cos."""
    order = 4
    light = rng.normal(size=order * order)

    def radiance(d):
        return sh.basis(d, order) @ light

    b = M.brdf_matrix(brdf, order, M.view_grid(32))
    full = M.factorize(brdf, order, order * order, resolution=32, matrix=b)
    grid_views = M.view_grid(32)[::97]
    ref_grid = M.shade_unshadowed(brdf, grid_views, radiance, 48, 96)
    np.testing.assert_allclose(full.shade(grid_views, light), ref_grid, atol=1e-9 * np.abs(ref_grid).max())
    views = _hemi(rng, 150)
    ref = M.shade_unshadowed(brdf, views, radiance, 64, 128)
    rms = np.sqrt(np.mean(ref**2))
    err_full = np.sqrt(np.mean((full.shade(views, light) - ref) ** 2)) / rms
    assert err_full < RTOL_VIEW_INTERP_32
    err = [np.sqrt(np.mean((M.factorize(brdf, order, k, matrix=b).shade(views, light) - ref) ** 2)) / rms
           for k in (3, 9)]
    assert err[1] < err[0]


def test_bad_parameters():
    with pytest.raises(ValueError, match="distribution"):
        M.Microfacet(0.3, "phong")
    with pytest.raises(ValueError, match="roughness"):
        M.Microfacet(0.0)
    with pytest.raises(ValueError, match="rank"):
        M.factorize(M.Phong(), 2, 5)
    with pytest.raises(ValueError, match="glossiness"):
        M.Microfacet.from_glossiness(1.0)
