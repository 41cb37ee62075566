"""Fitting sums of zonal-harmonic lobes to SH vectors (private; the public API is warpshade.basis.zh).

Notation (Sloan, Luna, Snyder 2005): a lobe has a unit axis ``s`` and per-band coefficients
``g*_l`` in the *convolution* normalisation, so the SH vector of a lobe set is
``t~_lm = sum_i y_lm(s_i) g*_il`` (eq. 11). The fit minimises
``psi = |t~ - t|^2`` (eq. 17) over the bands that are not stored exactly ("fitted bands"); the
stored leading bands (DC, and the linear band when asked) are copied, so their error is zero.

Everything here is float64 NumPy and batched over a leading axis B of independent problems.
The unknowns of one problem are packed as ``x = [s_1 .. s_N (3 each), g*_1 .. g*_N (one per
fitted band each)]``; the axes are unconstrained 3-vectors used through ``h(s) = s / |s|``
(eq. 21), so BFGS never leaves the sphere.

Builds on :mod:`warpshade.basis._core` (float64 SH) and :mod:`warpshade.basis._zh_grad`;
:mod:`warpshade.basis.zh` re-exports this module as ``zh.fitting`` (and :data:`DEFAULT_RIDGE`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._core import band_of, basis
from ._zh_grad import normalised_gradient

__all__ = [
    "FitProblem",
    "band_norms",
    "bfgs_batched",
    "bfgs_scipy",
    "closed_form",
    "fit_lobes",
    "fit_single",
    "hemicube_axes",
    "objective",
    "optimal_linear_axes",
    "pack",
    "solve_coefficients",
    "unpack",
]

#: Armijo sufficient-decrease constant of the batched BFGS line search.
ARMIJO_C1 = 1e-4
#: Backtracking halvings before a line search is declared failed (step 2^-40: converged).
LINE_SEARCH_STEPS = 40
#: Singular values below this fraction of the largest are cut in the frozen-axes least squares
#: (near-parallel lobe axes would otherwise get huge, cancelling coefficients).
LSTSQ_RCOND = 1e-8
#: Default ridge ``mu`` of the fit: ``psi + mu * sum_il g*_il^2`` is minimised. The SH norm of a
#: lobe is exactly ``|g*|`` (sum_m y_lm^2 = (2l+1)/4pi cancels the convolution scale), so the
#: ridge is dimensionless and bounds the lobe energy a fit may spend on cancellation: a fit of
#: relative error e cannot gain by lobes of norm much above ``e / sqrt(mu)`` times the target's.
#: Cancelling lobes (norms 1e3-1e5 x the target's, seen on BRDF-specialised glossy rows) turn
#: the float32 table lookups and rotations of the shading kernels into noise.
DEFAULT_RIDGE = 1e-5


def band_norms(order: int) -> np.ndarray:
    """``sum_m y_lm(s)^2 = (2l + 1) / (4 pi)`` per band (the denominator of eq. 18), shape (n,)."""
    l = np.arange(order, dtype=np.float64)
    return (2.0 * l + 1.0) / (4.0 * np.pi)


@dataclass(frozen=True)
class FitProblem:
    """Static description of a batch of fits: SH order, lobe count and which bands are fitted."""

    order: int
    lobe_count: int
    stored_bands: int  # leading bands copied exactly (0, 1 = DC, 2 = DC + linear)
    ridge: float = 0.0  # mu: the objective is psi + mu * |g*|^2 (see DEFAULT_RIDGE)

    @property
    def fitted(self) -> np.ndarray:
        """Indices of the fitted bands, shape (n - stored_bands,)."""
        return np.arange(self.stored_bands, self.order)

    @property
    def parameter_count(self) -> int:
        return self.lobe_count * (3 + len(self.fitted))

    @property
    def band(self) -> np.ndarray:
        return band_of(self.order)


def pack(problem: FitProblem, axes: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
    """Axes (B, N, 3) and full per-band coefficients (B, N, n) -> parameters (B, P)."""
    b = axes.shape[0]
    return np.concatenate([axes.reshape(b, -1), coeffs[:, :, problem.fitted].reshape(b, -1)], axis=1)


def unpack(problem: FitProblem, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parameters (B, P) -> raw axes (B, N, 3), full coefficients (B, N, n) (stored bands 0)."""
    b, n_lobes = x.shape[0], problem.lobe_count
    axes = x[:, : 3 * n_lobes].reshape(b, n_lobes, 3)
    coeffs = np.zeros((b, n_lobes, problem.order))
    coeffs[:, :, problem.fitted] = x[:, 3 * n_lobes :].reshape(b, n_lobes, -1)
    return axes, coeffs


