"""Zonal-harmonic (ZH) lobes: SH conversion, rotation, evaluation and fitting.

A *lobe* is a function circularly symmetric about a unit axis ``s*``. A set of N lobes
approximates a spherical function given by its SH coefficients ``t`` (Sloan, Luna, Snyder 2005):

    t~_lm = sum_i y_lm(s*_i) g*_il                          (eq. 11)
    t~(s) = sum_i sum_l g*_il (2l + 1) / (4 pi) P_l(s*_i . s)

Normalisation. ``g*_l`` are the paper's *convolution* coefficients (eq. 4). They relate to the
ZH coefficients ``g_l`` used by :func:`warpshade.basis.sh.zh_to_sh` (the m = 0 SH coefficients
of the lobe when its axis is +z) by::

    g*_l = sqrt(4 pi / (2l + 1)) * g_l          (convolution_from_zh / zh_from_convolution)

so ``to_sh(axes, g*) == sum_i sh.zh_to_sh(axes_i, zh_from_convolution(g*_i))``. In this
normalisation the clamped cosine ``max(0, n.s)`` about n is the lobe ``g*_l = A_l`` (pi, 2pi/3,
pi/4, 0, -pi/24, ..., :func:`warpshade.basis.sh.clamped_cosine_zh`), and a lobe evaluated
against lighting SH ``e`` is ``sum_l g*_l e_l(s*)`` with ``e_l(s) = sum_m y_lm(s) e_lm``
(eq. 24-25).

Properties used throughout: rotating a lobe set by R rotates its axes (eq. 10); the lobe about
``-s*`` with the odd bands of ``g*`` negated is the same function (:func:`flip`).

Fitting (:func:`fit`, Sec. 4.1): batched over any leading shape; per problem the DC band (and the
linear band when N >= 3) is stored exactly by default (Sec. 3.3) and the lobes are fitted to the
rest. The default strategy searches over the axes alone with the coefficients solved exactly
(variable projection, eq. 18 generalised to N lobes, gradients of eq. 19-21): a batched beam
search over hemi-cube candidate sets, BFGS from the best, and targeted restarts (screened random
sets, swap moves) where the error stays above a threshold. The earlier greedy fit (one lobe at a
time, then joint BFGS, random multi-start) stays available as ``strategy="greedy"``. :func:`fit_budget` picks the lobe count per
problem from a target error.

Warp functions for evaluating lobe sets inside kernels: :func:`zh_kernels` (per SH order, a
:class:`ZHKernels` bundle) and the grid of its light-specialised table, :func:`table_directions`.

This module is the public facade of the ZH layers: it imports :mod:`~warpshade.basis._core`
(float64 SH), :mod:`~warpshade.basis._zh_grad`, :mod:`~warpshade.basis._zh_fit` and
:mod:`~warpshade.basis._zh_warp` at the top, and none of them imports it. Besides the functions
defined here it re-exports :data:`DEFAULT_RIDGE`, :func:`basis_and_gradient` (the SH basis with
its gradient, behind the fit's analytic derivatives), the Warp bundle and, as :data:`fitting`,
the batched low-level fitting machinery that :func:`fit` drives.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from . import _zh_fit, _zh_global
from ._core import MAX_ORDER, band_of, band_scale, basis, check_coeffs
from ._zh_fit import DEFAULT_RIDGE, hemicube_axes
from ._zh_grad import basis_and_gradient
from ._zh_warp import ZHKernels, table_directions, zh_kernels

__all__ = [
    "DEFAULT_RIDGE",
    "PAPER_STORED_BANDS",
    "LobeBudget",
    "ZHFit",
    "ZHKernels",
    "basis_and_gradient",
    "choose_order",
    "convolution_from_zh",
    "evaluate",
    "fit",
    "fit_budget",
    "fitting",
    "flip",
    "hemicube_axes",
    "linear_lobe",
    "objective",
    "optimal_linear_axis",
    "rotate",
    "single_lobe_coefficients",
    "stored_band_count",
    "table_directions",
    "to_sh",
    "zh_from_convolution",
    "zh_kernels",
]

#: Documentation of the paper's storage rule (Sec. 3.3): bands stored exactly for N lobes.
PAPER_STORED_BANDS = "DC always; DC and linear when N >= 3"

#: The batched float64 machinery behind :func:`fit` (module :mod:`warpshade.basis._zh_fit`):
#: ``FitProblem`` / ``FitOptions``, ``pack`` / ``unpack`` of the parameters (B, P),
#: ``objective(problem, x, target) -> (psi (B,), grad (B, P))``, ``solve_coefficients``,
#: ``optimal_linear_axes``, ``bfgs_batched`` / ``bfgs_scipy`` and ``fit_lobes``, for callers
#: that set up their own fits (e.g. one optimisation over a whole parameter map).
fitting = _zh_fit


def convolution_from_zh(zh_coeffs) -> np.ndarray:
    """``g*_l = sqrt(4 pi / (2l + 1)) g_l``: ZH coefficients (as in :func:`sh.zh_to_sh`) to the
    convolution coefficients of this module. Shape (..., n) -> (..., n), float64."""
    g = np.asarray(zh_coeffs, dtype=np.float64)
    return g * band_scale(g.shape[-1])


def zh_from_convolution(coeffs) -> np.ndarray:
    """Inverse of :func:`convolution_from_zh`, shape (..., n), float64."""
    g = np.asarray(coeffs, dtype=np.float64)
    return g / band_scale(g.shape[-1])


def _axes(axes, name: str) -> np.ndarray:
    a = np.asarray(axes, dtype=np.float64)
    if a.ndim < 2 or a.shape[-1] != 3:
        raise ValueError(f"{name}: expected lobe axes of shape (..., N, 3), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    length = np.linalg.norm(a, axis=-1, keepdims=True)
    if np.any(length == 0.0):
        raise ValueError(f"{name}: contains zero-length axes")
    return a / length


def _lobe_coeffs(coeffs, name: str) -> np.ndarray:
    c = np.asarray(coeffs, dtype=np.float64)
    if c.ndim < 2 or not 1 <= c.shape[-1] <= MAX_ORDER:
        raise ValueError(f"{name}: expected lobe coefficients of shape (..., N, n), got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    return c


def to_sh(axes, coeffs) -> np.ndarray:
    """SH vector of a set of lobes, ``t~_lm = sum_i y_lm(s_i) g*_il`` (eq. 11), float64.

    Args:
        axes: lobe axes, shape (..., N, 3) (normalised here).
        coeffs: convolution coefficients ``g*``, shape (..., N, n); batch shapes broadcast.

    Returns:
        shape (..., n*n).
    """
    a = _axes(axes, "zh.to_sh: axes")
    c = _lobe_coeffs(coeffs, "zh.to_sh: coeffs")
    order = c.shape[-1]
    batch = np.broadcast_shapes(a.shape[:-1], c.shape[:-1])
    a = np.broadcast_to(a, batch + (3,))
    c = np.broadcast_to(c, batch + (order,))
    y = basis(a, order)
    return np.sum(y * c[..., band_of(order)], axis=-2)


def _legendre(x: np.ndarray, order: int) -> np.ndarray:
    """P_0..P_{n-1}(x), shape (..., n)."""
    p = [np.ones_like(x), x]
    for l in range(1, order - 1):
        p.append(((2 * l + 1) * x * p[l] - l * p[l - 1]) / (l + 1))
    return np.stack(p[:order], axis=-1)


def evaluate(axes, coeffs, directions) -> np.ndarray:
    """Value of lobe sets at directions, by the addition theorem (float64).

    ``t~(d) = sum_i sum_l g*_il (2l + 1) / (4 pi) P_l(s_i . d)``.

    Args:
        axes: (..., N, 3); coeffs: (..., N, n) as in :func:`to_sh`.
        directions: (..., K, 3) unit directions (normalised here), batch broadcast with axes.

    Returns:
        shape (..., K).
    """
    a = _axes(axes, "zh.evaluate: axes")
    c = _lobe_coeffs(coeffs, "zh.evaluate: coeffs")
    d = _axes(directions, "zh.evaluate: directions")
    order = c.shape[-1]
    cos = np.einsum("...nc,...kc->...kn", a, d)
    p = _legendre(np.clip(cos, -1.0, 1.0), order)  # (..., K, N, n)
    weights = c * _zh_fit.band_norms(order)
    return np.einsum("...knl,...nl->...k", p, weights)


def rotate(axes, rotation) -> np.ndarray:
    """Rotate lobe sets: axes ``R s_i`` (eq. 10); the coefficients do not change.

    Args:
        axes: (..., N, 3); rotation: (..., 3, 3) proper rotations, batch broadcast with axes.

    Returns:
        rotated axes, shape (..., N, 3), float64.
    """
    a = np.asarray(axes, dtype=np.float64)
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape[-2:] != (3, 3):
        raise ValueError(f"zh.rotate: rotation must have shape (..., 3, 3), got {r.shape}")
    return np.einsum("...ij,...nj->...ni", r, a)


def flip(axes, coeffs) -> tuple[np.ndarray, np.ndarray]:
    """The same lobes written about the negated axes: ``(-s, (-1)^l g*_l)`` (Sec. 3.1)."""
    c = np.array(coeffs, dtype=np.float64)
    c[..., 1::2] *= -1.0
    return -np.asarray(axes, dtype=np.float64), c


def single_lobe_coefficients(sh_coeffs, axes) -> np.ndarray:
    """Best coefficients of one lobe with a fixed axis, eq. 18 (per band least squares).

    ``g*_l = sum_m y_lm(s) t_lm / ((2l + 1) / (4 pi))``.

    Args:
        sh_coeffs: (..., n*n). axes: (..., 3), batch broadcast.

    Returns:
        shape (..., n).
    """
    t, order = check_coeffs(sh_coeffs, "zh.single_lobe_coefficients: sh")
    a = _axes(np.asarray(axes)[..., None, :], "zh.single_lobe_coefficients: axes")[..., 0, :]
    batch = np.broadcast_shapes(t.shape[:-1], a.shape[:-1])
    t = np.broadcast_to(t, batch + (order * order,))
    y = basis(np.broadcast_to(a, batch + (3,)), order)
    proj = np.add.reduceat(t * y, np.arange(order) ** 2, axis=-1)
    return proj / _zh_fit.band_norms(order)


def optimal_linear_axis(sh_coeffs) -> np.ndarray:
    """Axis of symmetry of the linear band, ``normalise(-f_1,1, -f_1,-1, f_1,0)`` (Sec. 3.3).

    Returns unit axes, shape (..., 3); +z where the linear band vanishes.
    """
    t, order = check_coeffs(sh_coeffs, "zh.optimal_linear_axis: sh")
    if order < 2:
        raise ValueError("zh.optimal_linear_axis: needs SH order >= 2")
    flat = t.reshape(-1, order * order)
    return _zh_fit.optimal_linear_axes(flat).reshape(t.shape[:-1] + (3,))


def linear_lobe(sh_coeffs) -> tuple[np.ndarray, np.ndarray]:
    """The optimal linear single lobe: the linear band's axis with the eq. 18 coefficients.

    Returns:
        ``(axes (..., 1, 3), coeffs (..., 1, n))``.
    """
    axis = optimal_linear_axis(sh_coeffs)
    return axis[..., None, :], single_lobe_coefficients(sh_coeffs, axis)[..., None, :]


def stored_band_count(lobe_count: int, stored_bands: int | str | None = "paper") -> int:
    """Leading bands stored exactly: ``"paper"`` -> 1 (DC) for N < 3, 2 (DC + linear) for N >= 3."""
    if stored_bands in ("paper", None):
        return 1 if lobe_count < 3 else 2
    if stored_bands not in (0, 1, 2):
        raise ValueError(f"zh: stored_bands must be 'paper', 0, 1 or 2, got {stored_bands!r}")
    return int(stored_bands)


def objective(sh_coeffs, axes, coeffs, stored_bands: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``psi = |t~ - t|^2`` over the fitted bands (eq. 17) and its analytic gradients (eq. 19-21).

    The axes enter through ``h(s) = s / |s|``, so the axis gradient is ``J_h^T grad y`` and is
    orthogonal to s.

    Args:
        sh_coeffs: targets, shape (B, n*n). axes: raw axes (B, N, 3). coeffs: (B, N, n).
        stored_bands: leading bands excluded from the fit (their coefficients are ignored).

    Returns:
        ``(psi (B,), d psi / d axes (B, N, 3), d psi / d coeffs (B, N, n))`` (stored bands: 0).
    """
    t, order = check_coeffs(sh_coeffs, "zh.objective: sh")
    a = np.asarray(axes, dtype=np.float64)
    c = np.asarray(coeffs, dtype=np.float64)
    problem = _zh_fit.FitProblem(order, a.shape[1], stored_bands)
    target = t.copy()
    target[:, : stored_bands * stored_bands] = 0.0
    psi, grad = _zh_fit.objective(problem, _zh_fit.pack(problem, a, c), target)
    b, n_lobes = a.shape[:2]
    d_axes = grad[:, : 3 * n_lobes].reshape(b, n_lobes, 3)
    d_coeffs = np.zeros_like(c)
    d_coeffs[:, :, problem.fitted] = grad[:, 3 * n_lobes :].reshape(b, n_lobes, -1)
    return psi, d_axes, d_coeffs


