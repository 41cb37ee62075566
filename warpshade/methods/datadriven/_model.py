"""The data-driven transfer model (Nowrouzezahrai et al. 2007): linear maps from pose to transfer.

Training data: ``p`` poses (rows of ``A``, p x a, :mod:`.pose`) and, per pose, the ray-traced
transfer of every vertex (``B``, p x V x C: ``C = n*n`` SH coefficients, world frame, the
convention of :mod:`warpshade.methods.prt`). Per coefficient ``c`` the model is a linear map
with a bias, ``B^c ~ [A, 1] X^c``, fitted by Tikhonov-regularised least squares

    min ||A X - B||^2 + alpha^2 ||X||^2,    X = (A^T A + alpha^2 I)^-1 A^T B

on standardised pose features (each centred and divided by its training standard deviation;
features constant over the training poses are dropped and reported), the bias left
unregularised (centring). ``alpha`` is chosen per coefficient by the leave-one-out error,
computed in closed form from one SVD of the centred poses ``A = U S W^T``: the fitted values are
``H B`` with the hat matrix ``H = 11^T/p + U diag(s^2 / (s^2 + alpha^2)) U^T`` and the LOO residual
of pose ``i`` is ``e_i / (1 - H_ii)`` -- no refits. Singular values below ``RCOND * s_max`` are
dropped (rank-deficient or ill-conditioned poses, fewer poses than pose dimensions), so
``alpha -> 0`` is the minimum-norm least-squares solution, never a division by zero; where
``1 - H_ii`` vanishes (a pose the fit interpolates exactly) its LOO error is undefined and that
``alpha`` is not chosen.

Reduced model (the paper's section 5): PCA of the pose vectors (``Pi_a``: the first ``ka``
principal directions of the standardised poses) and of the per-vertex coefficient vectors
(``Pi_v``: the first ``kv`` right singular vectors of the ``(p * C) x V`` matrix stacking every
``B^c``, uncentred as in the paper, so the mean transfer lives in the same basis and the model
stores ``V * kv`` numbers instead of one mesh's ``V * C``). Then ``X^c`` maps ``Pi_a(a)`` to
``Pi_v(b^c)`` and a frame costs three products: ``z = Pi_a(a)`` (a x ka), ``y^c = [z, 1] X^c``
(C kv (ka + 1)) and ``b^c = Pi_v y^c`` (V C kv). ``ka``, ``kv`` are chosen from an error budget
on validation frames held out of the training clip (:func:`choose_sizes`).

Errors here are relative RMS over every vertex and coefficient, ``||B_pred - B|| / ||B||``, the
SH L2 norm: the lighting-independent transfer error integrated over the whole sphere.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .._shared.pose_space import PoseSpace, pose_space

__all__ = [
    "RCOND",
    "ALPHA_GRID",
    "RidgeSolver",
    "coefficient_basis",
    "lighting_weights",
    "validation_split",
]

#: Relative singular-value cut-off of every pseudo-inverse.
RCOND = 1e-10
#: Candidate alphas, as multiples of the largest singular value of the centred, standardised
#: poses (0 = least squares); the LOO error picks one per coefficient.
ALPHA_GRID = np.concatenate([[0.0], np.logspace(-4.0, 1.0, 31)])
#: The coarser grid the size search (:func:`choose_sizes`) picks alpha from for every candidate;
#: the final fit uses :data:`ALPHA_GRID`.
SEARCH_ALPHA_GRID = np.concatenate([[0.0], np.logspace(-4.0, 1.0, 11)])
#: Where 1 - H_ii is below this the LOO residual of pose i is undefined (the fit interpolates it).
LOO_MIN_DENOMINATOR = 1e-8


class RidgeSolver:
    """Tikhonov-regularised least squares with a bias for many target columns, one SVD.

    ``Z`` (p, k) are the inputs; targets are given per call. The SVD of the centred inputs is
    made once; every alpha and target group reuses it.
    """

    def __init__(self, Z: np.ndarray):
        Z = np.asarray(Z, np.float64)
        self.p = Z.shape[0]
        self.mean = Z.mean(0)
        u, s, wt = np.linalg.svd(Z - self.mean, full_matrices=False)
        keep = s > RCOND * max(float(s[0]) if s.size else 0.0, 1e-300)
        self.u, self.s, self.w = u[:, keep], s[keep], wt[keep].T
        self.rank = int(keep.sum())
        self.condition = float(s[0] / s[keep][-1]) if self.rank else float("inf")
        self.s_max = float(s[0]) if s.size else 0.0

    def alphas(self, grid=ALPHA_GRID) -> np.ndarray:
        return np.asarray(grid, np.float64) * self.s_max

    def shrink(self, alpha: float) -> np.ndarray:
        """``s^2 / (s^2 + alpha^2)`` per kept singular value."""
        return self.s ** 2 / (self.s ** 2 + alpha * alpha)

    def leverage(self, alpha: float) -> np.ndarray:
        """Diagonal of the hat matrix (with the bias), (p,)."""
        return 1.0 / self.p + (self.u ** 2) @ self.shrink(alpha)

    def loo_weights(self, alpha: float) -> np.ndarray:
        """``1 / (1 - H_ii)^2`` per pose; inf where it is undefined."""
        den = 1.0 - self.leverage(alpha)
        with np.errstate(divide="ignore"):
            return np.where(den > LOO_MIN_DENOMINATOR, 1.0 / np.maximum(den, LOO_MIN_DENOMINATOR) ** 2, np.inf)

    def loo_from_gram(self, gram: np.ndarray, alphas) -> np.ndarray:
        """LOO sum of squared errors of one target group per alpha, from the Gram matrix
        ``Y_c Y_c^T`` (p, p) of its centred targets (any number of columns)."""
        out = np.empty(len(alphas))
        eye = np.eye(self.p)
        for i, alpha in enumerate(alphas):
            r = eye - (self.u * self.shrink(alpha)) @ self.u.T
            rows = np.einsum("ij,ji->i", r @ gram, r.T)
            out[i] = _weighted_sum(np.maximum(rows, 0.0), self.loo_weights(alpha))
        return out

    def loo_columns(self, Yc: np.ndarray, alphas) -> np.ndarray:
        """LOO squared error per alpha and target column of centred targets Yc (p, m) -> (len(alphas), m)."""
        proj = self.u.T @ Yc
        out = np.empty((len(alphas), Yc.shape[1]))
        for i, alpha in enumerate(alphas):
            e = Yc - self.u @ (self.shrink(alpha)[:, None] * proj)
            wts = self.loo_weights(alpha)
            if np.all(np.isfinite(wts)):
                out[i] = wts @ (e * e)
            else:
                out[i] = np.inf
        return out

    def solve(self, Yc: np.ndarray, alpha: float) -> np.ndarray:
        """The regularised map of centred targets Yc (p, m) -> X (k, m)."""
        d = self.s / (self.s ** 2 + alpha * alpha)
        return self.w @ (d[:, None] * (self.u.T @ Yc))


def _weighted_sum(values, weights) -> float:
    if not np.all(np.isfinite(weights)):
        return float("inf")
    return float(values @ weights)


def lighting_weights(light: np.ndarray, outputs: int) -> np.ndarray:
    """Per-output weights that turn squared transfer errors into expected squared shading errors.

    For an SH lighting ``L`` (channels, n*n) rotated uniformly at random, the expected squared
    shading error of a transfer error ``d`` is ``sum_l P_l / (2l + 1) ||d_l||^2`` with the band
    power ``P_l = sum_(m, channel) L_lm^2`` (rotation invariant). Weights are normalised to mean
    1 over the coefficients; ``outputs`` = n*n, or 3 n*n for per-channel transfer (the channel
    weights then use that channel's power only).
    """
    light = np.atleast_2d(np.asarray(light, np.float64))
    n2 = light.shape[1]
    order = int(round(np.sqrt(n2)))
    band = np.repeat(np.arange(order), 2 * np.arange(order) + 1)
    if outputs == n2:
        power = np.bincount(band, weights=(light ** 2).sum(0), minlength=order)
        w = power[band] / (2 * band + 1)
    elif outputs == 3 * n2 and light.shape[0] == 3:
        w = np.concatenate([np.bincount(band, weights=light[c] ** 2, minlength=order)[band] / (2 * band + 1) for c in range(3)])
    else:
        raise ValueError(f"lighting weights: {outputs} outputs per vertex do not match lighting of {n2} coefficients")
    mean = float(w.mean())
    if not np.isfinite(mean) or mean <= 0:
        return np.ones(outputs)
    return np.maximum(w / mean, 1e-6)


def coefficient_basis(data: np.ndarray, k_max: int, seed: int = 0, power: int = 3,
                      weights: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """``Pi_v``: the leading right singular vectors of the ``(p * C) x V`` matrix of every pose's
    and coefficient's per-vertex values (uncentred), by a randomised range finder (Halko,
    Martinsson, Tropp 2011) with ``power`` subspace iterations.

    Args:
        data: training transfer (p, V, C).
        k_max: components wanted (clipped to the rank bound min(p * C, V)).
        weights: per-coefficient weights (C,) (:func:`lighting_weights`): rows of coefficient
            ``c`` are scaled by ``sqrt(weights[c])``, so the basis keeps what shading needs.

    Returns:
        ``(basis (V, k) float64 orthonormal columns, singular values (k,), total energy ||B||_F^2)``.
    """
    p, v, c = data.shape
    k = int(min(k_max, p * c, v))
    if k < 1:
        raise ValueError("coefficient basis needs at least one component")
    rows = np.transpose(data, (0, 2, 1)).astype(np.float64)
    if weights is not None:
        rows *= np.sqrt(np.asarray(weights, np.float64)).reshape(1, c, 1)
    rows = np.ascontiguousarray(rows.reshape(p * c, v))
    total = float(np.einsum("ij,ij->", rows, rows))
    if min(rows.shape) <= k + 10 or min(rows.shape) <= 1500:
        _, s, vt = np.linalg.svd(rows, full_matrices=False)
        return vt[:k].T.copy(), s[:k], total
    rng = np.random.default_rng(seed)
    over = min(k + 16, min(rows.shape))
    q = np.linalg.qr(rows.T @ rng.standard_normal((rows.shape[0], over)))[0]  # (V, over) range of rows^T
    for _ in range(power):
        q = np.linalg.qr(rows @ q)[0]
        q = np.linalg.qr(rows.T @ q)[0]
    small = rows @ q  # (pC, over)
    _, s, vt = np.linalg.svd(small, full_matrices=False)
    basis = q @ vt.T
    return basis[:, :k].copy(), s[:k], total


@dataclass
class DataDrivenModel:
    """A fitted model, full or reduced, as the frame kernels use it.

    Full (``basis`` None): ``b[v, c] = [z, 1] . weights[v, c]``; reduced:
    ``y[c, k] = [z, 1] . coefficients[c, k]`` and ``b[v, c] = basis[v] . y[c]``, with
    ``z = (a - pose.mean) @ pose.weights``.

    Attributes:
        pose: the :class:`PoseSpace` (standardisation and ``Pi_a``).
        weights: full model, (V, C, k + 1) float64 (the bias last), or None.
        coefficients: reduced model, (C, kv, ka + 1) float64 (the bias last), or None.
        basis: reduced model ``Pi_v``, (V, kv) float64, or None.
        alphas: the regularisation chosen per coefficient, (C,).
        loo_error: relative LOO error of the fit per coefficient, (C,).
        info: how it was fitted (sizes, times, rank, condition, energy retained).
    """

    pose: PoseSpace
    weights: np.ndarray | None
    coefficients: np.ndarray | None
    basis: np.ndarray | None
    alphas: np.ndarray
    loo_error: np.ndarray
    info: dict = field(default_factory=dict)

    @property
    def reduced(self) -> bool:
        return self.basis is not None

    @property
    def coefficient_count(self) -> int:
        return int((self.coefficients if self.reduced else self.weights).shape[0 if self.reduced else 1])

    def predict(self, poses) -> np.ndarray:
        """Transfer at raw pose vectors (n, a) -> (n, V, C), float64 (the host mirror)."""
        z = self.pose.project(np.atleast_2d(poses))
        z1 = np.concatenate([z, np.ones((z.shape[0], 1))], 1)
        n = z1.shape[0]
        if self.reduced:
            c, kv, k = self.coefficients.shape
            y = (z1 @ self.coefficients.reshape(c * kv, k).T).reshape(n * c, kv)
            return (y @ self.basis.T).reshape(n, c, -1).transpose(0, 2, 1)
        v, c, k = self.weights.shape
        return (z1 @ self.weights.reshape(v * c, k).T).reshape(n, v, c)

    def stored_floats(self) -> int:
        """Numbers the frame kernels read (what a float32 copy of the model stores)."""
        pose = self.pose.mean.size + self.pose.components.size
        if self.reduced:
            return int(pose + self.coefficients.size + self.basis.size)
        return int(pose + self.weights.size)

    def flops_per_frame(self) -> int:
        """Multiply-adds per frame of the three products (pose projection, maps, basis)."""
        a, k = self.pose.components.shape
        if self.reduced:
            c, kv, k1 = self.coefficients.shape
            return int(a * k + c * kv * k1 + self.basis.shape[0] * c * kv)
        v, c, k1 = self.weights.shape
        return int(a * k + v * c * k1)


def _choose_alpha(loo: np.ndarray, alphas: np.ndarray, fixed: float | None) -> int:
    if fixed is not None:
        return int(np.argmin(np.abs(alphas - fixed)))
    finite = np.isfinite(loo)
    if not finite.any():
        return len(alphas) - 1  # every alpha interpolates some pose: the strongest regularisation
    return int(np.flatnonzero(finite)[np.argmin(loo[finite])])


def fit_full(poses: np.ndarray, data: np.ndarray, alpha: float | None = None, progress: bool = False) -> DataDrivenModel:
    """The full linear model: one regularised map per coefficient over every vertex.

    Args:
        poses: training pose vectors (p, a), raw.
        data: training transfer (p, V, C).
        alpha: a fixed alpha (in units of the largest singular value of the standardised
            poses), or None to choose one per coefficient by closed-form LOO.
    """
    t0 = time.perf_counter()
    space = pose_space(poses, pca=False)
    Z = space.project(poses)
    solver = RidgeSolver(Z)
    p, v, c = data.shape
    grid = solver.alphas(ALPHA_GRID if alpha is None else [alpha])
    weights = np.empty((v, c, space.size + 1))
    alphas = np.empty(c)
    loo = np.empty(c)
    for ci in _maybe_progress(range(c), progress, "fitting full model (coefficients)"):
        y = np.asarray(data[:, :, ci], np.float64)
        mean = y.mean(0)
        yc = y - mean
        gram = yc @ yc.T
        curve = solver.loo_from_gram(gram, grid)
        best = _choose_alpha(curve, grid, None if alpha is None else grid[0])
        alphas[ci] = grid[best] / max(solver.s_max, 1e-300)
        loo[ci] = np.sqrt(curve[best] / max(float(np.einsum("ij,ij->", y, y)), 1e-300))
        x = solver.solve(yc, grid[best])  # (k, V)
        weights[:, ci, :-1] = x.T
        weights[:, ci, -1] = mean - solver.mean @ x
    info = {"kind": "full", "poses": int(p), "pose_features": int(space.mean.size), "active_features": int(space.active.sum()),
            "rank": solver.rank, "condition": solver.condition, "fit_s": time.perf_counter() - t0}
    return DataDrivenModel(space, weights, None, None, alphas, loo, info)


def fit_reduced(poses: np.ndarray, data: np.ndarray, ka: int, kv: int, alpha: float | None = None,
                basis: tuple | None = None, seed: int = 0, progress: bool = False,
                weights: np.ndarray | None = None, alpha_grid=ALPHA_GRID) -> DataDrivenModel:
    """The reduced model ``b = Pi_v^-1(Pi_a(a) X^c)`` with ``ka`` pose and ``kv`` vertex components.

    Args:
        basis: a precomputed :func:`coefficient_basis` result with at least ``kv`` components.
        weights: per-coefficient weights of the basis (:func:`coefficient_basis`).
        alpha_grid: candidate alphas (multiples of the largest singular value of the poses) the
            LOO error picks from when ``alpha`` is None.
    """
    t0 = time.perf_counter()
    full_space = pose_space(poses, pca=True)
    ka = int(max(1, min(ka, full_space.size)))
    space = full_space.truncated(ka)
    if basis is None:
        basis = coefficient_basis(data, kv, seed=seed, weights=weights)
    t_pca = time.perf_counter() - t0
    pv = basis[0][:, :kv]
    kv = pv.shape[1]
    Z = space.project(poses)
    solver = RidgeSolver(Z)
    grid = solver.alphas(alpha_grid if alpha is None else [alpha])
    p, v, c = data.shape
    coeffs = np.empty((c, kv, ka + 1))
    alphas = np.empty(c)
    loo = np.empty(c)
    for ci in _maybe_progress(range(c), progress, "fitting reduced model (coefficients)"):
        y = np.asarray(data[:, :, ci], np.float64) @ pv  # (p, kv)
        mean = y.mean(0)
        yc = y - mean
        curve = solver.loo_columns(yc, grid).sum(1)
        best = _choose_alpha(curve, grid, None if alpha is None else grid[0])
        alphas[ci] = grid[best] / max(solver.s_max, 1e-300)
        loo[ci] = np.sqrt(curve[best] / max(float(np.einsum("ij,ij->", y, y)), 1e-300))
        x = solver.solve(yc, grid[best])  # (ka, kv)
        coeffs[ci, :, :-1] = x.T
        coeffs[ci, :, -1] = mean - solver.mean @ x
    energy = float(np.sum(basis[1][:kv] ** 2) / max(basis[2], 1e-300))
    info = {"kind": "reduced", "ka": int(ka), "kv": int(kv), "poses": int(p), "pose_features": int(space.mean.size),
            "active_features": int(space.active.sum()), "rank": solver.rank, "condition": solver.condition,
            "pose_variance_retained": float(space.variance.sum() / max(full_space.total_variance, 1e-300)),
            "coefficient_energy_retained": energy, "pca_s": t_pca, "fit_s": time.perf_counter() - t0}
    return DataDrivenModel(space, None, coeffs, pv, alphas, loo, info)


def validation_split(count: int, fraction: float, blocks: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Training and validation frame positions: ``blocks`` contiguous runs holding ``fraction`` of
    the frames, spread evenly over the clip (contiguous, because neighbouring frames of an
    animation are near-duplicates: held-out single frames would flatter the model).

    Returns:
        ``(train, validation)`` index arrays into ``range(count)``; validation is empty when
        ``fraction`` is 0 or there are too few frames to spare (< 8).
    """
    idx = np.arange(count)
    n_val = int(round(count * float(fraction)))
    if fraction <= 0 or count < 8 or n_val < 1:
        return idx, idx[:0]
    blocks = max(1, min(blocks, n_val))
    size = max(1, n_val // blocks)
    starts = np.linspace(0, count - size, blocks + 2)[1:-1].round().astype(int)
    val = np.unique(np.concatenate([np.arange(s, s + size) for s in starts]))
    return np.setdiff1d(idx, val), val


@dataclass
class SizeChoice:
    """What :func:`choose_sizes` measured and chose.

    Attributes:
        ka, kv: the chosen sizes.
        error: validation error of every candidate, {(ka, kv): relative error}.
        full_error: validation error of the full (unreduced) model.
        target: the error the choice had to meet; met: whether one met it.
        reason: one sentence for the report.
    """

    ka: int
    kv: int
    error: dict
    full_error: float
    target: float
    met: bool
    reason: str
    cost: dict = field(default_factory=dict)


def _project_vertices(data: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """``einsum("nvc,vk->nck")`` of transfer (n, V, C) and a vertex basis (V, k) as one BLAS
    product (einsum's own loop is ~25x slower at these sizes)."""
    n, v, c = data.shape
    out = np.empty((n, c, basis.shape[1]))
    step = max(1, int(2 ** 26 // max(v * c, 1)))  # ~0.5 GB of float64 rows at a time
    for a in range(0, n, step):
        rows = np.transpose(data[a:a + step], (0, 2, 1)).astype(np.float64).reshape(-1, v)
        out[a:a + step] = (rows @ basis).reshape(-1, c, basis.shape[1])
    return out


def _size_grid(limit: int, values) -> list[int]:
    out = sorted({int(v) for v in values if 1 <= int(v) <= limit} | {int(limit)})
    return out


KA_GRID = (2, 3, 4, 6, 8, 10, 12, 16, 20, 24, 32, 48, 64)
KV_GRID = (4, 8, 12, 16, 22, 32, 48, 64, 96, 128, 192, 256, 384, 512)


def choose_sizes(poses: np.ndarray, data: np.ndarray, train: np.ndarray, validation: np.ndarray,
                 target_error: float | None = None, tolerance: float = 0.05, kv_max: int = 512,
                 ka_grid=KA_GRID, kv_grid=KV_GRID, seed: int = 0, progress: bool = False,
                 weights: np.ndarray | None = None) -> SizeChoice:
    """The cheapest ``(ka, kv)`` whose validation error meets the budget.

    Every candidate is fitted on the ``train`` poses (alpha per coefficient by LOO) and measured
    on the ``validation`` poses. The budget is ``target_error`` (relative transfer error) when
    given, else ``(1 + tolerance)`` times the full model's validation error (no more model than
    the data supports). Cost = multiply-adds per frame (:meth:`DataDrivenModel.flops_per_frame`).
    When nothing meets the budget the most accurate candidate is chosen and ``met`` is False.
    With ``weights`` (C,) (:func:`lighting_weights`) every error is the weighted one,
    ``sqrt(sum_c w_c ||e_c||^2 / sum_c w_c ||b_c||^2)``: the expected relative shading error
    under the rotated lighting rather than the plain SH L2 error.
    """
    if validation.size == 0:
        raise ValueError("choosing PCA sizes needs validation frames (validation > 0 and at least 8 training frames)")
    A_tr, A_val = poses[train], poses[validation]
    B_tr, B_val = data[train], data[validation]
    w = np.ones(data.shape[2]) if weights is None else np.asarray(weights, np.float64)
    full = fit_full(A_tr, B_tr)
    pred = full.predict(A_val)
    val_energy = float(np.einsum("nvc,nvc,c->", B_val.astype(np.float64), B_val.astype(np.float64), w))
    full_error = float(np.sqrt(np.einsum("nvc,c->", (pred - B_val) ** 2, w) / max(val_energy, 1e-300)))
    del pred
    space_all = pose_space(A_tr, pca=True)
    basis = coefficient_basis(B_tr, kv_max, seed=seed, weights=weights)
    pv = basis[0]
    kv_max = pv.shape[1]
    kas = _size_grid(space_all.size, ka_grid)
    kvs = _size_grid(kv_max, kv_grid)
    p, v, c = B_tr.shape
    # validation energy outside the first k basis vectors: ||B||^2 - sum_k (B pv_k)^2, per k
    proj_val = _project_vertices(B_val, pv)  # (n_val, C, kv_max)
    outside = val_energy - np.concatenate([[0.0], np.cumsum(np.einsum("nck,nck,c->k", proj_val, proj_val, w))])
    proj_tr = _project_vertices(B_tr, pv)  # (p, C, kv_max)
    error = {}
    for ka in _maybe_progress(kas, progress, "choosing PCA sizes (pose dimensions)"):
        space = space_all.truncated(ka)
        solver = RidgeSolver(space.project(A_tr))
        zv = space.project(A_val) - solver.mean
        grid = solver.alphas(SEARCH_ALPHA_GRID)
        inside = np.zeros(len(kvs))
        for ci in range(c):
            y = proj_tr[:, ci, :]
            mean = y.mean(0)
            yc = y - mean
            loo = np.cumsum(solver.loo_columns(yc, grid), axis=1)  # (alphas, kv_max)
            val_sq = np.empty((len(grid), kv_max))
            proj_u = solver.u.T @ yc
            for i, alpha in enumerate(grid):
                d = solver.s / (solver.s ** 2 + alpha * alpha)
                x = solver.w @ (d[:, None] * proj_u)
                r = proj_val[:, ci, :] - (zv @ x + mean)
                val_sq[i] = np.sum(r * r, 0)
            val_cum = np.cumsum(val_sq, axis=1)
            for j, kv in enumerate(kvs):
                col = loo[:, kv - 1]
                best = _choose_alpha(col, grid, None)
                inside[j] += w[ci] * val_cum[best, kv - 1]
        for j, kv in enumerate(kvs):
            error[(ka, kv)] = float(np.sqrt(max(inside[j] + outside[kv], 0.0) / max(val_energy, 1e-300)))
    target = float(target_error) if target_error is not None else (1.0 + tolerance) * full_error
    a = poses.shape[1]

    def cost(ka, kv):
        return a * ka + c * kv * (ka + 1) + v * c * kv

    costs = {key: cost(*key) for key in error}
    ok = [key for key, e in error.items() if e <= target]
    if ok:
        ka, kv = min(ok, key=lambda key: (costs[key], error[key]))
        met = True
        how = f"the cheapest of {len(error)} (ka, kv) candidates with validation error <= {target:.4g}"
    else:
        ka, kv = min(error, key=lambda key: (error[key], costs[key]))
        met = False
        how = f"no candidate met {target:.4g}; the most accurate of {len(error)}"
    basis_note = "target_error" if target_error is not None else f"full model x (1 + {tolerance:g})"
    reason = (f"PCA({ka},{kv}): {how} (budget: {basis_note}; full model {full_error:.4g}, chosen {error[(ka, kv)]:.4g} "
              f"on {validation.size} validation frames)")
    return SizeChoice(ka, kv, error, full_error, target, met, reason, costs)


def _maybe_progress(items, progress: bool, desc: str):
    if not progress:
        return items
    from ...tasks import progress_bar

    return progress_bar(items, desc=desc, leave=False)
