"""Zonal-harmonic lobes: normalisation, rotation, evaluation, fitting and the Warp functions.

Oracles: the float64 SH reference (warpshade.basis.sh), quadrature projections, numpy.linalg.lstsq,
scipy.optimize.check_grad and scipy's BFGS.
"""

import numpy as np
import pytest
from scipy.optimize import check_grad
from scipy.spatial.transform import Rotation

from warpshade._wp import wp
from warpshade.basis import quadrature, sh, zh
from warpshade.basis.zh import basis_and_gradient, table_directions
from warpshade.basis.zh import fitting as _zh_fit

from tolerances import ATOL_FLOAT32, ATOL_FLOAT64, ATOL_QUADRATURE

# Relative error of an exact fit (BFGS stops at |grad| <= 1e-9 |t|; the reached error is far lower).
EXACT_FIT_REL = 1e-5
# Analytic vs finite-difference gradient (check_grad, step 1.5e-8), relative to the gradient norm.
GRAD_REL = 1e-5
# Batched BFGS may end in a different local minimum than scipy's from the same start only rarely;
# from the same start on smooth problems both reach the same error within this relative margin.
OPTIMISER_REL = 0.02
# Light-specialised table vs direct evaluation: bilinear interpolation on a (W/2+1) x W lat-long
# grid of band-limited functions (order 3) has error O(h^2); at W = 128 the measured worst case
# over random directions is 5e-4 of the lighting's norm (2e-3 at W = 64); 4x margin.
TABLE_REL_128 = 2e-3
# Relative error the default ridge (1e-5) leaves on exactly representable lobe sets (2.5e-5 seen).
RIDGE_BIAS_REL = 1e-4
# Lobe-set norm over target norm that the default ridge allows on BRDF rows (measured 9.5).
MAX_LOBE_NORM_RATIO = 20.0
# The ridge may not cost more than this in total relative error (measured: it lowers it).
RIDGE_ERROR_MARGIN = 0.01


def _unit(rng, shape):
    v = rng.normal(size=shape + (3,))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ---- normalisation and algebra -------------------------------------------------------------


def test_convolution_normalisation_matches_sh_zh_to_sh(rng):
    axes = _unit(rng, (5, 3))
    g_star = rng.normal(size=(5, 3, 4))
    expected = sum(sh.zh_to_sh(axes[:, i], zh.zh_from_convolution(g_star[:, i])) for i in range(3))
    np.testing.assert_allclose(zh.to_sh(axes, g_star), expected, atol=ATOL_FLOAT64)
    np.testing.assert_allclose(zh.convolution_from_zh(zh.zh_from_convolution(g_star)), g_star, atol=ATOL_FLOAT64)


def test_clamped_cosine_is_the_convolution_lobe():
    """max(0, n.s) projected by quadrature == the lobe about n with g*_l = A_l (pi, 2pi/3, ...)."""
    order = 5
    n = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    projected = sh.project(lambda d: np.maximum(d @ n, 0.0), order, quadrature.gauss_legendre(400))
    lobe = zh.to_sh(n[None], sh.clamped_cosine_zh(order, "convolution")[None])
    np.testing.assert_allclose(lobe, projected, atol=ATOL_QUADRATURE)


def test_evaluate_matches_sh_basis(rng):
    axes, coeffs = _unit(rng, (4, 3)), rng.normal(size=(4, 3, 5))
    dirs = _unit(rng, (4, 7))
    via_sh = np.einsum("bkj,bj->bk", sh.basis(dirs, 5), zh.to_sh(axes, coeffs))
    np.testing.assert_allclose(zh.evaluate(axes, coeffs, dirs), via_sh, atol=ATOL_FLOAT64)


def test_rotation_rotates_axes(rng):
    axes, coeffs = _unit(rng, (6, 2)), rng.normal(size=(6, 2, 5))
    rot = Rotation.random(6, random_state=3).as_matrix()
    np.testing.assert_allclose(zh.to_sh(zh.rotate(axes, rot), coeffs), sh.rotate(zh.to_sh(axes, coeffs), rot),
                               atol=1e-10)


