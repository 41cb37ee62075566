"""Spherical Gaussians (warpshade.basis.sg, sg_warp) against quadrature and closed forms.

Oracles: a 200 x 400 product Gauss-Legendre x trapezoid rule on the sphere for integrals and
inner products, direct evaluation for products, the Bessel-function quadrature of ``f_h`` (itself
checked against the closed form at the pole and the symmetry ``f_h(t) + f_h(-t) = integral``).
"""

from functools import partial

import numpy as np
import pytest

from warpshade._wp import wp
from warpshade.basis import sg, sg_warp

from tolerances import RTOL_FLOAT32

#: the issue's goal for the inner product against quadrature.
INNER_PRODUCT_TOL = 1e-3
#: the issue's goal for f_h (erf form), as a fraction of f_h(pi/2, lambda), for lambda in [1, 400].
FH_ERF_TOL = 0.01
#: what the erf form reaches here (module docstring of basis.sg); a regression guard.
FH_ERF_MEASURED = 0.004


def _sphere_rule(nt=200, nphi=400):
    x, w = np.polynomial.legendre.leggauss(nt)
    phi = (np.arange(nphi) + 0.5) * 2 * np.pi / nphi
    ct, ph = np.meshgrid(x, phi, indexing="ij")
    st = np.sqrt(1 - ct**2)
    dirs = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3)
    weights = (w[:, None] * np.full(nphi, 2 * np.pi / nphi)[None]).reshape(-1)
    return dirs, weights


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_integral_matches_quadrature():
    dirs, w = _sphere_rule()
    for lam in (0.0, 0.3, 2.0, 20.0):
        q = np.sum(w * sg.evaluate(dirs, [0.0, 0.0, 1.0], lam, 1.7))
        assert sg.integral(lam, 1.7) == pytest.approx(q, rel=1e-9)


def test_inner_product_within_goal_of_quadrature():
    rng = np.random.default_rng(3)
    dirs, w = _sphere_rule(300, 600)
    worst = 0.0
    for _ in range(12):
        a1, a2 = _unit(rng.normal(size=3)), _unit(rng.normal(size=3))
        l1, l2 = rng.uniform(0.5, 60.0, size=2)
        q = np.sum(w * sg.evaluate(dirs, a1, l1, 1.3) * sg.evaluate(dirs, a2, l2, 0.7))
        got = sg.inner_product(a1, l1, 1.3, a2, l2, 0.7)
        scale = max(abs(q), 1e-3 * np.sqrt(sg.inner_product(a1, l1, 1.3, a1, l1, 1.3) * sg.inner_product(a2, l2, 0.7, a2, l2, 0.7)))
        worst = max(worst, abs(got - q) / scale)
    assert worst < INNER_PRODUCT_TOL


def test_inner_product_stays_finite_for_huge_sharpness():
    z = np.array([0.0, 0.0, 1.0])
    x = np.array([1.0, 0.0, 0.0])
    # the textbook form 4 pi e^-(l1+l2) sinh(d)/d overflows here; the closed form is 2 pi / (2 l)
    lam = 1e6
    assert sg.inner_product(z, lam, 1.0, z, lam, 1.0) == pytest.approx(2 * np.pi / (2 * lam), rel=1e-9)
    assert sg.inner_product(z, lam, 1.0, x, lam, 1.0) == 0.0
    assert np.isfinite(sg.inner_product(z, 1e12, 1.0, z, 0.0, 1.0))


def test_product_is_exact():
    rng = np.random.default_rng(5)
    dirs = _unit(rng.normal(size=(500, 3)))
    for _ in range(10):
        a1, a2 = _unit(rng.normal(size=3)), _unit(rng.normal(size=3))
        l1, l2 = rng.uniform(0.1, 200.0, size=2)
        axis, lam, amp = sg.product(a1, l1, 2.0, a2, l2, 0.5)
        direct = sg.evaluate(dirs, a1, l1, 2.0) * sg.evaluate(dirs, a2, l2, 0.5)
        np.testing.assert_allclose(sg.evaluate(dirs, axis, lam, amp), direct, rtol=1e-10, atol=1e-300)
        assert np.linalg.norm(axis) == pytest.approx(1.0)


def test_product_of_opposite_equal_lobes_is_a_constant():
    axis, lam, amp = sg.product([0, 0, 1.0], 3.0, 1.0, [0, 0, -1.0], 3.0, 1.0)
    assert lam == pytest.approx(0.0, abs=1e-15) and amp == pytest.approx(np.exp(-6.0))
    assert np.all(np.isfinite(axis))


