"""Local inputs of a cluster: the joint rotations of the joints near it (``regressor = "auto"``).

A skinned cluster's visibility depends mostly on the joints that move it and their neighbours in
the skeleton (the locality of data-driven PRT, James and Fatahalian's and Nowrouzezahrai et al.'s
observation that a vertex's transfer depends on nearby joints); a map from every joint's rotation
learns spurious dependences on far joints from a training clip, which a held-out clip with
other combinations of far joints then pays for. The candidates of :mod:`._select` include, per
cluster, maps from the rotations of

* ring 0: the joints skinning the cluster (those with at least :data:`SHARE` of its skinning weight),
* ring r: those and every joint within ``r`` steps of them in the skeleton,

where two joints are neighbours when some vertex is skinned to both (above :data:`BLEND_WEIGHT`):
the skeleton's edges as the skin sees them (the pose vectors carry no parent indices). Each
candidate's inputs are the PCA of its joints' standardised pose features to the model's input
budget, each divided by its standard deviation, as the global inputs
(:func:`warpshade.methods.visibility._model.input_space`). Unskinned clusters (the ground) take
the global inputs only.
"""

from __future__ import annotations

import numpy as np

from .._shared.pose import PARAMETERISATIONS, ROOT_FEATURES

__all__ = ["BLEND_WEIGHT", "RINGS", "SHARE", "cluster_joints", "joint_columns", "local_inputs"]

#: A joint skins a cluster when it holds at least this share of the cluster's skinning weight.
SHARE = 0.02
#: Two joints are neighbours when a vertex has at least this weight on each.
BLEND_WEIGHT = 0.05
#: Skeleton rings the candidates use.
RINGS = (0, 1, 2)
#: Pose features with a smaller standard deviation are constant (as the global input PCA).
CONSTANT_STD = 1e-8


def joint_columns(root_mask: np.ndarray, kind: str, root: str) -> list[np.ndarray]:
    """Columns of every joint (skin-weight order) in the pose vectors the fit reads.

    ``root_mask``: 1 on the root features of the full (``root = "include"``) layout, the
    ``root_<kind>`` array of ``visibility.data``; a root's 6 numbers come first in its skeleton
    (UsdSkel lists parents before children). With ``root = "exclude"`` a root has no columns.
    ValueError when the mask does not split into joints.
    """
    mask = np.asarray(root_mask).reshape(-1).astype(bool)
    width = PARAMETERISATIONS[kind]
    keep = np.cumsum(~mask) - 1 if root == "exclude" else np.arange(mask.size)
    out, pos = [], 0
    while pos < mask.size:
        w = ROOT_FEATURES if mask[pos] else width
        if pos + w > mask.size or np.any(mask[pos:pos + w] != mask[pos]):
            raise ValueError(f"pose vectors of {mask.size} numbers do not split into joints of {width} ({kind}) "
                             f"and roots of {ROOT_FEATURES}")
        cols = np.arange(pos, pos + w)
        out.append(np.zeros(0, np.int64) if (root == "exclude" and mask[pos]) else keep[cols].astype(np.int64))
        pos += w
    return out


def cluster_joints(skin_weights: np.ndarray, labels: np.ndarray, cluster: int, ring: int) -> np.ndarray | None:
    """Joints of a cluster's ring (module docstring), or None for an unskinned cluster."""
    w = np.asarray(skin_weights, np.float64)
    rows = np.flatnonzero(np.asarray(labels) == cluster)
    total = w[rows].sum(0)
    if rows.size == 0 or total.sum() <= 0.0:
        return None
    joints = total / total.sum() >= SHARE
    b = (w >= BLEND_WEIGHT).astype(np.float64)
    adjacent = (b.T @ b) > 0.0
    for _ in range(ring):
        joints = joints | adjacent[joints].any(0)
    return np.flatnonzero(joints)


def local_inputs(poses: np.ndarray, columns: np.ndarray, variance: float, k_max: int) -> tuple[np.ndarray, np.ndarray]:
    """Inputs from some columns of the pose vectors: ``(W (a, m), x (p, m))`` with
    ``x = (poses - poses.mean(0)) @ W`` of unit variance, ``W`` zero outside ``columns``;
    ``m`` the fewest principal components holding ``variance`` (at most ``k_max``; 0 when
    nothing varies)."""
    a = np.asarray(poses, np.float64)
    cols = np.asarray(columns, np.int64)
    sub = a[:, cols] - a[:, cols].mean(0)
    std = sub.std(0)
    cols, sub, std = cols[std > CONSTANT_STD], sub[:, std > CONSTANT_STD], std[std > CONSTANT_STD]
    w = np.zeros((a.shape[1], 0))
    if cols.size == 0:
        return w, np.zeros((a.shape[0], 0))
    z = sub / std
    _, s, vt = np.linalg.svd(z, full_matrices=False)
    var = s ** 2 / a.shape[0]
    keep = var > 1e-12 * var[0]
    cum = np.cumsum(var[keep]) / var[keep].sum()
    m = int(min(np.searchsorted(cum, variance - 1e-12) + 1, k_max, int(keep.sum())))
    w = np.zeros((a.shape[1], m))
    w[cols] = (vt[:m].T / std[:, None]) / np.sqrt(var[:m])
    return w, (a - a.mean(0)) @ w
