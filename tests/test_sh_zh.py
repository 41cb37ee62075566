"""Zonal harmonics: rotation rule, projection about an axis, clamped cosine, caps, windows."""

import numpy as np
import pytest
from scipy import integrate
from scipy.special import eval_legendre

from warpshade.basis import quadrature, sh

from tolerances import ATOL_FLOAT64, ATOL_ZH_FLOAT32

# scipy.integrate.quad on a smooth polynomial: its own error estimate is ~1e-14.
ATOL_QUAD = 1e-10


def zonal_values(axis: np.ndarray, g: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """g(s) = sum_l g_l sqrt((2l+1)/4pi) P_l(axis . s), straight from Legendre polynomials."""
    t = dirs @ axis
    return sum(g[l] * np.sqrt((2 * l + 1) / (4 * np.pi)) * eval_legendre(l, t) for l in range(len(g)))


def unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def hemisphere_rule(normal: np.ndarray, nodes: int):
    """Gauss-Legendre in z' = n.s over [0, 1] x uniform azimuth: exact for polynomials in s of
    degree < 2*nodes restricted to the hemisphere around ``normal`` (the clamp is the boundary)."""
    z, wz = np.polynomial.legendre.leggauss(nodes)
    z, wz = 0.5 * (z + 1.0), 0.5 * wz
    n_phi = 2 * nodes + 1
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - zz**2)
    local = np.stack([r * np.cos(pp), r * np.sin(pp), zz], -1).reshape(-1, 3)
    t1 = unit(np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0]))
    t2 = np.cross(normal, t1)
    dirs = local @ np.stack([t1, t2, normal])
    weights = np.repeat(wz * 2 * np.pi / n_phi, n_phi)
    return dirs, weights


@pytest.mark.parametrize("order", [1, 4, 8])
def test_zh_to_sh_matches_projection_of_the_zonal_function(order, rng):
    axis = unit(rng.standard_normal(3))
    g = rng.standard_normal(order)
    q = quadrature.gauss_legendre(2 * (order - 1))
    expect = (sh.basis(q.directions, order) * q.weights[:, None]).T @ zonal_values(axis, g, q.directions)
    np.testing.assert_allclose(sh.zh_to_sh(axis, g), expect, atol=ATOL_FLOAT64)


def test_zh_round_trip_and_projection_properties(rng):
    order = 7
    axes = unit(rng.standard_normal((5, 3)))
    g = rng.standard_normal((5, order))
    np.testing.assert_allclose(sh.zh_from_sh_about_axis(sh.zh_to_sh(axes, g), axes), g, atol=ATOL_FLOAT64)
    # About +z the projection keeps exactly the m = 0 coefficients.
    f = rng.standard_normal(order * order)
    m0 = np.array([f[l * l + l] for l in range(order)])
    np.testing.assert_allclose(sh.zh_from_sh_about_axis(f, [0, 0, 1]), m0, atol=ATOL_FLOAT64)
    # It is an orthogonal projection: the residual is orthogonal to every zonal function about a.
    resid = f - sh.zh_to_sh(axes[0], sh.zh_from_sh_about_axis(f, axes[0]))
    for l in range(order):
        e = np.zeros(order)
        e[l] = 1.0
        assert abs(resid @ sh.zh_to_sh(axes[0], e)) < ATOL_FLOAT64
    # A delta at the axis has g_l = sqrt((2l+1)/4pi) and SH coefficients y_lm(axis).
    delta = np.sqrt((2 * np.arange(order) + 1) / (4 * np.pi))
    np.testing.assert_allclose(sh.zh_to_sh(axes[1], delta), sh.basis(axes[1], order), atol=ATOL_FLOAT64)


