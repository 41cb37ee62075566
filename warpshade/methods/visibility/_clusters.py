"""As-rigid-as-possible clusters of a mesh and their temporally coherent tangent frames.

Clusters (sec. 5.1 of the paper): vertices that move together share a local frame and a model.

* Skinned meshes: **mean shift** on the per-vertex skinning weights (a flat kernel of radius
  ``bandwidth`` in weight space, every vertex a seed, modes closer than half the bandwidth
  merged), so each cluster is a set of vertices driven by the same blend of joints.
* Meshes that are not skinned (the ground, props): mean shift on rest positions, with the
  bandwidth as a fraction of the mesh's extent.
* Point-cached meshes (cloth): labels from :mod:`warpshade.methods.visibility._cloth` (triangles
  grouped by their rotation sequences) passed in as ``labels``.

Clusters smaller than ``min_size`` vertices are merged into the nearest cluster of the same mesh
(their mode distance), so that no cluster is too small to fit; a mesh smaller than ``min_size``
is one cluster.

Cluster frames. In the rest pose each cluster gets its centroid ``m`` and principal directions
``a1, a2`` (PCA of its rest points); vertex ``i`` of the cluster gets the weights
``w_k,i = (p_i - m) . a_k / sum_j ((p_j - m) . a_k)^2``. In any pose, the cluster's directions
are the least-squares images of ``a_k`` under the deformation, ``A_k = sum_i w_k,i p_i(t)``
(exact for a rigid motion, smooth under any deformation: temporally coherent), and each vertex's
tangent is ``A_1`` projected into its tangent plane, blended toward the projection of ``A_2``
where ``A_1`` is nearly along the normal::

    t_raw = P_n(A_1 / |A_1|),   a = (1 - |t_raw| / BLEND)^2 (0 above BLEND)
    t     = normalise(P_n(t_raw + a * BLEND * A_2 / |A_2|)),   b = n x t

rows ``(t, b, n)`` (world -> local), the convention of :mod:`warpshade.geometry._frames`. Every
normalisation is guarded (a collapsed cluster keeps its rest directions, a degenerate tangent
falls back to the branchless basis of ``n``). :func:`cluster_frames_f64` is the float64 mirror
of :func:`warpshade.methods.visibility._kernels.cluster_axes_kernel` and ``cluster_frames_kernel``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["BLEND", "ClusterFrames"]

#: Below this |P_n(A_1)| the tangent blends toward the second cluster direction.
BLEND = 0.25
#: Mean-shift iterations at most, and the shift below which a seed has converged (bandwidths).
MEAN_SHIFT_ITERATIONS = 100
MEAN_SHIFT_TOLERANCE = 1e-4


def mean_shift(x: np.ndarray, bandwidth: float) -> tuple[np.ndarray, np.ndarray]:
    """Flat-kernel mean shift of the points ``x`` (n, d): ``(labels (n,), modes (m, d))``.

    Every point is a seed; each moves to the mean of the points within ``bandwidth`` until it
    moves less than ``MEAN_SHIFT_TOLERANCE * bandwidth``; modes closer than ``bandwidth / 2``
    are merged (the one with more support first) and every point takes its seed's mode.
    """
    x = np.asarray(x, np.float64)
    if x.ndim != 2 or x.shape[0] == 0:
        raise ValueError(f"mean shift needs a non-empty (n, d) array, got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError("mean shift: the points contain NaN or infinite values")
    if not bandwidth > 0:
        raise ValueError(f"mean shift: bandwidth must be positive, got {bandwidth}")
    tree = cKDTree(x)
    seeds, inverse = np.unique(np.round(x, 9), axis=0, return_inverse=True)
    inverse = np.asarray(inverse).reshape(-1)
    pos = seeds.copy()
    active = np.ones(len(pos), bool)
    for _ in range(MEAN_SHIFT_ITERATIONS):
        if not active.any():
            break
        ids = np.flatnonzero(active)
        for i, nb in zip(ids, tree.query_ball_point(pos[ids], bandwidth)):
            new = x[nb].mean(0) if nb else pos[i]
            if np.linalg.norm(new - pos[i]) < MEAN_SHIFT_TOLERANCE * bandwidth:
                active[i] = False
            pos[i] = new
    support = np.array([len(nb) for nb in tree.query_ball_point(pos, bandwidth)])
    order = np.argsort(-support, kind="stable")
    modes: list[np.ndarray] = []
    mode_of = np.empty(len(pos), np.int64)
    for i in order:
        for m, mode in enumerate(modes):
            if np.linalg.norm(pos[i] - mode) < 0.5 * bandwidth:
                mode_of[i] = m
                break
        else:
            mode_of[i] = len(modes)
            modes.append(pos[i])
    return mode_of[inverse], np.asarray(modes)


def _merge_small(labels: np.ndarray, feats: np.ndarray, min_size: int) -> np.ndarray:
    """Clusters under ``min_size`` members merged into the cluster of nearest centre (in ``feats``)."""
    labels = labels.copy()
    while True:
        ids, counts = np.unique(labels, return_counts=True)
        if ids.size <= 1 or counts.min() >= min_size:
            break
        small = ids[np.argmin(counts)]
        centres = {i: feats[labels == i].mean(0) for i in ids}
        others = [i for i in ids if i != small]
        target = min(others, key=lambda i: float(np.linalg.norm(centres[i] - centres[small])))
        labels[labels == small] = target
    return np.unique(labels, return_inverse=True)[1].reshape(-1)


def cluster_vertices(skin_weights: np.ndarray, rest: np.ndarray, mesh_ids: np.ndarray, bandwidth: float = 0.3,
                     static_bandwidth: float = 0.35, min_size: int = 8, labels: np.ndarray | None = None) -> np.ndarray:
    """Cluster label of every vertex, (V,) int32, clusters never spanning two meshes.

    Args:
        skin_weights: dense skinning weights (V, J) (rows of meshes that are not skinned: zero).
        rest: rest positions (V, 3).
        mesh_ids: the mesh of each vertex (V,).
        bandwidth: mean-shift radius in skinning-weight space.
        static_bandwidth: mean-shift radius for meshes without skin, as a fraction of the mesh's
            largest extent.
        min_size: smallest cluster kept (smaller ones are merged).
        labels: given labels (V,) for the meshes without skin (e.g. cloth triangles grouped by
            rotation sequences); None: mean shift on positions.
    """
    w = np.asarray(skin_weights, np.float64)
    rest = np.asarray(rest, np.float64)
    mesh_ids = np.asarray(mesh_ids).reshape(-1)
    out = np.empty(mesh_ids.shape[0], np.int32)
    base = 0
    for m in np.unique(mesh_ids):
        rows = np.flatnonzero(mesh_ids == m)
        skinned = np.abs(w[rows]).sum(1).max() > 0
        if labels is not None and not skinned:
            lab = np.unique(np.asarray(labels)[rows], return_inverse=True)[1].reshape(-1)
            feats = rest[rows]
        elif skinned:
            feats = w[rows]
            lab, _ = mean_shift(feats, bandwidth)
        else:
            feats = rest[rows]
            extent = float(np.ptp(feats, axis=0).max()) if rows.size > 1 else 1.0
            lab, _ = mean_shift(feats, static_bandwidth * max(extent, 1e-12))
        if rows.size >= min_size:
            lab = _merge_small(lab, feats, min_size)
        else:
            lab = np.zeros(rows.size, np.int64)
        out[rows] = lab + base
        base += int(lab.max()) + 1
    return out


@dataclass
class ClusterFrames:
    """The rest-pose rule of the cluster frames.

    Attributes:
        labels: cluster of each vertex, (V,).
        order: vertices sorted by cluster, (V,); ``offsets`` (K + 1,) delimit each cluster's run.
        weights: ``(w_1, w_2)`` of each vertex in ``order``, (V, 2).
        rest_axes: ``a_1, a_2`` per cluster, (K, 2, 3) (kept where a cluster collapses).
    """

    labels: np.ndarray
    order: np.ndarray
    offsets: np.ndarray
    weights: np.ndarray
    rest_axes: np.ndarray

    @property
    def cluster_count(self) -> int:
        return int(self.offsets.shape[0] - 1)


def cluster_frame_rule(rest: np.ndarray, labels: np.ndarray) -> ClusterFrames:
    """The rest-pose weights and directions of every cluster (module docstring)."""
    rest = np.asarray(rest, np.float64)
    labels = np.asarray(labels, np.int64).reshape(-1)
    k = int(labels.max()) + 1 if labels.size else 0
    order = np.argsort(labels, kind="stable")
    counts = np.bincount(labels, minlength=k)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    weights = np.zeros((labels.size, 2))
    axes = np.zeros((k, 2, 3))
    for c in range(k):
        rows = order[offsets[c]:offsets[c + 1]]
        p = rest[rows] - rest[rows].mean(0)
        _, s, vt = np.linalg.svd(p, full_matrices=True) if rows.size > 1 else (None, np.zeros(0), np.eye(3))
        a = vt[:2]
        if np.linalg.matrix_rank(a) < 2:
            a = np.eye(3)[:2]
        axes[c] = a
        for j in range(2):
            coef = p @ a[j]
            den = float(coef @ coef)
            weights[offsets[c]:offsets[c + 1], j] = coef / den if den > 1e-20 * max(1.0, float((p * p).sum())) else 0.0
    return ClusterFrames(labels.astype(np.int32), order.astype(np.int32), offsets.astype(np.int32), weights, axes)


def _normalise(v: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 1e-12, v / np.maximum(n, 1e-300), fallback)


def cluster_frames_f64(points: np.ndarray, normals: np.ndarray, rule: ClusterFrames) -> np.ndarray:
    """Float64 mirror of the cluster frames of one pose, (V, 3, 3) rows (t, b, n)."""
    from ...geometry._frames import _onb_tangent

    p = np.asarray(points, np.float64)
    n = _normalise(np.asarray(normals, np.float64), np.array([0.0, 0.0, 1.0]))
    k = rule.cluster_count
    axes = np.zeros((k, 2, 3))
    sorted_points = p[rule.order]
    for j in range(2):
        contrib = rule.weights[:, j:j + 1] * sorted_points
        sums = np.add.reduceat(contrib, rule.offsets[:-1], axis=0) if k else np.zeros((0, 3))
        sums[np.diff(rule.offsets) == 0] = 0.0
        axes[:, j] = _normalise(sums, rule.rest_axes[:, j])
    a1, a2 = axes[rule.labels, 0], axes[rule.labels, 1]

    def project(v):
        return v - np.sum(v * n, axis=1, keepdims=True) * n

    t_raw = project(a1)
    length = np.linalg.norm(t_raw, axis=1, keepdims=True)
    blend = np.clip(1.0 - length / BLEND, 0.0, 1.0) ** 2
    t = project(t_raw + blend * BLEND * a2)
    t = _normalise(t, _onb_tangent(n))
    b = np.cross(n, t)
    return np.stack([t, b, n], axis=1)
