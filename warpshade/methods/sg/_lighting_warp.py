"""SG lighting on the Warp device: the prefiltered environment and the local-light lobes.

The float64 description and every oracle live in :mod:`._prefilter` and :mod:`._lights`; this
module holds the kernels and ``@wp.func`` helpers, float32:

* :class:`PrefilteredTable` (``@wp.struct``): the pyramid of :class:`._prefilter.PrefilteredEnvironment`
  on the device, all maps in one flat array so that a kernel takes one argument;
* :func:`gamma_hat_lookup` / :func:`gamma_lookup`: the normalised and the plain prefiltered
  environment ``Gamma_L(p, lambda)`` (eq. 34-35) at a *world* direction, given the world->map
  rotation, interpolated exactly as :meth:`._prefilter.PrefilteredEnvironment.lookup` documents;
* :data:`prefilter_kernel`: one level of the pyramid (each output texel sums the source texels
  inside the lobe's truncated support);
* :func:`point_light_sg` (eq. 32, normalised to the sphere's radiance times its solid angle) and
  :func:`directional_light_sg` (eq. 33).

Map layout (the one of :mod:`warpshade.scene._lighting`): row 0 is the map frame's +z pole,
``theta = (i + 0.5) pi / H``, azimuth ``phi = (j + 0.5) 2 pi / W`` from +x towards +y; bilinear
lookups clamp rows at the poles and wrap in azimuth (as ``env_radiance``).
"""

from __future__ import annotations

from ..._wp import wp
from ...basis.sg_warp import SG, sg_integral, sg_make, sg_sharpness_for_area
from ...scene._lighting_warp import latlong_taps

wp.set_module_options({"enable_backward": False})

__all__ = [
    "PrefilteredTable",
    "directional_light_sg",
    "gamma_hat_lookup",
    "gamma_lookup",
    "gamma_lookup_kernel",
    "point_light_kernel",
    "point_light_sg",
    "prefilter_kernel",
]

_PI = 3.141592653589793
_TWO_PI = 6.283185307179586


@wp.struct
class PrefilteredTable:
    """The prefiltered environment on one device (see :class:`._prefilter.PrefilteredEnvironment`).

    Fields:
        data: every map, flattened row-major one after the other, wp.array(vec3): the normalised
            ``Gamma_hat = Gamma / integral(G)`` of levels ``0 .. level_count - 1`` and, last, the
            environment itself (the lambda -> infinity limit), map frame, linear RGB.
        offset: start of each map in ``data``, (level_count + 1,) int32.
        height, width: size of each map, (level_count + 1,) int32.
        log_lambda: natural log of each level's sharpness, (level_count,) float32, increasing.
        level_count: number of prefiltered levels (>= 1).
        lambda_first, lambda_last: the first and last level's sharpness.
        mean: ``Gamma_hat`` at lambda = 0, the mean radiance ``(env integral) / (4 pi)``.
    """

    data: wp.array(dtype=wp.vec3)
    offset: wp.array(dtype=wp.int32)
    height: wp.array(dtype=wp.int32)
    width: wp.array(dtype=wp.int32)
    log_lambda: wp.array(dtype=float)
    level_count: int
    lambda_first: float
    lambda_last: float
    mean: wp.vec3


@wp.func
def _map_bilinear(table: PrefilteredTable, level: int, d: wp.vec3) -> wp.vec3:
    w = table.width[level]
    base = table.offset[level]
    t = latlong_taps(d, table.height[level], w)
    top = (1.0 - t.fu) * table.data[base + t.r0 * w + t.c0] + t.fu * table.data[base + t.r0 * w + t.c1]
    bottom = (1.0 - t.fu) * table.data[base + t.r1 * w + t.c0] + t.fu * table.data[base + t.r1 * w + t.c1]
    return (1.0 - t.fv) * top + t.fv * bottom


