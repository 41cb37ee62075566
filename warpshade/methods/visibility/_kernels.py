"""Warp kernels of the data-driven visibility model (float64 mirrors: :mod:`._mirror`).

A frame (all launches on buffers bound at set-up, recorded with the rest of the frame):

1. the pose vector from the joint transforms (:func:`warpshade.methods._shared.pose_kernels.pose_features_kernel`),
   or the cloth's dihedral angles (:mod:`._cloth`);
2. :func:`inputs_kernel` -- ``x = clip((a - mean) W, low, high)`` (thread per input component);
3. :func:`features_kernel` -- ``phi = [x, x_i x_j]`` into the activations (thread per feature);
4. :func:`hidden_kernel` -- every network's hidden units, ``tanh(b1 + W1 x)`` (thread per unit, all
   clusters in one launch);
5. :func:`outputs_kernel` -- every cluster's PCA weights, ``b2 + w2 . act`` (thread per output);
6. :func:`reconstruct_kernel` -- per vertex ``mean + U y`` of its cluster (thread per vertex, one SH
   vector per term);
7. the frames: :func:`cluster_axes_kernel` (thread per cluster) and :func:`cluster_frames_kernel`
   (thread per vertex), or the one-ring frames of :mod:`warpshade.geometry._frames`.

With relative inputs (``visibility.fit relative``, :mod:`._relative`), before step 2 the pose vector is
copied in front of them (:func:`copy_prefix_kernel`), then :func:`cluster_rigid_kernel` (thread per
cluster) and :func:`relative_features_kernel` (thread per cluster and neighbour) append them.

:func:`diffuse_kernel` is the diffuse path (eq. 14): ``albedo / pi * L . R(F^T) (v * cos)``.
"""

import functools

import numpy as np

from ..._wp import wp
from ...basis.sh_warp import SHTables, sh_kernels
from ...geometry._frames import onb_tangent
from ._clusters import BLEND
from ._relative import RANK_TOL

wp.set_module_options({"enable_backward": False})

_BLEND = wp.constant(BLEND)
_RANK_TOL = wp.constant(RANK_TOL)


def input_rows(weights) -> tuple:
    """Per input component ``k`` the rows ``[lo, hi)`` of ``weights`` (a, k_in) outside which its column
    is zero (a local block reads one cluster's relative inputs or some joints'), int32 arrays; an
    all-zero column gets an empty range."""
    nz = np.asarray(weights) != 0.0
    any_ = nz.any(0)
    lo = np.where(any_, nz.argmax(0), 0)
    hi = np.where(any_, nz.shape[0] - nz[::-1].argmax(0), 0)
    return lo.astype(np.int32), hi.astype(np.int32)


@wp.kernel
def inputs_kernel(features: wp.array(dtype=wp.float32), mean: wp.array(dtype=wp.float32),
                  weights: wp.array2d(dtype=wp.float32), rows_lo: wp.array(dtype=wp.int32),
                  rows_hi: wp.array(dtype=wp.int32), low: wp.array(dtype=wp.float32),
                  high: wp.array(dtype=wp.float32), x: wp.array(dtype=wp.float32)):
    """``x[k] = clip(sum_i (features[i] - mean[i]) weights[i, k], low[k], high[k])``, the sum over the
    rows where column ``k`` is not zero (:func:`input_rows`)."""
    k = wp.tid()
    acc = float(0.0)
    for i in range(rows_lo[k], rows_hi[k]):
        acc += (features[i] - mean[i]) * weights[i, k]
    x[k] = wp.clamp(acc, low[k], high[k])


@wp.kernel
def features_kernel(x: wp.array(dtype=wp.float32), quad_i: wp.array(dtype=wp.int32), quad_j: wp.array(dtype=wp.int32),
                    act: wp.array(dtype=wp.float32)):
    """``act[f] = x[f]`` for ``f < k_in``, then the products ``x[quad_i] x[quad_j]``."""
    f = wp.tid()
    k = x.shape[0]
    if f < k:
        act[f] = x[f]
    else:
        act[f] = x[quad_i[f - k]] * x[quad_j[f - k]]


@wp.kernel
def hidden_kernel(x: wp.array(dtype=wp.float32), w1: wp.array2d(dtype=wp.float32), b1: wp.array(dtype=wp.float32),
                  base: int, act: wp.array(dtype=wp.float32)):
    """Hidden unit ``u`` of every cluster's network: ``act[base + u] = tanh(b1[u] + w1[u] . x)`` (eq. 12)."""
    u = wp.tid()
    acc = b1[u]
    for j in range(x.shape[0]):
        acc += w1[u, j] * x[j]
    act[base + u] = wp.tanh(acc)


@wp.kernel
def outputs_kernel(act: wp.array(dtype=wp.float32), w2: wp.array(dtype=wp.float32), b2: wp.array(dtype=wp.float32),
                   source: wp.array(dtype=wp.int32), length: wp.array(dtype=wp.int32),
                   w_offset: wp.array(dtype=wp.int32), y: wp.array(dtype=wp.float32)):
    """Output ``o`` (a PCA weight of one cluster): ``b2[o] + w2[w_offset[o]:] . act[source[o]:]``."""
    o = wp.tid()
    acc = b2[o]
    s = source[o]
    w = w_offset[o]
    for j in range(length[o]):
        acc += w2[w + j] * act[s + j]
    y[o] = acc


