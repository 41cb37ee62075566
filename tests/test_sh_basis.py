"""Real SH basis: orthonormality by exact quadrature, Sloan's signs, scipy's complex SH, Warp."""

import numpy as np
import pytest
from scipy.special import sph_harm_y

from warpshade.basis import quadrature, sh

from tolerances import ATOL_FLOAT64

# float64 Gram matrix by an exact product rule: rounding of ~n^2 products over a few hundred nodes.
ORTHO_TOL_FLOAT64 = 1e-12
# float32 kernel values (relative error ~1e-7 each, recurrences over <= 10 bands) accumulated in
# float64 over the quadrature: the float32 bound.
ORTHO_TOL_FLOAT32 = 1e-5
# Kernel vs reference per value: float32 recurrences to band 9, |y| up to ~2.7.
ATOL_BASIS_FLOAT32 = 2e-6

Y1 = np.sqrt(3.0 / (4.0 * np.pi))  # 0.488603


def gram(y: np.ndarray, q: quadrature.SphereSamples) -> np.ndarray:
    y = y.astype(np.float64)
    return (y * q.weights[:, None]).T @ y


@pytest.mark.parametrize("order", [1, 2, 5, 10, 16])
def test_orthonormal_float64(order):
    q = quadrature.gauss_legendre(2 * (order - 1))
    err = np.abs(gram(sh.basis(q.directions, order), q) - np.eye(order * order)).max()
    assert err < ORTHO_TOL_FLOAT64


@pytest.mark.parametrize("order", [4, 10])
def test_orthonormal_float32_kernel(order, device):
    q = quadrature.gauss_legendre(2 * (order - 1))
    y = sh.basis(q.directions, order, device=device)
    assert y.dtype == np.float32
    err = np.abs(gram(y, q) - np.eye(order * order)).max()
    assert err < ORTHO_TOL_FLOAT32
    assert np.abs(y - sh.basis(q.directions, order)).max() < ATOL_BASIS_FLOAT32


def test_sloan_sign_convention_band1_and_band2():
    d = np.array([0.3, -0.5, 0.8])
    d = d / np.linalg.norm(d)
    x, y, z = d
    v = sh.basis(d, 3)
    expect = [
        0.5 / np.sqrt(np.pi),
        -Y1 * y,
        Y1 * z,
        -Y1 * x,
        0.5 * np.sqrt(15 / np.pi) * x * y,
        -0.5 * np.sqrt(15 / np.pi) * y * z,
        0.25 * np.sqrt(5 / np.pi) * (3 * z * z - 1),
        -0.5 * np.sqrt(15 / np.pi) * x * z,
        0.25 * np.sqrt(15 / np.pi) * (x * x - y * y),
    ]
    np.testing.assert_allclose(v, expect, atol=ATOL_FLOAT64)


@pytest.mark.parametrize("order", [3, 10])
def test_matches_scipy_complex_sh(order, rng):
    # y_lm = sqrt(2) Re Y_l^m (m > 0), y_l,-m = sqrt(2) Im Y_l^m, y_l0 = Y_l^0, with scipy's Y.
    d = rng.standard_normal((40, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    theta = np.arccos(np.clip(d[:, 2], -1, 1))
    phi = np.arctan2(d[:, 1], d[:, 0])
    v = sh.basis(d, order)
    for l in range(order):
        for m in range(l + 1):
            ylm = sph_harm_y(l, m, theta, phi)
            if m == 0:
                np.testing.assert_allclose(v[:, l * l + l], ylm.real, atol=ATOL_FLOAT64)
            else:
                np.testing.assert_allclose(v[:, l * l + l + m], np.sqrt(2) * ylm.real, atol=ATOL_FLOAT64)
                np.testing.assert_allclose(v[:, l * l + l - m], np.sqrt(2) * ylm.imag, atol=ATOL_FLOAT64)


def test_batch_shapes_and_bad_input():
    assert sh.basis(np.ones((2, 3, 3)), 4).shape == (2, 3, 16)
    with pytest.raises(ValueError, match="order"):
        sh.basis([0, 0, 1], 0)
    with pytest.raises(ValueError, match="zero-length"):
        sh.basis([0, 0, 0], 2)
    with pytest.raises(ValueError, match="shape"):
        sh.basis([0, 1], 2)


def test_index_helpers():
    assert sh.index(3, -2) == 10 and sh.coeff_count(5) == 25
    np.testing.assert_array_equal(sh.band_of(3), [0, 1, 1, 1, 2, 2, 2, 2, 2])
    with pytest.raises(ValueError):
        sh.index(1, 2)
