"""Pose vectors of a skinned scene: the inputs ``a`` of the data-driven models.

A pose is read from UsdSkel per frame (:class:`warpshade.scene.Skeleton`). Every joint that has
a parent contributes its joint-local rotation *relative to its rest rotation*,
``R_rel = R_rest^T R_local`` (column-vector matrices), in one of three parameterisations:

* ``"rotvec"`` -- the rotation vector (axis times angle, radians), 3 numbers per joint;
* ``"quaternion"`` -- the unit quaternion ``(x, y, z, w)`` with ``w >= 0``, 4 numbers per joint;
* ``"matrix"`` -- the nine entries of ``R_rel - I`` (row-major), 9 numbers per joint.

A root joint (no parent) is handled separately (``root``): with ``"include"`` it contributes
its world translation (3, scene units) and its world rotation as a rotation vector relative to a
reference rotation (the root's world rotation at the first training frame), whichever
parameterisation the other joints use; with ``"exclude"`` it contributes nothing (a character
whose root moves is then modelled as if it stood still). The world-frame transfer depends on
the root's rotation through a rotation of the whole SH vector, which no linear map of a few
numbers reproduces; ``"include"`` lets the model follow small root motion, a character that
turns around needs its transfer trained in the root's frame (not built here).

Joints are listed skeleton by skeleton in the scene's joint order (the order of
``FrameState.joint_transforms``). Joint scales are stripped by normalising the columns of the
rotation part (as the device kernel does). :func:`pose_features` is the float64 host mirror of
:func:`.pose_kernels.pose_features_kernel`; the tests compare the two and compare both with
SciPy's rotations.

Used by the data-driven transfer (:mod:`warpshade.methods.datadriven`, which exports
:data:`PARAMETERISATIONS`, :func:`pose_layout` and :func:`pose_features`) and the data-driven
visibility (:mod:`warpshade.methods.visibility`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "PARAMETERISATIONS",
    "ROOT_FEATURES",
    "ROOT_MODES",
    "PoseLayout",
    "features_from_rotations",
    "pose_features",
    "pose_layout",
    "root_references",
]

#: Pose parameterisations and the numbers per joint.
PARAMETERISATIONS = {"rotvec": 3, "quaternion": 4, "matrix": 9}
#: How a root joint enters the pose vector.
ROOT_MODES = ("include", "exclude")
#: Numbers a root joint contributes with ``root = "include"``: translation, rotation vector.
ROOT_FEATURES = 6


@dataclass(frozen=True)
class PoseLayout:
    """Where each joint's numbers sit in the pose vector.

    Attributes:
        kind: the parameterisation (a key of :data:`PARAMETERISATIONS`).
        root: ``"include"`` or ``"exclude"``.
        parents: parent per joint over all skeletons (global joint indices, -1 for roots), (J,).
        offsets: first feature of each joint, (J,), -1 for a root that is excluded.
        widths: numbers per joint, (J,).
        names: one name per feature, e.g. ``"Skel/Hips/Spine.rx"``.
    """

    kind: str
    root: str
    parents: np.ndarray
    offsets: np.ndarray
    widths: np.ndarray
    names: tuple

    @property
    def size(self) -> int:
        return len(self.names)

    @property
    def joint_count(self) -> int:
        return int(self.parents.shape[0])


_SUFFIXES = {"rotvec": ("rx", "ry", "rz"), "quaternion": ("qx", "qy", "qz", "qw"),
             "matrix": tuple(f"m{i}{j}" for i in range(3) for j in range(3))}


def pose_layout(scene, kind: str = "rotvec", root: str = "include") -> PoseLayout:
    """The layout of the pose vectors of ``scene`` (every skeleton, scene joint order).

    Raises:
        ValueError: an unknown parameterisation or root mode, or a scene without skeletons.
    """
    if kind not in PARAMETERISATIONS:
        raise ValueError(f"pose parameterisation must be one of {sorted(PARAMETERISATIONS)}, got {kind!r}")
    if root not in ROOT_MODES:
        raise ValueError(f"root must be one of {ROOT_MODES}, got {root!r}")
    if not scene.skeletons:
        raise ValueError(f"scene {scene.source or '<arrays>'}: has no UsdSkel skeleton, so no joint angles to learn from")
    parents, offsets, widths, names = [], [], [], []
    base = 0
    position = 0
    for skel in scene.skeletons:
        for j, parent in enumerate(np.asarray(skel.parents).reshape(-1)):
            joint = f"{skel.path}:{skel.joint_names[j]}"
            if parent < 0:
                parents.append(-1)
                if root == "include":
                    offsets.append(position)
                    widths.append(ROOT_FEATURES)
                    names.extend(f"{joint}.{s}" for s in ("tx", "ty", "tz", "rx", "ry", "rz"))
                    position += ROOT_FEATURES
                else:
                    offsets.append(-1)
                    widths.append(0)
            else:
                parents.append(base + int(parent))
                width = PARAMETERISATIONS[kind]
                offsets.append(position)
                widths.append(width)
                names.extend(f"{joint}.{s}" for s in _SUFFIXES[kind])
                position += width
        base += skel.joint_count
    return PoseLayout(kind, root, np.asarray(parents, np.int64), np.asarray(offsets, np.int64),
                      np.asarray(widths, np.int64), tuple(names))


def _orthonormal_columns(m: np.ndarray) -> np.ndarray:
    """Rotation parts with unit columns (joint scales stripped), (..., 3, 3)."""
    return m / np.linalg.norm(m, axis=-2, keepdims=True)


def features_from_rotations(rel: np.ndarray, kind: str) -> np.ndarray:
    """Features of relative rotations (column-vector matrices, (J, 3, 3)) -> (J, width)."""
    rot = Rotation.from_matrix(rel)
    if kind == "rotvec":
        return rot.as_rotvec()
    if kind == "quaternion":
        q = rot.as_quat()  # (x, y, z, w)
        return np.where(q[:, 3:4] < 0.0, -q, q)
    return (rel - np.eye(3)).reshape(-1, 9)


def _world_roots(skel, t: int) -> np.ndarray:
    """World transforms of the skeleton's joints that are roots, column-vector, (R, 4, 4)."""
    local = np.asarray(skel.local_transforms[t if skel.local_transforms.shape[0] > 1 else 0], np.float64)
    s2w = np.asarray(skel.skel_to_world[t if skel.skel_to_world.shape[0] > 1 else 0], np.float64)
    roots = np.flatnonzero(np.asarray(skel.parents) < 0)
    return np.transpose(local[roots] @ s2w, (0, 2, 1))  # row-vector world = local @ skel_to_world


