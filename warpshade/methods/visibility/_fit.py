"""One cluster's model: PCA of its local visibility and a map from the inputs to the PCA weights.

Per cluster ``c`` with ``n_c`` vertices, the training visibility in the cluster frames is a
``p x (n_c C)`` matrix ``Y``. Its PCA (centred, the mean kept) keeps the fewest components ``k_c``
holding ``variance`` of its variance (the error budget; at most ``k_max`` and ``p - 1``), so the
model predicts ``k_c`` weights ``y`` and the visibility is ``mean + U y``. A cluster whose
visibility does not vary keeps ``k_c = 0`` (its mean). After the fit, the components are cut
again to the fewest holding ``predictable`` of the variance the model *predicts* over the
training inputs: with noisy training visibility (a few hundred rays per vertex and frame) most of
the variance of the later components is ray noise no input explains, which a model maps to
~0 at the cost of a product per vertex.

**Metric** (task keys ``metric``, ``metric_inverse``; the stage parameter ``metric``): with a
per-vertex matrix ``M`` (the cosine product matrix of eq. 14 for ``metric = "diffuse"``) the PCA,
the selection and the fits minimise ``sum ||M (v - v_hat)||^2`` instead of the visibility's
squared error: the PCA is that of the mapped rows ``M v`` (the transfer diffuse shading reads), its
basis stored mapped back by the pseudo-inverse ``M^+`` (so ``M`` times the stored basis is the
transfer basis; directions ``M`` does not see are dropped), the mean the visibility's own (``M``
of it is the transfer's mean). The reported errors are then relative to the training transfer.

The inputs ``x`` are the standardised input-PCA coordinates of the frame (:mod:`._model`). Models
(the stage parameter ``model``):

* ``"linear"``: ``y = W x + b`` (ridge: ``||W||^2`` penalised, the bias not);
* ``"quadratic"``: the same on second-order features ``[x, x_i x_j (i <= j)]``;
* ``"network"``: one hidden layer of ``H`` tanh units, ``y = W2 tanh(W1 x + b1) + b2`` (eq. 12),
  fitted on ``0.5 / p ||Y - f(X)||^2 + 0.5 lambda (||W1||^2 + ||W2||^2)`` (eq. 13, targets
  divided by their RMS) by L-BFGS-B with the analytic gradient, **warm-started from the linear
  solution** (``W1 = eps V^T``, ``W2 = U S / eps`` from the SVD of the linear map, so that the
  first iterate is the ridge model up to ``O(eps^2)``), **early-stopped** on a held-out block of
  the training frames (the best iterate on it is kept; ``PATIENCE`` iterations without
  improvement end the fit).

* ``"auto"``: per cluster, the ridge map (linear or quadratic, on the first few input components
  or on the inputs of the joints near the cluster) that blocked cross-validation over pose
  segments of the training clip prefers (:mod:`._select`, :mod:`._locality`);
* ``"stack"``: per cluster, the non-negative combination (weights summing to one) of those
  candidates that minimises their blocked out-of-fold error, as one map on the union of their
  features (:mod:`._stack`).

The regulariser (and, for the network, ``H``) is chosen by ``FOLDS``-fold cross-validation over
contiguous blocks of training frames (neighbouring frames are near-duplicates). A network whose
fit is not finite, or whose cross-validated error is not below the linear model's, is replaced
by the linear model and the reason reported (``fallback``).
"""

from __future__ import annotations

import time

import numpy as np
from scipy.optimize import minimize

from ._select import RIDGE_GRID, check_folds, margin_penalty

__all__ = ["FOLDS", "expand_features", "fit_network", "folds", "metric_apply", "metric_inverse", "network_forward", "pca_size",
           "warm_start"]

#: Cross-validation folds.
FOLDS = 4
#: Network penalties (eq. 13 lambda, on inputs of unit variance and targets of unit RMS).
NETWORK_PENALTIES = (1e-4, 1e-3, 1e-2)
#: Network fits: most L-BFGS iterations, iterations without improvement on the stopping block.
MAX_ITERATIONS = 300
PATIENCE = 25
#: Largest |first-layer pre-activation| of the warm start (tanh is ~linear below it).
WARM_START_ACTIVATION = 0.5
#: Singular values of a fit metric below this fraction of the largest are dropped by its pseudo-inverse.
METRIC_RCOND = 1e-6


