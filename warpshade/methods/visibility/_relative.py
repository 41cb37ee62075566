"""Relative inputs of a cluster: where the other clusters are, seen from the cluster (``visibility.fit relative``).

A vertex's local visibility is the shape of the rest of the mesh as the vertex sees it, in its own
frame. For a cluster that moves nearly rigidly, that is set by where the nearby geometry sits in
the cluster's frame -- a function of the positions of the other parts relative to it, not of the
joint angles as such: the forearm's view of the torso depends on the shoulder and elbow
rotations only through the product of the chain between them, which a ridge map on joint angles
must learn from the training clip's particular combinations, while the torso's centroid in the
forearm's frame is nearly linear in what the forearm sees. These inputs need no skeleton: they are
read from the posed points (a skinned character, a point cache).

Per frame and cluster ``i`` (its rest points ``q``, posed points ``p``):

* its rigid motion: the rotation ``R_i`` and translation that best map the rest points onto the
  posed ones (least squares, Kabsch: ``R_i = V diag(1, 1, det(V U^T)) U^T`` from the SVD
  ``U S V^T`` of ``sum (q - q_bar)(p - p_bar)^T``), and its posed centroid ``c_i = p_bar``;
* its inputs (:data:`WIDTH` per neighbour plus :data:`EXTRA`): the centroids of its ``N`` nearest
  clusters (by rest centroid distance, nearest first) in its frame, ``R_i^T (c_j - c_i)``; then
  the world's second and third axes in its frame, ``R_i^T e_y`` and ``R_i^T e_z`` (its
  orientation, which sets where a ground plane and the sky are for either up axis), and its
  centroid ``c_i`` (its height above a ground).

The columns of cluster ``i`` are ``[i F, (i + 1) F)`` with ``F = 3 N + 9``; the nearest ``n < N``
neighbours' inputs are the first ``3 n`` of them, so a candidate of :mod:`._select` on ``n``
neighbours reads a prefix (:func:`candidate_columns`). :func:`relative_features_f64` is the
float64 mirror of :func:`warpshade.methods.visibility._kernels.cluster_rigid_kernel` and
:func:`~warpshade.methods.visibility._kernels.relative_features_kernel`; the tests compare the
rotation with SciPy's ``Rotation.align_vectors``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["COUNTS", "EXTRA", "WIDTH", "candidate_columns", "cluster_neighbours", "relative_features_f64",
           "rigid_f64"]

#: Inputs per neighbour (its centroid in the cluster's frame).
WIDTH = 3
#: Inputs after the neighbours': the world's e_y and e_z in the cluster's frame, its centroid.
EXTRA = 9
#: Neighbour counts the candidates use (those not above the model's ``relative``; it is always tried).
COUNTS = (4, 8)
#: A cluster whose second singular value (of the sum above) is below this fraction of its first
#: has points on a line (or one point), which fix no rotation: it gets the identity (and the
#: kernel agrees, instead of each returning an arbitrary rotation).
RANK_TOL = 1e-5


def width(count: int) -> int:
    """Inputs per cluster for ``count`` neighbours (0: none)."""
    return WIDTH * int(count) + EXTRA if count > 0 else 0


def cluster_neighbours(rest_points: np.ndarray, labels: np.ndarray, count: int) -> np.ndarray:
    """The ``count`` clusters nearest each cluster by rest centroid distance, nearest first, (K, n)
    int32 with ``n = min(count, K - 1)`` (ties broken by cluster index)."""
    labels = np.asarray(labels)
    kc = int(labels.max()) + 1
    rest = np.asarray(rest_points, np.float64)
    cent = np.stack([rest[labels == k].mean(0) for k in range(kc)])
    dist = np.linalg.norm(cent[:, None] - cent[None], axis=2)
    n = max(0, min(int(count), kc - 1))
    out = np.zeros((kc, n), np.int32)
    for k in range(kc):
        order = np.lexsort((np.arange(kc), dist[k]))
        out[k] = [j for j in order if j != k][:n]
    return out


def rigid_f64(points: np.ndarray, rest_points: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every cluster's rigid motion in every pose: rotations (T, K, 3, 3) and posed centroids (T, K, 3)
    (module docstring). A cluster whose points do not fix a rotation (fewer than three, or on a
    line: :data:`RANK_TOL`) gets the identity."""
    p = np.asarray(points, np.float64)
    if p.ndim == 2:
        p = p[None]
    rest = np.asarray(rest_points, np.float64)
    labels = np.asarray(labels)
    kc = int(labels.max()) + 1
    rots = np.empty((p.shape[0], kc, 3, 3))
    cents = np.empty((p.shape[0], kc, 3))
    for k in range(kc):
        rows = np.flatnonzero(labels == k)
        q = rest[rows] - rest[rows].mean(0)
        pc = p[:, rows].mean(1)
        h = np.einsum("ni,tnj->tij", q, p[:, rows] - pc[:, None])
        u, s, vt = np.linalg.svd(h)
        v = np.swapaxes(vt, 1, 2)
        d = np.sign(np.linalg.det(v @ np.swapaxes(u, 1, 2)))
        d[d == 0.0] = 1.0
        v[:, :, 2] *= d[:, None]
        r = v @ np.swapaxes(u, 1, 2)
        r[s[:, 1] <= RANK_TOL * s[:, 0]] = np.eye(3)
        rots[:, k] = r
        cents[:, k] = pc
    return rots, cents


def relative_features_f64(points: np.ndarray, rest_points: np.ndarray, labels: np.ndarray,
                          neighbours: np.ndarray) -> np.ndarray:
    """The relative inputs of every cluster (module docstring), (T, K F) float64."""
    rots, cents = rigid_f64(points, rest_points, labels)
    nb = np.asarray(neighbours, np.int64)
    t, kc = cents.shape[:2]
    rel = np.einsum("tkji,tknj->tkni", rots, cents[:, nb] - cents[:, :, None])  # R_k^T (c_j - c_k)
    axes = np.swapaxes(rots, 2, 3)[..., 1:]  # R^T e_y, R^T e_z: the columns 1, 2 of R^T
    out = np.concatenate([rel.reshape(t, kc, -1), np.swapaxes(axes, 2, 3).reshape(t, kc, 6), cents], axis=2)
    return out.reshape(t, -1)


def candidate_columns(cluster: int, count: int, available: int, base: int) -> np.ndarray:
    """Columns of cluster ``cluster``'s inputs on its ``count`` nearest neighbours, when the model
    stores ``available`` neighbours per cluster from column ``base`` on."""
    f = width(available)
    start = base + cluster * f
    return np.concatenate([np.arange(start, start + WIDTH * count),
                           np.arange(start + WIDTH * available, start + f)]).astype(np.int64)
