"""SH rotation: float64 Ivanic-Ruedenberg vs re-projection, group properties, Warp zxzxz."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from warpshade.basis import quadrature, sh

# Exact re-projection (Gauss-Legendre of a degree-2(n-1) integrand) vs recurrences, float64,
# coefficients O(1), up to order 10: accumulated rounding of ~n^3 products.
ATOL_ROTATE_FLOAT64 = 1e-12
# float32 zxzxz (5 passes over each band: 3 z-rotations, 2 dense 90-degree blocks of size
# <= 19, angles from float32 atan2) against float64 Ivanic-Ruedenberg, per unit of max |f|;
# ~1.2e-6 observed over 1000 random rotations at order 10, so 5e-6 leaves a 4x margin.
ATOL_ROTATE_FLOAT32 = 5e-6


def random_coeffs(rng, shape, order):
    return rng.standard_normal(shape + (order * order,))


def reprojected(f: np.ndarray, rotation: np.ndarray, order: int) -> np.ndarray:
    """Project s -> f(R^-1 s) onto SH by exact quadrature (independent of any rotation formula)."""
    q = quadrature.gauss_legendre(2 * (order - 1))
    y = sh.basis(q.directions, order)
    rotated_values = sh.basis(q.directions @ rotation, order) @ f  # rows of s @ R are R^T s
    return (y * q.weights[:, None]).T @ rotated_values


def special_rotations() -> np.ndarray:
    """Identity, axis-aligned half turns and rotations at and near the Euler-angle poles."""
    rs = [
        np.eye(3),
        Rotation.from_euler("z", 0.7).as_matrix(),
        Rotation.from_euler("x", np.pi).as_matrix(),
        Rotation.from_euler("y", np.pi).as_matrix(),
        Rotation.from_euler("zyz", [0.4, 1e-4, -1.1]).as_matrix(),
        Rotation.from_euler("zyz", [0.4, np.pi - 3e-6, 1.3]).as_matrix(),
        Rotation.from_euler("zyz", [2.0, 1e-9, 0.5]).as_matrix(),
        Rotation.from_euler("x", np.pi / 2).as_matrix(),
    ]
    return np.stack(rs)


@pytest.mark.parametrize("order", [1, 2, 3, 6, 10])
def test_rotate_matches_reprojection(order, rng):
    rotations = np.concatenate([quadrature.random_rotations(3, seed=order), special_rotations()[[2, 5]]])
    f = random_coeffs(rng, (), order)
    for r in rotations:
        np.testing.assert_allclose(sh.rotate(f, r), reprojected(f, r, order), atol=ATOL_ROTATE_FLOAT64)


def test_rotation_carries_lobes_along(rng):
    # A ZH lobe about d becomes the same lobe about R d.
    order = 6
    g = rng.standard_normal(order)
    d = np.array([0.3, -0.4, 0.866])
    d /= np.linalg.norm(d)
    for r in quadrature.random_rotations(3, seed=11):
        np.testing.assert_allclose(sh.rotate(sh.zh_to_sh(d, g), r), sh.zh_to_sh(r @ d, g), atol=ATOL_ROTATE_FLOAT64)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), order=st.integers(1, 10))
def test_composition_and_band_energy(seed, order):
    rng = np.random.default_rng(seed)
    r1, r2 = quadrature.random_rotations(2, seed=seed)
    f = random_coeffs(rng, (), order)
    np.testing.assert_allclose(sh.rotate(sh.rotate(f, r2), r1), sh.rotate(f, r1 @ r2), atol=ATOL_ROTATE_FLOAT64)
    np.testing.assert_allclose(sh.rotate(sh.rotate(f, r1), r1.T), f, atol=ATOL_ROTATE_FLOAT64)
    out = sh.rotate(f, r1)
    for l in range(order):
        sl = slice(l * l, (l + 1) ** 2)
        assert np.linalg.norm(out[sl]) == pytest.approx(np.linalg.norm(f[sl]), rel=1e-12)


def test_rotation_matrix_is_block_diagonal_orthogonal_and_consistent(rng):
    order = 5
    r = quadrature.random_rotations(4, seed=2)
    d = sh.rotation_matrix(r, order)
    assert d.shape == (4, 25, 25)
    np.testing.assert_allclose(d @ np.swapaxes(d, -1, -2), np.broadcast_to(np.eye(25), d.shape), atol=1e-13)
    band = sh.band_of(order)
    assert np.all(d[:, band[:, None] != band[None, :]] == 0)
    f = random_coeffs(rng, (4,), order)
    np.testing.assert_allclose(np.einsum("bij,bj->bi", d, f), sh.rotate(f, r), atol=ATOL_ROTATE_FLOAT64)
    # Band 1 in Sloan's convention is -c (y, z, x) with sign flips on m = +-1: D_1 = S P R P^T S.
    perm = [1, 2, 0]
    s = np.diag([-1.0, 1.0, -1.0])
    np.testing.assert_allclose(d[:, 1:4, 1:4], s @ r[:, perm][:, :, perm] @ s, atol=1e-15)


def test_rotate_broadcasting(rng):
    order = 3
    f = random_coeffs(rng, (2, 1), order)
    r = quadrature.random_rotations(5, seed=3)
    out = sh.rotate(f, r)
    assert out.shape == (2, 5, 9)
    np.testing.assert_allclose(out[1, 4], sh.rotate(f[1, 0], r[4]), atol=1e-14)
    assert sh.rotate(random_coeffs(rng, (7,), order), r[0]).shape == (7, 9)  # one R, many f


def test_rotate_rejects_non_rotations():
    f = np.zeros(9)
    with pytest.raises(ValueError, match="orthonormal"):
        sh.rotate(f, np.diag([1.0, 1.0, 1.1]))
    with pytest.raises(ValueError, match="reflection"):
        sh.rotate(f, np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="3, 3"):
        sh.rotate(f, np.eye(2))
    with pytest.raises(ValueError, match="NaN"):
        sh.rotation_matrix(np.full((3, 3), np.nan), 3)


@pytest.mark.parametrize("order", [4, 6, 10])  # 4 and 6 straight-line code, 10 the loops
def test_warp_zxzxz_matches_ivanic_ruedenberg(order, device, rng):
    rotations = np.concatenate([quadrature.random_rotations(40, seed=order), special_rotations()])
    f = random_coeffs(rng, (len(rotations),), order)
    got = sh.rotate(f, rotations, device=device)
    assert got.dtype == np.float32
    err = np.abs(got - sh.rotate(f, rotations)).max() / np.abs(f).max()
    assert err < ATOL_ROTATE_FLOAT32
