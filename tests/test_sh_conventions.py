"""Converters to other SH conventions, each checked against that convention's own formula.

Every check reconstructs the same function two ways: ``sum_i f_i y_i(s)`` with warpshade's
basis, and the converted coefficients times the other convention's basis functions written
here from scipy's associated Legendre functions and complex SH.
"""

import math

import numpy as np
import pytest
from scipy.special import lpmv, sph_harm_y

from warpshade.basis import sh

# Two float64 reconstructions of the same O(1)-coefficient function at order <= 7.
ATOL_RECON = 1e-11

ORDER = 7


@pytest.fixture
def sample(rng):
    f = rng.standard_normal(ORDER * ORDER)
    d = rng.standard_normal((30, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    theta = np.arccos(np.clip(d[:, 2], -1, 1))
    phi = np.arctan2(d[:, 1], d[:, 0])
    return f, d, theta, phi, sh.basis(d, ORDER) @ f


def legendre_no_cs(l: int, m: int, x: np.ndarray) -> np.ndarray:
    """P_l^m(x) without the Condon-Shortley phase (scipy's lpmv includes (-1)^m)."""
    return (-1.0) ** m * lpmv(m, l, x)


def test_real_without_condon_shortley(sample):
    f, d, theta, phi, values = sample
    c = sh.to_convention(f, "real_no_cs")
    recon = np.zeros_like(values)
    for l in range(ORDER):
        for m in range(-l, l + 1):
            am = abs(m)
            norm = math.sqrt((2 * l + 1) / (4 * math.pi) * math.factorial(l - am) / math.factorial(l + am))
            p = legendre_no_cs(l, am, np.cos(theta))
            if m == 0:
                basis = norm * p
            elif m > 0:
                basis = math.sqrt(2) * norm * p * np.cos(am * phi)
            else:
                basis = math.sqrt(2) * norm * p * np.sin(am * phi)
            recon += c[l * l + l + m] * basis
    np.testing.assert_allclose(recon, values, atol=ATOL_RECON)
    # Band 1 without the phase is +c (y, z, x).
    y = sh.to_convention(sh.basis(d[0], 2), "real_no_cs")  # coefficients of a delta = basis values
    np.testing.assert_allclose(y[1:], math.sqrt(3 / (4 * math.pi)) * d[0][[1, 2, 0]], atol=1e-15)
    np.testing.assert_allclose(sh.from_convention(c, "real_no_cs"), f, atol=0)


def test_complex_against_scipy(sample):
    f, d, theta, phi, values = sample
    c = sh.to_convention(f, "complex")
    assert c.dtype == np.complex128
    recon = sum(c[l * l + l + m] * sph_harm_y(l, m, theta, phi) for l in range(ORDER) for m in range(-l, l + 1))
    np.testing.assert_allclose(recon.real, values, atol=ATOL_RECON)
    assert np.abs(recon.imag).max() < ATOL_RECON
    # A real function: c_l,-m = (-1)^m conj(c_lm).
    for l in range(ORDER):
        for m in range(1, l + 1):
            assert c[l * l + l - m] == pytest.approx((-1) ** m * np.conj(c[l * l + l + m]), abs=1e-14)
    np.testing.assert_allclose(sh.from_convention(c, "complex"), f, atol=1e-14)
    bad = c.copy()
    bad[1] += 0.5j
    with pytest.raises(ValueError, match="real function"):
        sh.from_convention(bad, "complex")


def shtools_basis(l: int, m: int, kind: int, theta, phi, normalization: str, csphase: int) -> np.ndarray:
    """SHTOOLS real basis function: N_lm P_lm(cos theta) {cos, sin}(m phi)."""
    p = lpmv(m, l, np.cos(theta))  # with the Condon-Shortley phase
    if csphase == 1:
        p = (-1.0) ** m * p
    ratio = math.factorial(l - m) / math.factorial(l + m)
    two = 1.0 if m == 0 else 2.0
    norm = {
        "4pi": math.sqrt(two * (2 * l + 1) * ratio),
        "ortho": math.sqrt(two * (2 * l + 1) * ratio / (4 * math.pi)),
        "schmidt": math.sqrt(two * ratio),
        "unnorm": 1.0,
    }[normalization]
    trig = np.cos(m * phi) if kind == 0 else np.sin(m * phi)
    return norm * p * trig


@pytest.mark.parametrize("normalization", ["4pi", "ortho", "schmidt", "unnorm"])
@pytest.mark.parametrize("csphase", [1, -1])
def test_shtools_against_its_formula(sample, normalization, csphase):
    f, d, theta, phi, values = sample
    cilm = sh.to_convention(f, "shtools", normalization=normalization, csphase=csphase)
    assert cilm.shape == (2, ORDER, ORDER)
    assert np.all(cilm[1, :, 0] == 0) and np.all(np.triu(cilm[0], 1) == 0)
    recon = np.zeros_like(values)
    for l in range(ORDER):
        for m in range(l + 1):
            recon += cilm[0, l, m] * shtools_basis(l, m, 0, theta, phi, normalization, csphase)
            if m > 0:
                recon += cilm[1, l, m] * shtools_basis(l, m, 1, theta, phi, normalization, csphase)
    np.testing.assert_allclose(recon, values, atol=ATOL_RECON)
    np.testing.assert_allclose(
        sh.from_convention(cilm, "shtools", normalization=normalization, csphase=csphase), f, atol=1e-13
    )


def test_batched_and_bad_conventions(rng):
    f = rng.standard_normal((3, 2, 16))
    assert sh.to_convention(f, "shtools").shape == (3, 2, 2, 4, 4)
    assert sh.to_convention(f, "complex").shape == (3, 2, 16)
    np.testing.assert_allclose(sh.from_convention(sh.to_convention(f, "shtools"), "shtools"), f, atol=1e-14)
    with pytest.raises(ValueError, match="convention"):
        sh.to_convention(f, "e3nn")
    with pytest.raises(ValueError, match="normalization"):
        sh.to_convention(f, "shtools", normalization="orthonormal")
    with pytest.raises(ValueError, match="csphase"):
        sh.to_convention(f, "shtools", csphase=0)
    with pytest.raises(ValueError, match="2, L, L"):
        sh.from_convention(np.zeros((3, 4, 4)), "shtools")
