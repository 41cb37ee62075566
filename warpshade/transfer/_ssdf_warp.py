"""Warp side of the spherical signed distance functions (SSDFs) of :mod:`warpshade.transfer._ssdf`.

Kernels (float32; the float64 oracles are in :mod:`._ssdf` and :mod:`._ssdf_products`):

* :data:`trace_hemisphere_kernel` -- binary visibility of one ray per (receiver, texel) of the
  concentric hemisphere map, the texel direction taken from the tangent frame to world space;
* :data:`boundary_distance_kernel` -- brute-force nearest boundary point per (receiver, query
  direction): the unsigned angle ``2 asin(|q - t| / 2)`` (exact in angle: the chord is monotone in
  it), clamped to ``pi/2`` and signed;
* :data:`lobe_visibility_kernel` -- the ray-traced oracle of ``integral G(i; p, lambda, 1) V(i)``
  over the upper hemisphere, by sampling the lobe (eq. 2) itself;
* :data:`ssdf_eval_kernel`, :data:`ssdf_product_kernel` -- batch forms of the functions below.

Functions usable inside any kernel:

* ``local_to_concentric(d) -> vec2`` -- a local direction to the square ``[-1, 1]^2`` (the inverse
  of :func:`warpshade.scene._materials.concentric_to_hemisphere`; below the horizon clamped to it);
* ``ssdf_eval(mean, basis, coeffs, i0, i1, i2, w0, w1, w2, dir_local, resolution, terms) -> float``
  -- the PCA-compressed SSDF (eq. 24) of the barycentric blend of three vertices' coefficients,
  bilinear between texel centres at ``dir_local`` (radians, not clamped);
* ``ssdf_visible_fraction(theta_d, lam) -> float`` -- eq. 31's amplitude factor (an alias of
  :func:`warpshade.basis.sg_warp.sg_visible_fraction`, re-exported for SSDF users).
"""

from __future__ import annotations

from .._wp import wp
from ..basis.sg_warp import sg_visible_fraction
from ..scene._materials_warp import concentric_footprint, hemisphere_to_concentric

wp.set_module_options({"enable_backward": False})

__all__ = [
    "boundary_distance_kernel",
    "lobe_visibility_kernel",
    "ssdf_eval",
    "ssdf_eval_kernel",
    "ssdf_product_kernel",
    "trace_hemisphere_kernel",
]

_HALF_PI = wp.constant(1.5707963267948966)
_RAY_MAX = wp.constant(1.0e30)

ssdf_visible_fraction = sg_visible_fraction


#: A local direction -> the concentric square (the shared Warp mirror of the float64 map).
local_to_concentric = hemisphere_to_concentric


@wp.func
def _blend(coeffs: wp.array2d(dtype=float), i0: int, i1: int, i2: int, w0: float, w1: float, w2: float, k: int):
    return w0 * coeffs[i0, k] + w1 * coeffs[i1, k] + w2 * coeffs[i2, k]


@wp.func
def ssdf_eval(mean: wp.array(dtype=float), basis: wp.array2d(dtype=float), coeffs: wp.array2d(dtype=float),
              i0: int, i1: int, i2: int, w0: float, w1: float, w2: float, dir_local: wp.vec3,
              resolution: int, terms: int) -> float:
    """SSDF (radians) of the blend ``w0 c[i0] + w1 c[i1] + w2 c[i2]`` at a local direction.

    ``mean`` (R*R,), ``basis`` (>= terms, R*R) and ``coeffs`` (vertex_count, >= terms) are the
    arrays of an :class:`~warpshade.transfer._ssdf_pca.SSDFModel` (texel ``a * R + b``); the map is
    sampled bilinearly between texel centres with edge clamping (resolution >= 2).
    """
    res = resolution
    fp = concentric_footprint(local_to_concentric(dir_local), res)
    ia = int(fp[0])
    ib = int(fp[1])
    ta = fp[2]
    tb = fp[3]
    t00 = ia * res + ib
    t01 = t00 + 1
    t10 = t00 + res
    t11 = t10 + 1
    k00 = (1.0 - ta) * (1.0 - tb)
    k01 = (1.0 - ta) * tb
    k10 = ta * (1.0 - tb)
    k11 = ta * tb
    acc = k00 * mean[t00] + k01 * mean[t01] + k10 * mean[t10] + k11 * mean[t11]
    for k in range(terms):
        c = _blend(coeffs, i0, i1, i2, w0, w1, w2, k)
        acc += c * (k00 * basis[k, t00] + k01 * basis[k, t01] + k10 * basis[k, t10] + k11 * basis[k, t11])
    return acc


@wp.kernel
def ssdf_eval_kernel(mean: wp.array(dtype=float), basis: wp.array2d(dtype=float), coeffs: wp.array2d(dtype=float),
                     vertex_ids: wp.array(dtype=wp.vec3i), weights: wp.array(dtype=wp.vec3),
                     dirs_local: wp.array(dtype=wp.vec3), resolution: int, terms: int, out: wp.array(dtype=float)):
    i = wp.tid()
    ids = vertex_ids[i]
    w = weights[i]
    out[i] = ssdf_eval(mean, basis, coeffs, ids[0], ids[1], ids[2], w[0], w[1], w[2], dirs_local[i], resolution, terms)


