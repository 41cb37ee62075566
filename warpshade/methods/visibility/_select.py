"""Model selection per cluster (``regressor = "auto"``): blocked cross-validation over pose segments of the training clip.

A cluster's candidates are ridge maps from the first ``m`` input-PCA components (``m`` in
:data:`INPUT_COUNTS`, at most the model's input components) to its PCA weights, on those inputs
(``"linear"``) or on them and their products (``"quadratic"``); each with every ridge penalty
of :data:`RIDGE_GRID`. The chosen one (:func:`select_ridge`: the simplest whose validation error is
within :data:`SELECT_MARGIN` of the least) is refitted on every training frame.

The validation is **blocked**: the training frames (in clip order) are cut into
:data:`BLOCKS` contiguous segments; each is held out in turn, and the model is fitted on the rest
less :data:`GAP` frames on either side of the segment (neighbouring frames are near-duplicates,
so a fold without the gap would measure interpolation between them). A held-out segment is a
stretch of motion the fit has not seen (a joint's sweep of the range-of-motion part, a motion of
the library): the error measures generalisation to novel poses, the question a held-out clip asks.

The error is the squared error of the predicted PCA weights, i.e. of the cluster's visibility
(the basis is orthonormal), summed over the folds; it is reported with the truncation of the PCA
added, relative to the training visibility (``cv_error``), like the other models' reports.

The penalties are multiples of the largest squared singular value of the candidate's centred
features over **every** training frame, in every fold and in the final refit alike: a penalty
means the same thing wherever it is used. (Relative to each fold's own training part, a fold whose
training frames share one pose -- a clip's range-of-motion part returns to the rest pose between
sweeps -- had a largest singular value of rounding size, and its "fit" divided ray noise by
rounding noise: a selection that changed between machines with the last bit of the inputs.)

Ties and near-ties break by a stated rule, so that the choice does not depend on the last bits of
the data: within a candidate, the largest penalty whose validation error is within
:data:`SELECT_MARGIN` of the candidate's least; across candidates, the fewest features among those
within :data:`SELECT_MARGIN` of the least error, then the larger penalty, then the lesser error,
then the candidates' order (input sets as given, linear before quadratic, fewer inputs first).
Validation errors that are not finite never select.

The quadratic products are ordered by their larger index (``x0 x0, x0 x1, x1 x1, x0 x2, ...``:
:func:`prefix_pairs`), so that the products of the first ``m`` inputs are the first
``m (m + 1) / 2`` of every longer list: all the clusters of a model share one activation vector.
"""

from __future__ import annotations

import numpy as np

__all__ = ["RIDGE_GRID", "BLOCKS", "GAP", "INPUT_COUNTS", "SELECT_MARGIN", "FOLD_TRAIN_MIN", "blocked_folds", "candidates",
           "choose", "fewest_frames", "margin_penalty", "penalty_scale", "prefix_pairs", "prefix_features", "select_ridge"]

#: Ridge penalties as multiples of the largest squared singular value of the centred inputs (the
#: grid of the 4-fold ridge fits of :mod:`._fit` and of the blocked selection here).
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
RULE = "margin"
RULES = ("margin", "min", "1se")
#: Relative margin within which two validation errors count as tied. 1e-3 of the summed squared
#: error (5e-4 of the RMS error) is far below the spread of a blocked-CV estimate over a few folds
#: (the choice among candidates that close is a coin toss the validation cannot call) and far
#: above the rounding differences between machines (about 1e-12 of the error once the penalties
#: share one scale), so the simpler candidate is taken there and the choice is the same on every host.
SELECT_MARGIN = 1e-3
#: Training frames every fold's training part holds at least (two: a centred fit has a direction).
FOLD_TRAIN_MIN = 2


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


def fewest_frames(blocks: int = BLOCKS, gap: int = GAP, per_fold: int = FOLD_TRAIN_MIN) -> int:
    """The fewest training frames for which every fold of :func:`blocked_folds` trains on at
    least ``per_fold`` frames (8 with the defaults: two blocks of four, less the gap)."""
    count = 2
    while True:
        if all(tr.size >= per_fold for tr, _ in blocked_folds(count, blocks, gap)):
            return count
        count += 1


