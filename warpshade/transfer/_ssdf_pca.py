"""PCA compression of SSDF maps (Wang et al. 2009, eq. 24): :class:`SSDFModel` (mean, principal
maps, per-vertex coefficients, the error curve) and :func:`compress_ssdf`, the term count
from an RMS error budget in radians. The maps come from :func:`._ssdf.bake_ssdf`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ._raytrace import receiver_indices

__all__ = [
    "PCA_EXACT_MAX_ENTRIES",
    "PCA_OVERSAMPLE",
    "PCA_POWER_ITERATIONS",
    "as_maps",
]

#: Randomised SVD above this many matrix entries (V * R^2), exact SVD below. Measured on two CPU
#: cores (``benchmarks/bench_ssdf.py``): 64 x 64^2 maps, exact 2.6 s vs randomised 4.6 s;
#: 512 x 128^2 maps, exact 22 s vs randomised 11 s (error curves equal to 4e-7 rad).
PCA_EXACT_MAX_ENTRIES = 1 << 22
#: Oversampling and power iterations of the randomised SVD (Halko et al. 2011).
PCA_OVERSAMPLE = 16
PCA_POWER_ITERATIONS = 4


@dataclass
class SSDFModel:
    """PCA-compressed SSDFs of a set of vertices (eq. 24).

    Attributes:
        mean: mean map, shape (R*R,), float32, radians, flat texel ``ia * R + ib``.
        basis: orthonormal principal maps, shape (N, R*R), float32 (rows).
        coeffs: per-vertex coefficients, shape (V, N), float32 (rows in the order of the maps).
        resolution: map side R.
        error_curve: RMS reconstruction error (radians, over all texels and vertices, float64
            basis) with ``n + 1`` terms at index n, shape (max_terms,), float64, non-increasing.
        error_budget: the RMS budget N was chosen for (radians).
    """

    mean: np.ndarray
    basis: np.ndarray
    coeffs: np.ndarray
    resolution: int
    error_curve: np.ndarray
    error_budget: float = field(default=float("nan"))

    @property
    def terms(self) -> int:
        return int(self.basis.shape[0])

    @property
    def vertex_count(self) -> int:
        return int(self.coeffs.shape[0])

    @property
    def budget_met(self) -> bool:
        return bool(self.error_curve[self.terms - 1] <= self.error_budget)

    @property
    def rms_error(self) -> float:
        """RMS error of the chosen term count (radians)."""
        return float(self.error_curve[self.terms - 1])

    def arrays(self) -> dict:
        """The artifact arrays (what a cache stores)."""
        return {
            "mean": self.mean,
            "basis": self.basis,
            "coeffs": self.coeffs,
            "resolution": np.asarray(self.resolution, np.int64),
            "error_curve": self.error_curve,
            "error_budget": np.asarray(self.error_budget, np.float64),
        }

    @classmethod
    def from_arrays(cls, arrays: dict, vertex_count: int | None = None) -> "SSDFModel":
        """Rebuild from :meth:`arrays`; raises ValueError naming the array for anything that is not
        one: a missing array, wrong shape or dtype, a non-finite value."""
        names = ("mean", "basis", "coeffs", "resolution", "error_curve")
        missing = [n for n in names if n not in arrays]
        if missing:
            raise ValueError(f"ssdf: model arrays lack {missing}")
        r = np.asarray(arrays["resolution"])
        if r.shape != () or not np.issubdtype(r.dtype, np.integer) or int(r) < 2:
            raise ValueError(f"ssdf: resolution must be an integer scalar >= 2, got {r!r}")
        r = int(r)
        texels = r * r
        mean, basis, coeffs = (np.asarray(arrays[n]) for n in ("mean", "basis", "coeffs"))
        curve = np.asarray(arrays["error_curve"])
        for name, a, ndim in (("mean", mean, 1), ("basis", basis, 2), ("coeffs", coeffs, 2)):
            if a.dtype != np.float32 or a.ndim != ndim:
                raise ValueError(f"ssdf: {name} must be a float32 array of {ndim} dims, got {a.dtype} {a.shape}")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"ssdf: {name} contains NaN or infinite values")
        if mean.shape != (texels,):
            raise ValueError(f"ssdf: mean has shape {mean.shape}, resolution {r} needs ({texels},)")
        if basis.shape[1] != texels or basis.shape[0] < 1:
            raise ValueError(f"ssdf: basis has shape {basis.shape}, expected (N >= 1, {texels})")
        if coeffs.shape[1] != basis.shape[0]:
            raise ValueError(f"ssdf: coeffs has shape {coeffs.shape}, expected (V, {basis.shape[0]})")
        if vertex_count is not None and coeffs.shape[0] != vertex_count:
            raise ValueError(f"ssdf: coeffs has {coeffs.shape[0]} rows for {vertex_count} vertices")
        if curve.dtype != np.float64 or curve.ndim != 1 or curve.shape[0] < basis.shape[0]:
            raise ValueError(f"ssdf: error_curve must be float64 of length >= {basis.shape[0]}, got {curve.dtype} {curve.shape}")
        if not np.all(np.isfinite(curve)) or np.any(curve < 0.0):
            raise ValueError("ssdf: error_curve must be finite and >= 0")
        budget = float(np.asarray(arrays.get("error_budget", np.nan)))
        return cls(mean, basis, coeffs, r, curve, budget)

    def reconstruct(self, vertices=None) -> np.ndarray:
        """Decompressed maps (float64 arithmetic), shape (V', R, R), float64, radians (not clamped).

        Args:
            vertices: rows of :attr:`coeffs` (None: all).
        """
        c = self.coeffs if vertices is None else self.coeffs[receiver_indices(vertices, self.vertex_count)]
        maps = self.mean.astype(np.float64) + c.astype(np.float64) @ self.basis.astype(np.float64)
        return maps.reshape(-1, self.resolution, self.resolution)


def as_maps(maps) -> np.ndarray:
    """SSDF maps (V, R, R) as an array, checked: square, R >= 2, V >= 1, finite floats (ValueError
    otherwise)."""
    m = np.asarray(maps)
    if m.ndim != 3 or m.shape[1] != m.shape[2] or m.shape[1] < 2 or m.shape[0] < 1:
        raise ValueError(f"ssdf: maps must have shape (V >= 1, R, R) with R >= 2, got {m.shape}")
    if not np.issubdtype(m.dtype, np.floating) or not np.all(np.isfinite(m)):
        raise ValueError("ssdf: maps must be finite floating-point values")
    return m


def _principal_rows(xc: np.ndarray, k: int, method: str, seed: int) -> np.ndarray:
    """Orthonormal rows (k, T) spanning the leading principal directions of the centred xc (V, T)."""
    if method == "exact":
        _, _, vt = np.linalg.svd(xc, full_matrices=False)
        return vt[:k]
    # randomised range finder with power iterations on the row space (Halko et al. 2011, alg. 4.4)
    rng = np.random.default_rng(seed)
    width = min(k + PCA_OVERSAMPLE, min(xc.shape))
    y, _ = np.linalg.qr(xc @ rng.standard_normal((xc.shape[1], width)))
    for _ in range(PCA_POWER_ITERATIONS):
        z, _ = np.linalg.qr(xc.T @ y)
        y, _ = np.linalg.qr(xc @ z)
    _, _, vt = np.linalg.svd(y.T @ xc, full_matrices=False)
    return vt[:k]


def compress_ssdf(maps, error_budget: float = 0.02, max_terms: int = 64, method: str = "auto",
                  seed: int = 0) -> SSDFModel:
    """PCA of SSDF maps with the term count chosen from an RMS error budget.

    The error with n terms is the exact RMS residual (radians) of projecting the centred maps on
    the first n principal rows, over all texels and vertices:
    ``sqrt((|X - mean|_F^2 - sum_{j<n} |(X - mean) b_j|^2) / (V R^2))``. N is the smallest n in
    1..max_terms within the budget, or max_terms when none is (:attr:`SSDFModel.budget_met`).

    Args:
        maps: (V, R, R) float SSDFs (radians), e.g. :func:`bake_ssdf`.
        error_budget: RMS budget in radians (> 0).
        max_terms: the most terms considered (>= 1); the curve has this length (beyond the rank,
            min(V, R^2), it stays at the last value).
        method: ``"exact"`` (numpy SVD), ``"randomized"`` (range finder, ``seed``) or ``"auto"``
            (exact up to :data:`PCA_EXACT_MAX_ENTRIES` matrix entries).
        seed: random seed of the randomised method.

    Returns:
        :class:`SSDFModel`.
    """
    m = as_maps(maps)
    budget = float(error_budget) if isinstance(error_budget, (int, float, np.floating, np.integer)) else float("nan")
    if not math.isfinite(budget) or budget <= 0.0:
        raise ValueError(f"ssdf: error_budget must be a finite number > 0 (radians), got {error_budget!r}")
    if isinstance(max_terms, bool) or not isinstance(max_terms, (int, np.integer)) or int(max_terms) < 1:
        raise ValueError(f"ssdf: max_terms must be an integer >= 1, got {max_terms!r}")
    if method not in ("auto", "exact", "randomized"):
        raise ValueError(f"ssdf: method must be 'auto', 'exact' or 'randomized', got {method!r}")
    max_terms = int(max_terms)
    v, r = m.shape[0], m.shape[1]
    x = m.reshape(v, r * r).astype(np.float64)
    mean = x.mean(axis=0)
    xc = x - mean
    k = min(max_terms, v, r * r)
    if method == "auto":
        method = "exact" if x.size <= PCA_EXACT_MAX_ENTRIES else "randomized"
    rows = _principal_rows(xc, k, method, seed)
    rows, _ = np.linalg.qr(rows.T)  # re-orthonormalise (exact projection residuals below)
    rows = rows.T
    proj = xc @ rows.T  # (V, k)
    total = float(np.sum(xc * xc))
    residual = np.maximum(total - np.cumsum(np.sum(proj * proj, axis=0)), 0.0)
    curve = np.sqrt(residual / x.size)
    curve = np.concatenate([curve, np.full(max_terms - k, curve[-1])])
    curve = np.minimum.accumulate(curve)  # guard against round-off upticks
    within = np.flatnonzero(curve[:k] <= budget)
    terms = int(within[0]) + 1 if within.size else k
    return SSDFModel(mean=mean.astype(np.float32), basis=rows[:terms].astype(np.float32),
                     coeffs=proj[:, :terms].astype(np.float32), resolution=r, error_curve=curve, error_budget=budget)
