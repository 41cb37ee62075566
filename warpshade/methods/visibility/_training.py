"""Training data of the data-driven visibility model: what ``visibility.data`` stores.

Per training frame of a clip (a skinned character or a point-cached mesh):

* the ray-traced SH visibility of every vertex, **no cosine** (the paper's Fig. 8 choice),
  directions below the tangent plane counted open (the RPO convention, :mod:`warpshade.methods.rpo`),
  in the **world** frame. It is traced once, by the executor tasks of
  :func:`warpshade.methods._shared.training.trace_training` (``quantity = "visibility"``), and
  turned into any per-vertex local frame afterwards by exact SH rotations
  (:func:`to_local`): the projection of the same rays in a rotated frame is the rotation of
  the projection, so one trace serves the one-ring frames, the cluster frames and the world frame
  of the Fig. 9 comparison;
* the world positions and normals of the frame (the local frames are functions of them);
* the inputs: joint rotations (``features = "joints"``, the pose vectors of
  :mod:`warpshade.methods._shared.pose`) or, for point-cached meshes, the dihedral angles of the
  interior edges (``features = "dihedral"``, :mod:`warpshade.methods.visibility._cloth`);
* what the clustering reads: the rest pose, faces, per-vertex dense skinning weights and the mesh
  each vertex belongs to.
"""

from __future__ import annotations

import numpy as np

from ...basis import sh

__all__ = ["FEATURE_SOURCES", "dense_skin_weights", "mesh_ids", "rest_points"]

#: Where the model's inputs come from.
FEATURE_SOURCES = ("joints", "dihedral")


def rest_points(scene) -> np.ndarray:
    """The rest pose of every vertex, world space, (V, 3) float64: each mesh's authored points
    placed by its first transform (the convention of :class:`warpshade.geometry._frames.TangentFrames`)."""
    parts = []
    for mesh in scene.meshes:
        xf = mesh.transforms[0]
        parts.append(np.asarray(mesh.points, np.float64) @ xf[:3, :3] + xf[3, :3])
    return np.concatenate(parts)


def mesh_ids(scene) -> np.ndarray:
    """Index of the mesh of every vertex, (V,) int32."""
    return np.concatenate([np.full(m.vertex_count, i, np.int32) for i, m in enumerate(scene.meshes)])


def dense_skin_weights(scene) -> np.ndarray:
    """Skinning weights of every vertex over every joint of every skeleton, (V, J) float32; rows
    of meshes that are not skinned are zero."""
    offsets = np.cumsum([0] + [s.joint_count for s in scene.skeletons])
    out = np.zeros((scene.vertex_count, max(int(offsets[-1]), 1)), np.float32)
    for mesh in scene.meshes:
        if mesh.skin is None:
            continue
        idx = np.asarray(mesh.skin.joint_indices, np.int64) + offsets[mesh.skin.skeleton]
        w = np.asarray(mesh.skin.joint_weights, np.float32)
        rows = np.arange(mesh.vertex_offset, mesh.vertex_offset + mesh.vertex_count)
        np.add.at(out, (np.repeat(rows, idx.shape[1]), idx.reshape(-1)), w.reshape(-1))
    return out


def to_local(visibility: np.ndarray, frames: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """World-frame SH (..., V, C) turned into per-vertex frames ``F`` (..., V, 3, 3) (rows t, b, n,
    world -> local): coefficients of ``f(F^T s)``, i.e. :func:`warpshade.basis.sh.rotate` by ``F``.
    Float64 in, float64 out (the exact rotation, band by band)."""
    v = np.asarray(visibility, np.float64)
    f = np.asarray(frames, np.float64)
    lead = v.shape[:-1]
    c = v.shape[-1]
    vf = v.reshape(-1, c)
    ff = np.broadcast_to(f, lead + (3, 3)).reshape(-1, 3, 3)
    out = np.empty_like(vf)
    for lo in range(0, vf.shape[0], chunk):
        out[lo:lo + chunk] = sh.rotate(vf[lo:lo + chunk], ff[lo:lo + chunk])
    return out.reshape(v.shape)