def test_negated_axis_with_odd_bands_negated_is_the_same_function(rng):
    axes, coeffs = _unit(rng, (3, 2)), rng.normal(size=(3, 2, 6))
    fa, fc = zh.flip(axes, coeffs)
    np.testing.assert_allclose(fa, -axes)
    np.testing.assert_allclose(zh.to_sh(fa, fc), zh.to_sh(axes, coeffs), atol=ATOL_FLOAT64)
    dirs = _unit(rng, (3, 9))
    np.testing.assert_allclose(zh.evaluate(fa, fc, dirs), zh.evaluate(axes, coeffs, dirs), atol=ATOL_FLOAT64)
    # negating the axis alone is a different function (odd bands present)
    assert np.abs(zh.to_sh(-axes, coeffs) - zh.to_sh(axes, coeffs)).max() > 1e-3


def test_closed_form_eq18_equals_lstsq(rng):
    order = 5
    t = rng.normal(size=(4, order * order))
    axes = _unit(rng, (4,))
    g = zh.single_lobe_coefficients(t, axes)
    for b in range(4):
        y = sh.basis(axes[b], order)
        for l in range(order):
            sl = slice(l * l, (l + 1) ** 2)
            ref, *_ = np.linalg.lstsq(y[sl, None], t[b, sl], rcond=None)
            assert g[b, l] == pytest.approx(ref[0], abs=ATOL_FLOAT64)


def test_frozen_axes_least_squares_equals_lstsq(rng):
    order, n_lobes = 4, 3
    t = rng.normal(size=(2, order * order))
    axes = _unit(rng, (2, n_lobes))
    coeffs = _zh_fit.solve_coefficients(t, axes, np.arange(order))
    for b in range(2):
        y = sh.basis(axes[b], order)
        for l in range(order):
            sl = slice(l * l, (l + 1) ** 2)
            ref, *_ = np.linalg.lstsq(y[:, sl].T, t[b, sl], rcond=None)
            np.testing.assert_allclose(coeffs[b, :, l], ref, atol=1e-10)


def test_optimal_linear_lobe_reproduces_a_linear_function(rng):
    axis = np.array([0.2, -0.9, 0.4]) / np.linalg.norm([0.2, -0.9, 0.4])
    t = zh.to_sh(axis[None, None], np.array([[[0.0, 1.7, 0.0, 0.0]]]))[0]
    np.testing.assert_allclose(zh.optimal_linear_axis(t), axis, atol=ATOL_FLOAT64)
    a, c = zh.linear_lobe(t)
    np.testing.assert_allclose(zh.to_sh(a, c), t, atol=ATOL_FLOAT64)


def test_hemicube_axes():
    axes = zh.hemicube_axes(6)
    assert axes.shape == (6 * 6 + 4 * 6 * 3, 3)
    np.testing.assert_allclose(np.linalg.norm(axes, axis=1), 1.0)
    assert axes[:, 2].min() > 0.0


# ---- gradients -----------------------------------------------------------------------------


def test_sh_gradient_matches_finite_differences(rng):
    dirs = _unit(rng, (6,))
    _, grad = basis_and_gradient(dirs, 6)
    eps = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = eps
        fd = (basis_and_gradient(dirs + e, 6)[0] - basis_and_gradient(dirs - e, 6)[0]) / (2 * eps)
        np.testing.assert_allclose(grad[:, :, k], fd, atol=1e-7)


@pytest.mark.parametrize("n_lobes, stored, ridge", [(1, 0, 0.0), (2, 1, 0.0), (3, 2, 0.0), (3, 1, 0.1)])
def test_analytic_gradients_eq19_21_vs_check_grad(rng, n_lobes, stored, ridge):
    order = 5
    t = rng.normal(size=(1, order * order))
    problem = _zh_fit.FitProblem(order, n_lobes, stored, ridge)
    target = t.copy()
    target[:, : stored * stored] = 0.0
    x0 = _zh_fit.pack(problem, rng.normal(size=(1, n_lobes, 3)) * 1.3, rng.normal(size=(1, n_lobes, order)))[0]

    def f(x):
        return _zh_fit.objective(problem, x[None], target)[0][0]

    def g(x):
        return _zh_fit.objective(problem, x[None], target)[1][0]

    assert check_grad(f, g, x0) <= GRAD_REL * np.linalg.norm(g(x0))
    # the axis gradient is orthogonal to the axis (the objective only sees h(s) = s / |s|); the
    # ridge acts on the coefficients only, so this holds with it too
    raw_axes = x0[: 3 * n_lobes].reshape(n_lobes, 3)
    np.testing.assert_allclose(np.einsum("ik,ik->i", g(x0)[: 3 * n_lobes].reshape(n_lobes, 3), raw_axes), 0.0,
                               atol=1e-10)
    if ridge:
        return  # the public zh.objective below is the unpenalised psi
    _, d_axes, d_coeffs = zh.objective(t, x0[: 3 * n_lobes].reshape(1, n_lobes, 3),
                                         _zh_fit.unpack(problem, x0[None])[1], stored_bands=stored)
    np.testing.assert_allclose(np.einsum("bik,bik->bi", d_axes, x0[: 3 * n_lobes].reshape(1, n_lobes, 3)), 0.0,
                               atol=1e-10)
    assert np.all(d_coeffs[..., :stored] == 0.0)