def root_references(scene, frame_index: int = 0) -> np.ndarray:
    """World rotations of every root joint at a frame (the reference of the root features),
    column-vector, (R, 3, 3) over all skeletons."""
    return np.concatenate([_orthonormal_columns(_world_roots(s, frame_index)[:, :3, :3]) for s in scene.skeletons])


def pose_features(scene, frame_indices, layout: PoseLayout, root_reference: np.ndarray | None = None) -> np.ndarray:
    """Pose vectors of ``scene`` at frame indices (not time codes), float64, (n, layout.size).

    Args:
        scene: the scene (its skeletons' joint-local animation).
        frame_indices: indices into ``scene.frames``.
        layout: from :func:`pose_layout` on a scene with the same skeletons.
        root_reference: world rotations of the roots that root rotations are measured from,
            (R, 3, 3) column-vector; default: the roots at frame 0 of ``scene``.
    """
    frame_indices = np.asarray(frame_indices, np.int64).reshape(-1)
    if root_reference is None:
        root_reference = root_references(scene, 0)
    out = np.zeros((frame_indices.shape[0], layout.size))
    for row, t in enumerate(frame_indices):
        base = 0
        r = 0
        for skel in scene.skeletons:
            local = np.asarray(skel.local_transforms[t if skel.local_transforms.shape[0] > 1 else 0], np.float64)
            rest = np.asarray(skel.rest_transforms, np.float64)
            # row-vector matrices: the column-vector rotation is the transpose
            r_local = _orthonormal_columns(np.transpose(local[:, :3, :3], (0, 2, 1)))
            r_rest = _orthonormal_columns(np.transpose(rest[:, :3, :3], (0, 2, 1)))
            parents = np.asarray(skel.parents).reshape(-1)
            inner = np.flatnonzero(parents >= 0)
            if inner.size:
                rel = np.transpose(r_rest[inner], (0, 2, 1)) @ r_local[inner]
                feats = features_from_rotations(rel, layout.kind)
                for k, j in enumerate(inner):
                    o = layout.offsets[base + j]
                    out[row, o:o + layout.widths[base + j]] = feats[k]
            roots = np.flatnonzero(parents < 0)
            if layout.root == "include" and roots.size:
                world = _world_roots(skel, t)
                for k, j in enumerate(roots):
                    o = layout.offsets[base + j]
                    rot = root_reference[r + k].T @ _orthonormal_columns(world[k, :3, :3])
                    out[row, o:o + 3] = world[k, :3, 3]
                    out[row, o + 3:o + 6] = Rotation.from_matrix(rot).as_rotvec()
            r += roots.size
            base += skel.joint_count
    return out
