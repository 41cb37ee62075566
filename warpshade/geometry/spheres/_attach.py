"""Attachment coordinates of sphere centres to a mesh, float64 (geometry only).

How a fitted centre follows its deforming mesh:

* :func:`mvc_weights` -- mean value coordinates over the mesh vertices (:mod:`._mvc`), per closed
  component; a centre is then ``weights @ points`` on any deformed copy of the mesh;
* :func:`bone_coordinates` -- those coordinates pre-multiplied by per-vertex bone weights into a
  few (bone, weighted bind-space point) pairs, so that a linearly blend-skinned mesh moves the
  centre by its bones' matrices (exact when every bone is kept);
* :func:`skin_weight_coordinates` -- the alternative: linear blend skinning of the centre
  itself with the mean bone weights of the surface samples its sphere bounds;
* :func:`triangle_frame_attachment` -- for open (shell) meshes: the nearest triangle's
  barycentric point plus an offset fixed in that triangle's orthonormal frame
  (:func:`triangle_frame_points` evaluates it on a deformed mesh).

Matrices are row-vector (USD): a point maps as ``[p, 1] @ M``.
"""

from __future__ import annotations

import numpy as np

from . import _mvc as _mvc

__all__ = [
    "bone_coordinates",
    "closest_on_triangles",
    "mvc_weights",
    "skin_weight_coordinates",
    "triangle_frame_attachment",
    "triangle_frame_points",
    "triangle_frames",
]


def triangle_frames(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Rows (unit edge a->b, normal x edge, unit normal) per triangle, (n, 3, 3) float64."""
    e = b - a
    n = np.cross(e, c - a)
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    le = np.linalg.norm(e, axis=1, keepdims=True)
    ok = (ln[:, 0] > 1e-30) & (le[:, 0] > 1e-30)
    n = np.where(ok[:, None], n / np.maximum(ln, 1e-300), [0.0, 0.0, 1.0])
    e = np.where(ok[:, None], e / np.maximum(le, 1e-300), [1.0, 0.0, 0.0])
    return np.stack([e, np.cross(n, e), n], axis=1)


def triangle_frame_points(points, triangle, bary, local_offset) -> np.ndarray:
    """Evaluate :func:`triangle_frame_attachment` on a (deformed) copy of the mesh.

    Args:
        points: the mesh's vertices, (V, 3) float64.
        triangle: vertex indices of each centre's triangle, (S, 3) int.
        bary: barycentric coordinates in it, (S, 3); local_offset: offset in its frame, (S, 3).

    Returns:
        centres, (S, 3) float64, in the frame of ``points``.
    """
    a, b, c = (points[triangle[:, k]] for k in range(3))
    frames = triangle_frames(a, b, c)
    base = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:3] * c
    return base + np.einsum("si,sij->sj", local_offset, frames)


def closest_on_triangles(x: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest point of each triangle to a point (Ericson's region test), float64.

    Args:
        x: the query point per triangle, (n, 3); a, b, c: the triangles' corners, (n, 3) each.

    Returns:
        (closest points (n, 3), their barycentric coordinates (n, 3)).
    """
    ab, ac, ap = b - a, c - a, x - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = x - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = x - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    n = x.shape[0]
    bary = np.zeros((n, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = vb / denom
        w = vc / denom
        bary[:] = np.stack([1 - v - w, v, w], axis=1)
        # edge and vertex regions
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        regions = [
            ((d1 <= 0) & (d2 <= 0), np.stack([np.ones(n), np.zeros(n), np.zeros(n)], 1)),
            ((d3 >= 0) & (d4 <= d3), np.stack([np.zeros(n), np.ones(n), np.zeros(n)], 1)),
            ((d6 >= 0) & (d5 <= d6), np.stack([np.zeros(n), np.zeros(n), np.ones(n)], 1)),
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), np.stack([1 - t_ab, t_ab, np.zeros(n)], 1)),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), np.stack([1 - t_ac, np.zeros(n), t_ac], 1)),
            ((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), np.stack([np.zeros(n), 1 - t_bc, t_bc], 1)),
        ]
    done = np.zeros(n, dtype=bool)
    for mask, value in regions:
        m = mask & ~done
        bary[m] = value[m]
        done |= m
    bary = np.nan_to_num(bary, nan=1.0 / 3.0)
    return bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:3] * c, bary