@dataclass
class ZHFit:
    """Result of :func:`fit` (float64; leading shape ``batch`` of the input).

    Attributes:
        axes: unit lobe axes, shape (*batch, N, 3).
        coeffs: convolution coefficients ``g*`` of the fitted bands, shape (*batch, N, n); zero in
            the stored bands.
        stored: SH coefficients of the exactly stored leading bands, shape (*batch, n*n) (zero
            from band ``stored_bands`` on): DC = ``stored[..., 0]``, linear = ``stored[..., 1:4]``.
        stored_bands: number of leading bands stored exactly (0, 1 or 2).
        error: L2 error ``|t~ - t|`` per problem, shape (*batch,).
        rel_error: ``error / |t|`` (the paper's RMS for one vector), shape (*batch,); 0 for t = 0.
        greedy_error: L2 error of the starting point: the best scanned axis set with its
            coefficients solved ("global"), or the greedy pass + frozen-axes least squares
            ("greedy"); before any BFGS, shape (*batch,).
        restarted: multi-start engaged (the error stayed above ``restart_error``), (*batch,) bool.
        restart_gain: error reduction bought by the multi-start (``error_before - error``), >= 0.
        seconds: wall time of the fit.

    Iterating yields ``(axes, coeffs)`` with the stored bands folded into the lobes
    (:meth:`folded`), so ``axes, coeffs = zh.fit(t, N)`` and ``zh.to_sh(axes, coeffs)``
    reproduce ``to_sh()``.
    """

    axes: np.ndarray
    coeffs: np.ndarray
    stored: np.ndarray
    stored_bands: int
    error: np.ndarray
    rel_error: np.ndarray
    greedy_error: np.ndarray
    restarted: np.ndarray
    restart_gain: np.ndarray
    seconds: float = 0.0
    notes: dict = field(default_factory=dict)

    @property
    def lobe_count(self) -> int:
        return int(self.axes.shape[-2])

    @property
    def order(self) -> int:
        return int(self.coeffs.shape[-1])

    def to_sh(self) -> np.ndarray:
        """Reconstructed SH vectors (lobes + stored bands), shape (*batch, n*n)."""
        return to_sh(self.axes, self.coeffs) + self.stored

    def folded(self) -> tuple[np.ndarray, np.ndarray]:
        """Lobes that carry the stored bands too: ``(axes, coeffs)`` with ``to_sh == self.to_sh()``.

        The DC goes exactly into lobe 0 (``g*_0 += sqrt(4 pi) t_00``); the linear band is solved
        over all lobes (``sum_i y_1m(s_i) g*_i1 = t_1m``, minimum-norm least squares), exact when
        the lobe axes span 3-space (N >= 3 and not coplanar). The residual of that solve, if
        any, is in ``notes["fold_error"]`` (max over problems).
        """
        coeffs = self.coeffs.copy()
        if self.stored_bands >= 1:
            coeffs[..., 0, 0] += np.sqrt(4.0 * np.pi) * self.stored[..., 0]
        if self.stored_bands >= 2:
            flat_axes = self.axes.reshape(-1, self.lobe_count, 3)
            lin = self.stored.reshape(-1, self.order**2)[:, 1:4]
            target = np.zeros((lin.shape[0], self.order**2))
            target[:, 1:4] = lin
            sol = _zh_fit.solve_coefficients(target, flat_axes, np.array([1]))
            coeffs.reshape(-1, self.lobe_count, self.order)[:, :, 1] = sol[:, :, 1]
            y = basis(flat_axes.reshape(-1, 3), 2).reshape(-1, self.lobe_count, 4)
            resid = np.einsum("bij,bi->bj", y[:, :, 1:4], sol[:, :, 1]) - lin
            self.notes["fold_error"] = float(np.abs(resid).max(initial=0.0))
        return self.axes.copy(), coeffs

    def __iter__(self):
        return iter(self.folded())


