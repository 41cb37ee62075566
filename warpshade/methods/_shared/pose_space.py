"""The pose space of the data-driven methods (:mod:`warpshade.methods.datadriven`,
:mod:`warpshade.methods.visibility`): pose vectors (:mod:`.pose`) standardised and, optionally,
reduced by PCA, and how far new poses lie from the training poses.

* :func:`pose_space` -- each feature centred and divided by its training standard deviation
  (features constant over the training poses, :data:`CONSTANT_STD`, dropped and kept apart), with
  ``pca`` the principal directions sorted by variance: a :class:`PoseSpace`;
* :func:`novelty` -- the distance of poses to the nearest training pose, to the span of the
  training poses and past each feature's training range, in standardised units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CONSTANT_STD", "PoseSpace", "novelty", "pose_space"]

#: A feature whose training standard deviation is below this (radians, scene units) is constant.
CONSTANT_STD = 1e-6


@dataclass
class PoseSpace:
    """Standardisation and projection of pose vectors: ``z = (a - mean) @ weights``.

    Attributes:
        mean: training mean of each feature, (a,).
        scale: training standard deviation of each feature (1 where constant), (a,).
        active: features that vary over the training poses, (a,) bool.
        components: orthonormal directions in standardised feature space, (a, k); rows of
            inactive features are zero. The identity on the active features for the full model.
        variance: variance of the standardised training poses along each component, (k,).
        total_variance: their total variance (over every active feature).
        low, high: the training range of each feature (novelty, :func:`novelty`).
    """

    mean: np.ndarray
    scale: np.ndarray
    active: np.ndarray
    components: np.ndarray
    variance: np.ndarray
    total_variance: float
    low: np.ndarray
    high: np.ndarray

    @property
    def weights(self) -> np.ndarray:
        """``components / scale``: maps centred raw features to ``z``, (a, k)."""
        return self.components / self.scale[:, None]

    @property
    def size(self) -> int:
        return int(self.components.shape[1])

    def project(self, poses) -> np.ndarray:
        return (np.asarray(poses, np.float64) - self.mean) @ self.weights

    def truncated(self, k: int) -> "PoseSpace":
        return PoseSpace(self.mean, self.scale, self.active, self.components[:, :k], self.variance[:k],
                         self.total_variance, self.low, self.high)


def pose_space(poses: np.ndarray, pca: bool) -> PoseSpace:
    """Standardise ``poses`` (p, a); with ``pca``, principal directions sorted by variance.

    Raises:
        ValueError: fewer than two poses, non-finite values, or no feature that varies.
    """
    A = np.asarray(poses, np.float64)
    if A.ndim != 2 or A.shape[0] < 2:
        raise ValueError(f"data-driven fit needs at least 2 training poses, got {A.shape[0] if A.ndim == 2 else A.shape}")
    if not np.all(np.isfinite(A)):
        raise ValueError("training poses contain NaN or infinite values")
    mean = A.mean(0)
    std = A.std(0)
    active = std > CONSTANT_STD
    if not np.any(active):
        raise ValueError("no pose feature varies over the training poses: the transfer cannot be learnt from the pose")
    scale = np.where(active, std, 1.0)
    Z = np.where(active, (A - mean) / scale, 0.0)
    a = A.shape[1]
    idx = np.flatnonzero(active)
    if pca:
        _, s, wt = np.linalg.svd(Z[:, idx], full_matrices=False)
        comps = np.zeros((a, wt.shape[0]))
        comps[idx] = wt.T
        variance = s ** 2 / A.shape[0]
    else:
        comps = np.zeros((a, idx.size))
        comps[idx, np.arange(idx.size)] = 1.0
        variance = (Z[:, idx] ** 2).mean(0)
    return PoseSpace(mean, scale, active, comps, variance, float((Z ** 2).mean(0).sum()), A.min(0), A.max(0))


def novelty(space: PoseSpace, poses: np.ndarray, training: np.ndarray) -> dict:
    """How far poses lie from the training poses, in standardised units.

    Returns ``{"nearest": RMS distance per feature to the nearest training pose, "subspace":
    RMS distance from the span of the training poses' principal directions holding 99.9 % of
    their variance, "range": largest excess over a feature's training range in units of its
    training standard deviation, "constant": largest change of a feature that was constant in
    training (raw units)}``, each (n,) float64. 0 for a training pose.
    """
    poses = np.atleast_2d(np.asarray(poses, np.float64))
    act = space.active
    z = np.where(act, (poses - space.mean) / space.scale, 0.0)[:, act]
    zt = np.where(act, (np.asarray(training, np.float64) - space.mean) / space.scale, 0.0)[:, act]
    n_act = max(int(act.sum()), 1)
    d2 = (z ** 2).sum(1)[:, None] - 2 * z @ zt.T + (zt ** 2).sum(1)[None]
    nearest = np.sqrt(np.maximum(d2.min(1), 0.0) / n_act)
    _, s, wt = np.linalg.svd(zt - zt.mean(0), full_matrices=False)
    energy = np.cumsum(s ** 2) / max(float(np.sum(s ** 2)), 1e-300)
    k = int(np.searchsorted(energy, 0.999) + 1)
    w = wt[:k]
    zc = z - zt.mean(0)
    off = zc - (zc @ w.T) @ w
    subspace = np.sqrt((off ** 2).sum(1) / n_act)
    lo = np.where(act, (space.low - space.mean) / space.scale, 0.0)[act]
    hi = np.where(act, (space.high - space.mean) / space.scale, 0.0)[act]
    excess = np.maximum(np.maximum(z - hi, lo - z), 0.0).max(1) if act.any() else np.zeros(len(poses))
    const = (np.abs(poses[:, ~act] - space.mean[~act]).max(1) if (~act).any() else np.zeros(len(poses)))
    return {"nearest": nearest, "subspace": subspace, "range": excess, "constant": const}