# ---- fitting -------------------------------------------------------------------------------


def test_ridge_stops_cancelling_lobes_on_brdf_rows():
    """BRDF-specialised rows (GGX, n = 6) fitted with 3 lobes: the unregularised objective ends
    in lobes whose norms are ~1e5 x the row's (they cancel; float32 shading turns that into
    noise); the default ridge keeps them near the row's norm at no loss of total error."""
    from warpshade.scene._materials import Microfacet, factorize

    rows = factorize(Microfacet(roughness=0.5, distribution="ggx", f0=0.04), 6, 12, 16).rows
    # the joint (axes + coefficients) BFGS of the greedy strategy shows the cancellation plainly;
    # the global strategy's projection keeps a tiny ridge of its own (150x seen)
    plain = zh.fit(rows, 3, ridge=0.0, restarts=1, strategy="greedy")
    ridged = zh.fit(rows, 3, restarts=1)
    assert plain.notes["max_lobe_norm_ratio"] > 1e3, "the case must show the cancellation"
    assert ridged.notes["ridge"] == _zh_fit.DEFAULT_RIDGE
    assert ridged.notes["max_lobe_norm_ratio"] < MAX_LOBE_NORM_RATIO
    total = lambda r: np.linalg.norm(r.error) / np.linalg.norm(rows)  # noqa: E731
    assert total(ridged) <= total(plain) + RIDGE_ERROR_MARGIN
    # the reported error is the fit error alone, not the penalised objective
    np.testing.assert_allclose(ridged.error, np.linalg.norm(ridged.to_sh() - rows, axis=-1), rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match="ridge"):
        zh.fit(rows, 3, ridge=-1.0)


def test_fit_recovers_exact_lobe_sets(rng):
    order = 5
    axes = _unit(rng, (4, 2))
    coeffs = rng.normal(size=(4, 2, order))
    t = zh.to_sh(axes, coeffs)
    single = zh.fit(t[:, None] * 0 + zh.to_sh(axes[:, :1], coeffs[:, :1])[:, None], 1, ridge=0.0)
    assert single.rel_error.max() < EXACT_FIT_REL
    double = zh.fit(t, 2, ridge=0.0)
    assert np.median(double.rel_error) < EXACT_FIT_REL
    np.testing.assert_allclose(double.to_sh(), t, atol=1e-3 * np.abs(t).max())
    # the default ridge shrinks an exact fit by about mu: a bias far below any modelling error
    assert np.median(zh.fit(t, 2).rel_error) < RIDGE_BIAS_REL


def test_fit_reports_error_it_cannot_remove(rng):
    """A random order-6 vector is not a single lobe: the error is reported, never hidden."""
    t = rng.normal(size=(6, 36))
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    res = zh.fit(t, 1, restarts=0)
    recomputed = np.linalg.norm(res.to_sh() - t, axis=1)
    np.testing.assert_allclose(res.error, recomputed, atol=1e-10)
    np.testing.assert_allclose(res.rel_error, recomputed, atol=1e-10)
    assert res.rel_error.min() > 0.3  # far from representable (paper's example: 0.751)
    # stored DC exact; folded lobes reproduce the same function
    assert np.allclose(res.to_sh()[:, 0], t[:, 0], atol=ATOL_FLOAT64)
    axes, coeffs = res
    np.testing.assert_allclose(zh.to_sh(axes, coeffs), res.to_sh(), atol=1e-10)


def test_stored_dc_and_linear_are_exact_and_fold_back(rng):
    t = rng.normal(size=(5, 16))
    res = zh.fit(t, 3, restarts=0)  # paper rule: N >= 3 stores DC + linear
    assert res.stored_bands == 2
    np.testing.assert_allclose(res.to_sh()[:, :4], t[:, :4], atol=ATOL_FLOAT64)
    assert np.all(res.coeffs[..., :2] == 0.0)
    axes, coeffs = res.folded()
    np.testing.assert_allclose(zh.to_sh(axes, coeffs), res.to_sh(), atol=1e-9)
    assert zh.fit(t, 2, restarts=0).stored_bands == 1
    assert zh.fit(t, 2, stored_bands=0, restarts=0).stored_bands == 0