def triangle_frame_attachment(points: np.ndarray, faces: np.ndarray, centres: np.ndarray) -> dict:
    """Each centre as a point of its nearest triangle plus an offset in that triangle's frame.

    Args:
        points: the mesh's vertices, (V, 3) float64; faces: its triangles, (F, 3) int.
        centres: sphere centres in the frame of ``points``, (S, 3).

    Returns:
        dict with ``triangle`` (S, 3) int32 vertex indices, ``bary`` (S, 3) and
        ``local_offset`` (S, 3) float64 (rows of :func:`triangle_frames` as the basis).
    """
    tri = np.zeros((centres.shape[0], 3), np.int32)
    bary = np.zeros((centres.shape[0], 3))
    offset = np.zeros((centres.shape[0], 3))
    a, b, c = (points[faces[:, k]] for k in range(3))
    for i, x in enumerate(centres):
        q, w = closest_on_triangles(np.broadcast_to(x, a.shape), a, b, c)
        f = int(np.argmin(np.linalg.norm(q - x, axis=1)))
        frame = triangle_frames(a[f : f + 1], b[f : f + 1], c[f : f + 1])[0]
        tri[i], bary[i], offset[i] = faces[f], w[f], frame @ (x - q[f])
    return {"triangle": tri, "bary": bary, "local_offset": offset}


def _representatives(solid) -> np.ndarray:
    """For each merged vertex, the first original vertex that maps to it."""
    _, first = np.unique(solid.merged_index, return_index=True)
    return first


def mvc_weights(solid, centres: np.ndarray, sphere_set=None) -> tuple[np.ndarray, np.ndarray]:
    """Mean value coordinates of each centre over the caller's vertices.

    On a mesh of several closed components each centre uses the component that holds most of
    its cluster's surface samples (``sphere_set`` given), so it moves with what it bounds.

    Args:
        solid: the closed :class:`~._fit.Solid` the spheres were fit to.
        centres: sphere centres in the frame of ``solid.points``, (S, 3).
        sphere_set: the :class:`~._core.SphereSet` of those centres, or None.

    Returns:
        (weights (S, V) float64 over ``solid.points``, each row summing to 1; the
        linear-precision error ``|sum_v w_v p_v - centre|`` per centre, (S,)).
    """
    vlabel = _mvc.vertex_components(solid.merged_faces, solid.merged_points.shape[0])
    comps = vlabel[solid.merged_faces[:, 0]]
    rep = _representatives(solid)
    dominant = [None] * centres.shape[0]
    if sphere_set is not None and np.unique(comps).size > 1:
        sample_comp = vlabel[solid.merged_index[solid.faces[sphere_set.sample_face, 0]]]
        for i in range(centres.shape[0]):
            own = sample_comp[sphere_set.sample_sphere == i]
            if own.size:
                dominant[i] = int(np.bincount(own).argmax())
    w = np.zeros((centres.shape[0], solid.points.shape[0]))
    err = np.zeros(centres.shape[0])
    for i, x in enumerate(centres):
        lam = _mvc.component_mvc(solid.merged_points, solid.merged_faces, x, comps, component=dominant[i])
        w[i, rep] = lam
        err[i] = float(np.linalg.norm(lam @ solid.merged_points - x))
    return w, err


