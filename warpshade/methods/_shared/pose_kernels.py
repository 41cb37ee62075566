"""Pose vectors on the device: the first launch of a frame of the data-driven methods
(:mod:`warpshade.methods.datadriven`, :mod:`warpshade.methods.visibility`).

:func:`pose_features_kernel` reads the frame's skeleton-space joint transforms
(``FrameState.joint_transforms``; roots from the skinning matrices), one thread per joint, and
writes the pose vector in the layout of :mod:`.pose`, whose :func:`~.pose.pose_features` is its
float64 host mirror; :class:`PoseInputs` holds what it reads besides the frame state and
launches it.
"""

from __future__ import annotations

import numpy as np

from ..._wp import wp
from .pose import pose_layout

wp.set_module_options({"enable_backward": False})

__all__ = ["KIND_CODES", "PoseInputs", "pose_features_kernel"]

#: Pose parameterisations as kernel codes (see :mod:`.pose`).
KIND_CODES = {"rotvec": 0, "quaternion": 1, "matrix": 2}


@wp.func
def _rotation(m: wp.mat44) -> wp.mat33:
    """The rotation part of a column-vector transform with unit columns (scale stripped)."""
    c0 = wp.normalize(wp.vec3(m[0, 0], m[1, 0], m[2, 0]))
    c1 = wp.normalize(wp.vec3(m[0, 1], m[1, 1], m[2, 1]))
    c2 = wp.normalize(wp.vec3(m[0, 2], m[1, 2], m[2, 2]))
    return wp.matrix_from_cols(c0, c1, c2)


@wp.func
def _rotvec(r: wp.mat33) -> wp.vec3:
    q = wp.quat_from_matrix(r)
    if q[3] < 0.0:
        q = -q
    v = wp.vec3(q[0], q[1], q[2])
    s = wp.length(v)
    if s < 1.0e-7:
        return 2.0 * v
    return v * (2.0 * wp.atan2(s, q[3]) / s)


@wp.kernel
def pose_features_kernel(
    joints: wp.array(dtype=wp.mat44),
    skin: wp.array(dtype=wp.mat44),
    parents: wp.array(dtype=wp.int32),
    offsets: wp.array(dtype=wp.int32),
    rest_t: wp.array(dtype=wp.mat33),
    bind: wp.array(dtype=wp.mat44),
    root_ref_t: wp.array(dtype=wp.mat33),
    kind: int,
    features: wp.array(dtype=wp.float32),
):
    """Pose features of joint ``j`` into ``features[offsets[j]:]`` (nothing where offsets[j] < 0).

    ``joints``: skeleton-space joint transforms; ``skin``: ``skel_to_world @ joint @ bind^-1``
    (column-vector); ``rest_t``: transposed rest rotations; ``bind``: bind transforms (roots);
    ``root_ref_t``: transposed reference world rotations of the roots.
    """
    j = wp.tid()
    o = offsets[j]
    if o < 0:
        return
    p = parents[j]
    if p < 0:
        world = skin[j] * bind[j]
        features[o + 0] = world[0, 3]
        features[o + 1] = world[1, 3]
        features[o + 2] = world[2, 3]
        rv = _rotvec(root_ref_t[j] * _rotation(world))
        features[o + 3] = rv[0]
        features[o + 4] = rv[1]
        features[o + 5] = rv[2]
        return
    rel = rest_t[j] * (wp.transpose(_rotation(joints[p])) * _rotation(joints[j]))
    if kind == 0:
        rv = _rotvec(rel)
        features[o + 0] = rv[0]
        features[o + 1] = rv[1]
        features[o + 2] = rv[2]
    elif kind == 1:
        q = wp.quat_from_matrix(rel)
        if q[3] < 0.0:
            q = -q
        features[o + 0] = q[0]
        features[o + 1] = q[1]
        features[o + 2] = q[2]
        features[o + 3] = q[3]
    else:
        for r in range(3):
            for c in range(3):
                d = float(0.0)
                if r == c:
                    d = 1.0
                features[o + 3 * r + c] = rel[r, c] - d


class PoseInputs:
    """The frame's pose vector on the device: the pose layout of a scene's skeletons and the
    arrays :func:`pose_features_kernel` reads besides the frame state.

    Args:
        scene: the scene whose skeletons are read (rest and bind transforms).
        kind, root: the parameterisation and root mode (:func:`.pose.pose_layout`).
        root_reference: world rotations the root rotations are measured from, (R, 3, 3)
            column-vector (:func:`.pose.root_references` of the training clip).
        device: the Warp device.

    Attributes:
        layout: the :class:`~.pose.PoseLayout`.
        features: the pose vector, wp.array(float32) of (max(layout.size, 1),), filled by :meth:`launch`.
    """

    def __init__(self, scene, kind: str, root: str, root_reference, device):
        self.layout = layout = pose_layout(scene, kind, root)
        rest_t, bind, ref_t = [], [], []
        roots = iter(np.transpose(np.asarray(root_reference, np.float64), (0, 2, 1)))
        for skel in scene.skeletons:
            r = np.transpose(np.asarray(skel.rest_transforms, np.float64)[:, :3, :3], (0, 2, 1))  # column-vector rest
            r = r / np.linalg.norm(r, axis=-2, keepdims=True)
            rest_t.extend(np.transpose(r, (0, 2, 1)))
            bind.extend(np.transpose(np.asarray(skel.bind_transforms, np.float64), (0, 2, 1)))
            for parent in np.asarray(skel.parents):
                ref_t.append(next(roots) if parent < 0 and root == "include" else np.eye(3))

        def f32(values, dtype):
            return wp.array(np.asarray(values, np.float32), dtype=dtype, device=device)

        self._parents = wp.array(layout.parents.astype(np.int32), dtype=wp.int32, device=device)
        self._offsets = wp.array(layout.offsets.astype(np.int32), dtype=wp.int32, device=device)
        self._rest_t, self._bind, self._ref_t = f32(rest_t, wp.mat33), f32(bind, wp.mat44), f32(ref_t, wp.mat33)
        self._kind = KIND_CODES[kind]
        self.features = wp.zeros(max(layout.size, 1), dtype=wp.float32, device=device)
        self._device = device

    def launch(self, state) -> None:
        """The pose vector of the frame ``state`` (its joint transforms and skinning matrices)."""
        wp.launch(pose_features_kernel, dim=self.layout.joint_count, device=self._device,
                  inputs=[state.joint_transforms, state.skin_matrices, self._parents, self._offsets, self._rest_t,
                          self._bind, self._ref_t, self._kind, self.features])