def _prepare_target(sh_coeffs, name: str):
    t, order = check_coeffs(sh_coeffs, name)
    batch = t.shape[:-1]
    return t.reshape(-1, order * order), order, batch


def fit(
    sh_coeffs,
    lobe_count: int,
    *,
    stored_bands: int | str = "paper",
    candidate_resolution: int = 6,
    starts: int = 3,
    max_iterations: int = 200,
    restarts: int = 6,
    restart_error: float = 0.05,
    optimizer: str = "batched",
    seed: int = 0,
    initial_axes=None,
    ridge: float = DEFAULT_RIDGE,
    strategy: str = "global",
    screened_sets: int = 128,
) -> ZHFit:
    """Fit N zonal-harmonic lobes to SH vectors (Sloan et al. 2005, Sec. 4.1), batched.

    ``strategy="global"`` (default; :mod:`warpshade.basis._zh_global`): the coefficients are
    eliminated (for given axes they are a linear least-squares solve per band), so the search runs
    over the axes alone (variable projection, with the eq. 20-21 gradient at the solved
    coefficients). Per problem: a batched beam search grows axis sets from the hemi-cube
    candidates (and the optimal linear axis) scoring every extension exactly; BFGS descends from
    the ``starts`` best sets. Where the relative error is still above ``restart_error``,
    ``screened_sets`` random axis sets (with the scan's other sets) are screened by a short
    descent, the ``restarts`` best are descended to convergence, then rounds of swap moves (one
    lobe moved to the best hemi-cube axis for the others' residual) are tried; the best result is
    kept (``restarted`` / ``restart_gain``). On random unit order-6 vectors this reaches the
    optimum of a 200-start search within a few per cent for N = 3, 4
    (``benchmarks/bench_zh.py``).

    ``strategy="greedy"`` (the earlier fit, kept for comparison): lobes are added greedily, each
    fitted to the residual of the previous ones (closed-form eq. 18 at every hemi-cube candidate
    axis and at the optimal linear axis, BFGS with the analytic gradients of eq. 19-21 from the
    ``starts`` best candidates and the linear axis, best kept); then the coefficients are
    re-solved with the axes frozen, then BFGS runs over all axes and coefficients jointly. Where
    the relative error is still above ``restart_error``, ``restarts`` random axis sets are each
    solved by least squares + joint BFGS and the best result kept.

    Args:
        sh_coeffs: SH vectors, shape (..., n*n), any order 1..MAX_ORDER.
        lobe_count: N >= 1.
        stored_bands: leading bands stored exactly: "paper" (DC; DC + linear for N >= 3), or 0,
            1, 2. Storing is free in error terms (a lobe set represents a DC exactly, and a
            linear band exactly once 3 axes span 3-space), it saves lobe storage.
        candidate_resolution: hemi-cube cells per face edge (``r^2 + 4 r ceil(r/2)`` axes).
        starts: BFGS starts from the best scanned axis sets ("global"); per lobe from the best
            candidates plus the optimal linear axis ("greedy").
        max_iterations: BFGS iterations per run.
        restarts: restart descents where the error stays high (0 disables them).
        restart_error: relative error above which the restarts engage.
        optimizer: "batched" (BFGS vectorised over all problems in NumPy) or "scipy"
            (``scipy.optimize.minimize(method="BFGS", jac=True)`` per problem; slower).
        seed: seed of the random restarts.
        initial_axes: optional (..., N0, 3) axes of an earlier fit (N0 < N) to extend.
        ridge: ``mu``: the coefficient solves and BFGS minimise ``psi + mu |g*|^2`` (the reported
            error is ``psi`` alone). A lobe's SH norm is ``|g*|``, so mu is dimensionless; the
            default (1e-5) keeps lobes from cancelling each other with huge coefficients, which
            float32 shading would turn into noise, at a relative cost of order mu on well-posed
            fits. 0 gives the unregularised paper objective.
        strategy: "global" or "greedy" (see above).
        screened_sets: random axis sets screened per restarted problem ("global") with
            ``restarts >= 6``; ``screened_sets * restarts / 6`` with fewer restarts.

    Returns:
        :class:`ZHFit`; ``notes["max_lobe_norm_ratio"]`` is the largest ``|g*| / |t|`` over the
        problems (about 1 for lobes that do not cancel).
    """
    if not isinstance(lobe_count, (int, np.integer)) or lobe_count < 1:
        raise ValueError(f"zh.fit: lobe_count must be an integer >= 1, got {lobe_count!r}")
    t, order, batch = _prepare_target(sh_coeffs, "zh.fit: sh")
    stored = stored_band_count(int(lobe_count), stored_bands)
    stored = min(stored, order)
    if restart_error < 0.0 or restarts < 0 or starts < 1 or max_iterations < 0:
        raise ValueError("zh.fit: restarts, restart_error, max_iterations must be >= 0 and starts >= 1")
    if not (np.isfinite(ridge) and ridge >= 0.0):
        raise ValueError(f"zh.fit: ridge must be a finite number >= 0, got {ridge!r}")
    if strategy not in ("global", "greedy"):
        raise ValueError(f"zh.fit: strategy must be 'global' or 'greedy', got {strategy!r}")
    if screened_sets < 0:
        raise ValueError(f"zh.fit: screened_sets must be >= 0, got {screened_sets!r}")
    options = _zh_fit.FitOptions(candidate_resolution, starts, max_iterations, restarts, restart_error, optimizer, seed)
    _zh_fit._optimiser(options)  # validate the name early
    t0 = time.perf_counter()
    target = t.copy()
    target[:, : stored * stored] = 0.0
    stored_sh = t - target
    problem = _zh_fit.FitProblem(order, int(lobe_count), stored, float(ridge))
    init = None
    if initial_axes is not None:
        init = _axes(initial_axes, "zh.fit: initial_axes").reshape(t.shape[0], -1, 3)
    if stored >= order:  # everything stored: lobes carry nothing
        raw = _zh_fit.LobeFit(np.tile([0.0, 0.0, 1.0], (t.shape[0], int(lobe_count), 1)),
                              np.zeros((t.shape[0], int(lobe_count), order)), np.zeros(t.shape[0]),
                              np.zeros(t.shape[0]), np.zeros(t.shape[0], bool), np.zeros(t.shape[0]))
    elif strategy == "global":
        global_options = _zh_global.GlobalOptions(
            candidate_resolution=candidate_resolution, starts=starts, random_sets=screened_sets,
            restarts=restarts, restart_error=restart_error, max_iterations=max_iterations,
            optimizer=optimizer, seed=seed)
        raw = _zh_global.fit_lobes_global(target, problem, global_options, init)
    else:
        raw = _zh_fit.fit_lobes(target, problem, options, init)
    norm = np.linalg.norm(t, axis=1)
    err = np.sqrt(raw.psi)
    rel = np.where(norm > 0.0, err / np.where(norm > 0.0, norm, 1.0), 0.0)
    shape = lambda a, *tail: a.reshape(batch + tail)
    gain = np.sqrt(raw.psi + raw.restart_gain) - err
    lobe_norm = np.linalg.norm(raw.coeffs.reshape(t.shape[0], -1), axis=1)  # a lobe's SH norm is |g*|
    lobe_ratio = np.where(norm > 0.0, lobe_norm / np.where(norm > 0.0, norm, 1.0), 0.0)
    return ZHFit(
        axes=shape(raw.axes, int(lobe_count), 3),
        coeffs=shape(raw.coeffs, int(lobe_count), order),
        stored=shape(stored_sh, order * order),
        stored_bands=stored,
        error=shape(err),
        rel_error=shape(rel),
        greedy_error=shape(np.sqrt(raw.psi_greedy)),
        restarted=shape(raw.restarted),
        restart_gain=shape(gain),
        seconds=time.perf_counter() - t0,
        notes={"optimizer": optimizer, "strategy": strategy, "stored_bands_rule": stored_bands, "ridge": float(ridge),
               "max_lobe_norm_ratio": float(np.max(lobe_ratio, initial=0.0))},
    )


