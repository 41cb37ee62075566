"""Stacked regression per cluster (``regressor = "stack"``): a weighted sum of the selection's candidates.

Where blocked cross-validation ranks a cluster's candidates (:mod:`._select`) unstably, picking
one of them is a noisy choice; stacking (Wolpert 1992; Breiman 1996, "Stacked regressions")
combines them instead. Every candidate (or the :data:`TOP` with the least blocked-CV error; every input set and kind,
each at its own best penalty) keep their out-of-fold predictions ``P_j`` (p, k): each
validation segment predicted by the map fitted without it and its gap. The weights minimise the
out-of-fold error of the combination,

    min_w || sum_j w_j P_j - Y ||^2   subject to   w_j >= 0  (and sum_j w_j = 1: ``total = "one"``),

a non-negative least-squares problem in ``J`` unknowns (a few tens) (Breiman's constraint: the
non-negativity keeps the combination from extrapolating between near-collinear candidates; with
``total = "free"`` the sum may be below 1, a shrinkage towards the cluster's mean, as the targets
are the centred PCA weights). Every candidate with a positive weight is refitted on every training
frame and the model is the weighted sum of the maps.

Every candidate is linear in features of one common list, the **union** of the cluster:
``[x (the global inputs, all of them), the cluster's local blocks (each set in name order, as many
inputs as its widest candidate uses), the products x_i x_j of the first q global inputs]`` (q the
widest quadratic candidate; :func:`._select.prefix_pairs` order). A weighted sum of the maps is one
map on the union, so the stacked cluster costs one output row per PCA weight, like a single
candidate: the frame's work grows with the union's width only (:func:`union_map`).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import nnls

from ._select import blocked_folds, candidates, check_folds, fit_selected, prefix_pairs

__all__ = ["TOP", "TOTALS", "stack_weights", "fit_stack", "union_features", "union_map"]

#: Candidates (least blocked-CV error first) the combination may use; 0: every candidate (Breiman's
#: stacking: the non-negativity alone selects).
TOP = 0
#: Constraints on the sum of the weights.
TOTALS = ("one", "free", "equal")
#: Weights below this fraction of the largest are dropped (and the rest rescaled to the same sum).
WEIGHT_FLOOR = 1e-4


def stack_weights(preds: np.ndarray, y: np.ndarray, total: str = "one") -> np.ndarray:
    """Non-negative weights ``w`` (J,) minimising ``||sum_j w_j preds[j] - y||^2``.

    ``preds`` (J, ...) and ``y`` (...) are flattened. ``total = "one"``: ``sum w = 1`` (the
    simplex), solved exactly as the non-negative least squares of the problem with the
    constraint eliminated through a large weight on the row ``sum w = 1`` and then projected on
    the simplex's face of the solution's support (a KKT solve on that support); ``"free"``: plain
    non-negative least squares. Degenerate problems (a candidate constant zero, identical
    candidates, all-zero targets) give finite weights."""
    if total not in TOTALS:
        raise ValueError(f"stack: total must be one of {TOTALS}, got {total!r}")
    if total == "equal":
        return np.full(len(preds), 1.0 / max(len(preds), 1))
    a = np.asarray(preds, np.float64).reshape(len(preds), -1).T  # (n, J)
    b = np.asarray(y, np.float64).reshape(-1)
    j = a.shape[1]
    if j == 0:
        return np.zeros(0)
    if j == 1:
        if total == "one":
            return np.ones(1)
        den = float(a[:, 0] @ a[:, 0])
        return np.array([max(float(a[:, 0] @ b) / den, 0.0) if den > 0 else 0.0])
    scale = max(float(np.sqrt((a * a).sum() / j)), float(np.linalg.norm(b)), 1e-300)
    a, b = a / scale, b / scale
    if total == "free":
        w, _ = nnls(a, b, maxiter=50 * j)
        return w
    # the simplex: the row sqrt(big) (sum w - 1) makes nnls find the support; then the exact KKT
    # solution of the equality-constrained problem on that support, kept while it stays >= 0
    big = 1e6 * max(float((a * a).sum()), 1.0)
    aa = np.vstack([a, np.full((1, j), np.sqrt(big))])
    bb = np.r_[b, np.sqrt(big)]
    w, _ = nnls(aa, bb, maxiter=50 * j)
    support = np.flatnonzero(w > 0)
    if support.size == 0:
        return np.full(j, 1.0 / j)
    for _ in range(j):
        g = a[:, support].T @ a[:, support]
        kkt = np.zeros((support.size + 1, support.size + 1))
        kkt[:-1, :-1] = 2.0 * g
        kkt[:-1, -1] = 1.0
        kkt[-1, :-1] = 1.0
        rhs = np.r_[2.0 * (a[:, support].T @ b), 1.0]
        sol = np.linalg.lstsq(kkt, rhs, rcond=None)[0][:-1]
        if np.all(sol >= -1e-12) and np.all(np.isfinite(sol)):
            w = np.zeros(j)
            w[support] = np.maximum(sol, 0.0)
            break
        support = support[sol > 0]  # a negative weight leaves the support
        if support.size == 0:
            break
    w = np.maximum(w, 0.0)
    s = float(w.sum())
    return w / s if s > 0 else np.full(j, 1.0 / j)


def _layout(picks: list[dict], widths: dict) -> dict:
    """The union of some candidates: ``{"local": [(set, m)], "quad": q, "global": D}``."""
    local = {}
    q = 0
    for c in picks:
        if c["set"] == "global":
            if c["kind"] == "quadratic":
                q = max(q, c["inputs"])
        else:
            if c["kind"] != "linear":
                raise ValueError(f"stack: local inputs take linear maps only, got {c['kind']!r} on {c['set']!r}")
            local[c["set"]] = max(local.get(c["set"], 0), c["inputs"])
    return {"local": sorted(local.items()), "quad": int(q), "global": int(widths["global"])}


def union_features(sets: dict, layout: dict) -> np.ndarray:
    """The union's features (p, D_u) (module docstring) of the inputs ``sets`` (name -> (x, kinds))."""
    x = np.asarray(sets["global"][0], np.float64)
    parts = [x[:, :layout["global"]]]
    parts += [np.asarray(sets[name][0], np.float64)[:, :m] for name, m in layout["local"]]
    qi, qj = prefix_pairs(layout["quad"])
    parts.append(x[:, qi] * x[:, qj])
    return np.concatenate(parts, axis=1)