def test_multistart_engages_where_error_stays_high(rng):
    t = rng.normal(size=(8, 25))
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    plain = zh.fit(t, 2, restarts=0)
    multi = zh.fit(t, 2, restarts=3, restart_error=0.05)
    assert not plain.restarted.any()
    assert multi.restarted.all()  # every random vector stays above 5% with 2 lobes
    assert np.all(multi.error <= plain.error + 1e-12)
    np.testing.assert_allclose(multi.restart_gain, plain.error - multi.error, atol=1e-9)
    # a low-error problem does not trigger it
    easy = zh.fit(zh.to_sh(_unit(rng, (3, 1)), rng.normal(size=(3, 1, 5))), 1, restarts=3, restart_error=0.05)
    assert not easy.restarted.any()


def test_batched_bfgs_matches_scipy_bfgs(rng):
    order, n_lobes = 4, 2
    t = rng.normal(size=(5, order * order))
    problem = _zh_fit.FitProblem(order, n_lobes, 1)
    target = t.copy()
    target[:, 0] = 0.0
    axes0 = _unit(rng, (5, n_lobes))
    x0 = _zh_fit.pack(problem, axes0, _zh_fit.solve_coefficients(target, axes0, problem.fitted))

    def fun(x, rows):
        return _zh_fit.objective(problem, x, target[rows])

    scale = np.sum(target**2, axis=1)
    _, f_batched, _ = _zh_fit.bfgs_batched(fun, x0, scale)
    _, f_scipy, _ = _zh_fit.bfgs_scipy(fun, x0, scale)
    start = fun(x0, np.arange(5))[0]
    assert np.all(f_batched < start) and np.all(f_scipy < start)
    agree = np.abs(np.sqrt(f_batched) - np.sqrt(f_scipy)) <= OPTIMISER_REL * np.sqrt(scale)
    assert agree.sum() >= 4  # same local minimum from the same start (at most one may differ)


def test_scipy_optimizer_option_runs(rng):
    t = rng.normal(size=(2, 9))
    res = zh.fit(t, 1, optimizer="scipy", restarts=0)
    ref = zh.fit(t, 1, optimizer="batched", restarts=0)
    np.testing.assert_allclose(res.error, ref.error, rtol=OPTIMISER_REL)


def test_fit_budget_picks_lobe_counts(rng):
    order = 4
    one = zh.to_sh(_unit(rng, (6, 1)), rng.normal(size=(6, 1, order)))
    three = zh.to_sh(_unit(rng, (6, 3)), rng.normal(size=(6, 3, order)))
    t = np.concatenate([one, three])
    budget = zh.fit_budget(t, 1e-4, max_lobes=3, restarts=2)
    assert np.all(budget.counts[:6] == 1)
    assert np.all(budget.counts[6:] >= 2)
    assert sum(budget.histogram.values()) == 12
    np.testing.assert_allclose(np.linalg.norm(budget.to_sh() - t, axis=1), budget.error, atol=1e-9)
    assert np.all(budget.error[budget.met] <= 1e-4 * budget.scale[budget.met] * (1 + 1e-9))
    loose = zh.fit_budget(t, 10.0, max_lobes=3)
    assert np.all(loose.counts == 1)


def test_choose_order():
    t = np.zeros((2, 25))
    t[:, 0] = 1.0
    t[:, 6] = 0.1  # band 2
    order, errors = zh.choose_order(t, 0.05)
    assert order == 2 + 1 and errors[0] > 0.05 and errors[2] == 0.0


@pytest.mark.parametrize("bad", [np.full((2, 9), np.nan), np.zeros((2, 8))])
def test_fit_rejects_bad_input(bad):
    with pytest.raises(ValueError):
        zh.fit(bad, 1)


def test_fit_rejects_bad_lobe_count():
    with pytest.raises(ValueError, match="lobe_count"):
        zh.fit(np.ones((1, 4)), 0)
    with pytest.raises(ValueError, match="optimizer"):
        zh.fit(np.ones((1, 4)), 1, optimizer="newton")


def test_zero_signal_fits_without_nan():
    res = zh.fit(np.zeros((3, 16)), 2)
    assert np.all(np.isfinite(res.axes)) and np.all(res.error == 0.0) and np.all(res.rel_error == 0.0)


# ---- Warp functions ------------------------------------------------------------------------

ORDER_WP = 3


