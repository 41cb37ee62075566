"""Quadrature rules against closed-form integrals of monomials on the unit sphere."""

import itertools
import math

import numpy as np
import pytest

from warpshade.basis import quadrature

# Gauss-Legendre x uniform-phi products are exact up to rounding: a few ulps of 4*pi summed
# over a few hundred nodes.
RTOL_EXACT = 1e-12
# Spherical Fibonacci (equal weights) on a smooth degree-4 integrand with 20k points: the
# low-discrepancy error decays roughly like 1/N; 1e-4 is ~10x above what it achieves.
ATOL_FIBONACCI_20K = 1e-4


def monomial_integral(a: int, b: int, c: int) -> float:
    """integral over S^2 of x^a y^b z^c (Folland's formula); 0 if any exponent is odd."""
    if a % 2 or b % 2 or c % 2:
        return 0.0
    beta = [(e + 1) / 2.0 for e in (a, b, c)]
    return 2.0 * math.prod(math.gamma(x) for x in beta) / math.gamma(sum(beta))


def monomials(degree: int):
    for a, b, c in itertools.product(range(degree + 1), repeat=3):
        if a + b + c <= degree:
            yield a, b, c


@pytest.mark.parametrize("degree", [0, 1, 4, 9, 18])
def test_gauss_legendre_is_exact_to_its_degree(degree):
    q = quadrature.gauss_legendre(degree)
    assert len(q) == (degree // 2 + 1) * (degree + 1)
    x, y, z = q.directions.T
    for a, b, c in monomials(degree):
        got = q.integrate(x**a * y**b * z**c)
        assert got == pytest.approx(monomial_integral(a, b, c), abs=RTOL_EXACT * 4 * np.pi)


def test_gauss_legendre_fails_beyond_its_degree():
    # z^(2k) needs k+1 Gauss nodes in z: one node fewer must give a visibly wrong answer, so the
    # exactness test above can fail.
    q = quadrature.gauss_legendre(8)  # 5 nodes: exact to degree 9 in z
    z = q.directions[:, 2]
    assert abs(q.integrate(z**10) - monomial_integral(0, 0, 10)) > 1e-4


@pytest.mark.parametrize(
    "rule",
    [
        lambda: quadrature.gauss_legendre(7),
        lambda: quadrature.fibonacci(1001),
        lambda: quadrature.latlong(16, 32),
    ],
)
def test_rules_are_unit_vectors_with_weights_summing_to_4pi(rule):
    q = rule()
    assert q.directions.shape == (len(q), 3) and q.weights.shape == (len(q),)
    np.testing.assert_allclose(np.linalg.norm(q.directions, axis=1), 1.0, atol=1e-14)
    assert q.weights.sum() == pytest.approx(4 * np.pi, rel=RTOL_EXACT)
    assert np.all(q.weights > 0)


def test_latlong_weights_are_exact_pixel_solid_angles():
    h, w = 8, 16
    q = quadrature.latlong(h, w)
    # Row i spans theta in [i pi/h, (i+1) pi/h]: solid angle (cos t0 - cos t1) * 2 pi / w.
    for i in range(h):
        expect = (math.cos(i * math.pi / h) - math.cos((i + 1) * math.pi / h)) * 2 * math.pi / w
        np.testing.assert_allclose(q.weights[i * w : (i + 1) * w], expect, rtol=1e-13)
    d = quadrature.latlong_directions(h, w)
    assert d[0, 0, 2] > 0.9 and d[-1, 0, 2] < -0.9  # row 0 is the +z pole
    phi = np.arctan2(d[3, :, 1], d[3, :, 0]) % (2 * np.pi)
    np.testing.assert_allclose(phi, (np.arange(w) + 0.5) * 2 * np.pi / w, atol=1e-12)


def test_fibonacci_converges_on_a_smooth_integrand():
    q = quadrature.fibonacci(20000)
    x, y, z = q.directions.T
    got = q.integrate(x**2 * z**2 + y**4)
    assert got == pytest.approx(monomial_integral(2, 0, 2) + monomial_integral(0, 4, 0), abs=ATOL_FIBONACCI_20K)


def test_random_rotations_are_proper_and_seeded():
    r = quadrature.random_rotations(50, seed=7)
    np.testing.assert_allclose(np.einsum("nji,njk->nik", r, r), np.broadcast_to(np.eye(3), (50, 3, 3)), atol=1e-13)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-13)
    np.testing.assert_array_equal(r, quadrature.random_rotations(50, seed=7))


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="degree"):
        quadrature.gauss_legendre(-1)
    with pytest.raises(ValueError, match="count"):
        quadrature.fibonacci(0)
    with pytest.raises(ValueError, match="image size"):
        quadrature.latlong(0, 4)