def union_map(picks: list[dict], maps: list, weights: np.ndarray, layout: dict) -> tuple[np.ndarray, np.ndarray]:
    """The weighted sum of candidate maps ``maps[i] = (W (k, D_i), b (k,))`` (on their own
    :func:`._select.prefix_features`) as one map on the union: ``(W (k, D_u), b (k,))``."""
    dg = layout["global"]
    pos, at = dg, {}
    for name, m in layout["local"]:
        at[name] = pos
        pos += m
    qbase = pos
    k = maps[0][0].shape[0]
    w_u = np.zeros((k, qbase + prefix_pairs(layout["quad"])[0].size))
    b_u = np.zeros(k)
    for c, (w, b), wt in zip(picks, maps, weights):
        m = c["inputs"]
        if c["set"] == "global":
            w_u[:, :m] += wt * w[:, :m]
            if c["kind"] == "quadratic":
                nq = m * (m + 1) // 2
                w_u[:, qbase:qbase + nq] += wt * w[:, m:m + nq]
        else:
            w_u[:, at[c["set"]]:at[c["set"]] + m] += wt * w[:, :m]
        b_u += wt * b
    return w_u, b_u


def fit_stack(sets: dict, y: np.ndarray, top: int = TOP, total: str = "one", splits=None) -> dict:
    """The stacked model of targets ``y`` (p, k) over the candidates of ``sets`` (module docstring).

    Returns ``{"w", "b"}`` (the map on the union), ``"layout"`` (:func:`_layout`), ``"picks"`` (the
    candidates with positive weight, each with its ``"weight"``), ``"sse"`` (the out-of-fold SSE of
    the combination), ``"best_sse"`` (of the single best candidate) and ``"table"`` (every
    candidate's blocked-CV SSE)."""
    y = np.asarray(y, np.float64)
    if splits is None:
        splits = blocked_folds(y.shape[0])
        check_folds(splits, y.shape[0])
    cands = candidates(sets, y, splits, oof=True)
    if not cands:
        raise ValueError("stack: no candidate inputs")
    table = {f"{c['set']} {c['kind']} {c['inputs']}": c["sse"] for c in cands}
    ranked = sorted(cands, key=lambda c: c["sse"])[:int(top) if int(top) > 0 else None]
    w = stack_weights(np.stack([c["oof"] for c in ranked]), y, total)
    keep = np.flatnonzero(w > WEIGHT_FLOOR * max(float(w.max(initial=0.0)), 1e-300))
    if keep.size == 0:  # every weight 0 ("free" on targets no candidate predicts): the mean
        keep, w = np.array([0]), np.zeros(len(ranked))
    wk = w[keep] * (float(w.sum()) / max(float(w[keep].sum()), 1e-300))
    picks = [dict(ranked[i], weight=float(v)) for i, v in zip(keep, wk)]
    oof = sum(p["weight"] * p["oof"] for p in picks)
    layout = _layout(picks, {"global": np.asarray(sets["global"][0]).shape[1]})
    maps = [fit_selected(np.asarray(sets[p["set"]][0], np.float64), y, p["kind"], p["inputs"], p["penalty"])
            for p in picks]
    w_u, b_u = union_map(picks, maps, np.array([p["weight"] for p in picks]), layout)
    for p in picks:
        del p["oof"], p["folds"]
    return {"w": w_u, "b": b_u, "layout": layout, "picks": picks, "sse": float(((oof - y) ** 2).sum()),
            "best_sse": float(ranked[0]["sse"]), "table": table}