def test_zh_broadcasting_and_bad_input(rng):
    assert sh.zh_to_sh(unit(rng.standard_normal((4, 1, 3))), rng.standard_normal((3, 5))).shape == (4, 3, 25)
    assert sh.zh_from_sh_about_axis(rng.standard_normal(16), unit(rng.standard_normal((6, 3)))).shape == (6, 4)
    with pytest.raises(ValueError, match="zero-length"):
        sh.zh_to_sh([0, 0, 0], [1.0, 2.0])
    with pytest.raises(ValueError, match="NaN"):
        sh.zh_to_sh([0, 0, 1], [np.nan])


def test_clamped_cosine_values_and_quadrature():
    order = 9
    conv = sh.clamped_cosine_zh(order)
    expected_head = [np.pi, 2 * np.pi / 3, np.pi / 4, 0.0, -np.pi / 24, 0.0, np.pi / 64, 0.0]
    np.testing.assert_allclose(conv[:8], expected_head, atol=ATOL_FLOAT64)
    # ZH normalisation: g_l = integral max(z, 0) y_l0 ds, by exact hemisphere quadrature.
    dirs, w = hemisphere_rule(np.array([0.0, 0.0, 1.0]), nodes=order + 1)
    y = sh.basis(dirs, order)
    g_quad = np.array([np.sum(w * dirs[:, 2] * y[:, l * l + l]) for l in range(order)])
    np.testing.assert_allclose(sh.clamped_cosine_zh(order, normalization="zh"), g_quad, atol=ATOL_FLOAT64)
    np.testing.assert_allclose(conv, np.sqrt(4 * np.pi / (2 * np.arange(order) + 1)) * g_quad, atol=ATOL_FLOAT64)
    with pytest.raises(ValueError, match="normalization"):
        sh.clamped_cosine_zh(3, normalization="other")


def test_clamped_cosine_sh_is_the_projection_of_the_clamped_cosine():
    # every coefficient integral max(z, 0) y_i ds by exact hemisphere quadrature: the m = 0
    # slots hold g_l, the others vanish (the function is zonal about +z)
    order = 7
    dirs, w = hemisphere_rule(np.array([0.0, 0.0, 1.0]), nodes=order + 1)
    want = (w * dirs[:, 2]) @ sh.basis(dirs, order)
    got = sh.clamped_cosine_sh(order)
    assert got.shape == (order * order,) and got.dtype == np.float64
    np.testing.assert_allclose(got, want, atol=ATOL_FLOAT64)
    np.testing.assert_array_equal(got[[l * l + l for l in range(order)]], sh.clamped_cosine_zh(order, normalization="zh"))


def test_irradiance_by_convolution_matches_quadrature(rng):
    # E(n) = integral L(s) max(n.s, 0) ds = sum_lm A_l L_lm y_lm(n) for band-limited L.
    order = 6
    light = rng.standard_normal(order * order) / (1 + sh.band_of(order))
    conv = sh.clamped_cosine_zh(order)[sh.band_of(order)]
    for normal in unit(rng.standard_normal((4, 3))):
        dirs, w = hemisphere_rule(normal, nodes=order + 1)
        e_quad = np.sum(w * (dirs @ normal) * (sh.basis(dirs, order) @ light))
        e_sh = sh.basis(normal, order) @ (conv * light)
        assert e_sh == pytest.approx(e_quad, abs=ATOL_FLOAT64)


@pytest.mark.parametrize("theta", [0.0, 0.05, 0.7, np.pi / 2, 2.5, np.pi])
def test_cap_zh_matches_numerical_integration(theta):
    order = 8
    got = sh.cap_zh(theta, order)
    for l in range(order):
        norm = np.sqrt((2 * l + 1) / (4 * np.pi))
        val, _ = integrate.quad(lambda z: 2 * np.pi * norm * eval_legendre(l, z), np.cos(theta), 1.0, epsabs=1e-13)
        assert got[l] == pytest.approx(val, abs=ATOL_QUAD)