def reconstruct(axes: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
    """SH vector of lobe sets: axes (B, N, 3), coeffs (B, N, n) -> (B, n*n) (eq. 11)."""
    order = coeffs.shape[-1]
    b, n_lobes = axes.shape[:2]
    y = basis(axes.reshape(-1, 3), order).reshape(b, n_lobes, order * order)
    return np.einsum("bij,bij->bj", y, coeffs[:, :, band_of(order)])


def objective(problem: FitProblem, x: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``psi`` (eq. 17) and its analytic gradient (eq. 19-21) for a batch.

    With ``problem.ridge = mu > 0`` the value and gradient are those of ``psi + mu |g*|^2``.

    Args:
        x: parameters, shape (B, P).
        target: SH vectors to fit with the stored bands zeroed, shape (B, n*n).

    Returns:
        ``(psi (B,), grad (B, P))``.
    """
    order, n_lobes = problem.order, problem.lobe_count
    b = x.shape[0]
    axes, coeffs = unpack(problem, x)
    _, y, dy = normalised_gradient(axes.reshape(-1, 3), order)
    y = y.reshape(b, n_lobes, -1)
    dy = dy.reshape(b, n_lobes, -1, 3)
    g_exp = coeffs[:, :, problem.band]  # (B, N, n*n)
    residual = np.einsum("bij,bij->bj", y, g_exp) - target
    psi = np.einsum("bj,bj->b", residual, residual)
    # eq. 19: d psi / d g*_il = 2 sum_m y_lm(s_i) r_lm
    starts = np.arange(order) ** 2
    d_coeffs = 2.0 * np.add.reduceat(y * residual[:, None, :], starts, axis=2)[:, :, problem.fitted]
    # eq. 20-21: d psi / d s_i = 2 sum_lm (J_h^T grad y_lm(s_i)) g*_il r_lm
    d_axes = 2.0 * np.einsum("bijk,bij->bik", dy, g_exp * residual[:, None, :])
    if problem.ridge > 0.0:
        g = coeffs[:, :, problem.fitted]
        psi = psi + problem.ridge * np.einsum("bil,bil->b", g, g)
        d_coeffs = d_coeffs + 2.0 * problem.ridge * g
    return psi, np.concatenate([d_axes.reshape(b, -1), d_coeffs.reshape(b, -1)], axis=1)


# ---------------------------------------------------------------------------------------------
# Optimisers
# ---------------------------------------------------------------------------------------------


def bfgs_batched(fun, x0: np.ndarray, scale: np.ndarray, max_iterations: int = 200, gtol: float = 1e-9,
                 ftol: float = 1e-12) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """BFGS on B independent problems at once, vectorised over the batch (float64).

    Each problem keeps its own inverse-Hessian approximation (B, P, P), step and line search
    (backtracking with the Armijo condition, Shanno's initial scaling of the inverse Hessian,
    the update skipped when the curvature ``s.y`` is not positive). A problem stops when its
    gradient's max-norm falls below ``gtol * sqrt(scale)``, its relative decrease below
    ``ftol``, its objective below ``1e-28 * scale`` (an exact fit) or its line search fails.
    Finished problems are compacted away, so the work per iteration follows the active count.

    Args:
        fun: ``fun(x (K, P), rows (K,)) -> (f (K,), grad (K, P))`` for the problems ``rows``.
        x0: start, shape (B, P).
        scale: per-problem objective scale (|t|^2), shape (B,), > 0.
        max_iterations: BFGS iterations per problem.

    Returns:
        ``(x (B, P), f (B,), iterations (B,) int)``.
    """
    x_out = np.array(x0, dtype=np.float64)
    batch, p = x_out.shape
    scale_all = np.maximum(np.asarray(scale, dtype=np.float64), 1e-300)
    f_out, g0 = fun(x_out, np.arange(batch))
    iterations = np.zeros(batch, dtype=np.int64)
    ids = np.flatnonzero(f_out > 1e-28 * scale_all)  # working set (global rows)
    x, f, g = x_out[ids].copy(), f_out[ids].copy(), g0[ids]
    sc = scale_all[ids]
    h = np.broadcast_to(np.eye(p), (ids.size, p, p)).copy()
    fresh = np.ones(ids.size, dtype=bool)  # inverse Hessian not yet scaled
    eye = np.eye(p)
    for _ in range(max_iterations):
        if ids.size == 0:
            break
        direction = -np.einsum("bij,bj->bi", h, g)
        slope = np.einsum("bi,bi->b", g, direction)
        bad = slope >= 0.0  # not a descent direction: restart from steepest descent
        if np.any(bad):
            h[bad] = eye
            direction[bad] = -g[bad]
            slope[bad] = -np.einsum("bi,bi->b", g[bad], g[bad])
            fresh[bad] = True
        step = np.ones(ids.size)
        accepted = np.zeros(ids.size, dtype=bool)
        f_new = f.copy()
        g_new = g.copy()
        for _ls in range(LINE_SEARCH_STEPS):
            pending = np.flatnonzero(~accepted)
            if pending.size == 0:
                break
            ft, gt = fun(x[pending] + step[pending, None] * direction[pending], ids[pending])
            ok = np.isfinite(ft) & (ft <= f[pending] + ARMIJO_C1 * step[pending] * slope[pending])
            hit = pending[ok]
            accepted[hit] = True
            f_new[hit] = ft[ok]
            g_new[hit] = gt[ok]
            step[pending[~ok]] *= 0.5
        s = np.where(accepted[:, None], step[:, None] * direction, 0.0)
        yv = g_new - g
        f_old = f
        x = x + s
        f, g = f_new, g_new
        iterations[ids[accepted]] += 1
        sy = np.einsum("bi,bi->b", s, yv)
        yy = np.einsum("bi,bi->b", yv, yv)
        upd = accepted & (sy > 1e-12 * np.sqrt(np.einsum("bi,bi->b", s, s) * np.maximum(yy, 1e-300)))
        first = upd & fresh
        if np.any(first):
            h[first] = (sy[first] / yy[first])[:, None, None] * eye
            fresh[first] = False
        # H+ = H - rho (s hy^T + hy s^T) + (rho^2 y.Hy + rho) s s^T; rho = 0 leaves H unchanged
        rho = np.where(upd, 1.0 / np.where(upd, sy, 1.0), 0.0)
        hy = np.einsum("bij,bj->bi", h, yv)
        yhy = np.einsum("bi,bi->b", yv, hy)
        outer = s[:, :, None] * hy[:, None, :]
        h -= rho[:, None, None] * (outer + np.swapaxes(outer, 1, 2))
        h += ((rho * rho * yhy + rho)[:, None, None] * s[:, :, None]) * s[:, None, :]
        done = (
            ~accepted
            | (np.abs(g).max(axis=1) <= gtol * np.sqrt(sc))
            | (f_old - f <= ftol * np.maximum(f_old, 1e-300))
            | (f <= 1e-28 * sc)
        )
        if np.any(done):
            x_out[ids[done]] = x[done]
            f_out[ids[done]] = f[done]
            keep = ~done
            ids, x, f, g, h, fresh, sc = ids[keep], x[keep], f[keep], g[keep], h[keep], fresh[keep], sc[keep]
    x_out[ids] = x
    f_out[ids] = f
    return x_out, f_out, iterations


def bfgs_scipy(fun, x0: np.ndarray, scale: np.ndarray, max_iterations: int = 200, gtol: float = 1e-9,
               ftol: float = 1e-12) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The same problems solved one by one with ``scipy.optimize.minimize(method="BFGS", jac=True)``.

    Same call shape as :func:`bfgs_batched` (``ftol`` is unused: scipy's BFGS stops on ``gtol``).
    """
    from scipy.optimize import minimize

    x = np.array(x0, dtype=np.float64)
    f = np.empty(x.shape[0])
    iterations = np.zeros(x.shape[0], dtype=np.int64)
    for i in range(x.shape[0]):

        def one(v, row=i):
            fv, gv = fun(v[None], np.array([row]))
            return float(fv[0]), gv[0]

        res = minimize(one, x[i], jac=True, method="BFGS",
                       options={"gtol": gtol * float(np.sqrt(max(scale[i], 1e-300))), "maxiter": max_iterations})
        x[i] = res.x
        f[i] = res.fun
        iterations[i] = res.nit
    return x, f, iterations


# ---------------------------------------------------------------------------------------------
# Single-lobe building blocks
# ---------------------------------------------------------------------------------------------


def hemicube_axes(resolution: int) -> np.ndarray:
    """Unit axes through the cell centres of a hemi-cube (z >= 0 half of the unit cube).

    The top face is sampled with ``resolution x resolution`` cells, each of the four side faces
    with ``resolution x ceil(resolution / 2)`` cells (its upper half). A hemi-cube suffices
    because a lobe about ``-s`` with its odd bands negated is the same function (Sec. 3.1).

    Returns:
        shape (resolution^2 + 4 resolution ceil(resolution/2), 3), float64.
    """
    r = int(resolution)
    if r < 1:
        raise ValueError(f"hemicube_axes: resolution must be >= 1, got {resolution!r}")
    u = (np.arange(r) + 0.5) / r * 2.0 - 1.0
    half = (r + 1) // 2
    w = (np.arange(half) + 0.5) / half
    a, b = np.meshgrid(u, u, indexing="ij")
    top = np.stack([a.ravel(), b.ravel(), np.ones(a.size)], axis=1)
    t, z = np.meshgrid(u, w, indexing="ij")
    t, z = t.ravel(), z.ravel()
    one = np.ones_like(t)
    sides = [np.stack([one, t, z], 1), np.stack([-one, -t, z], 1), np.stack([-t, one, z], 1), np.stack([t, -one, z], 1)]
    pts = np.concatenate([top] + sides)
    return pts / np.linalg.norm(pts, axis=1, keepdims=True)


def closed_form(target: np.ndarray, axes: np.ndarray, fitted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Best single-lobe coefficients for fixed axes (eq. 18) and the resulting ``psi``.

    ``g*_l = sum_m y_lm(s) t_lm / ((2l + 1) / (4 pi))`` for the fitted bands (0 elsewhere);
    ``psi = |t|^2 - sum_l (sum_m y_lm(s) t_lm)^2 (4 pi / (2l + 1))`` over the fitted bands.

    Args:
        target: shape (B, n*n) with the stored bands zeroed.
        axes: unit axes, shape (K, 3) shared by all B, or (B, K, 3).
        fitted: fitted band indices.

    Returns:
        ``(coeffs (B, K, n), psi (B, K))``.
    """
    order = math.isqrt(target.shape[-1])
    norms = band_norms(order)
    shared = axes.ndim == 2
    y = basis(axes.reshape(-1, 3), order)
    y = y if shared else y.reshape(axes.shape[0], axes.shape[1], -1)
    k = axes.shape[-2]
    coeffs = np.zeros((target.shape[0], k, order))
    psi = np.broadcast_to(np.einsum("bj,bj->b", target, target)[:, None], (target.shape[0], k)).copy()
    for l in fitted:
        sl = slice(l * l, (l + 1) * (l + 1))
        proj = target[:, sl] @ y[:, sl].T if shared else np.einsum("bj,bkj->bk", target[:, sl], y[:, :, sl])
        coeffs[:, :, l] = proj / norms[l]
        psi -= proj * proj / norms[l]
    return coeffs, np.maximum(psi, 0.0)


def solve_coefficients(target: np.ndarray, axes: np.ndarray, fitted: np.ndarray, ridge: float = 0.0) -> np.ndarray:
    """Least-squares lobe coefficients for frozen axes (a linear problem per band).

    Band l: ``min |A_l g_l - t_l|`` with ``A_l[m, i] = y_lm(s_i)``, (2l+1) x N, solved by the
    pseudo-inverse (the minimum-norm least-squares solution that ``numpy.linalg.lstsq`` returns;
    singular values below ``LSTSQ_RCOND`` of the largest are cut). With ``ridge = mu > 0`` it is
    ``min |A_l g_l - t_l|^2 + mu |g_l|^2`` instead, ``g_l = (A_l^T A_l + mu I)^-1 A_l^T t_l``.

    Args:
        target: (B, n*n), stored bands zeroed. axes: (B, N, 3) unit. fitted: band indices.
        ridge: mu (0: plain minimum-norm least squares).

    Returns:
        coefficients (B, N, n), zero outside the fitted bands.
    """
    order = math.isqrt(target.shape[-1])
    b, n_lobes = axes.shape[:2]
    y = basis(axes.reshape(-1, 3), order).reshape(b, n_lobes, -1)
    coeffs = np.zeros((b, n_lobes, order))
    for l in fitted:
        sl = slice(l * l, (l + 1) * (l + 1))
        a = np.swapaxes(y[:, :, sl], 1, 2)  # (B, 2l+1, N)
        if ridge > 0.0:
            normal = np.einsum("bmi,bmj->bij", a, a) + ridge * np.eye(n_lobes)
            rhs = np.einsum("bmi,bm->bi", a, target[:, sl])
            coeffs[:, :, l] = np.linalg.solve(normal, rhs[..., None])[..., 0]
        else:
            coeffs[:, :, l] = np.einsum("bij,bj->bi", np.linalg.pinv(a, rcond=LSTSQ_RCOND), target[:, sl])
    return coeffs


def optimal_linear_axes(target: np.ndarray) -> np.ndarray:
    """Axis of symmetry of the linear band, ``normalise(-f_1,1, -f_1,-1, f_1,0)`` (Sec. 3.3).

    Returns unit axes (B, 3); +z where the linear band is zero.
    """
    v = np.stack([-target[:, 3], -target[:, 1], target[:, 2]], axis=1)
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return np.where(length > 0.0, v / np.maximum(length, 1e-300), np.array([0.0, 0.0, 1.0]))


@dataclass
class FitOptions:
    """Knobs of the fit (see :func:`warpshade.basis.zh.fit` for their meaning)."""

    candidate_resolution: int = 6
    starts: int = 3
    max_iterations: int = 200
    restarts: int = 4
    restart_error: float = 0.05
    optimizer: str = "batched"
    seed: int = 0


def _optimiser(options: FitOptions):
    if options.optimizer == "batched":
        return bfgs_batched
    if options.optimizer == "scipy":
        return bfgs_scipy
    raise ValueError(f"zh.fit: optimizer must be 'batched' or 'scipy', got {options.optimizer!r}")


def _run_bfgs(problem: FitProblem, target: np.ndarray, axes: np.ndarray, coeffs: np.ndarray, options: FitOptions):
    """Joint BFGS over axes and coefficients from (axes, coeffs); returns unit axes, coeffs, psi."""
    scale = np.einsum("bj,bj->b", target, target)

    def fun(x, rows):
        return objective(problem, x, target[rows])

    x, psi, _ = _optimiser(options)(fun, pack(problem, axes, coeffs), scale, options.max_iterations)
    raw, c = unpack(problem, x)
    unit = raw / np.maximum(np.linalg.norm(raw, axis=-1, keepdims=True), 1e-300)
    if problem.ridge > 0.0:  # report the fit error alone, not the penalised objective
        psi = _psi(target, unit, c)
    return unit, c, psi


def fit_single(target: np.ndarray, fitted: np.ndarray, options: FitOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One lobe per problem: hemi-cube + optimal-linear candidates, closed form, BFGS from the best.

    The closed-form error (eq. 18) is evaluated for every candidate axis at once; BFGS over axis
    and coefficients starts from the ``options.starts`` best candidates and from the optimal
    linear lobe, and the best local minimum is kept.

    Returns:
        ``(axes (B, 3), coeffs (B, n), psi (B,))``.
    """
    order = math.isqrt(target.shape[-1])
    b = target.shape[0]
    candidates = hemicube_axes(options.candidate_resolution)
    _, psi_c = closed_form(target, candidates, fitted)
    s = min(options.starts, candidates.shape[0])
    best = np.argpartition(psi_c, s - 1, axis=1)[:, :s] if s < candidates.shape[0] else np.tile(np.arange(s), (b, 1))
    starts = [candidates[best]]
    if 1 in set(fitted.tolist()):
        starts.append(optimal_linear_axes(target)[:, None, :])
    axes0 = np.concatenate(starts, axis=1)  # (B, S, 3)
    s_total = axes0.shape[1]
    coeffs0, _ = closed_form(target, axes0, fitted)
    problem = FitProblem(order, 1, order - len(fitted))
    rep = np.repeat(target, s_total, axis=0)
    axes, coeffs, psi = _run_bfgs(problem, rep, axes0.reshape(-1, 1, 3), coeffs0.reshape(-1, 1, order), options)
    psi = psi.reshape(b, s_total)
    pick = np.argmin(psi, axis=1)
    rows = np.arange(b) * s_total + pick
    return axes[rows, 0], coeffs[rows, 0], psi[np.arange(b), pick]


@dataclass
class LobeFit:
    """Raw result of :func:`fit_lobes` (float64; the public wrapper is zh.ZHFit)."""

    axes: np.ndarray  # (B, N, 3) unit
    coeffs: np.ndarray  # (B, N, n), stored bands 0
    psi: np.ndarray  # (B,) squared L2 error over the fitted bands
    psi_greedy: np.ndarray  # (B,) after greedy + frozen-axes least squares, before joint BFGS
    restarted: np.ndarray  # (B,) bool: multi-start engaged
    restart_gain: np.ndarray  # (B,) psi before multi-start minus psi after (>= 0)


def fit_lobes(target: np.ndarray, problem: FitProblem, options: FitOptions,
              initial_axes: np.ndarray | None = None) -> LobeFit:
    """Greedy lobe-by-lobe fit, frozen-axes least squares, joint BFGS, multi-start (Sec. 4.1).

    Args:
        target: SH vectors with the stored bands zeroed, shape (B, n*n).
        problem: order, lobe count, stored bands.
        initial_axes: optional (B, N0, 3) axes of an earlier fit with N0 < N lobes; the greedy
            step then adds only the remaining lobes to them (used by the lobe-count budget).
    """
    fitted = problem.fitted
    b, n_lobes, order = target.shape[0], problem.lobe_count, problem.order
    scale = np.einsum("bj,bj->b", target, target)
    axes = np.zeros((b, n_lobes, 3))
    coeffs = np.zeros((b, n_lobes, order))
    first = 0
    if initial_axes is not None and initial_axes.shape[1] > 0:
        first = min(initial_axes.shape[1], n_lobes)
        axes[:, :first] = initial_axes[:, :first]
        coeffs[:, :first] = solve_coefficients(target, axes[:, :first], fitted, problem.ridge)
    residual = target - reconstruct(axes[:, :first], coeffs[:, :first]) if first else target.copy()
    for i in range(first, n_lobes):
        a, c, _ = fit_single(residual, fitted, options)
        axes[:, i], coeffs[:, i] = a, c
        residual = residual - reconstruct(a[:, None], c[:, None])
    if n_lobes > 1:
        coeffs = solve_coefficients(target, axes, fitted, problem.ridge)
    psi_greedy = np.einsum("bj,bj->b", residual, residual) if n_lobes == 1 else _psi(target, axes, coeffs)
    if n_lobes > 1:
        axes, coeffs, psi = _run_bfgs(problem, target, axes, coeffs, options)
    else:
        psi = psi_greedy.copy()
    # Multi-start where the error stays high: random axis sets, least squares, joint BFGS.
    rel = np.sqrt(psi / np.maximum(scale, 1e-300))
    restart_rows = np.flatnonzero((rel > options.restart_error) & (scale > 0.0))
    restarted = np.zeros(b, dtype=bool)
    gain = np.zeros(b)
    if options.restarts > 0 and restart_rows.size:
        restarted[restart_rows] = True
        rng = np.random.default_rng(options.seed)
        k = options.restarts
        rand = rng.normal(size=(restart_rows.size * k, n_lobes, 3))
        rand /= np.linalg.norm(rand, axis=-1, keepdims=True)
        rep = np.repeat(target[restart_rows], k, axis=0)
        c0 = solve_coefficients(rep, rand, fitted, problem.ridge)
        ra, rc, rpsi = _run_bfgs(problem, rep, rand, c0, options)
        rpsi = rpsi.reshape(restart_rows.size, k)
        pick = np.argmin(rpsi, axis=1)
        best = rpsi[np.arange(restart_rows.size), pick]
        better = best < psi[restart_rows]
        rows = restart_rows[better]
        src = (np.arange(restart_rows.size) * k + pick)[better]
        gain[rows] = psi[rows] - best[better]
        axes[rows], coeffs[rows], psi[rows] = ra[src], rc[src], best[better]
    return LobeFit(axes, coeffs, psi, psi_greedy, restarted, gain)


def _psi(target: np.ndarray, axes: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
    r = reconstruct(axes, coeffs) - target
    return np.einsum("bj,bj->b", r, r)