@wp.func
def _geometric(a: wp.vec3, b: wp.vec3, t: float) -> wp.vec3:
    # a^(1-t) b^t per channel (inputs are >= 0)
    return wp.vec3(
        wp.pow(wp.max(a[0], 0.0), 1.0 - t) * wp.pow(wp.max(b[0], 0.0), t),
        wp.pow(wp.max(a[1], 0.0), 1.0 - t) * wp.pow(wp.max(b[1], 0.0), t),
        wp.pow(wp.max(a[2], 0.0), 1.0 - t) * wp.pow(wp.max(b[2], 0.0), t),
    )


@wp.func
def gamma_hat_lookup(table: PrefilteredTable, d_map: wp.vec3, lam: float) -> wp.vec3:
    """``Gamma_hat(p, lambda) = Gamma / integral(G)`` at a unit *map-frame* direction.

    lambda <= lambda_first: linear in lambda from the mean radiance; between levels: geometric
    (linear in log lambda of log Gamma_hat); lambda >= lambda_last: linear in the lobe width
    ``sqrt(lambda_last / lambda)`` towards the environment itself.
    """
    lam_c = wp.max(lam, 0.0)
    last = table.level_count - 1
    if lam_c <= table.lambda_first:
        t = lam_c / table.lambda_first
        return (1.0 - t) * table.mean + t * _map_bilinear(table, 0, d_map)
    if lam_c >= table.lambda_last:
        s = wp.sqrt(table.lambda_last / lam_c)
        return s * _map_bilinear(table, last, d_map) + (1.0 - s) * _map_bilinear(table, last + 1, d_map)
    ll = wp.log(lam_c)
    k = int(0)
    while k < last - 1 and table.log_lambda[k + 1] <= ll:
        k += 1
    t = wp.clamp((ll - table.log_lambda[k]) / (table.log_lambda[k + 1] - table.log_lambda[k]), 0.0, 1.0)
    return _geometric(_map_bilinear(table, k, d_map), _map_bilinear(table, k + 1, d_map), t)


@wp.func
def gamma_lookup(table: PrefilteredTable, world_to_map: wp.mat33, p: wp.vec3, lam: float) -> wp.vec3:
    """``Gamma_L(p, lambda) = integral G(i; p, lambda, 1) L(i) di`` (eq. 34-35), RGB.

    Args:
        table: the prefiltered environment.
        world_to_map: rotation taking world directions to the table's map frame (the transpose of
            the environment's current ``to_world``: a turning sky costs nothing).
        p: lobe axis, world frame (normalised here).
        lam: lobe sharpness (negative values are treated as 0).
    """
    lam_c = wp.max(lam, 0.0)
    d = wp.normalize(world_to_map * p)
    unit = sg_integral(sg_make(d, lam_c, wp.vec3(1.0, 1.0, 1.0)))
    return wp.cw_mul(gamma_hat_lookup(table, d, lam_c), unit)