def check_folds(splits, count: int, what: str = "blocked cross-validation") -> None:
    """ValueError naming the shortfall when a fold of ``what`` trains on fewer than
    :data:`FOLD_TRAIN_MIN` frames."""
    short = [int(tr.size) for tr, _ in splits if tr.size < FOLD_TRAIN_MIN]
    if short:
        raise ValueError(f"{what} of {count} training frame(s): a fold trains on {min(short)} "
                         f"frame(s) (at least {FOLD_TRAIN_MIN} each); give at least {fewest_frames()} training frames")


def penalty_scale(f: np.ndarray) -> float:
    """The unit of :data:`RIDGE_GRID` for features ``f`` (p, D): the largest squared singular value
    of the centred features over every training frame (module docstring)."""
    f = np.asarray(f, np.float64)
    if f.size == 0:
        return 1e-30
    s = np.linalg.svd(f - f.mean(0), compute_uv=False)
    return max(float(s[0] ** 2) if s.size else 0.0, 1e-30)


def _path_sse(f_tr, y_tr, f_va, y_va, predictions: bool = False, scale: float | None = None):
    """Validation SSE of the ridge map fitted on (f_tr, y_tr) for every penalty of RIDGE_GRID
    (multiples of ``scale``, :func:`penalty_scale` of the features over every training frame;
    None: of the fold's own training part); with ``predictions`` also the validation predictions
    of every penalty (grid, n, k)."""
    mx, my = f_tr.mean(0), y_tr.mean(0)
    u, s, vt = np.linalg.svd(f_tr - mx, full_matrices=False)
    a = u.T @ (y_tr - my)  # (r, k)
    b = (f_va - mx) @ vt.T  # (n, r)
    base = y_va - my
    smax = float(scale) if scale is not None else (float(s[0] ** 2) if s.size else 0.0)
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


def margin_penalty(sse: np.ndarray) -> int:
    """Index of the largest penalty whose SSE is within :data:`SELECT_MARGIN` of the least
    finite one (-1 when none is finite)."""
    finite = np.isfinite(sse)
    if not finite.any():
        return -1
    least = float(sse[finite].min())
    ok = np.flatnonzero(finite & (sse <= least * (1.0 + SELECT_MARGIN)))
    return int(ok.max())  # RIDGE_GRID ascends


def candidates(sets: dict, y: np.ndarray, splits=None, input_counts=INPUT_COUNTS, oof: bool = False) -> list[dict]:
    """Every candidate of :func:`select_ridge` at its penalty (the largest within
    :data:`SELECT_MARGIN` of its least validation error): ``{"set", "kind", "inputs", "penalty",
    "sse", "features", "folds"}`` (the summed and per-fold validation SSE), and with ``oof`` its
    out-of-fold predictions ``"oof"`` (p, k). A candidate with no finite validation error is left
    out; ValueError when a fold trains on too few frames (:func:`check_folds`)."""
    y = np.asarray(y, np.float64)
    finite_y = bool(np.isfinite(y).all())
    cands = []
    for name, (x, kinds) in sets.items():
        x = np.asarray(x, np.float64)
        if splits is None:
            splits = blocked_folds(x.shape[0], BLOCKS, GAP)
            check_folds(splits, x.shape[0])
        if x.shape[1] == 0:
            continue
        counts = sorted({m for m in input_counts if m <= x.shape[1]} | {x.shape[1]})
        for kind in kinds:
            for m in counts:
                feats = prefix_features(x, kind, m)
                if not (finite_y and np.isfinite(feats).all()):
                    continue  # its validation error is not finite: it never selects
                scale = penalty_scale(feats)
                paths = [_path_sse(feats[tr], y[tr], feats[va], y[va], oof, scale) for tr, va in splits]
                per = np.stack([p[0] for p in paths] if oof else paths)  # (folds, grid)
                g = margin_penalty(per.sum(0))
                if g < 0:
                    continue
                c = {"set": name, "kind": kind, "inputs": int(m), "penalty": float(RIDGE_GRID[g]),
                     "sse": float(per[:, g].sum()), "features": feats.shape[1], "folds": per[:, g]}
                if oof:  # each validation segment predicted by the map fitted without it (rows no fold validates: 0)
                    c["oof"] = np.zeros(y.shape)
                    for (_, va), (_, pr) in zip(splits, paths):
                        c["oof"][va] = pr[g]
                cands.append(c)
    return cands


