"""Model selection per cluster (``model = "auto"``): blocked cross-validation over pose segments of the training clip.

A cluster's candidates are ridge maps from the first ``m`` input-PCA components (``m`` in
:data:`INPUT_COUNTS`, at most the model's input components) to its PCA weights, on those inputs
(``"linear"``) or on them and their products (``"quadratic"``); each with every ridge penalty
of :data:`RIDGE_GRID`. The one with the least validation error is refitted on every training frame.

The validation is **blocked**: the training frames (in clip order) are cut into
:data:`BLOCKS` contiguous segments; each is held out in turn, and the model is fitted on the rest
less :data:`GAP` frames on either side of the segment (neighbouring frames are near-duplicates,
so a fold without the gap would measure interpolation between them). A held-out segment is a
stretch of motion the fit has not seen (a joint's sweep of the range-of-motion part, a motion of
the library): the error measures generalisation to novel poses, the question a held-out clip asks.

The error is the squared error of the predicted PCA weights, i.e. of the cluster's visibility
(the basis is orthonormal), summed over the folds; it is reported with the truncation of the PCA
added, relative to the training visibility (``cv_error``), like the other models' reports.

The quadratic products are ordered by their larger index (``x0 x0, x0 x1, x1 x1, x0 x2, ...``:
:func:`prefix_pairs`), so that the products of the first ``m`` inputs are the first
``m (m + 1) / 2`` of every longer list: all the clusters of a model share one activation vector.
"""

from __future__ import annotations

import numpy as np

__all__ = ["RIDGE_GRID", "BLOCKS", "GAP", "INPUT_COUNTS", "blocked_folds", "candidates", "prefix_pairs", "prefix_features", "select_ridge"]

#: Ridge penalties as multiples of the largest squared singular value of the centred inputs (the
#: grid of the 4-fold ridge fits of :mod:`.fit` and of the blocked selection here).
RIDGE_GRID = np.logspace(-7.0, 0.0, 15)
#: Contiguous segments of the training frames held out in turn.
BLOCKS = 8
#: Training frames left out on either side of a held-out segment.
GAP = 2
#: Input-PCA components the candidates use (those not above the model's input components).
INPUT_COUNTS = (2, 4, 6, 8, 12, 16, 24)
#: Candidate kinds.
KINDS = ("linear", "quadratic")
#: How the candidate is chosen from the validation errors (:func:`select_ridge`).
RULE = "min"