#: Storage of the per-vertex PCA basis on the device: ``"half"`` (float16, converted to float32 in
#: the kernel) or ``"single"``. The basis is what a frame reads most (16 floats per component and
#: vertex: 28 MB a frame on the wanderer at float32), so half storage halves the frame's memory
#: traffic; its rounding (2^-11 of an entry) is far below the model's error.
BASIS_PRECISIONS = ("half", "single")


@functools.lru_cache(maxsize=None)
def reconstruct_kernel(coefficients: int, precision: str = "single"):
    """``kernel(mean, basis, labels, components, y_offset, y, start, visibility)``: per vertex
    ``visibility[v] = mean[v] + sum_j basis[v, j] y[y_offset[c] + j]`` over the ``components[c]``
    PCA vectors of its cluster ``c`` (thread per vertex from ``start``).

    ``mean`` and ``basis`` hold one vector of ``coefficients`` SH coefficients per entry (the basis
    as ``(vertices, max components)``, float32 or float16 by ``precision``), so a term is one
    vector multiply-add: the CPU build turns it into SIMD code, about 10x the speed of a scalar
    loop over a ``(v, i, j)`` array.
    """
    if precision not in BASIS_PRECISIONS:
        raise ValueError(f"reconstruct_kernel: precision must be one of {BASIS_PRECISIONS}, got {precision!r}")
    vec_t = wp.types.vector(length=coefficients, dtype=wp.float32)
    basis_t = wp.types.vector(length=coefficients, dtype=wp.float16 if precision == "half" else wp.float32)

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(mean: wp.array(dtype=vec_t), basis: wp.array2d(dtype=basis_t), labels: wp.array(dtype=wp.int32),
               components: wp.array(dtype=wp.int32), y_offset: wp.array(dtype=wp.int32), y: wp.array(dtype=wp.float32),
               start: int, visibility: wp.array2d(dtype=wp.float32)):
        v = start + wp.tid()
        c = labels[v]
        o = y_offset[c]
        acc = mean[v]
        for j in range(components[c]):
            acc += vec_t(basis[v, j]) * y[o + j]
        for i in range(coefficients):
            visibility[v, i] = acc[i]

    return kernel


def reconstruct_setup(mean, basis, device, precision: str = "half"):
    """The :func:`reconstruct_kernel` of the model's SH size and its ``mean`` (V, n*n) and ``basis``
    (V, n*n, components) on ``device`` in the kernel's layout (the basis in ``precision``):
    ``(kernel, mean, basis)``."""
    import numpy as np

    mean = np.asarray(mean, np.float32)
    kernel = reconstruct_kernel(mean.shape[1], precision)
    vec_t, basis_t = kernel.adj.args[0].type.dtype, kernel.adj.args[1].type.dtype
    basis = np.ascontiguousarray(np.asarray(basis, np.float32).transpose(0, 2, 1))
    if precision == "half":
        basis = basis.astype(np.float16)
    return kernel, wp.array(mean, dtype=vec_t, device=device), wp.array(basis, dtype=basis_t, device=device)


@wp.func
def _unit_or(v: wp.vec3, fallback: wp.vec3) -> wp.vec3:
    n = wp.length(v)
    if n > 1.0e-12:
        return v / n
    return fallback


@wp.kernel
def cluster_axes_kernel(points: wp.array(dtype=wp.vec3), order: wp.array(dtype=wp.int32),
                        offsets: wp.array(dtype=wp.int32), weights: wp.array2d(dtype=wp.float32),
                        rest_axes: wp.array2d(dtype=wp.vec3), axes: wp.array2d(dtype=wp.vec3)):
    """The cluster's directions of this pose, ``A_k = sum_i w_k,i p_i`` normalised (thread per cluster)."""
    c = wp.tid()
    a1 = wp.vec3(0.0, 0.0, 0.0)
    a2 = wp.vec3(0.0, 0.0, 0.0)
    for r in range(offsets[c], offsets[c + 1]):
        p = points[order[r]]
        a1 += weights[r, 0] * p
        a2 += weights[r, 1] * p
    axes[c, 0] = _unit_or(a1, rest_axes[c, 0])
    axes[c, 1] = _unit_or(a2, rest_axes[c, 1])


@wp.kernel
def cluster_frames_kernel(normals: wp.array(dtype=wp.vec3), labels: wp.array(dtype=wp.int32),
                          axes: wp.array2d(dtype=wp.vec3), start: int, frames: wp.array(dtype=wp.mat33)):
    """Vertex frame from its cluster's directions (:mod:`._clusters`): rows (t, n x t, n) (thread per
    vertex from ``start``)."""
    v = start + wp.tid()
    n = _unit_or(normals[v], wp.vec3(0.0, 0.0, 1.0))
    c = labels[v]
    a1 = axes[c, 0]
    a2 = axes[c, 1]
    t_raw = a1 - wp.dot(a1, n) * n
    blend = wp.clamp(1.0 - wp.length(t_raw) / _BLEND, 0.0, 1.0)
    t = t_raw + blend * blend * _BLEND * a2
    t = t - wp.dot(t, n) * n
    t = _unit_or(t, onb_tangent(n))
    b = wp.cross(n, t)
    frames[v] = wp.matrix_from_rows(t, b, n)


