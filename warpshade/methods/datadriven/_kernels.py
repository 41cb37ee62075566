"""Warp kernels of the data-driven transfer model (float64 mirrors: :mod:`._mirror`).

A frame is four launches on fixed buffers, recorded with the rest of the frame:

1. :func:`~warpshade.methods._shared.pose_kernels.pose_features_kernel` -- the pose vector from
   the frame's skeleton-space joint transforms (shared with :mod:`warpshade.methods.visibility`);
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