def choose(cands: list[dict], rule: str = RULE) -> dict:
    """The candidate ``rule`` picks from ``cands`` (each with ``"sse"``, ``"features"``,
    ``"penalty"``, ``"folds"``; listed in the candidates' order): :func:`select_ridge`."""
    order = {id(c): i for i, c in enumerate(cands)}
    best = min(cands, key=lambda c: (c["sse"], order[id(c)]))
    if rule == "min":
        return best
    if rule == "1se":
        f = best["folds"].size
        bound = best["sse"] + float(np.std(best["folds"] * f, ddof=1) / np.sqrt(f))
    else:
        bound = best["sse"] * (1.0 + SELECT_MARGIN)
    return min((c for c in cands if c["sse"] <= bound), key=lambda c: (c["features"], -c["penalty"], c["sse"], order[id(c)]))


def select_ridge(sets: dict, y: np.ndarray, splits=None, rule: str = RULE, input_counts=INPUT_COUNTS) -> dict:
    """Blocked CV over (inputs, kind, count, penalty) for targets ``y`` (p, k).

    ``sets``: name -> ``(x (p, D), kinds)``, the candidate inputs (the global input PCA, a
    cluster's local inputs) and the kinds tried on them. ``rule``: ``"margin"`` takes the
    candidate with the fewest features among those whose summed validation SSE is within
    :data:`SELECT_MARGIN` of the least (then the larger penalty, the lesser SSE, the candidates'
    order: module docstring); ``"min"`` the least summed validation SSE (ties to the candidates'
    order); ``"1se"`` the fewest features among those within one standard error (over the folds)
    of the least (Hastie, Tibshirani and Friedman's one-standard-error rule: a simpler model the
    validation cannot tell apart from the best), with the same ties as ``"margin"``.
    ``input_counts``: the leading input counts tried (each set's full width is always tried).
    Returns ``{"set", "kind", "inputs", "penalty", "sse", "table"}``: the chosen candidate,
    its summed validation SSE, and the best SSE of every (set, kind, count) for the report.
    ValueError when no candidate has a finite validation error, or a fold trains on too few frames."""
    if rule not in RULES:
        raise ValueError(f"select: rule must be one of {RULES}, got {rule!r}")
    cands = candidates(sets, y, splits, input_counts)
    if not cands:
        raise ValueError("select: no candidate has a finite validation error (inputs or targets not finite, "
                         "or no inputs)")
    table = {f"{c['set']} {c['kind']} {c['inputs']}": c["sse"] for c in cands}
    best = choose(cands, rule)
    out = {k: best[k] for k in ("set", "kind", "inputs", "penalty", "sse")}
    out["table"] = table
    return out


def fit_selected(x: np.ndarray, y: np.ndarray, kind: str, m: int, penalty: float,
                 scale: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The ridge map of a selected candidate on every frame: ``(W (k, D_m), b (k,))``. ``penalty``
    in units of ``scale`` (None: :func:`penalty_scale` of these features, the selection's unit
    when ``x`` holds every training frame)."""
    f = prefix_features(x, kind, m)
    mx, my = f.mean(0), y.mean(0)
    u, s, vt = np.linalg.svd(f - mx, full_matrices=False)
    smax = float(scale) if scale is not None else (float(s[0] ** 2) if s.size else 0.0)
    den = s * s + penalty * max(smax, 1e-30)
    d = np.divide(s, den, out=np.zeros_like(s), where=den > 0.0)
    w = (vt.T * d) @ (u.T @ (y - my))  # (D_m, k)
    return w.T, my - mx @ w