@dataclass
class LobeBudget:
    """Per-problem lobe counts chosen from a target error (:func:`fit_budget`).

    Padded layout: problem b uses lobes ``0 .. counts[b]-1``; the rest are zero (axis +z).

    Attributes:
        axes: (B, N_max, 3) unit; coeffs: (B, N_max, n) convolution coefficients (stored bands 0).
        counts: lobes used per problem, (B,) int32, in 1..N_max.
        stored: exactly stored leading bands as SH, (B, n*n) (band count per problem follows the
            storage rule for its own lobe count, see ``stored_bands``).
        stored_bands: per problem, (B,) int32.
        error: L2 error per problem, (B,). scale: the error scale used, (B,).
        target: the target error (relative to ``scale``).
        met: whether the problem met the target, (B,) bool (False only at N_max).
        histogram: ``{lobe count: problems}``.
        restarted: multi-start engaged in the final fit, (B,) bool.
        seconds: wall time.
    """

    axes: np.ndarray
    coeffs: np.ndarray
    counts: np.ndarray
    stored: np.ndarray
    stored_bands: np.ndarray
    error: np.ndarray
    scale: np.ndarray
    target: float
    met: np.ndarray
    histogram: dict
    restarted: np.ndarray
    seconds: float = 0.0

    def to_sh(self) -> np.ndarray:
        """Reconstructed SH vectors, (B, n*n)."""
        return to_sh(self.axes, self.coeffs) + self.stored