def test_rotation_and_mixtures():
    rng = np.random.default_rng(7)
    axes = _unit(rng.normal(size=(4, 3)))
    mix = sg.SGMixture(axes, rng.uniform(1, 30, 4), rng.uniform(0.1, 2, (4, 3)))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    rot = q * np.sign(np.linalg.det(q))
    dirs = _unit(rng.normal(size=(200, 3)))
    np.testing.assert_allclose(mix.rotated(rot).evaluate(dirs @ rot.T), mix.evaluate(dirs), rtol=1e-12)
    other = sg.SGMixture(axes[:2], [5.0, 50.0], [1.0, 0.5])
    prod = mix.product(other)
    np.testing.assert_allclose(prod.evaluate(dirs), mix.evaluate(dirs) * other.evaluate(dirs)[:, None], rtol=1e-10)
    d, w = _sphere_rule()
    np.testing.assert_allclose(mix.inner_product(other), (w[:, None] * mix.evaluate(d) * other.evaluate(d)[:, None]).sum(0), rtol=1e-6)
    np.testing.assert_allclose(mix.integral(), (w[:, None] * mix.evaluate(d)).sum(0), rtol=1e-8)
    with pytest.raises(ValueError, match="axes"):
        sg.SGMixture(axes, [1.0], [1.0])


def test_area_round_trip():
    lam = np.array([3.0, 40.0, 1e4])
    np.testing.assert_allclose(sg.sharpness_for_area(sg.area(lam)), lam)
    with pytest.raises(ValueError, match="area"):
        sg.sharpness_for_area(0.0)


def test_clamped_cosine_fits():
    x, w = np.polynomial.legendre.leggauss(400)
    target = np.maximum(x, 0)

    def l2(fit):
        _, lam, mu = sg.clamped_cosine(np.array([0.0, 0.0, 1.0]), fit)
        return np.sqrt(np.sum(w * (mu * np.exp(lam * (x - 1)) - target) ** 2) / np.sum(w * target**2))

    paper, best = l2("paper"), l2("l2")
    assert best <= paper  # the L2 optimum is at least as good as the paper's lobe
    assert paper < 0.18   # the paper's single lobe: 17.7 % relative L2 error over the sphere
    lam, mu = sg.fit_clamped_cosine()
    for dl in (-1e-3, 1e-3):  # it is a minimum
        g = np.exp((lam + dl) * (x - 1))
        m = np.sum(w * g * target) / np.sum(w * g * g)
        assert np.sum(w * (m * g - target) ** 2) >= np.sum(w * (mu * np.exp(lam * (x - 1)) - target) ** 2) - 1e-15
    with pytest.raises(ValueError, match="fit"):
        sg.clamped_cosine([0, 0, 1.0], "cubic")


def test_fh_quadrature_oracle_closed_forms():
    for lam in (0.01, 1.0, 30.0, 400.0):
        pole = 2 * np.pi / lam * (1 - np.exp(-lam))
        assert sg.hemisphere_integral(np.pi / 2, lam, "quadrature") == pytest.approx(pole, rel=1e-10)
        t = np.linspace(0, np.pi / 2, 7)
        both = sg.hemisphere_integral(t, lam, "quadrature") + sg.hemisphere_integral(-t, lam, "quadrature")
        np.testing.assert_allclose(both, sg.integral(lam), rtol=1e-9)


def test_fh_against_brute_force_sphere_quadrature():
    dirs, w = _sphere_rule(400, 400)
    for lam, theta in ((2.0, 0.3), (25.0, -0.1), (8.0, 1.2)):
        p = np.array([0.0, np.cos(theta), np.sin(theta)])  # the visible hemisphere is z >= 0
        q = np.sum(w * sg.evaluate(dirs, p, lam) * (dirs[:, 2] >= 0))
        assert sg.hemisphere_integral(theta, lam, "quadrature") == pytest.approx(q, rel=2e-3)


def _fh_errors(method, lams):
    t = np.linspace(-np.pi / 2, np.pi / 2, 121)
    out = []
    for lam in lams:
        exact = sg.hemisphere_integral(t, lam, "quadrature")
        out.append(np.max(np.abs(sg.hemisphere_integral(t, lam, method) - exact)) / exact[-1])
    return np.array(out)