def bone_coordinates(weights: np.ndarray, joint_indices, joint_weights, bind_points: np.ndarray, joint_count: int, max_bones: int) -> dict:
    """Pre-multiply per-vertex coordinates by skin weights: per sphere (bone, q_j, b_j).

    ``centre = sum_j [q_j, b_j] @ M_j`` with ``b_j = sum_v w_v W_vj`` and ``q_j = sum_v w_v W_vj
    p_v`` (bind-space points), exact for any joint matrices when every bone is kept. Only the
    ``max_bones`` bones of largest |b_j| are stored; each dropped bone's (q_j, b_j) is folded
    into the strongest kept bone, which keeps the fit-pose centre and the weight sum exact.

    Args:
        weights: per-vertex coordinates of each centre, (S, V) (:func:`mvc_weights`).
        joint_indices, joint_weights: per-vertex bone influences, (V, K) int / float.
        bind_points: the vertices in bind space, (V, 3) float64.
        joint_count: bones of the skeleton (J); max_bones: bones kept per centre (B).

    Returns:
        dict with ``joint_index`` (S, B) int32 (-1: unused), ``joint_point`` (S, B, 3) and
        ``joint_weight`` (S, B) float64.
    """
    idx = np.asarray(joint_indices, np.int64)
    wts = np.asarray(joint_weights, np.float64)
    s_count = weights.shape[0]
    b = np.zeros((s_count, joint_count))
    q = np.zeros((s_count, joint_count, 3))
    for k in range(idx.shape[1]):
        vw = weights * wts[None, :, k]  # (S, V)
        for j in np.unique(idx[:, k]):
            sel = idx[:, k] == j
            b[:, j] += vw[:, sel].sum(axis=1)
            q[:, j] += vw[:, sel] @ bind_points[sel]
    bones = min(max_bones, joint_count)
    order = np.argsort(-np.abs(b), axis=1)
    keep = order[:, :bones]
    rows = np.arange(s_count)[:, None]
    jb = b[rows, keep].copy()
    jq = q[rows, keep].copy()
    dropped = order[:, bones:]
    if dropped.shape[1]:
        jb[:, 0] += b[rows, dropped].sum(axis=1)
        jq[:, 0] += q[rows, dropped].sum(axis=1)
    used = (np.abs(jb) > 0) | np.any(jq != 0, axis=2)
    used[:, 0] = True
    return {
        "joint_index": np.where(used, keep, -1).astype(np.int32),
        "joint_point": np.where(used[..., None], jq, 0.0),
        "joint_weight": np.where(used, jb, 0.0),
    }


def skin_weight_coordinates(
    centres: np.ndarray,
    sphere_set,
    faces: np.ndarray,
    joint_indices,
    joint_weights,
    skinning_matrices: np.ndarray,
    max_bones: int,
) -> dict:
    """Bone coordinates of centres skinned with their samples' mean bone weights.

    Each centre takes the mean bone weights of the surface samples its sphere bounds
    (barycentric blends of their triangle's vertex weights), keeps the ``max_bones`` largest
    (renormalised) and is carried back to bind space through the blend of its bones' matrices
    at the fit frame, so that linear blend skinning with those matrices reproduces it there.

    Args:
        centres: sphere centres at the fit frame, (S, 3), world space.
        sphere_set: the :class:`~._core.SphereSet` (its ``sample_face``, ``sample_bary``,
            ``sample_sphere``).
        faces: the mesh's triangles, (F, 3) int.
        joint_indices, joint_weights: per-vertex bone influences, (V, K) int / float.
        skinning_matrices: per joint, bind space to world at the fit frame, (J, 4, 4)
            row-vector float64.
        max_bones: bones kept per centre.

    Returns:
        dict with ``joint_index`` (S, B) int32, ``joint_point`` (S, B, 3) and ``joint_weight``
        (S, B) float64, the same form as :func:`bone_coordinates`.
    """
    idx = np.asarray(joint_indices, np.int64)
    wts = np.asarray(joint_weights, np.float64)
    mats = np.asarray(skinning_matrices, np.float64)
    joint_count = mats.shape[0]
    vertex_count = idx.shape[0]
    vertex_bones = np.zeros((vertex_count, joint_count))
    for kk in range(idx.shape[1]):
        np.add.at(vertex_bones, (np.arange(vertex_count), idx[:, kk]), wts[:, kk])
    tri = np.asarray(faces, np.int64)[sphere_set.sample_face]
    sample_bones = np.einsum("nk,nkj->nj", sphere_set.sample_bary, vertex_bones[tri])
    bone = np.zeros((centres.shape[0], joint_count))
    np.add.at(bone, sphere_set.sample_sphere, sample_bones)
    bone /= np.maximum(bone.sum(axis=1, keepdims=True), 1e-300)
    bones = min(max_bones, joint_count)
    order = np.argsort(-bone, axis=1)[:, :bones]
    rows = np.arange(bone.shape[0])[:, None]
    jb = bone[rows, order]
    jb = jb / jb.sum(axis=1, keepdims=True)
    # the centre carried back to bind space through the blended fit-frame transform
    blended = np.einsum("sk,skab->sab", jb, mats[order])
    homo = np.concatenate([centres, np.ones((centres.shape[0], 1))], axis=1)
    bind_centre = np.einsum("sa,sab->sb", homo, np.linalg.inv(blended))[:, :3]
    return {"joint_index": order.astype(np.int32), "joint_point": jb[..., None] * bind_centre[:, None, :], "joint_weight": jb}