def expand_features(x: np.ndarray, model: str) -> np.ndarray:
    """Inputs of the model's output layer: ``x`` or ``[x, x_i x_j (i <= j)]`` (quadratic)."""
    x = np.asarray(x, np.float64)
    if model != "quadratic":
        return x
    i, j = np.triu_indices(x.shape[1])
    return np.concatenate([x, x[:, i] * x[:, j]], axis=1)


def folds(count: int, k: int = FOLDS) -> list[tuple[np.ndarray, np.ndarray]]:
    """``k`` contiguous (train, validation) splits of ``range(count)`` (fewer when count < 2k)."""
    k = max(2, min(k, count // 2))
    edges = np.linspace(0, count, k + 1).round().astype(int)
    idx = np.arange(count)
    return [(np.concatenate([idx[:a], idx[b:]]), idx[a:b]) for a, b in zip(edges[:-1], edges[1:])]


def pca_size(singular: np.ndarray, variance: float, k_max: int) -> int:
    """Fewest components holding ``variance`` of the total (0 when there is none)."""
    s2 = np.asarray(singular, np.float64) ** 2
    total = float(s2.sum())
    if total <= 1e-20:
        return 0
    k = int(np.searchsorted(np.cumsum(s2) / total, variance - 1e-12) + 1)
    return int(min(k, k_max, s2.size))


# ---- ridge -------------------------------------------------------------------------------------
def _ridge_path(x, y, penalties):
    """Ridge maps for every penalty: [(W (K, D), b (K,))]; inputs centred internally."""
    mx, my = x.mean(0), y.mean(0)
    u, s, vt = np.linalg.svd(x - mx, full_matrices=False)
    proj = u.T @ (y - my)
    out = []
    for lam in penalties:
        den = s * s + lam
        d = np.divide(s, den, out=np.zeros_like(s), where=den > 0.0)
        w = (vt.T * d) @ proj  # (D, K)
        out.append((w.T, my - mx @ w))
    return out, float(s[0] ** 2) if s.size else 0.0


def _ridge_cv(x, y, splits):
    """Summed validation SSE per entry of :data:`RIDGE_GRID`, in units of the largest squared
    singular value of the centred inputs over every training frame, in every fold as in the final
    fit (:func:`._select.penalty_scale`: a fold's own would be of rounding size where its training
    frames share one pose)."""
    sse = np.zeros(RIDGE_GRID.size)
    _, smax = _ridge_path(x, y, [0.0])
    for tr, va in splits:
        fits, _ = _ridge_path(x[tr], y[tr], RIDGE_GRID * max(smax, 1e-30))
        for g, (w, b) in enumerate(fits):
            r = x[va] @ w.T + b - y[va]
            sse[g] += float((r * r).sum())
    return sse


def _ridge_fit(x, y, splits):
    sse = _ridge_cv(x, y, splits)
    g = margin_penalty(sse)
    if g < 0:
        raise ValueError("visibility fit: no ridge penalty has a finite validation error (inputs or visibility not finite)")
    _, smax = _ridge_path(x, y, [0.0])
    (w, b), = _ridge_path(x, y, [RIDGE_GRID[g] * max(smax, 1e-30)])[0]
    return w, b, float(sse[g]), float(RIDGE_GRID[g])


# ---- network -----------------------------------------------------------------------------------
def _unpack(theta, h, d, k):
    w1 = theta[:h * d].reshape(h, d)
    b1 = theta[h * d:h * d + h]
    w2 = theta[h * d + h:h * d + h + k * h].reshape(k, h)
    b2 = theta[h * d + h + k * h:]
    return w1, b1, w2, b2


def network_forward(x, w1, b1, w2, b2):
    """Eq. 12: ``tanh(x W1^T + b1) W2^T + b2``, (n, K)."""
    return np.tanh(x @ w1.T + b1) @ w2.T + b2


def _loss_grad(theta, x, y, h, lam):
    """Eq. 13 and its analytic gradient."""
    d, k = x.shape[1], y.shape[1]
    w1, b1, w2, b2 = _unpack(theta, h, d, k)
    hid = np.tanh(x @ w1.T + b1)
    e = hid @ w2.T + b2 - y
    p = x.shape[0]
    loss = 0.5 / p * float((e * e).sum()) + 0.5 * lam * (float((w1 * w1).sum()) + float((w2 * w2).sum()))
    gw2 = e.T @ hid / p + lam * w2
    gb2 = e.sum(0) / p
    da = (e @ w2) / p * (1.0 - hid * hid)
    gw1 = da.T @ x + lam * w1
    gb1 = da.sum(0)
    return loss, np.concatenate([gw1.ravel(), gb1, gw2.ravel(), gb2])


def warm_start(w_lin, b_lin, x, hidden: int, seed: int = 0):
    """Network parameters reproducing the linear map ``x W^T + b`` to first order (module doc)."""
    k, d = w_lin.shape
    u, s, vt = np.linalg.svd(w_lin, full_matrices=False)
    r = min(hidden, s.size)
    reach = np.abs(x @ vt[:r].T).max() if x.size and r else 1.0
    eps = WARM_START_ACTIVATION / max(float(reach), 1e-12)
    rng = np.random.default_rng(seed)
    w1 = rng.normal(0.0, 0.1 * eps, (hidden, d))
    w1[:r] = eps * vt[:r]
    w2 = np.zeros((k, hidden))
    w2[:, :r] = u[:, :r] * (s[:r] / eps)
    return w1, np.zeros(hidden), w2, np.asarray(b_lin, np.float64).copy()


def fit_network(x, y, hidden, lam, w_lin, b_lin, stop=None, max_iterations=MAX_ITERATIONS, seed=0):
    """One network fit (module doc). ``stop``: (x, y) of the early-stopping block or None.

    Returns ``(params (w1, b1, w2, b2), info)``; info has ``iterations``, ``stopped_early``,
    ``finite`` and the optimiser's ``message``."""
    d, k = x.shape[1], y.shape[1]
    theta0 = np.concatenate([a.ravel() for a in warm_start(w_lin, b_lin, x, hidden, seed)])
    best = {"theta": theta0.copy(), "err": np.inf, "since": 0, "it": 0}

    def stop_error(theta):
        if stop is None:
            return None
        r = network_forward(stop[0], *_unpack(theta, hidden, d, k)) - stop[1]
        return float((r * r).sum())

    best["err"] = stop_error(theta0) if stop is not None else np.inf

    def callback(intermediate_result):
        best["it"] += 1
        if stop is None:
            return
        e = stop_error(intermediate_result.x)
        if not np.isfinite(e):
            raise StopIteration
        if e < best["err"]:
            best.update(theta=intermediate_result.x.copy(), err=e, since=0)
        else:
            best["since"] += 1
            if best["since"] >= PATIENCE:
                raise StopIteration

    with np.errstate(over="ignore", invalid="ignore"):
        res = minimize(_loss_grad, theta0, args=(x, y, hidden, lam), jac=True, method="L-BFGS-B",
                       callback=callback, options={"maxiter": int(max_iterations)})
    theta = best["theta"] if stop is not None else res.x
    finite = bool(np.all(np.isfinite(theta)) and np.isfinite(res.fun))
    info = {"iterations": int(best["it"]), "stopped_early": bool(stop is not None and best["since"] >= PATIENCE),
            "finite": finite, "message": str(res.message)}
    return _unpack(theta, hidden, d, k), info


def _principal(yc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values and right singular vectors of a wide ``yc`` (p, m), from the p x p Gram
    matrix (p << m: the training frames against a cluster's coefficients)."""
    if yc.shape[0] >= yc.shape[1]:
        _, s, vt = np.linalg.svd(yc, full_matrices=False)
        return s, vt
    evals, evecs = np.linalg.eigh(yc @ yc.T)
    order = np.argsort(evals)[::-1]
    evals, evecs = np.maximum(evals[order], 0.0), evecs[:, order]
    s = np.sqrt(evals)
    keep = s > 1e-10 * max(float(s[0]) if s.size else 0.0, 1e-300)
    vt = np.zeros((s.size, yc.shape[1]))
    vt[keep] = (evecs[:, keep].T @ yc) / s[keep, None]
    return s * keep, vt


# ---- the metric of the fit ---------------------------------------------------------------------------
def metric_apply(y: np.ndarray, matrix) -> np.ndarray:
    """Rows of per-vertex blocks ``y`` (p, n_c C) with every vertex's C coefficients mapped by
    ``matrix`` (C, C): ``v -> M v``; ``y`` itself (float64) when ``matrix`` is None."""
    y = np.asarray(y, np.float64)
    if matrix is None:
        return y
    m = np.asarray(matrix, np.float64)
    c = m.shape[0]
    return (y.reshape(y.shape[0], -1, c) @ m.T).reshape(y.shape)


def metric_inverse(matrix: np.ndarray, rcond: float = METRIC_RCOND) -> np.ndarray:
    """Pseudo-inverse of a metric matrix ``M`` (C, C): singular values below ``rcond`` times the
    largest dropped (directions the metric does not see)."""
    return np.linalg.pinv(np.asarray(matrix, np.float64), rcond=rcond)


# ---- one cluster ---------------------------------------------------------------------------------
def fit_cluster(task: dict) -> dict:
    """PCA and model of one cluster (an executor task; everything it needs is in ``task``).

    Task keys: ``x`` (p, D) standardised inputs, ``y`` (p, n_c * C) visibility, ``model``,
    ``variance``, ``predictable``, ``k_max``, ``hidden`` (candidate neuron counts), ``max_iterations``, ``seed``,
    ``cluster``. Returns the PCA (``mean``, ``basis`` (n_c C, k)), the output layer ``w2`` (k,
    D' or H), ``b2``, and for a network ``w1`` (H, D), ``b1``; ``report`` says what was chosen.
    """
    t0 = time.perf_counter()
    x = np.asarray(task["x"], np.float64)
    model = task["model"]
    vis_mean = np.asarray(task["y"], np.float64).mean(0)
    y = metric_apply(task["y"], task.get("metric"))
    mean = y.mean(0)
    yc = y - mean
    s, vt = _principal(yc)
    k = pca_size(s, task["variance"], min(task["k_max"], max(y.shape[0] - 1, 0)))
    basis = vt[:k].T  # (n_c C, k), orthonormal in the metric
    total = float((s * s).sum())
    retained = float((s[:k] ** 2).sum() / total) if total > 0 else 1.0
    report = {"cluster": int(task["cluster"]), "vertices": int(task["vertices"]), "components": int(k),
              "retained_variance": retained, "model": model}
    # stored in visibility space: the mean, and the basis mapped back through the metric's pseudo-inverse
    out = {"mean": vis_mean.astype(np.float32),
           "basis": metric_apply(basis.T, task.get("metric_inverse")).T.astype(np.float32)}
    feats_dim = expand_features(x[:1], "quadratic" if model == "quadratic" else "linear").shape[1]
    if k == 0:
        out.update(w2=np.zeros((0, feats_dim), np.float32), b2=np.zeros(0, np.float32))
        report.update(model_used="constant", cv_error=0.0, fit_s=time.perf_counter() - t0)
        out["report"] = report
        return out
    target = yc @ basis  # (p, k)
    norm = float((y * y).sum()) or 1.0
    truncation = float(((yc - target @ basis.T) ** 2).sum())
    if model == "stack":
        from ._stack import TOP, fit_stack, union_features

        sets = task.get("input_sets") or {"global": (x, ("linear", "quadratic"))}
        st = fit_stack(sets, target, top=task.get("stack_top", TOP), total=task.get("stack_total", "one"))
        out.update(w2=st["w"].astype(np.float32), b2=st["b"].astype(np.float32), stack=st["layout"])
        report.update(model_used="stack", stack=[{k: p[k] for k in ("set", "kind", "inputs", "penalty", "weight")}
                                                 for p in st["picks"]],
                      cv_error=float(np.sqrt((st["sse"] + truncation) / norm)),
                      cv_error_best=float(np.sqrt((st["best_sse"] + truncation) / norm)))
        _keep_predictable(out, union_features(sets, st["layout"]), task["predictable"], report)
        report["fit_s"] = time.perf_counter() - t0
        out["report"] = report
        return out
    if model == "auto":
        from . import _select as select
        from ._select import fit_selected, prefix_features, select_ridge

        sets = task.get("input_sets") or {"global": (x, ("linear", "quadratic"))}
        sel = select_ridge(sets, target, rule=task.get("rule", select.RULE))
        xs = np.asarray(sets[sel["set"]][0], np.float64)
        w, b = fit_selected(xs, target, sel["kind"], sel["inputs"], sel["penalty"])
        out.update(w2=w.astype(np.float32), b2=b.astype(np.float32), select=(sel["set"], sel["kind"], sel["inputs"]))
        report.update(model_used=sel["kind"], input_set=sel["set"], inputs=sel["inputs"], ridge=sel["penalty"],
                      cv_error=float(np.sqrt((sel["sse"] + truncation) / norm)),
                      cv_table={k: float(np.sqrt((v + truncation) / norm)) for k, v in sel["table"].items()})
        _keep_predictable(out, prefix_features(xs, sel["kind"], sel["inputs"]), task["predictable"], report)
        report["fit_s"] = time.perf_counter() - t0
        out["report"] = report
        return out
    scale = float(np.sqrt((target ** 2).mean())) or 1.0
    splits = folds(x.shape[0])
    check_folds(splits, x.shape[0], "cross-validation")
    feats = expand_features(x, model)
    w, b, sse, g = _ridge_fit(feats, target, splits)
    report.update(ridge=g, cv_error=float(np.sqrt((sse + truncation) / norm)))
    out.update(w2=w.astype(np.float32), b2=b.astype(np.float32))
    report["model_used"] = "quadratic" if model == "quadratic" else "linear"
    if model == "network":
        tn = target / scale
        best = None
        for hidden in task["hidden"]:
            for lam in NETWORK_PENALTIES:
                err, ok = 0.0, True
                for tr, va in splits:
                    wl, bl, _, _ = _ridge_fit(x[tr], tn[tr], folds(tr.size))
                    inner = folds(tr.size, 6)[-1]
                    params, info = fit_network(x[tr][inner[0]], tn[tr][inner[0]], hidden, lam, wl, bl,
                                               stop=(x[tr][inner[1]], tn[tr][inner[1]]),
                                               max_iterations=task["max_iterations"], seed=task["seed"])
                    r = network_forward(x[va], *params) * scale - target[va]
                    e = float((r * r).sum())
                    ok = ok and info["finite"] and np.isfinite(e)
                    err += e
                if ok and (best is None or err < best[0]):
                    best = (err, hidden, lam)
        if best is None or not best[0] < sse:
            report["fallback"] = ("the network's fit was not finite" if best is None else
                                  f"the network's cross-validated error {np.sqrt((best[0] + truncation) / norm):.4g} "
                                  f"is not below the linear model's {report['cv_error']:.4g}")
        else:
            err, hidden, lam = best
            wl, bl, _, _ = _ridge_fit(x, tn, splits)
            fit_rows, stop_rows = folds(x.shape[0], 6)[-1]
            (w1, b1, w2, b2), info = fit_network(x[fit_rows], tn[fit_rows], hidden, lam, wl, bl,
                                                 stop=(x[stop_rows], tn[stop_rows]),
                                                 max_iterations=task["max_iterations"], seed=task["seed"])
            if not info["finite"]:
                report["fallback"] = f"the final network fit was not finite ({info['message']})"
            else:
                out.update(w1=w1.astype(np.float32), b1=b1.astype(np.float32), w2=(w2 * scale).astype(np.float32),
                           b2=(b2 * scale).astype(np.float32))
                report.update(model_used="network", hidden=int(hidden), penalty=float(lam),
                              cv_error=float(np.sqrt((err + truncation) / norm)), iterations=info["iterations"],
                              stopped_early=info["stopped_early"])
    _keep_predictable(out, x if "w1" in out else feats, task["predictable"], report)
    report["fit_s"] = time.perf_counter() - t0
    out["report"] = report
    return out


def _keep_predictable(out: dict, x: np.ndarray, budget: float, report: dict) -> None:
    """Keep the fewest PCA components holding ``budget`` of the variance the fitted model
    predicts over the training inputs (components it cannot predict, the training data's ray
    noise among them, cost a product per vertex and add nothing); in place. ``x``: the network's
    inputs, or the features of the output layer of a ridge model."""
    if budget >= 1.0 or out["basis"].shape[1] == 0:
        return
    if "w1" in out:
        pred = network_forward(x, out["w1"].astype(np.float64), out["b1"].astype(np.float64),
                               out["w2"].astype(np.float64), out["b2"].astype(np.float64))
    else:
        pred = x @ out["w2"].T.astype(np.float64) + out["b2"]
    var = pred.var(0)
    total = float(var.sum())
    if total <= 0.0:
        keep = np.zeros(0, np.int64)
    else:
        order = np.argsort(-var, kind="stable")
        count = int(np.searchsorted(np.cumsum(var[order]) / total, budget - 1e-12) + 1)
        keep = np.sort(order[:count])
    dropped = np.setdiff1d(np.arange(var.size), keep)
    # a dropped component's constant prediction (its mean over the training inputs) stays in the mean
    out["mean"] = (out["mean"] + out["basis"][:, dropped].astype(np.float64) @ pred[:, dropped].mean(0)).astype(np.float32)
    out["basis"] = np.ascontiguousarray(out["basis"][:, keep])
    out["w2"] = np.ascontiguousarray(out["w2"][keep])
    out["b2"] = np.ascontiguousarray(out["b2"][keep])
    report["components_fitted"] = int(var.size)
    report["components"] = int(keep.size)
    report["predicted_variance_kept"] = float(var[keep].sum() / total) if total > 0 else 1.0
