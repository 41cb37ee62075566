"""Warp kernel of SHEXP's hierarchy cut: the per-band ratio vectors of eq. 37.

A cut entry that is an inner node of the sphere hierarchy stands for all the leaves under it;
its bounding sphere over-blocks, so each band of its log visibility is scaled by the ratio
vector :func:`ratio_kernel` computes at the cluster's representative point.
:class:`._model.BlockerFrames` builds the :class:`RatioArrays` once and launches the
kernel every frame; the receiver pass (:func:`._kernels.receiver_kernel`) reads the result as
``BlockerSet.cut_weights``.
"""

# No "from __future__ import annotations": Warp resolves closure types in annotations.

import functools

from ..._wp import wp
from ...basis.sh_warp import SHExpTables, sh_kernels
from ._kernels import MODULE_OPTIONS, sphere_angle

wp.set_module_options({"enable_backward": False})

__all__ = ["RatioArrays", "ratio_kernel"]


@wp.struct
class RatioArrays:
    """Arrays of the ratio-vector pass: the refit hierarchy, the frame's cut, and the output.

    Fields:
        rep_points: representative point ``p*`` of each receiver cluster, world space,
            (clusters,) vec3.
        node_centres, node_radii: hierarchy node spheres, world space, (node_count,) vec3 /
            float32 (scene units).
        leaf_first, leaf_count: the leaves under node i are ``leaf_index[leaf_first[i] ..
            leaf_first[i] + leaf_count[i]]``, (node_count,) int32 each.
        leaf_index: node index of each leaf, in hierarchy order, (leaves,) int32.
        cut_nodes: per cluster, the cut's node indices, (clusters, capacity) int32; entries
            at and after ``cut_count[c]`` are ignored.
        cut_count: entries used per cluster, (clusters,) int32.
        theta_min: leaves of angular radius below this (radians) are left out of the detailed
            log ``f_d``.
        weights: output, per-band ratio vector of each cut entry, (clusters, capacity, n)
            float32 (1 for leaves, unused entries and where ``f_b`` vanishes).
    """

    rep_points: wp.array(dtype=wp.vec3)
    node_centres: wp.array(dtype=wp.vec3)
    node_radii: wp.array(dtype=wp.float32)
    leaf_first: wp.array(dtype=wp.int32)
    leaf_count: wp.array(dtype=wp.int32)
    leaf_index: wp.array(dtype=wp.int32)
    cut_nodes: wp.array2d(dtype=wp.int32)
    cut_count: wp.array(dtype=wp.int32)
    theta_min: float
    weights: wp.array3d(dtype=wp.float32)


@functools.lru_cache(maxsize=None)
def ratio_kernel(order: int):
    """Kernel computing the per-band ratio vectors of eq. 37 for every cut entry.

    Thread (c, e): cut entry e of cluster c with node i. At the cluster's representative point
    ``p*``, ``f_b = F(theta_i) y(s_i)`` of the node's bounding sphere and ``f_d`` = the sum of
    the same over the leaves of i whose angular radius is at least ``theta_min``; then per band
    ``w_l = sum_m f_b,lm f_d,lm / sum_m f_b,lm^2`` (1 for leaves and where ``f_b`` vanishes).

    Signature ``(arrays: RatioArrays, exp_tables: SHExpTables)``, launched over
    ``(clusters, capacity)``; writes ``arrays.weights``.
    """
    k = sh_kernels(order)
    vec_t, log_cap_zh, zh_accumulate = k.vec, k.log_cap_zh, k.zh_accumulate
    ORDER = order

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def kernel(arrays: RatioArrays, exp_tables: SHExpTables):
        c, e = wp.tid()
        out = arrays.weights
        for l in range(ORDER):
            out[c, e, l] = 1.0
        if e >= arrays.cut_count[c]:
            return
        node = arrays.cut_nodes[c, e]
        if node < 0:
            return
        if arrays.leaf_count[node] <= 1:
            return
        p = arrays.rep_points[c]
        centres = arrays.node_centres
        radii = arrays.node_radii
        sb = sphere_angle(p, wp.vec4(centres[node][0], centres[node][1], centres[node][2], radii[node]))
        fb = zh_accumulate(vec_t(), wp.vec3(sb[0], sb[1], sb[2]), log_cap_zh(sb[3], exp_tables))
        fd = vec_t()
        first = arrays.leaf_first[node]
        for q in range(first, first + arrays.leaf_count[node]):
            leaf = arrays.leaf_index[q]
            sl = sphere_angle(p, wp.vec4(centres[leaf][0], centres[leaf][1], centres[leaf][2], radii[leaf]))
            if sl[3] >= arrays.theta_min:
                fd = zh_accumulate(fd, wp.vec3(sl[0], sl[1], sl[2]), log_cap_zh(sl[3], exp_tables))
        for l in range(ORDER):
            num = float(0.0)
            den = float(0.0)
            for m in range(-l, l + 1):
                num += fb[l * l + l + m] * fd[l * l + l + m]
                den += fb[l * l + l + m] * fb[l * l + l + m]
            if den > 1.0e-20:
                out[c, e, l] = num / den

    return kernel