@wp.kernel
def copy_prefix_kernel(source: wp.array(dtype=wp.float32), out: wp.array(dtype=wp.float32)):
    """``out[i] = source[i]``: the pose vector in front of the relative inputs (thread per number)."""
    i = wp.tid()
    out[i] = source[i]


@wp.kernel
def cluster_rigid_kernel(points: wp.array(dtype=wp.vec3), rest: wp.array(dtype=wp.vec3), order: wp.array(dtype=wp.int32),
                         offsets: wp.array(dtype=wp.int32), rest_centroids: wp.array(dtype=wp.vec3),
                         rotations: wp.array(dtype=wp.mat33), centroids: wp.array(dtype=wp.vec3)):
    """A cluster's rigid motion in this pose (Kabsch, :mod:`._relative`): ``R = V diag(1, 1, det(V U^T)) U^T``
    from the SVD of ``sum (q - q_bar)(p - p_bar)^T``, and its posed centroid (thread per cluster)."""
    c = wp.tid()
    lo = offsets[c]
    hi = offsets[c + 1]
    pc = wp.vec3(0.0, 0.0, 0.0)
    for r in range(lo, hi):
        pc += points[order[r]]
    pc = pc / float(wp.max(hi - lo, 1))
    qc = rest_centroids[c]
    h = wp.mat33(0.0)
    for r in range(lo, hi):
        v = order[r]
        h += wp.outer(rest[v] - qc, points[v] - pc)
    u = wp.mat33()
    s = wp.vec3()
    vm = wp.mat33()
    wp.svd3(h, u, s, vm)
    rot = vm * wp.transpose(u)
    if wp.determinant(rot) < 0.0:
        flip = wp.mat33(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, -1.0)
        rot = vm * flip * wp.transpose(u)
    s_max = wp.max(s[0], wp.max(s[1], s[2]))
    s_mid = s[0] + s[1] + s[2] - s_max - wp.min(s[0], wp.min(s[1], s[2]))
    if s_mid <= _RANK_TOL * s_max:  # points on a line or one point: no rotation (as the mirror)
        rot = wp.identity(n=3, dtype=float)
    rotations[c] = rot
    centroids[c] = pc


@wp.kernel
def relative_features_kernel(rotations: wp.array(dtype=wp.mat33), centroids: wp.array(dtype=wp.vec3),
                             neighbours: wp.array2d(dtype=wp.int32), base: int, features: wp.array(dtype=wp.float32)):
    """Cluster ``k``'s relative inputs (:mod:`._relative`), three numbers per thread: slot ``s < N`` its
    ``s``-th neighbour's centroid ``R_k^T (c_j - c_k)``, then ``R_k^T e_y``, ``R_k^T e_z``, ``c_k``
    (thread per cluster and slot)."""
    tid = wp.tid()
    n = neighbours.shape[1]
    k = tid / (n + 3)
    s = tid - k * (n + 3)
    rt = wp.transpose(rotations[k])
    ck = centroids[k]
    out = ck
    if s < n:
        out = rt * (centroids[neighbours[k, s]] - ck)
    elif s == n:
        out = rt * wp.vec3(0.0, 1.0, 0.0)
    elif s == n + 1:
        out = rt * wp.vec3(0.0, 0.0, 1.0)
    at = base + k * (3 * n + 9) + 3 * s
    features[at] = out[0]
    features[at + 1] = out[1]
    features[at + 2] = out[2]


@functools.lru_cache(maxsize=None)
def diffuse_kernel(order: int):
    """``kernel(visibility, frames, albedo, light, cos_sh, tables, start, radiance)``: eq. 14 then
    the lighting, ``albedo / pi * L . R(F^T)(v * cos)``, negative sums clamped to 0."""
    shk = sh_kernels(order)
    N2 = order * order
    vec_t = shk.vec
    sh_rotate, sh_product, sh_load = shk.rotate, shk.product, shk.load

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(visibility: wp.array2d(dtype=wp.float32), frames: wp.array(dtype=wp.mat33),
               albedo: wp.array2d(dtype=wp.float32), light: wp.array2d(dtype=wp.float32),
               cos_sh: wp.array(dtype=wp.float32), tables: SHTables, start: int,
               radiance: wp.array2d(dtype=wp.float32)):
        v = wp.tid() + start
        vis = sh_load(visibility, v)
        c = vec_t()
        for i in range(N2):
            c[i] = cos_sh[i]
        t = sh_product(vis, c, tables)
        tw = sh_rotate(t, wp.transpose(frames[v]), tables)
        for ch in range(3):
            acc = float(0.0)
            for i in range(N2):
                acc += tw[i] * light[ch, i]
            radiance[v, ch] = wp.max(acc, 0.0) * albedo[v, ch] / wp.pi

    return kernel
