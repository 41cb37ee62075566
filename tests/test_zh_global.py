"""The global ZH fit (variable projection, beam scan, restarts): zh.fit(strategy="global").

Oracles: a many-start search over the same objective (random axis sets, each descended to
convergence), scipy.optimize.check_grad, direct linear solves, exactly representable lobe sets.
"""

import numpy as np
import pytest
from scipy.optimize import check_grad

from warpshade.basis import zh
from warpshade.basis import _zh_global
from warpshade.basis.zh import fitting as _zh_fit

# The fit must reach the median error of a many-start search within this factor (issue 27's
# goal: 5 %); on the 8 seeded vectors below it reaches 1.00-1.02x, the greedy fit 1.3-1.4x.
OPTIMUM_MARGIN = 1.05
# Random starts of the many-start oracle in the test (the benchmark uses 200).
ORACLE_STARTS = 48
# An exactly representable lobe set is recovered to this relative error (BFGS stops at a gradient
# of 1e-9 |t|; the projection's own ridge is 1e-10).
EXACT_FIT_REL = 1e-5
# The default ridge (1e-5) shrinks a fitted DC by mu / (mu + 1 / (4 pi)) = 1.3e-4 relative.
RIDGE_SHRINK_REL = 5e-4
# LM and BFGS from one start reach the same local minimum of phi to this relative error (LM stops
# at a relative decrease of 1e-8 per step).
LM_BFGS_REL = 1e-3
# Analytic vs finite-difference gradient of the projected objective, relative to its norm.
GRAD_REL = 1e-5
# A fit descended in slices matches the one-piece fit to this relative error (float64 rounding of
# batched array operations of other shapes; measured 3e-9 on 150 problems).
SLICED_FIT_REL = 1e-7


def _unit_vectors(seed, count, order=6):
    t = np.random.default_rng(seed).normal(size=(count, order * order))
    return t / np.linalg.norm(t, axis=1, keepdims=True)


def _many_start_error(t, n_lobes, starts, seed):
    """Best of ``starts`` random axis sets, each descended to convergence (relative error)."""
    stored = zh.stored_band_count(n_lobes)
    target = t.copy()
    target[:, : stored * stored] = 0.0
    order = 6
    fitted = np.arange(stored, order)
    rand = np.random.default_rng(seed).normal(size=(t.shape[0], starts, n_lobes, 3))
    rand /= np.linalg.norm(rand, axis=-1, keepdims=True)
    axes, _ = _zh_global._best_of(target, rand, order, fitted, _zh_fit.DEFAULT_RIDGE, _zh_global.GlobalOptions())
    coeffs = _zh_fit.solve_coefficients(target, axes, fitted, _zh_fit.DEFAULT_RIDGE)
    return np.linalg.norm(_zh_fit.reconstruct(axes, coeffs) - target, axis=1) / np.linalg.norm(t, axis=1)


def test_global_fit_reaches_the_many_start_optimum():
    t = _unit_vectors(2027, 8)
    oracle = _many_start_error(t, 4, ORACLE_STARTS, seed=11)
    fit = zh.fit(t, 4)
    assert fit.notes["strategy"] == "global"
    assert np.median(fit.rel_error) <= OPTIMUM_MARGIN * np.median(oracle)
    greedy = zh.fit(t, 4, strategy="greedy")
    assert np.median(greedy.rel_error) > OPTIMUM_MARGIN * np.median(oracle), "the case must have local minima"
    # the reported error is the fit's own
    np.testing.assert_allclose(fit.error, np.linalg.norm(fit.to_sh() - t, axis=1), rtol=1e-9, atol=1e-12)
    assert np.all(fit.error <= fit.greedy_error + 1e-12)  # descent never loses the scanned start