@wp.kernel
def ssdf_product_kernel(mean: wp.array(dtype=float), basis: wp.array2d(dtype=float), coeffs: wp.array2d(dtype=float),
                        vertex_ids: wp.array(dtype=wp.vec3i), weights: wp.array(dtype=wp.vec3),
                        axes_local: wp.array(dtype=wp.vec3), sharpness: wp.array(dtype=float), resolution: int,
                        terms: int, theta_d: wp.array(dtype=float), fraction: wp.array(dtype=float)):
    """eq. 31: the SSDF at the lobe axis and the lobe's amplitude factor ``f_h(theta_d) / f_h(pi/2)``."""
    i = wp.tid()
    ids = vertex_ids[i]
    w = weights[i]
    t = ssdf_eval(mean, basis, coeffs, ids[0], ids[1], ids[2], w[0], w[1], w[2], axes_local[i], resolution, terms)
    t = wp.clamp(t, -_HALF_PI, _HALF_PI)
    theta_d[i] = t
    fraction[i] = ssdf_visible_fraction(t, sharpness[i])


@wp.kernel
def trace_hemisphere_kernel(mesh_id: wp.uint64, points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                            frames: wp.array(dtype=wp.mat33), receivers: wp.array(dtype=wp.int32), first: int,
                            dirs_local: wp.array(dtype=wp.vec3), offset: float, start: int,
                            visible: wp.array(dtype=wp.uint8)):
    """One ray per item ``start + tid`` = (receiver ``first + item // T``, texel ``item % T``)."""
    item = start + wp.tid()
    texels = dirs_local.shape[0]
    r = item // texels
    t = item - r * texels
    v = receivers[first + r]
    d = wp.transpose(frames[v]) * dirs_local[t]  # rows (t, b, n): world = F^T local
    origin = points[v] + offset * normals[v]
    hit = wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX)
    visible[item] = wp.uint8(wp.where(hit, 0, 1))


@wp.kernel
def boundary_distance_kernel(queries: wp.array(dtype=wp.vec3), boundary: wp.array(dtype=wp.vec3),
                             boundary_offsets: wp.array(dtype=wp.int32), signs: wp.array(dtype=wp.int8), start: int,
                             out: wp.array(dtype=float)):
    """Item ``start + tid`` = (map ``item // Q``, query ``item % Q``): the signed, clamped angle to
    the nearest of the map's boundary points ``boundary[offsets[m]:offsets[m + 1]]``."""
    item = start + wp.tid()
    count = queries.shape[0]
    m = item // count
    q = queries[item - m * count]
    best = float(4.0)  # squared chord of pi/2 is 2: anything above clamps
    for k in range(boundary_offsets[m], boundary_offsets[m + 1]):
        e = boundary[k] - q
        best = wp.min(best, wp.dot(e, e))
    angle = _HALF_PI
    if best < 2.0:
        angle = wp.min(2.0 * wp.asin(wp.min(0.5 * wp.sqrt(best), 1.0)), _HALF_PI)
    out[item] = float(signs[item]) * angle


@wp.func
def _log1p(x: float) -> float:
    # log(1 + x) accurate for small |x| (the classic y = 1 + x correction)
    y = 1.0 + x
    if y == 1.0:
        return x
    return wp.log(y) * x / (y - 1.0)


@wp.func
def _one_minus_exp(x: float) -> float:
    # 1 - exp(-x) for x >= 0, accurate for small x
    if x < 1.0e-3:
        return x * (1.0 - 0.5 * x * (1.0 - x / 3.0))
    return 1.0 - wp.exp(-x)


@wp.kernel
def lobe_visibility_kernel(mesh_id: wp.uint64, points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3),
                           frames: wp.array(dtype=wp.mat33), receivers: wp.array(dtype=wp.int32),
                           axes_local: wp.array2d(dtype=wp.vec3), sharpness: wp.array(dtype=float), samples: int,
                           offset: float, seed: int, start: int, visible_count: wp.array(dtype=wp.int32)):
    """Item ``start + tid`` = (receiver r, axis a, sharpness l) in row-major order: how many of
    ``samples`` directions drawn from the lobe ``G(.; p, lambda)`` (a stratified lattice in
    (u, phi) under the exact inverse CDF, rotated about the axis by a random angle per item) leave
    the receiver unoccluded *and* above its horizon."""
    item = start + wp.tid()
    axis_count = axes_local.shape[1]
    lam_count = sharpness.shape[0]
    r = item // (axis_count * lam_count)
    rest = item - r * axis_count * lam_count
    a = rest // lam_count
    li = rest - a * lam_count
    v = receivers[r]
    f = frames[v]
    n = normals[v]
    p = wp.normalize(wp.transpose(f) * axes_local[r, a])
    lam = sharpness[li]
    # orthonormal basis around p (Duff et al.)
    sgn = wp.where(p[2] >= 0.0, 1.0, -1.0)
    aa = -1.0 / (sgn + p[2])
    bb = p[0] * p[1] * aa
    e1 = wp.vec3(1.0 + sgn * p[0] * p[0] * aa, sgn * bb, -sgn * p[0])
    e2 = wp.vec3(bb, sgn + p[1] * p[1] * aa, -p[1])
    state = wp.rand_init(seed, item)
    spin = 2.0 * wp.pi * wp.randf(state)
    origin = points[v] + offset * n
    tail = _one_minus_exp(2.0 * lam)
    golden = 0.6180339887498949
    count = int(0)
    for s in range(samples):
        u = (float(s) + 0.5) / float(samples)
        # 1 - cos(theta) = -log(1 - u (1 - e^-2l)) / l, finite for every u < 1
        one_minus = 2.0 * u
        if lam > 1.0e-4:
            one_minus = -_log1p(-u * tail) / lam
        cos_t = wp.clamp(1.0 - one_minus, -1.0, 1.0)
        sin_t = wp.sqrt(wp.max(0.0, 1.0 - cos_t * cos_t))
        frac = float(s) * golden
        phi = 2.0 * wp.pi * (frac - wp.floor(frac)) + spin
        d = cos_t * p + sin_t * (wp.cos(phi) * e1 + wp.sin(phi) * e2)
        if wp.dot(d, n) > 0.0:
            if not wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX):
                count += 1
    visible_count[item] = count