@wp.kernel
def gamma_lookup_kernel(table: PrefilteredTable, world_to_map: wp.mat33, dirs: wp.array(dtype=wp.vec3),
                        lams: wp.array(dtype=float), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = gamma_lookup(table, world_to_map, dirs[i], lams[i])


@wp.kernel
def prefilter_kernel(
    src: wp.array2d(dtype=wp.vec3),
    src_dir: wp.array2d(dtype=wp.vec3),
    row_weight: wp.array(dtype=float),
    out_height: int,
    out_width: int,
    lam: float,
    support_angle: float,
    inv_integral: float,
    start: int,
    out: wp.array(dtype=wp.vec3),
):
    """One pyramid level: ``out[texel] = sum_s G(s; p, lam) L(s) w(s) / integral(G)``.

    ``src`` is the source map (H_s, W_s) of radiance values, ``src_dir`` the unit map-frame
    direction each stands for, ``row_weight`` the texel solid angle of each row (see
    :func:`._envmap.source_chain`). Source texels farther than ``support_angle`` from the lobe axis (where
    the lobe is below the truncation threshold) are skipped, conservatively by row band and
    azimuth window; ``G`` is evaluated as ``exp(-lam |p - s|^2 / 2)`` (no cancellation in
    ``1 - p.s`` for sharp lobes).
    """
    idx = wp.tid() + start
    i = idx // out_width
    j = idx - i * out_width
    theta_p = (float(i) + 0.5) * _PI / float(out_height)
    phi_p = (float(j) + 0.5) * _TWO_PI / float(out_width)
    st = wp.sin(theta_p)
    p = wp.vec3(st * wp.cos(phi_p), st * wp.sin(phi_p), wp.cos(theta_p))
    hs = src.shape[0]
    ws = src.shape[1]
    dtheta = _PI / float(hs)
    dphi = _TWO_PI / float(ws)
    lo = theta_p - support_angle
    hi = theta_p + support_angle
    r_begin = wp.clamp(int(wp.floor(lo / dtheta)), 0, hs - 1)
    r_end = wp.clamp(int(wp.floor(hi / dtheta)), 0, hs - 1)
    c_begin = int(0)
    c_count = ws
    if lo > 0.0 and hi < _PI:
        half = wp.asin(wp.min(1.0, wp.sin(support_angle) / st))
        c_begin = int(wp.floor((phi_p - half) / dphi))
        c_count = wp.min(int(wp.floor((phi_p + half) / dphi)) - c_begin + 1, ws)
    acc = wp.vec3(0.0)
    for r in range(r_begin, r_end + 1):
        row = wp.vec3(0.0)
        for cc in range(c_count):
            c = ((c_begin + cc) % ws + ws) % ws
            q = p - src_dir[r, c]
            row += src[r, c] * wp.exp(-0.5 * lam * wp.dot(q, q))
        acc += row * row_weight[r]
    out[idx] = acc * inv_integral


# ---- local lights (eq. 32-33) -----------------------------------------------------------------
@wp.func
def point_light_sg(position: wp.vec3, radius: float, radiance: wp.vec3, x: wp.vec3) -> SG:
    """The SG of a sphere light seen from ``x`` (eq. 32), float32 mirror of
    :func:`._lights.point_light_lobe`: axis towards the centre, sharpness
    ``f_a^-1(2 pi r^2 / d^2)``, amplitude such that the lobe integrates to ``radiance`` times the
    sphere's solid angle from ``x``. A receiver inside the sphere (``d <= r``) gets the constant
    lobe (sharpness 0, amplitude ``radiance``): it sees the light in every direction."""
    offset = position - x
    d = wp.length(offset)
    axis = wp.vec3(0.0, 0.0, 1.0)
    if d > 1.0e-20:
        axis = offset / d
    if d <= radius:
        return sg_make(axis, 0.0, radiance)
    sin_a = radius / d
    sin2 = sin_a * sin_a
    cos_a = wp.sqrt(wp.max(0.0, 1.0 - sin2))
    solid = _TWO_PI * sin2 / (1.0 + cos_a)  # 2 pi (1 - cos a), without cancellation
    lam = sg_sharpness_for_area(_TWO_PI * sin2)
    unit = sg_integral(sg_make(axis, lam, wp.vec3(1.0, 1.0, 1.0)))
    return sg_make(axis, lam, radiance * (solid / unit[0]))


@wp.func
def directional_light_sg(direction: wp.vec3, sharpness: float, amplitude: wp.vec3) -> SG:
    """The SG of a distant light (eq. 33) from :func:`._lights.directional_light_lobe`'s values
    (``direction`` towards the light, world frame; normalised here)."""
    return sg_make(wp.normalize(direction), sharpness, amplitude)


@wp.kernel
def point_light_kernel(position: wp.vec3, radius: float, radiance: wp.vec3, x: wp.array(dtype=wp.vec3),
                       axes: wp.array(dtype=wp.vec3), sharpness: wp.array(dtype=float),
                       amplitude: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    g = point_light_sg(position, radius, radiance, x[i])
    axes[i] = g.axis
    sharpness[i] = g.sharpness
    amplitude[i] = g.amplitude
