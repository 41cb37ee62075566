"""Global ZH lobe fitting by variable projection (private; the public API is warpshade.basis.zh).

For fixed lobe axes ``S = (s_1 .. s_N)`` the fit of Sloan et al. 2005 (eq. 17) is linear in the
coefficients and separates by band: band l solves ``min |A_l g_l - t_l|^2 + mu |g_l|^2`` with
``A_l[m, i] = y_lm(s_i)``. Eliminating the coefficients leaves a function of the axes alone
(variable projection, Golub and Pereyra 1973)::

    phi(S) = sum_l |t_l|^2 - r_l^T (G_l + mu I)^-1 r_l,
    G_l[i, j] = y_l(s_i) . y_l(s_j) = (2l + 1) / (4 pi) P_l(s_i . s_j),   r_l[i] = y_l(s_i) . t_l

(the Gram matrix by the addition theorem). Its gradient is the axis part of eq. 20-21 evaluated
at the solved coefficients (the coefficient part vanishes there: the envelope theorem), so BFGS
runs over 3N unconstrained numbers instead of N (3 + bands).

The global strategy of :func:`fit_global`, per problem:

1. **Batched initial scan (beam search).** Axis sets are grown one axis at a time from a pool of
   candidate axes (the hemi-cube cells of eq. 18's search, plus the optimal linear axis when the
   linear band is fitted). Adding a candidate c to a set with solved ``(G + mu I)^-1`` lowers phi
   by ``sum_l (r_l(c) - b_l^T u_l)^2 / (d_l - b_l^T (G + mu I)^-1 b_l)`` (a Schur complement:
   ``b_l = G_l[S, c]``, ``u_l = (G_l + mu I)^-1 r_l``, ``d_l = G_l[c, c] + mu``), so every
   extension of every kept set is scored exactly at once; the ``beam`` best distinct sets are
   kept. Greedy matching pursuit is the beam of width 1.
2. **Local descent** from the ``starts`` best sets of the scan: batched BFGS on phi, or, where the
   scanned set already fits to within ``gauss_newton_below`` (near-representable targets such as
   diffuse transfer, where BFGS crawls along the ridge-flattened valley), batched
   Levenberg-Marquardt on the projected residual with Kaufman's Jacobian
   ``P_perp (dY/dS) g`` (:func:`levenberg_marquardt`), the axes moved in their tangent planes.
3. **Targeted restarts.** Where the relative error is still above ``restart_error``:
   ``random_sets`` random axis sets (``random_sets * restarts / 6`` below 6 restarts; with the
   scan's other sets) are screened by a short BFGS
   (``screen_iterations``), the ``restarts`` best are descended to convergence; then rounds of
   re-seating moves (basin hopping): one or two lobes removed and put back by the beam scan on
   the others' residual, each move scored exactly, BFGS from the ``swaps`` best; a move is kept
   when it lowers phi (``hop_rounds`` rounds, while moves keep helping).

Measured (``benchmarks/bench_zh.py``, 30 seeded random unit order-6 vectors and 16 others): the
median error is within 1.000-1.031x of a 200-start search's for N = 3, 4, at 1.1-2.4x the time of
the greedy fit, which was 1.10-1.41x off.

Builds on :mod:`warpshade.basis._core`, :mod:`~warpshade.basis._zh_grad` and
:mod:`~warpshade.basis._zh_fit` (the batched BFGS and coefficient solve).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._core import basis
from ._zh_fit import (
    LobeFit,
    band_norms,
    bfgs_batched,
    bfgs_scipy,
    hemicube_axes,
    optimal_linear_axes,
    reconstruct,
    solve_coefficients,
)
from ._zh_grad import basis_and_gradient

__all__ = [
    "GlobalOptions",
    "GlobalResult",
    "fit_global",
    "fit_lobes_global",
    "projected_objective",
    "projected_solve",
    "projected_value",
    "scan_sets",
]

#: Smallest ridge used inside the projected objective (dimensionless, like the fit's mu): keeps
#: ``G + mu I`` invertible where two axes coincide. The returned coefficients are re-solved with
#: the caller's ridge (minimum-norm least squares when it is 0), so this only shapes the search.
PROJECTION_MIN_RIDGE = 1e-10
#: A candidate within this cosine of an axis already in the set adds nothing new (its Schur
#: denominator is ~mu); it is skipped in the scan.
SAME_AXIS_COS = 0.999
#: Problems handled at once by the scan (bounds temporaries to a few tens of MB).
SCAN_CHUNK = 128
#: Start sets descended at once (problems x start sets a problem): bounds the descents' memory
#: (about 13 KiB a set at order 6 with 4 lobes: BFGS state, Gram solves; ~200 MiB a chunk). Each
#: problem descends on its own, so a problem's result does not depend on the chunk.
DESCENT_CHUNK_SETS = 16384


def _row_chunks(rows: int, sets_per_row: int):
    """Slices of ``rows`` problems holding at most :data:`DESCENT_CHUNK_SETS` start sets (at
    least one problem a slice)."""
    step = max(1, DESCENT_CHUNK_SETS // max(int(sets_per_row), 1))
    for lo in range(0, rows, step):
        yield slice(lo, min(rows, lo + step))


@dataclass
class GlobalOptions:
    """Knobs of :func:`fit_global` (see the module docstring)."""

    candidate_resolution: int = 6  # hemi-cube cells per face edge of the pool
    beam: int = 16  # distinct sets kept per step of the scan
    random_sets: int = 128  # random axis sets screened by the restarts
    screen_iterations: int = 15  # BFGS iterations of the screening descent
    starts: int = 3  # BFGS starts from the best scanned sets
    restarts: int = 6  # restarts: screened random sets descended to convergence (0: none)
    swaps: int = 3  # BFGS starts per round of swap moves (the best moves)
    hop_rounds: int = 2  # rounds of swap moves
    restart_error: float = 0.05  # relative error above which the swaps engage
    max_iterations: int = 200
    optimizer: str = "batched"
    seed: int = 0
    gtol: float = 1e-9  # BFGS stops at |grad|_max <= gtol |t|
    ftol: float = 1e-12  # ... or at a relative decrease of phi below ftol
    gauss_newton_below: float = 0.1  # scanned relative error below which LM replaces BFGS
    lm_ftol: float = 1e-8  # LM stops at a relative decrease of phi below this
    lm_iterations: int = 200  # LM iterations at most


@dataclass
class GlobalResult:
    axes: np.ndarray  # (B, N, 3) unit
    phi: np.ndarray  # (B,) projected objective (penalised by mu)
    scan_axes: np.ndarray  # (B, N, 3) best scanned set, before BFGS
    descent_axes: np.ndarray  # (B, N, 3) after BFGS from the scanned sets, before the restarts
    restarted: np.ndarray  # (B,) bool: restarts engaged


def _legendre(x: np.ndarray, order: int) -> np.ndarray:
    """P_0..P_{n-1}(x), shape (..., n)."""
    p = [np.ones_like(x), x]
    for l in range(1, order - 1):
        p.append(((2 * l + 1) * x * p[l] - l * p[l - 1]) / (l + 1))
    return np.stack(p[:order], axis=-1)


def _band_projections(target: np.ndarray, y: np.ndarray, fitted: np.ndarray) -> np.ndarray:
    """``r_l(s) = sum_m y_lm(s) t_lm`` for the fitted bands: target (B, n*n), y (B, K, n*n) or
    (K, n*n) -> (B, K, F)."""
    out = []
    for l in fitted:
        sl = slice(l * l, (l + 1) * (l + 1))
        if y.ndim == 2:
            out.append(target[:, sl] @ y[:, sl].T)
        else:
            out.append(np.einsum("bj,bkj->bk", target[:, sl], y[:, :, sl]))
    return np.stack(out, axis=-1)


def _gram(a: np.ndarray, b: np.ndarray, order: int, fitted: np.ndarray) -> np.ndarray:
    """Band Gram entries ``(2l+1)/(4 pi) P_l(a . b)`` for the fitted bands: (..., F)."""
    cos = np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)
    return _legendre(cos, order)[..., fitted] * band_norms(order)[fitted]


def _set_state(target, axes, order, fitted, mu):
    """Per set and fitted band: ``(G + mu I)^-1`` (..., F, k, k), ``u = (G + mu I)^-1 r`` (..., F, k)
    and ``phi`` (...,). axes: (B, W, k, 3); target: (B, n*n)."""
    b, w, k = axes.shape[:3]
    tt = np.einsum("bj,bj->b", target, target)
    if k == 0:
        return np.zeros((b, w, len(fitted), 0, 0)), np.zeros((b, w, len(fitted), 0)), np.repeat(tt[:, None], w, 1)
    y = basis(axes.reshape(-1, 3), order).reshape(b, w * k, -1)
    r = _band_projections(target, y, fitted).reshape(b, w, k, -1)  # (B, W, k, F)
    g = _gram(axes[:, :, :, None, :], axes[:, :, None, :, :], order, fitted)  # (B, W, k, k, F)
    g = np.moveaxis(g, -1, 2) + mu * np.eye(k)  # (B, W, F, k, k)
    ginv = np.linalg.inv(g)
    rf = np.moveaxis(r, -1, 2)  # (B, W, F, k)
    u = np.einsum("bwfij,bwfj->bwfi", ginv, rf)
    phi = tt[:, None] - np.einsum("bwfi,bwfi->bw", rf, u)
    return ginv, u, phi


def _extension_gain(ginv, u, axes, cand, r_cand, order, fitted, mu):
    """Decrease of phi when candidate c joins each set (Schur complement), (B, W, K).

    ginv (B, W, F, k, k), u (B, W, F, k), axes (B, W, k, 3), cand (B, K, 3), r_cand (B, K, F).
    Candidates within SAME_AXIS_COS of a set's axis get -inf.
    """
    norms = band_norms(order)[fitted]
    k = axes.shape[2]
    if k == 0:
        gain = np.sum(r_cand**2 / (norms + mu), axis=-1)[:, None, :]
        return gain
    cos = np.einsum("bwkc,bpc->bwkp", axes, cand)  # (B, W, k, K)
    bl = _legendre(np.clip(cos, -1.0, 1.0), order)[..., fitted] * norms  # (B, W, k, K, F)
    bl = np.moveaxis(bl, -1, 2)  # (B, W, F, k, K)
    num = np.moveaxis(r_cand, -1, 1)[:, None] - np.einsum("bwfkp,bwfk->bwfp", bl, u)  # (B, W, F, K)
    v = np.einsum("bwfij,bwfjp->bwfip", ginv, bl)
    den = (norms + mu)[None, None, :, None] - np.einsum("bwfkp,bwfkp->bwfp", bl, v)
    gain = np.sum(num * num / np.maximum(den, 1e-300), axis=2)
    close = np.any(np.abs(cos) > SAME_AXIS_COS, axis=2)
    return np.where(close, -np.inf, gain)


def _candidates(target: np.ndarray, fitted: np.ndarray, resolution: int) -> np.ndarray:
    """Pool of candidate axes per problem (B, K, 3): hemi-cube cells (+ optimal linear axis)."""
    pool = hemicube_axes(resolution)
    b = target.shape[0]
    cand = np.broadcast_to(pool, (b,) + pool.shape)
    if 1 in set(fitted.tolist()):
        cand = np.concatenate([cand, optimal_linear_axes(target)[:, None, :]], axis=1)
    return np.ascontiguousarray(cand)


def _top_distinct(score: np.ndarray, keys: np.ndarray, count: int) -> np.ndarray:
    """Per row, flat indices of the ``count`` highest finite scores with distinct keys.

    score, keys: (B, M). Returns (B, count) indices (repeating the best where fewer exist)."""
    order = np.argsort(-score, axis=1, kind="stable")
    ks = np.take_along_axis(keys, order, axis=1)  # keys in score order
    by_key = np.argsort(ks, axis=1, kind="stable")  # equal keys stay in score order
    ks2 = np.take_along_axis(ks, by_key, axis=1)
    dup_sorted = np.zeros(ks.shape, dtype=bool)
    dup_sorted[:, 1:] = ks2[:, 1:] == ks2[:, :-1]
    dup = np.empty_like(dup_sorted)
    np.put_along_axis(dup, by_key, dup_sorted, axis=1)
    valid = ~dup & np.isfinite(np.take_along_axis(score, order, axis=1))
    first = np.argsort(~valid, axis=1, kind="stable")[:, :count]  # positions of valid entries, in order
    pick = np.take_along_axis(order, first, axis=1)
    n_valid = valid.sum(axis=1)
    short = np.arange(pick.shape[1])[None, :] >= np.maximum(n_valid, 1)[:, None]
    return np.where(short, pick[:, :1], pick)


def scan_sets(target: np.ndarray, order: int, fitted: np.ndarray, lobe_count: int, beam: int,
              resolution: int, mu: float, initial_axes: np.ndarray | None = None):
    """Beam search over axis sets from the candidate pool (step 1 of :func:`fit_global`).

    Args:
        target: (B, n*n) with the stored bands zeroed.
        initial_axes: optional (B, N0, 3) axes every set starts from (N0 < N).

    Returns:
        ``(axes (B, beam, N, 3), phi (B, beam))``, best first.
    """
    b = target.shape[0]
    cand = _candidates(target, fitted, resolution)  # (B, K, 3)
    kc = cand.shape[1]
    y = basis(cand.reshape(-1, 3), order).reshape(b, kc, -1)
    r_cand = _band_projections(target, y, fitted)  # (B, K, F)
    if initial_axes is not None and initial_axes.shape[1] > 0:
        axes = initial_axes[:, None].copy()
        ids = np.full((b, 1, axes.shape[2]), -1, dtype=np.int64) - np.arange(axes.shape[2])
    else:
        axes = np.zeros((b, 1, 0, 3))
        ids = np.zeros((b, 1, 0), dtype=np.int64)
    while axes.shape[2] < lobe_count:
        ginv, u, phi = _set_state(target, axes, order, fitted, mu)
        gain = _extension_gain(ginv, u, axes, cand, r_cand, order, fitted, mu)  # (B, W, K)
        w = axes.shape[1]
        new_ids = np.concatenate([np.repeat(ids[:, :, None], kc, 2), np.broadcast_to(
            np.arange(kc)[None, None, :, None], (b, w, kc, 1))], axis=3)  # (B, W, K, k+1)
        keys = _set_keys(new_ids.reshape(b, w * kc, -1), kc)
        score = (gain - phi[:, :, None]).reshape(b, w * kc)  # -(phi after)
        pick = _top_distinct(score, keys, beam)  # (B, beam)
        src_w, src_c = pick // kc, pick % kc
        rows = np.arange(b)[:, None]
        axes = np.concatenate([axes[rows, src_w], cand[rows, src_c][:, :, None, :]], axis=2)
        ids = new_ids.reshape(b, w * kc, -1)[rows, pick]
    _, _, phi = _set_state(target, axes, order, fitted, mu)
    best = np.argsort(phi, axis=1)
    rows = np.arange(b)[:, None]
    return axes[rows, best], phi[rows, best]


def _set_keys(ids: np.ndarray, base: int) -> np.ndarray:
    """Order-independent integer key of index sets (..., k) (negative ids: fixed initial axes)."""
    s = np.sort(ids, axis=-1) + ids.shape[-1] + 1  # shift negatives to >= 1
    key = np.zeros(ids.shape[:-1], dtype=np.int64)
    for j in range(ids.shape[-1]):
        key = key * (base + ids.shape[-1] + 2) + s[..., j]
    return key


def projected_solve(target, axes, order, fitted, mu):
    """Coefficients minimising ``|t~ - t|^2 + mu |g*|^2`` for unit axes (B, N, 3): (B, N, n)."""
    b, n_lobes = axes.shape[:2]
    y = basis(axes.reshape(-1, 3), order).reshape(b, n_lobes, -1)
    return _solve_from_basis(target, y, order, fitted, mu)


def _solve_from_basis(target, y, order, fitted, mu):
    b, n_lobes = y.shape[:2]
    coeffs = np.zeros((b, n_lobes, order))
    eye = np.eye(n_lobes)
    for l in fitted:
        sl = slice(l * l, (l + 1) * (l + 1))
        a = y[:, :, sl]  # (B, N, 2l+1)
        normal = np.einsum("bim,bjm->bij", a, a) + mu * eye
        rhs = np.einsum("bim,bm->bi", a, target[:, sl])
        coeffs[:, :, l] = np.linalg.solve(normal, rhs[..., None])[..., 0]
    return coeffs


def projected_objective(target: np.ndarray, raw_axes: np.ndarray, order: int, fitted: np.ndarray,
                        mu: float) -> tuple[np.ndarray, np.ndarray]:
    """``phi(S)`` and its gradient for unnormalised axes (the eq. 20-21 axis gradient at the
    solved coefficients).

    Args:
        target: (B, n*n), stored bands zeroed. raw_axes: (B, N, 3), nonzero.
        mu: ridge (> 0).

    Returns:
        ``(phi (B,), d phi / d raw_axes (B, N, 3))``.
    """
    b, n_lobes = raw_axes.shape[:2]
    s = raw_axes.reshape(-1, 3)
    length = np.maximum(np.linalg.norm(s, axis=-1, keepdims=True), 1e-300)
    unit = s / length
    y, dy = basis_and_gradient(unit, order)  # (B N, n*n), (B N, n*n, 3)
    y3 = y.reshape(b, n_lobes, -1)
    coeffs = _solve_from_basis(target, y3, order, fitted, mu)
    band = np.repeat(np.arange(order), 2 * np.arange(order) + 1)
    g_exp = coeffs[:, :, band]
    residual = np.einsum("bij,bij->bj", y3, g_exp) - target
    phi = np.einsum("bj,bj->b", residual, residual) + mu * np.einsum("bil,bil->b", coeffs, coeffs)
    # eq. 20-21: contract the polynomial gradient first, then apply J_h = (I - u u^T) / |s|
    weight = (g_exp * residual[:, None, :]).reshape(b * n_lobes, 1, -1)
    g = 2.0 * np.matmul(weight, dy)[:, 0]  # (B N, 3)
    g = (g - np.sum(g * unit, axis=-1, keepdims=True) * unit) / length
    grad = g.reshape(b, n_lobes, 3)
    return phi, grad


def projected_value(target, axes, order, fitted, mu) -> np.ndarray:
    """``phi(S)`` alone for unit axes (B, N, 3), shape (B,)."""
    return projected_objective(target, axes, order, fitted, mu)[0]


def _descend(target, axes0, order, fitted, mu, options: GlobalOptions, iterations: int):
    """BFGS on phi from axes0 (B, N, 3); returns unit axes and phi."""
    b, n_lobes = axes0.shape[:2]
    scale = np.einsum("bj,bj->b", target, target)

    def fun(x, rows):
        phi, grad = projected_objective(target[rows], x.reshape(-1, n_lobes, 3), order, fitted, mu)
        return phi, grad.reshape(x.shape[0], -1)

    optimiser = bfgs_scipy if options.optimizer == "scipy" else bfgs_batched
    x, phi, _ = optimiser(fun, axes0.reshape(b, -1), scale, iterations, gtol=options.gtol, ftol=options.ftol)
    raw = x.reshape(b, n_lobes, 3)
    unit = raw / np.maximum(np.linalg.norm(raw, axis=-1, keepdims=True), 1e-300)
    return unit, phi


def _descend_sets(target, starts_axes, order, fitted, mu, options, iterations):
    """BFGS (``iterations`` at most) from S sets per problem (B, S, N, 3): axes and phi (B, S)."""
    b, s, n_lobes = starts_axes.shape[:3]
    axes = np.empty((b, s, n_lobes, 3))
    phi = np.empty((b, s))
    for sl in _row_chunks(b, s):
        k = sl.stop - sl.start
        rep = np.repeat(target[sl], s, axis=0)
        a, p = _descend(rep, starts_axes[sl].reshape(k * s, n_lobes, 3), order, fitted, mu, options, iterations)
        axes[sl], phi[sl] = a.reshape(k, s, n_lobes, 3), p.reshape(k, s)
    return axes, phi


def _best_of(target, starts_axes, order, fitted, mu, options, small=None):
    """Descent from S start sets per problem (B, S, N, 3); the best (axes (B, N, 3), phi (B,)).

    BFGS, or Levenberg-Marquardt (:func:`levenberg_marquardt`) for the problems flagged ``small``
    (B,) bool: near-representable targets, where Gauss-Newton converges fast and BFGS crawls.
    """
    b, s, n_lobes = starts_axes.shape[:3]
    if small is None or not np.any(small):
        axes, phi = _descend_sets(target, starts_axes, order, fitted, mu, options, options.max_iterations)
    else:
        axes = np.empty_like(starts_axes)
        phi = np.empty((b, s))
        big = ~small
        if np.any(big):
            axes[big], phi[big] = _descend_sets(target[big], starts_axes[big], order, fitted, mu, options,
                                                options.max_iterations)
        where = np.flatnonzero(small)
        for sl in _row_chunks(where.size, s):
            rows = where[sl]
            k = rows.size
            a, p, _ = levenberg_marquardt(np.repeat(target[rows], s, axis=0), starts_axes[rows].reshape(k * s, n_lobes, 3),
                                          order, fitted, mu, options.lm_iterations, options.lm_ftol)
            axes[rows], phi[rows] = a.reshape(k, s, n_lobes, 3), p.reshape(k, s)
    pick = np.argmin(phi, axis=1)
    return axes[np.arange(b), pick], phi[np.arange(b), pick]


def _swap_moves(target, axes, order, fitted, mu, resolution, count):
    """The ``count`` best re-seatings per problem: one or two lobes removed and put back by the
    beam scan on the others' residual (pool axes), each scored exactly; (B, count, N, 3).

    A re-seating that puts every removed lobe back within 12 degrees of where it was is no move.
    """
    import itertools

    b, n_lobes = axes.shape[:2]
    moves, phis = [], []
    near = np.cos(np.radians(12.0))
    for r in (1, 2):
        if n_lobes - r < 1 and r > 1:
            break
        for removed in itertools.combinations(range(n_lobes), r):
            kept = np.delete(axes, removed, axis=1)
            sets, phi = scan_sets(target, order, fitted, n_lobes, 2, resolution, mu, kept)
            added = sets[:, :, n_lobes - r :]  # (B, 2, r, 3)
            same = np.all(np.max(np.abs(np.einsum("bwrc,bqc->bwrq", added, axes[:, list(removed)])), axis=-1) > near,
                          axis=-1)
            moves.append(sets)
            phis.append(np.where(same, np.inf, phi))
    moves = np.concatenate(moves, axis=1)
    phis = np.concatenate(phis, axis=1)
    pick = np.argsort(phis, axis=1)[:, :count]
    return moves[np.arange(b)[:, None], pick]


def fit_global(target: np.ndarray, order: int, fitted: np.ndarray, lobe_count: int, ridge: float,
               options: GlobalOptions, initial_axes: np.ndarray | None = None) -> GlobalResult:
    """Scan, descend, swap (module docstring) for B problems; target (B, n*n), stored bands zeroed."""
    mu = max(float(ridge), PROJECTION_MIN_RIDGE)
    b = target.shape[0]
    scale = np.einsum("bj,bj->b", target, target)
    sets = []
    phis = []
    for lo in range(0, b, SCAN_CHUNK):
        sl = slice(lo, lo + SCAN_CHUNK)
        init = None if initial_axes is None else initial_axes[sl]
        a, p = scan_sets(target[sl], order, fitted, lobe_count, options.beam, options.candidate_resolution, mu, init)
        sets.append(a)
        phis.append(p)
    sets = np.concatenate(sets)
    phi_scan = np.concatenate(phis)[:, 0]
    s = min(options.starts, sets.shape[1])
    small = np.sqrt(phi_scan / np.maximum(scale, 1e-300)) < options.gauss_newton_below
    axes, phi = _best_of(target, sets[:, :s], order, fitted, mu, options, small)
    better = phi > phi_scan  # never lose the best scanned set
    axes[better], phi[better] = sets[better, 0], phi_scan[better]
    descent_axes = axes.copy()
    rel = np.sqrt(phi / np.maximum(scale, 1e-300))
    hard = np.flatnonzero((rel > options.restart_error) & (scale > 0.0))
    restarted = np.zeros(b, dtype=bool)
    if options.restarts > 0 and lobe_count > 1 and hard.size:
        restarted[hard] = True
        _restart(target, axes, phi, hard, order, fitted, lobe_count, mu, options, initial_axes, sets[hard, s:])
    return GlobalResult(axes, phi, sets[:, 0].copy(), descent_axes, restarted)


def _restart(target, axes, phi, rows, order, fitted, lobe_count, mu, options, initial_axes, scanned):
    """Targeted restarts for the problems ``rows`` (updates axes and phi in place): random axis
    sets screened by a short descent, the ``restarts`` best descended to convergence, then rounds
    of swap moves."""
    k = rows.size
    rng = np.random.default_rng(options.seed)
    # screening effort follows the restarts asked for: random_sets at restarts >= 6
    screened = max(1, int(round(options.random_sets * min(options.restarts, 6) / 6)))
    per_row = scanned.shape[1] + screened
    s = min(options.restarts, per_row)
    new_axes = np.empty((k, lobe_count, 3))
    new_phi = np.empty(k)
    # in slices of problems (memory); the draws follow one another as one draw of (k, ...) would
    for sl in _row_chunks(k, per_row):
        c, sub = sl.stop - sl.start, rows[sl]
        rand = rng.normal(size=(c, screened, lobe_count, 3))
        rand /= np.linalg.norm(rand, axis=-1, keepdims=True)
        if initial_axes is not None and initial_axes.shape[1] > 0:
            rand[:, :, : initial_axes.shape[1]] = initial_axes[sub][:, None]
        rand = np.concatenate([scanned[sl], rand], axis=1)  # the scan's other sets are screened too
        if rand.shape[1] > s:  # screening: a short descent from every set, the best s go on
            kept, phi_s = _descend_sets(target[sub], rand, order, fitted, mu, options, options.screen_iterations)
            pick = np.argsort(phi_s, axis=1)[:, :s]
            rand = kept[np.arange(c)[:, None], pick]
        new_axes[sl], new_phi[sl] = _best_of(target[sub], rand, order, fitted, mu, options)
    gain = new_phi < phi[rows]
    axes[rows[gain]], phi[rows[gain]] = new_axes[gain], new_phi[gain]
    active = rows
    for _ in range(options.hop_rounds):
        if active.size == 0:
            break
        moves = np.concatenate([_swap_moves(target[active[lo:lo + SCAN_CHUNK]], axes[active[lo:lo + SCAN_CHUNK]],
                                            order, fitted, mu, options.candidate_resolution, options.swaps)
                                for lo in range(0, active.size, SCAN_CHUNK)])
        new_axes, new_phi = _best_of(target[active], moves, order, fitted, mu, options)
        gain = new_phi < phi[active] * (1.0 - 1e-9)
        moved = active[gain]
        axes[moved], phi[moved] = new_axes[gain], new_phi[gain]
        active = moved  # only problems that moved can move again


def fit_lobes_global(target: np.ndarray, problem, options: GlobalOptions, initial_axes: np.ndarray | None = None):
    """:func:`fit_global` with the coefficients solved for the found axes, as a
    :class:`~warpshade.basis._zh_fit.LobeFit` (psi: the unpenalised error; psi_greedy: that of
    the best scanned set; restart_gain: what the restarts bought).

    Args:
        target: (B, n*n) with the stored bands zeroed.
        problem: :class:`~warpshade.basis._zh_fit.FitProblem` (order, lobes, stored bands, ridge).
    """
    fitted = problem.fitted
    res = fit_global(target, problem.order, fitted, problem.lobe_count, problem.ridge, options, initial_axes)

    def solved(axes):
        coeffs = solve_coefficients(target, axes, fitted, problem.ridge)
        r = reconstruct(axes, coeffs) - target
        return coeffs, np.einsum("bj,bj->b", r, r)

    coeffs, psi = solved(res.axes)
    _, psi_scan = solved(res.scan_axes)
    _, psi_descent = solved(res.descent_axes)
    gain = np.where(res.restarted, np.maximum(psi_descent - psi, 0.0), 0.0)
    return LobeFit(res.axes, coeffs, psi, psi_scan, res.restarted, gain)


def _tangent_frames(axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to each unit axis and to each other, (..., 3) each."""
    other_axis = np.where(np.abs(axes[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    e1 = np.cross(axes, other_axis)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    return e1, np.cross(axes, e1)


def _residual_and_jacobian(target, axes, order, fitted, mu, with_jacobian=True):
    """Projected residual ``r = Y(S) g(S) - t`` over the fitted coefficients, phi, and Kaufman's
    Jacobian ``P_perp dY/dS g`` in tangent coordinates (two per axis).

    Returns ``(phi (B,), r (B, M), J (B, M, 2N) or None, e1, e2)``.
    """
    b, n_lobes = axes.shape[:2]
    flat = axes.reshape(-1, 3)
    if with_jacobian:
        y, dy = basis_and_gradient(flat, order)
    else:
        y, dy = basis(flat, order), None
    y3 = y.reshape(b, n_lobes, -1)
    coeffs = np.zeros((b, n_lobes, order))
    eye = np.eye(n_lobes)
    rows = []
    jac = []
    phi = mu * 0.0
    e1 = e2 = None
    if with_jacobian:
        e1, e2 = _tangent_frames(axes)
        dy4 = dy.reshape(b, n_lobes, -1, 3)
        d1 = np.einsum("bijk,bik->bij", dy4, e1)  # (B, N, n*n): dy/d(tangent 1)
        d2 = np.einsum("bijk,bik->bij", dy4, e2)
    for l in fitted:
        sl = slice(l * l, (l + 1) * (l + 1))
        a = y3[:, :, sl]  # (B, N, 2l+1)
        ginv = np.linalg.inv(np.einsum("bim,bjm->bij", a, a) + mu * eye)
        g = np.einsum("bij,bj->bi", ginv, np.einsum("bim,bm->bi", a, target[:, sl]))
        coeffs[:, :, l] = g
        r = np.einsum("bim,bi->bm", a, g) - target[:, sl]
        rows.append(r)
        if with_jacobian:
            # D[:, m, (i, c)] = g_i d y_lm(s_i) / d tangent_c ; then P_perp D = D - A^T Ginv A D
            dl = np.stack([d1[:, :, sl], d2[:, :, sl]], axis=-1) * g[:, :, None, None]  # (B, N, 2l+1, 2)
            dmat = np.moveaxis(dl, 2, 1).reshape(b, 2 * l + 1, n_lobes * 2)  # (B, 2l+1, 2N)
            proj = np.einsum("bim,bmk->bik", a, dmat)  # (B, N, 2N)
            dmat = dmat - np.einsum("bim,bij,bjk->bmk", a, ginv, proj)
            jac.append(dmat)
    r = np.concatenate(rows, axis=1)
    phi = np.einsum("bm,bm->b", r, r) + mu * np.einsum("bil,bil->b", coeffs, coeffs)
    return phi, r, (np.concatenate(jac, axis=1) if with_jacobian else None), e1, e2


def levenberg_marquardt(target, axes0, order, fitted, mu, iterations, ftol=1e-10):
    """Batched Levenberg-Marquardt on the projected objective (variable projection with Kaufman's
    Jacobian), axes moved in their tangent planes and renormalised.

    Args:
        target: (B, n*n) stored bands zeroed; axes0: (B, N, 3) unit.

    Returns:
        ``(axes (B, N, 3), phi (B,), iterations (B,))``.
    """
    axes = np.array(axes0, dtype=np.float64)
    b, n_lobes = axes.shape[:2]
    scale = np.maximum(np.einsum("bj,bj->b", target, target), 1e-300)
    phi, r, jac, e1, e2 = _residual_and_jacobian(target, axes, order, fitted, mu)
    lam = np.full(b, 1e-3)
    its = np.zeros(b, dtype=np.int64)
    active = np.flatnonzero(phi > 1e-28 * scale)
    eye = np.eye(2 * n_lobes)
    while active.size and its[active].max() < iterations:
        j, rr = jac[active], r[active]
        jtj = np.einsum("bmk,bml->bkl", j, j)
        jtr = np.einsum("bmk,bm->bk", j, rr)
        diag = np.einsum("bkk->bk", jtj)
        damp = lam[active, None] * (diag + 1e-12 * scale[active, None])
        step = -np.linalg.solve(jtj + damp[:, :, None] * eye, jtr[..., None])[..., 0]
        step = step.reshape(-1, n_lobes, 2)
        trial = axes[active] + step[..., :1] * e1[active] + step[..., 1:] * e2[active]
        trial /= np.linalg.norm(trial, axis=-1, keepdims=True)
        p_t, r_t, j_t, e1_t, e2_t = _residual_and_jacobian(target[active], trial, order, fitted, mu)
        ok = p_t < phi[active]
        its[active] += 1
        good = active[ok]
        decrease = (phi[good] - p_t[ok]) / np.maximum(phi[good], 1e-300)
        axes[good], phi[good], r[good], jac[good] = trial[ok], p_t[ok], r_t[ok], j_t[ok]
        e1[good], e2[good] = e1_t[ok], e2_t[ok]
        lam[good] = np.maximum(lam[good] / 3.0, 1e-12)
        lam[active[~ok]] *= 4.0
        done = np.zeros(b, dtype=bool)
        done[good[decrease < ftol]] = True
        done[active[~ok][lam[active[~ok]] > 1e10]] = True
        done[active[phi[active] <= 1e-28 * scale[active]]] = True
        active = active[~done[active]]
    return axes, phi, its