def test_cap_zh_array_blocked_and_limits():
    order = 5
    thetas = np.array([[0.1, 0.4], [1.0, 3.0]])
    out = sh.cap_zh(thetas, order)
    assert out.shape == (2, 2, order)
    np.testing.assert_allclose(out[1, 0], sh.cap_zh(1.0, order), atol=0)
    # Solid angle of the cap: g_0 y_00 * 4 pi = 2 pi (1 - cos theta).
    np.testing.assert_allclose(out[..., 0] * np.sqrt(4 * np.pi), 2 * np.pi * (1 - np.cos(thetas)), atol=1e-14)
    # Whole sphere = the constant 1; blocker visibility = 1 - indicator.
    np.testing.assert_allclose(sh.cap_zh(np.pi, order), [np.sqrt(4 * np.pi), 0, 0, 0, 0], atol=1e-14)
    whole = [np.sqrt(4 * np.pi), 0, 0, 0, 0]
    np.testing.assert_allclose(sh.cap_zh(0.3, order, blocked=True) + sh.cap_zh(0.3, order), whole, atol=1e-14)
    with pytest.raises(ValueError, match="theta"):
        sh.cap_zh(-0.1, order)
    with pytest.raises(ValueError, match="theta"):
        sh.cap_zh(4.0, order)


def test_windows_formulas_and_bad_input(rng):
    order = 6
    l = np.arange(order)
    weights = sh.window_weights
    np.testing.assert_allclose(weights("cosine", order), np.cos(np.pi / 2 * l / (2 * order)), atol=1e-15)
    cos_h4 = [1, np.cos(np.pi / 8), np.cos(np.pi / 4), np.cos(3 * np.pi / 8), 0, 0]
    np.testing.assert_allclose(weights("cosine", order, size=4), cos_h4, atol=1e-15)
    np.testing.assert_allclose(weights("hanning", order), 0.5 * (1 + np.cos(np.pi * l / order)), atol=1e-15)
    lanczos = np.ones(order)
    lanczos[1:] = np.sin(np.pi * l[1:] / order) / (np.pi * l[1:] / order)
    np.testing.assert_allclose(weights("lanczos", order), lanczos, atol=1e-15)
    np.testing.assert_allclose(weights("gaussian", order, strength=0.01), np.exp(-0.01 * l * (l + 1)), atol=1e-15)
    f = rng.standard_normal((3, order * order))
    np.testing.assert_allclose(sh.window(f, "hanning"), f * weights("hanning", order)[sh.band_of(order)], atol=0)
    bad_args = [
        dict(kind="box"), dict(kind="cosine", size=0.0), dict(kind="gaussian"), dict(kind="cosine", strength=1.0)
    ]
    for bad in bad_args:
        with pytest.raises(ValueError, match="window"):
            sh.window(f, **bad)


@pytest.mark.parametrize("kind", ["cosine", "hanning", "lanczos"])
def test_windowing_reduces_ringing_of_a_sharp_cap(kind):
    # The truncated SH of a small disc rings: negative lobes away from it. Windows reduce the
    # most negative value of the reconstruction (Gibbs undershoot).
    order = 8
    g = sh.cap_zh(0.3, order)
    z = np.linspace(-1, 1, 2001)
    def recon(gl):
        return sum(gl[l] * np.sqrt((2 * l + 1) / (4 * np.pi)) * eval_legendre(l, z) for l in range(order))
    raw = recon(g).min()
    windowed = recon(g * sh.window_weights(kind, order)).min()
    assert raw < 0 and windowed > raw


@pytest.mark.parametrize("order", [4])
def test_warp_zh_kernels_match_reference(order, device, rng):
    axes = rng.standard_normal((50, 3))
    g = rng.standard_normal((50, order))
    f = rng.standard_normal((50, order * order))
    got = sh.zh_to_sh(axes, g, device=device)
    assert got.dtype == np.float32
    assert np.abs(got - sh.zh_to_sh(axes, g)).max() < ATOL_ZH_FLOAT32
    got_zh = sh.zh_from_sh_about_axis(f, axes, device=device)
    assert np.abs(got_zh - sh.zh_from_sh_about_axis(f, axes)).max() < ATOL_ZH_FLOAT32