def prefix_pairs(m: int) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``i <= j < m`` ordered by ``j`` then ``i`` (module docstring)."""
    j = np.concatenate([np.full(k + 1, k) for k in range(m)]).astype(np.int64) if m else np.zeros(0, np.int64)
    i = np.concatenate([np.arange(k + 1) for k in range(m)]).astype(np.int64) if m else np.zeros(0, np.int64)
    return i, j


def prefix_features(x: np.ndarray, kind: str, m: int) -> np.ndarray:
    """``x[:, :m]``, or with their products in :func:`prefix_pairs` order (``"quadratic"``)."""
    x = np.asarray(x, np.float64)[:, :m]
    if kind != "quadratic":
        return x
    i, j = prefix_pairs(m)
    return np.concatenate([x, x[:, i] * x[:, j]], axis=1)


def blocked_folds(count: int, blocks: int = BLOCKS, gap: int = GAP) -> list[tuple[np.ndarray, np.ndarray]]:
    """(train, validation) index pairs: each of ``blocks`` contiguous segments of ``range(count)``
    held out, ``gap`` indices either side of it left out of the training part."""
    blocks = max(2, min(blocks, count // 4))
    edges = np.linspace(0, count, blocks + 1).round().astype(int)
    idx = np.arange(count)
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        train = np.concatenate([idx[:max(a - gap, 0)], idx[min(b + gap, count):]])
        out.append((train, idx[a:b]))
    return out


def _path_sse(f_tr, y_tr, f_va, y_va, predictions: bool = False):
    """Validation SSE of the ridge map fitted on (f_tr, y_tr) for every penalty of RIDGE_GRID
    (relative to the largest squared singular value of the centred training features); with
    ``predictions`` also the validation predictions of every penalty (grid, n, k)."""
    mx, my = f_tr.mean(0), y_tr.mean(0)
    u, s, vt = np.linalg.svd(f_tr - mx, full_matrices=False)
    a = u.T @ (y_tr - my)  # (r, k)
    b = (f_va - mx) @ vt.T  # (n, r)
    base = y_va - my
    smax = float(s[0] ** 2) if s.size else 0.0
    out = np.empty(RIDGE_GRID.size)
    preds = np.empty((RIDGE_GRID.size,) + y_va.shape) if predictions else None
    for g, rel in enumerate(RIDGE_GRID):
        den = s * s + rel * max(smax, 1e-30)
        d = np.divide(s, den, out=np.zeros_like(s), where=den > 0.0)
        r = (b * d) @ a - base
        out[g] = float((r * r).sum())
        if predictions:
            preds[g] = r + y_va
    return (out, preds) if predictions else out


def candidates(sets: dict, y: np.ndarray, splits=None, input_counts=INPUT_COUNTS, oof: bool = False) -> list[dict]:
    """Every candidate of :func:`select_ridge` at its best penalty: ``{"set", "kind", "inputs",
    "penalty", "sse", "features", "folds"}`` (the summed and per-fold validation SSE), and with
    ``oof`` its out-of-fold predictions ``"oof"`` (p, k)."""
    y = np.asarray(y, np.float64)
    cands = []
    for name, (x, kinds) in sets.items():
        x = np.asarray(x, np.float64)
        if splits is None:
            splits = blocked_folds(x.shape[0], BLOCKS, GAP)
        if x.shape[1] == 0:
            continue
        counts = sorted({m for m in input_counts if m <= x.shape[1]} | {x.shape[1]})
        for kind in kinds:
            for m in counts:
                feats = prefix_features(x, kind, m)
                paths = [_path_sse(feats[tr], y[tr], feats[va], y[va], oof) for tr, va in splits]
                per = np.stack([p[0] for p in paths] if oof else paths)  # (folds, grid)
                g = int(np.argmin(per.sum(0)))
                c = {"set": name, "kind": kind, "inputs": int(m), "penalty": float(RIDGE_GRID[g]),
                     "sse": float(per[:, g].sum()), "features": feats.shape[1], "folds": per[:, g]}
                if oof:  # each validation segment predicted by the map fitted without it (rows no fold validates: 0)
                    c["oof"] = np.zeros(y.shape)
                    for (_, va), (_, pr) in zip(splits, paths):
                        c["oof"][va] = pr[g]
                cands.append(c)
    return cands


def select_ridge(sets: dict, y: np.ndarray, splits=None, rule: str = RULE, input_counts=INPUT_COUNTS) -> dict:
    """Blocked CV over (inputs, kind, count, penalty) for targets ``y`` (p, k).

    ``sets``: name -> ``(x (p, D), kinds)``, the candidate inputs (the global input PCA, a
    cluster's local inputs) and the kinds tried on them. ``rule``: ``"min"`` takes the least
    summed validation SSE; ``"1se"`` the candidate with the fewest features among those whose
    SSE is within one standard error (over the folds) of the least (Hastie, Tibshirani and
    Friedman's one-standard-error rule: a simpler model the validation cannot tell apart from the
    best). ``input_counts``: the leading input counts tried (each set's full width is always tried).
    Returns ``{"set", "kind", "inputs", "penalty", "sse", "table"}``: the chosen candidate,
    its summed validation SSE, and the best SSE of every (set, kind, count) for the report."""
    cands = candidates(sets, y, splits, input_counts)
    table = {f"{c['set']} {c['kind']} {c['inputs']}": c["sse"] for c in cands}
    best = min(cands, key=lambda c: c["sse"])
    if rule == "1se":
        f = best["folds"].size
        se = float(np.std(best["folds"] * f, ddof=1) / np.sqrt(f))
        best = min((c for c in cands if c["sse"] <= best["sse"] + se), key=lambda c: (c["features"], c["sse"]))
    out = {k: best[k] for k in ("set", "kind", "inputs", "penalty", "sse")}
    out["table"] = table
    return out


def fit_selected(x: np.ndarray, y: np.ndarray, kind: str, m: int, penalty: float) -> tuple[np.ndarray, np.ndarray]:
    """The ridge map of a selected candidate on every frame: ``(W (k, D_m), b (k,))``."""
    f = prefix_features(x, kind, m)
    mx, my = f.mean(0), y.mean(0)
    u, s, vt = np.linalg.svd(f - mx, full_matrices=False)
    smax = float(s[0] ** 2) if s.size else 0.0
    den = s * s + penalty * max(smax, 1e-30)
    d = np.divide(s, den, out=np.zeros_like(s), where=den > 0.0)
    w = (vt.T * d) @ (u.T @ (y - my))  # (D_m, k)
    return w.T, my - mx @ w