def test_fh_erf_within_one_percent_for_lambda_1_to_400():
    lams = np.geomspace(1.0, 400.0, 40)
    err = _fh_errors("erf", lams)
    assert err.max() < FH_ERF_TOL
    assert err.max() < FH_ERF_MEASURED
    # and beyond the goal's range
    assert _fh_errors("erf", np.array([0.01, 0.1, 1000.0, 5000.0])).max() < FH_ERF_MEASURED


def test_fh_paper_sigmoid_is_the_appendix_form_and_worse():
    # eq. 47 at theta_d = 0 is 1/2 (a = 1.05): the integral of half the lobe's hemisphere
    assert sg.visible_fraction(0.0, 10.0, "paper") == pytest.approx(0.5)
    err = _fh_errors("paper", np.array([1.0, 10.0, 100.0]))
    assert np.all(err > _fh_errors("erf", np.array([1.0, 10.0, 100.0])))
    assert err[0] > 0.1  # broad lobes: the sigmoid's 1/2 at the horizon is far from (1 + e^-1)/2


def test_visible_fraction_limits():
    assert sg.visible_fraction(np.pi / 2, 7.0) == pytest.approx(1.0, abs=1e-12)
    assert sg.visible_fraction(-np.pi / 2, 7.0) == pytest.approx(np.exp(-7.0), rel=0.05)
    assert sg.visible_fraction(3.0, 7.0) == sg.visible_fraction(np.pi / 2, 7.0)  # clamped
    v = sg.visible_fraction(np.linspace(-1.5, 1.5, 31), 1e7)
    assert np.all(np.isfinite(v)) and np.all(np.diff(v) >= 0)
    with pytest.raises(ValueError, match="method"):
        sg.hemisphere_integral(0.0, 1.0, "table")
    with pytest.raises(ValueError, match="sharpness"):
        sg.hemisphere_integral(0.0, -1.0)


def _arr(device, a, dtype=wp.vec3):
    return wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=dtype, device=device)


def test_warp_functions_match_float64(device):
    rng = np.random.default_rng(11)
    n = 256
    arr = partial(_arr, device)
    a1, a2, d = (_unit(rng.normal(size=(n, 3))) for _ in range(3))
    l1, l2 = rng.uniform(0.1, 300, n), rng.uniform(0.1, 300, n)
    m1, m2 = rng.uniform(0.1, 2, (n, 3)), rng.uniform(0.1, 2, (n, 3))
    out = wp.zeros(n, dtype=wp.vec3, device=device)
    wp.launch(sg_warp.evaluate_kernel, dim=n, inputs=[arr(d), arr(a1), arr(l1, float), arr(m1)], outputs=[out], device=device)
    np.testing.assert_allclose(out.numpy(), sg.evaluate(d, a1, l1)[:, None] * m1, rtol=RTOL_FLOAT32 * 50, atol=1e-30)
    wp.launch(sg_warp.inner_kernel, dim=n, inputs=[arr(a1), arr(l1, float), arr(m1), arr(a2), arr(l2, float), arr(m2)],
              outputs=[out], device=device)
    ref = sg.inner_product(a1, l1, 1.0, a2, l2, 1.0)[:, None] * m1 * m2
    np.testing.assert_allclose(out.numpy(), ref, rtol=RTOL_FLOAT32 * 50, atol=1e-30)
    axes, lam, amp = (wp.zeros(n, dtype=t, device=device) for t in (wp.vec3, float, wp.vec3))
    wp.launch(sg_warp.product_kernel, dim=n, inputs=[arr(a1), arr(l1, float), arr(m1), arr(a2), arr(l2, float), arr(m2)],
              outputs=[axes, lam, amp], device=device)
    ra, rl, rm = sg.product(a1, l1, 1.0, a2, l2, 1.0)
    np.testing.assert_allclose(axes.numpy(), ra, atol=1e-5)
    np.testing.assert_allclose(lam.numpy(), rl, rtol=RTOL_FLOAT32)
    # exp(|u| - l1 - l2) with |u| and l1 + l2 both O(300): float32 cancellation in the exponent
    np.testing.assert_allclose(amp.numpy(), rm[:, None] * m1 * m2, rtol=3e-3, atol=1e-30)
    t = rng.uniform(-1.6, 1.6, n)
    lams = np.geomspace(0.05, 2000, n)
    fh = wp.zeros(n, dtype=float, device=device)
    wp.launch(sg_warp.fh_kernel, dim=n, inputs=[arr(t, float), arr(lams, float)], outputs=[fh], device=device)
    np.testing.assert_allclose(fh.numpy(), sg.hemisphere_integral(t, lams), rtol=1e-4, atol=1e-6 * sg.integral(lams).max())