@pytest.mark.parametrize("n_lobes", [1, 3, 4])
def test_global_fit_recovers_exact_lobe_sets(rng, n_lobes):
    order = 6
    axes = rng.normal(size=(4, n_lobes, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    t = zh.to_sh(axes, rng.normal(size=(4, n_lobes, order)))
    res = zh.fit(t, n_lobes, ridge=0.0)
    assert res.rel_error.max() < EXACT_FIT_REL
    folded_axes, folded_coeffs = res
    np.testing.assert_allclose(zh.to_sh(folded_axes, folded_coeffs), t, atol=1e-4 * np.abs(t).max())


def test_global_fit_extends_initial_axes(rng):
    """fit_budget's path: axes of an N0-lobe fit extended to N lobes."""
    t = _unit_vectors(5, 4)
    two = zh.fit(t, 2, stored_bands=1)
    three = zh.fit(t, 3, stored_bands=1, initial_axes=two.axes)
    assert np.all(three.error <= two.error + 1e-12)


@pytest.mark.parametrize("stored_bands", ["paper", 0])
def test_degenerate_inputs_never_nan(stored_bands):
    zero = np.zeros((2, 36))
    dc = np.zeros((2, 36))
    dc[:, 0] = [1.0, -3.0]
    linear = np.zeros((1, 36))
    linear[0, 1:4] = [0.2, -0.5, 0.1]
    for t in (zero, dc, linear):
        for n_lobes in (1, 3, 4):
            res = zh.fit(t, n_lobes, stored_bands=stored_bands)
            for a in (res.axes, res.coeffs, res.error, res.rel_error, res.greedy_error, res.restart_gain):
                assert np.all(np.isfinite(a))
            np.testing.assert_allclose(np.linalg.norm(res.axes, axis=-1), 1.0, atol=1e-12)
            np.testing.assert_allclose(res.to_sh(), t, atol=RIDGE_SHRINK_REL * max(1.0, np.abs(t).max()))


def test_nan_and_bad_options_are_refused():
    bad = _unit_vectors(1, 2)
    bad[1, 7] = np.nan
    with pytest.raises(ValueError, match="NaN|finite"):
        zh.fit(bad, 3)
    with pytest.raises(ValueError, match="strategy"):
        zh.fit(bad[:1], 3, strategy="annealing")
    with pytest.raises(ValueError, match="screened_sets"):
        zh.fit(bad[:1], 3, screened_sets=-1)


def test_projected_gradient_vs_check_grad(rng):
    order, n_lobes = 6, 3
    target = rng.normal(size=(1, order * order))
    target[:, :4] = 0.0
    fitted = np.arange(2, order)
    x0 = rng.normal(size=n_lobes * 3) * 1.4

    def f(x):
        return _zh_global.projected_objective(target, x.reshape(1, n_lobes, 3), order, fitted, 1e-5)[0][0]

    def g(x):
        return _zh_global.projected_objective(target, x.reshape(1, n_lobes, 3), order, fitted, 1e-5)[1].ravel()

    assert check_grad(f, g, x0) <= GRAD_REL * max(1.0, np.linalg.norm(g(x0)))


def test_projected_value_is_the_solved_least_squares(rng):
    """phi(S) equals |t~ - t|^2 + mu |g*|^2 with the coefficients of the ridge solve."""
    order, n_lobes, mu = 5, 3, 1e-3
    target = rng.normal(size=(3, order * order))
    target[:, 0] = 0.0
    fitted = np.arange(1, order)
    axes = rng.normal(size=(3, n_lobes, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    coeffs = _zh_fit.solve_coefficients(target, axes, fitted, mu)
    r = _zh_fit.reconstruct(axes, coeffs) - target
    direct = np.sum(r * r, axis=1) + mu * np.sum(coeffs**2, axis=(1, 2))
    np.testing.assert_allclose(_zh_global.projected_value(target, axes, order, fitted, mu), direct, rtol=1e-10)


def test_scan_scores_extensions_exactly(rng):
    """The Schur-complement gain of the beam scan equals phi solved directly for each extension."""
    order, mu = 5, 1e-5
    target = rng.normal(size=(2, order * order))
    target[:, 0] = 0.0
    fitted = np.arange(1, order)
    axes = rng.normal(size=(2, 1, 2, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    cand = rng.normal(size=(2, 5, 3))
    cand /= np.linalg.norm(cand, axis=-1, keepdims=True)
    from warpshade.basis._core import basis

    r_cand = _zh_global._band_projections(target, basis(cand.reshape(-1, 3), order).reshape(2, 5, -1), fitted)
    ginv, u, phi = _zh_global._set_state(target, axes, order, fitted, mu)
    after = phi[:, :, None] - _zh_global._extension_gain(ginv, u, axes, cand, r_cand, order, fitted, mu)
    for c in range(5):
        grown = np.concatenate([axes[:, 0], cand[:, c : c + 1]], axis=1)
        np.testing.assert_allclose(after[:, 0, c], _zh_global.projected_value(target, grown, order, fitted, mu),
                                   rtol=1e-9)


def test_levenberg_marquardt_reaches_the_bfgs_minimum(rng):
    """On near-representable targets (a lobe set plus 1 % noise) LM on the projected objective and
    BFGS from the same start end at the same phi (LM in a fraction of the iterations)."""
    order, n_lobes, mu = 6, 3, _zh_fit.DEFAULT_RIDGE
    axes = rng.normal(size=(6, n_lobes, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    t = zh.to_sh(axes, rng.normal(size=(6, n_lobes, order)))
    t += 0.01 * np.linalg.norm(t, axis=1, keepdims=True) * rng.normal(size=t.shape) / 6.0
    target = t.copy()
    target[:, :4] = 0.0
    fitted = np.arange(2, order)
    start = axes + 0.15 * rng.normal(size=axes.shape)
    start /= np.linalg.norm(start, axis=-1, keepdims=True)
    phi0 = _zh_global.projected_value(target, start, order, fitted, mu)
    _, phi_lm, its = _zh_global.levenberg_marquardt(target, start, order, fitted, mu, 200)
    _, phi_bfgs = _zh_global._descend(target, start, order, fitted, mu, _zh_global.GlobalOptions(), 200)
    assert np.all(phi_lm < phi0)
    np.testing.assert_allclose(np.sqrt(phi_lm), np.sqrt(phi_bfgs), rtol=LM_BFGS_REL)


def test_descents_in_slices_bound_memory_and_give_the_same_fit(monkeypatch):
    """The descents run over slices of at most DESCENT_CHUNK_SETS start sets (a 13,860-vertex
    glossy fit, 166k problems, needed over 24 GiB in one piece): the peak of traced allocations
    falls with the slice, and the fit is the same (each problem descends on its own; lobes may come
    out in another order, so the reconstructions are compared)."""
    import tracemalloc

    rng = np.random.default_rng(5)
    order, lobes, count = 6, 4, 32
    bands = np.repeat(np.arange(order), 2 * np.arange(order) + 1)
    t = rng.normal(size=(count, order * order)) * 0.6**bands  # mostly hard: the restarts engage
    axes = rng.normal(size=(8, lobes, 3))
    t[:8] = zh.to_sh(axes / np.linalg.norm(axes, axis=-1, keepdims=True), rng.normal(size=(8, lobes, order)))

    def fit_with(chunk):
        monkeypatch.setattr(_zh_global, "DESCENT_CHUNK_SETS", chunk)
        tracemalloc.start()
        try:
            res = zh.fit(t, lobes)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        return res, peak

    whole, peak_whole = fit_with(10**9)
    sliced, peak_sliced = fit_with(512)
    assert whole.restarted.sum() > 16  # the restart phase is exercised, in several slices
    assert peak_sliced < 0.5 * peak_whole, (peak_sliced, peak_whole)
    rec_whole = zh.to_sh(whole.axes, whole.coeffs) + whole.stored
    rec_sliced = zh.to_sh(sliced.axes, sliced.coeffs) + sliced.stored
    rel = np.linalg.norm(rec_whole - rec_sliced, axis=1) / np.linalg.norm(rec_whole, axis=1)
    assert rel.max() < SLICED_FIT_REL, rel.max()
    np.testing.assert_allclose(sliced.error, whole.error, rtol=SLICED_FIT_REL, atol=0.0)