def fit_budget(
    sh_coeffs,
    target_error: float,
    max_lobes: int = 4,
    *,
    scale=None,
    stored_bands: int | str = "paper",
    min_lobes: int = 1,
    **fit_options,
) -> LobeBudget:
    """Choose the lobe count per problem: the fewest lobes whose error meets a target.

    Problems are fitted with ``min_lobes`` lobes; those whose error exceeds
    ``target_error * scale`` are refitted with one more lobe (the earlier axes extended
    greedily), up to ``max_lobes``. The default scale is the RMS norm of all problems,
    ``sqrt(mean_b |t_b|^2)``, which makes the target an error relative to the whole signal (the
    paper's mesh metric): with every problem at or below it, the total relative RMS error is too.

    Args:
        sh_coeffs: (B, n*n) or (..., n*n) (flattened to B).
        target_error: target error relative to ``scale`` (> 0).
        max_lobes: N_max; min_lobes: first lobe count tried.
        scale: per-problem (B,) or scalar error scale (default: RMS norm, see above).
        stored_bands: storage rule (see :func:`fit`), applied per problem's own lobe count.
        **fit_options: passed to :func:`fit`.

    Returns:
        :class:`LobeBudget`.
    """
    if not target_error > 0.0:
        raise ValueError(f"zh.fit_budget: target_error must be > 0, got {target_error!r}")
    if not 1 <= min_lobes <= max_lobes:
        raise ValueError(f"zh.fit_budget: need 1 <= min_lobes <= max_lobes, got {min_lobes}, {max_lobes}")
    t, order, _ = _prepare_target(sh_coeffs, "zh.fit_budget: sh")
    b = t.shape[0]
    t0 = time.perf_counter()
    if scale is None:
        s = np.full(b, float(np.sqrt(np.mean(np.sum(t * t, axis=1)))) if b else 1.0)
    else:
        s = np.broadcast_to(np.asarray(scale, dtype=np.float64), (b,)).copy()
    s = np.where(s > 0.0, s, 1.0)
    axes = np.tile(np.array([0.0, 0.0, 1.0]), (b, max_lobes, 1))
    coeffs = np.zeros((b, max_lobes, order))
    stored = np.zeros((b, order * order))
    stored_n = np.zeros(b, np.int32)
    counts = np.zeros(b, np.int32)
    error = np.zeros(b)
    restarted = np.zeros(b, bool)
    active = np.arange(b)
    prev_axes = None
    for n_lobes in range(min_lobes, max_lobes + 1):
        if active.size == 0:
            break
        res = fit(t[active], n_lobes, stored_bands=stored_bands, initial_axes=prev_axes, **fit_options)
        ok = (res.error <= target_error * s[active]) | (n_lobes == max_lobes)
        rows = active[ok]
        axes[rows, :n_lobes] = res.axes[ok]
        coeffs[rows, :n_lobes] = res.coeffs[ok]
        stored[rows] = res.stored[ok]
        stored_n[rows] = res.stored_bands
        counts[rows] = n_lobes
        error[rows] = res.error[ok]
        restarted[rows] = res.restarted[ok]
        active = active[~ok]
        prev_axes = res.axes[~ok]
    hist = {int(k): int(v) for k, v in zip(*np.unique(counts, return_counts=True))}
    return LobeBudget(axes, coeffs, counts, stored, stored_n, error, s, float(target_error),
                      error <= target_error * s * (1.0 + 1e-12), hist, restarted, time.perf_counter() - t0)


def choose_order(sh_coeffs, target_error: float, scale=None) -> tuple[int, np.ndarray]:
    """Smallest SH order whose truncation meets a target error (relative to ``scale``).

    The truncation error of order k is the energy in bands >= k of the given vectors (which
    must be computed at an order high enough to contain what matters). The criterion is the
    total relative error ``sqrt(sum_b |t_b[>=k]|^2 / sum_b |t_b|^2)`` (the paper's mesh metric)
    unless per-problem ``scale`` is given.

    Returns:
        ``(order, errors)`` with the relative truncation error of every order 1..n, shape (n,).
    """
    t, order, _ = _prepare_target(sh_coeffs, "zh.choose_order: sh")
    band_energy = np.add.reduceat(t * t, np.arange(order) ** 2, axis=1).sum(axis=0)  # (n,)
    total = band_energy.sum() if scale is None else float(np.sum(np.asarray(scale, float) ** 2))
    tail = np.cumsum(band_energy[::-1])[::-1]  # energy in bands >= k
    errors = np.sqrt(np.append(tail[1:], 0.0) / max(total, 1e-300))
    chosen = int(np.argmax(errors <= target_error)) + 1 if np.any(errors <= target_error) else order
    return chosen, errors
