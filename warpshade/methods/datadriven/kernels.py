"""Warp kernels of the data-driven transfer model (float64 mirrors: :mod:`.mirror`).

A frame is four launches on fixed buffers, recorded with the rest of the frame:

1. :func:`pose_features_kernel` -- the pose vector from the frame's skeleton-space joint
   transforms (``FrameState.joint_transforms``; roots from the skinning matrices), one thread
   per joint, in the layout of :mod:`.pose`;
2. :data:`project_pose_kernel` -- ``z = (a - mean) @ W`` (the standardisation and ``Pi_a``), and
   the bias ``1`` appended;
3. :data:`coefficients_kernel` -- reduced model: ``y[c] = X^c [z, 1]`` per coefficient;
4. :data:`reconstruct_kernel` -- reduced: ``b[v, c] = Pi_v[v] . y[c]``; or
   :data:`full_kernel` -- full: ``b[v, c] = weights[v, c] . [z, 1]``.

Long dot products are stored as rows of :data:`BLOCK`-wide float32 vectors (zero padded), so one
compiled kernel serves every model size and the CPU compiler keeps the inner products in
vector registers.
"""

from __future__ import annotations

from ..._wp import wp

wp.set_module_options({"enable_backward": False})

#: Width of the vector blocks the long dot products are stored in.
BLOCK = 8
vec_block = wp.types.vector(length=BLOCK, dtype=wp.float32)

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


@wp.kernel
def project_pose_kernel(
    features: wp.array(dtype=wp.float32),
    mean: wp.array(dtype=wp.float32),
    weights: wp.array2d(dtype=wp.float32),
    z: wp.array(dtype=vec_block),
):
    """``z = [(features - mean) @ weights, 1, 0...]`` packed in blocks (one thread)."""
    k_count = weights.shape[1]
    for b in range(z.shape[0]):
        z[b] = vec_block()
    for k in range(k_count):
        acc = float(0.0)
        for i in range(features.shape[0]):
            acc += (features[i] - mean[i]) * weights[i, k]
        blk = z[k // BLOCK]
        blk[k % BLOCK] = acc
        z[k // BLOCK] = blk
    blk = z[k_count // BLOCK]
    blk[k_count % BLOCK] = 1.0
    z[k_count // BLOCK] = blk


@wp.kernel
def coefficients_kernel(
    coefficients: wp.array3d(dtype=vec_block),
    z: wp.array(dtype=vec_block),
    y: wp.array2d(dtype=vec_block),
):
    """Reduced model: ``y[c, k] = coefficients[c, k] . z`` (thread per coefficient c)."""
    c = wp.tid()
    kv = coefficients.shape[1]
    for b in range(y.shape[1]):
        y[c, b] = vec_block()
    for k in range(kv):
        acc = float(0.0)
        for b in range(z.shape[0]):
            acc += wp.dot(coefficients[c, k, b], z[b])
        blk = y[c, k // BLOCK]
        blk[k % BLOCK] = acc
        y[c, k // BLOCK] = blk


@wp.kernel
def reconstruct_kernel(
    basis: wp.array2d(dtype=vec_block),
    y: wp.array2d(dtype=vec_block),
    start: int,
    transfer: wp.array2d(dtype=wp.float32),
):
    """Reduced model: ``transfer[v, c] = basis[v] . y[c]`` (thread per vertex from ``start``)."""
    v = start + wp.tid()
    for c in range(y.shape[0]):
        acc = float(0.0)
        for b in range(basis.shape[1]):
            acc += wp.dot(basis[v, b], y[c, b])
        transfer[v, c] = acc


@wp.kernel
def full_kernel(
    weights: wp.array3d(dtype=vec_block),
    z: wp.array(dtype=vec_block),
    start: int,
    transfer: wp.array2d(dtype=wp.float32),
):
    """Full model: ``transfer[v, c] = weights[v, c] . z`` (thread per vertex from ``start``)."""
    v = start + wp.tid()
    for c in range(weights.shape[1]):
        acc = float(0.0)
        for b in range(z.shape[0]):
            acc += wp.dot(weights[v, c, b], z[b])
        transfer[v, c] = acc