@pytest.fixture(scope="module")
def lobe_sets():
    rng = np.random.default_rng(7)
    axes = _unit(rng, (9, 3))
    coeffs = rng.normal(size=(9, 3, ORDER_WP))
    counts = np.array([3, 1, 2, 3, 3, 0, 3, 2, 1], np.int32)
    return axes, coeffs, counts


def _masked(coeffs, counts):
    return coeffs * (np.arange(coeffs.shape[1])[None, :] < counts[:, None])[:, :, None]


def test_warp_to_sh_matches_float64(device, lobe_sets):
    axes, coeffs, counts = lobe_sets
    k = zh.zh_kernels(ORDER_WP)
    out = wp.zeros((9, ORDER_WP**2), dtype=wp.float32, device=device)
    wp.launch(k.to_sh_kernel, dim=9, inputs=[wp.array(axes.astype(np.float32), dtype=wp.vec3, device=device),
                                             wp.array(coeffs.astype(np.float32), device=device),
                                             wp.array(counts, device=device), out], device=device)
    np.testing.assert_allclose(out.numpy(), zh.to_sh(axes, _masked(coeffs, counts)), atol=ATOL_FLOAT32)


def test_warp_lobe_evaluation_matches_float64(device, lobe_sets):
    axes, coeffs, counts = lobe_sets
    rng = np.random.default_rng(8)
    dirs = _unit(rng, (9, 5))
    k = zh.zh_kernels(ORDER_WP)
    out = wp.zeros((9, 5), dtype=wp.float32, device=device)
    wp.launch(k.evaluate_kernel, dim=(9, 5),
              inputs=[wp.array(axes.astype(np.float32), dtype=wp.vec3, device=device),
                      wp.array(coeffs.astype(np.float32), device=device), wp.array(counts, device=device),
                      wp.array(dirs.astype(np.float32), dtype=wp.vec3, device=device), out], device=device)
    np.testing.assert_allclose(out.numpy(), zh.evaluate(axes, _masked(coeffs, counts), dirs), atol=ATOL_FLOAT32)


_TABLE_LOOKUP = zh.zh_kernels(ORDER_WP).table_lookup


@wp.kernel
def _lookup_kernel(table: wp.array4d(dtype=wp.float32), dirs: wp.array(dtype=wp.vec3),
                   out: wp.array3d(dtype=wp.float32)):
    i = wp.tid()
    b = _TABLE_LOOKUP(table, dirs[i])
    for c in range(3):
        for l in range(ORDER_WP):
            out[i, c, l] = b[c, l]


def _table(light, width, device):
    k = zh.zh_kernels(ORDER_WP)
    table = wp.zeros((width // 2 + 1, width, 3, ORDER_WP), dtype=wp.float32, device=device)
    wp.launch(k.table_kernel, dim=table.shape[:2],
              inputs=[wp.array(light.astype(np.float32), device=device), wp.ones(1, dtype=wp.int32, device=device), table],
              device=device)
    return table


def _light_bands_reference(light, dirs):
    y = sh.basis(dirs, ORDER_WP)  # (K, n^2)
    prod = y[:, None, :] * light[None, :, :]  # (K, 3, n^2)
    return np.add.reduceat(prod, np.arange(ORDER_WP) ** 2, axis=2)


def test_light_table_nodes_and_lookup_vs_direct(device):
    rng = np.random.default_rng(9)
    light = rng.normal(size=(3, ORDER_WP**2))
    table = _table(light, 128, device)
    nodes = table_directions(65, 128).reshape(-1, 3)
    ref_nodes = _light_bands_reference(light, nodes).reshape(65, 128, 3, ORDER_WP)
    np.testing.assert_allclose(table.numpy(), ref_nodes, atol=ATOL_FLOAT32)
    dirs = _unit(rng, (400,))
    dirs[:3] = [[0, 0, 1], [0, 0, -1], [1e-4, 0, 1]]  # poles and the seam
    errs = []
    for width in (64, 128):
        tab = _table(light, width, device)
        out = wp.zeros((400, 3, ORDER_WP), dtype=wp.float32, device=device)
        wp.launch(_lookup_kernel, dim=400, inputs=[tab, wp.array(dirs.astype(np.float32), dtype=wp.vec3,
                                                                       device=device), out], device=device)
        errs.append(np.abs(out.numpy() - _light_bands_reference(light, dirs)).max())
    norm = np.linalg.norm(light)
    assert errs[1] <= TABLE_REL_128 * norm
    assert errs[1] < 0.45 * errs[0]  # second-order convergence: halving h quarters the error
