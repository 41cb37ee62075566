"""Warp kernels of SHEXP (Ren et al. 2006): per-receiver blocker accumulation, exp and shading.

One pass over receivers (:func:`receiver_kernel`): for each receiver vertex ``p`` with unit
normal ``N``

1. walk its blocker list -- the cut of its receiver cluster (``cut_nodes``; the flat list of all
   leaf spheres is the one-cluster special case), skipping static spheres for receivers whose
   static visibility is baked;
2. replace or drop each sphere by the self-shadowing rules of sec. 6.2 (:func:`effective_sphere`);
3. accumulate ``f += W F(theta) y(s)`` (eqs. 34, 38: ``theta = asin(r / |P - p|)``,
   ``s = (P - p)/|P - p|``, F from the blocking-cap log table, W the per-band ratio vector of
   the cut entry) -- or, for the product baseline (Zhou et al. 2005), ``g = g * G(theta) y(s)``
   with the cap's visibility itself;
4. exponentiate (PS-p, PS*-p, OL or HYB; :func:`warpshade.basis.sh_warp.sh_kernels`) and window;
5. shade: ``radiance_c = albedo_c / pi * max(0, (L_c, g, X))`` with ``X = H(N)``, the clamped
   cosine about N (or a baked static transfer ``T_p``), by one of

   * ``"direct"``: ``t = g * X`` (one SH product), ``dot(L_c, t)``;
   * ``"table"``: ``dot(L_H,c(N), g)`` with ``L_H(N) = L * H(N)`` tabulated over normals on a
     lat-long grid (rebuilt per frame by :func:`lh_table_kernel`, bilinear lookup);
   * ``"product_matrix"``: ``dot(M_L,c g, X)`` with the lighting's product matrices built per
     frame -- the paper's path for lighting that changes every frame.

   All three are the exact triple integral of the order-n vectors except for the table's
   interpolation. Sphere lights add ``L_e,c (L_s, g, X)`` -- exactly (cap SH dotted with t) in
   "direct" mode, through the single-ZH-lobe fit of ``H * L_s`` (sec. 7, :mod:`.tables`) in
   the other modes.

Conventions follow :mod:`warpshade.methods.prt`: H here has no 1/pi (it is the transfer of an
unshadowed receiver, ``H_lm = A_l y_lm(N)``), so with no blockers the radiance equals
``prt.unshadowed`` exactly (paper eq. 9 puts the 1/pi into H instead).

Also here: :func:`sphere_trace_kernel`, a ray-traced reference that intersects rays with the
(replaced) blocker spheres instead of the mesh (the paper's Fig. 7b), and the small kernels for
ratio vectors and lighting tables.
"""

# No "from __future__ import annotations": Warp resolves closure types in annotations.

import functools
import math

import numpy as np

from ..._wp import wp
from ...basis import sh
from ...basis.sh_warp import SHExpTables, SHTables, sh_kernels
from ...geometry.frames import onb_tangent
from ...scene.lighting_warp import EnvironmentMap, env_pdf, env_radiance, env_sample

wp.set_module_options({"enable_backward": False})

__all__ = [
    "RULES",
    "SHADE_MODES",
    "ACCUMULATE",
    "MODULE_OPTIONS",
    "BlockerSet",
    "ReceiverSet",
    "ShadeInputs",
    "effective_sphere",
    "effective_sphere_kernel",
    "plane_cap",
    "PLANE_ON_SURFACE",
    "receiver_kernel",
    "lh_table_kernel",
    "ratio_kernel",
    "sphere_trace_kernel",
    "vec3_to_rows_kernel",
    "cosine_zh",
]

#: Self-shadowing replacement rules (sec. 6.2), in the order of the kernels' ``rule`` argument:
#: "none" keeps every sphere the receiver is outside of (and drops those containing it),
#: "paper" is the text's rule, "continuous" blends the straddling replacement from the
#: inside rule at the sphere boundary (see :func:`effective_sphere`).
RULES = ("none", "paper", "continuous")
#: Shading paths of :func:`receiver_kernel`.
SHADE_MODES = ("direct", "table", "product_matrix")
#: Accumulation of blocker visibility: SHEXP's log space, or the product baseline.
ACCUMULATE = ("log", "product")
#: Per-order kernels keep loops over n*n coefficients as loops: unrolling them multiplies
#: compile time (about 1.5x at n = 4) for no run-time gain (benchmarks/bench_shexp.py).
MODULE_OPTIONS = {"max_unroll": 4}

INV_PI = 1.0 / math.pi
INV_SQRT_4PI = 1.0 / math.sqrt(4.0 * math.pi)
#: Largest accepted norm of a visibility vector: a function with values in [0, 1] projects to
#: norm <= sqrt(4 pi); 1.5x leaves room for the ringing of truncated products.
VISIBILITY_NORM_LIMIT = 1.5 * math.sqrt(4.0 * math.pi)


@wp.struct
class BlockerSet:
    """Blocker spheres of one frame and the per-cluster lists each receiver walks.

    Fields:
        centres: sphere centres, world space, (node_count,) vec3 (hierarchy nodes or leaves).
        radii: radii, scene units, (node_count,) float32.
        is_static: 1 for spheres of static geometry (skipped by receivers with baked static
            visibility), (node_count,) int32.
        cut_nodes: per receiver cluster, the node indices to accumulate, (clusters, capacity)
            int32; entries at and after ``cut_count[c]`` are ignored.
        cut_count: entries used per cluster, (clusters,) int32.
        cut_weights: per-band ratio vectors W of each entry (eq. 37), (clusters, capacity, n)
            float32; read only when ``weighted`` is 1.
        weighted: 1 to apply ``cut_weights``.
        plane_centre, plane_normal, plane_radius: static planar blockers (ground planes) as
            discs of equivalent radius, (P,) each (see :func:`plane_cap`); skipped by receivers
            with baked static visibility.
    """

    centres: wp.array(dtype=wp.vec3)
    radii: wp.array(dtype=wp.float32)
    is_static: wp.array(dtype=wp.int32)
    cut_nodes: wp.array2d(dtype=wp.int32)
    cut_count: wp.array(dtype=wp.int32)
    cut_weights: wp.array3d(dtype=wp.float32)
    weighted: int
    plane_centre: wp.array(dtype=wp.vec3)
    plane_normal: wp.array(dtype=wp.vec3)
    plane_radius: wp.array(dtype=wp.float32)


@wp.struct
class ReceiverSet:
    """Receiver vertices of one frame.

    Fields:
        points, normals: world positions and unit normals, (V,) vec3.
        albedo: diffuse albedo, (V, 3) float32, linear RGB.
        cluster: receiver cluster of each vertex (row of the cut lists), (V,) int32.
        baked: 1 where static visibility is baked into ``bake`` (static receivers), (V,) int32.
        bake: baked transfer ``T_p`` (cosine-weighted static visibility, world frame, no 1/pi)
            used instead of ``H(N)``, (V, n*n) float32 (a (1, n*n) placeholder when nothing is baked).
    """

    points: wp.array(dtype=wp.vec3)
    normals: wp.array(dtype=wp.vec3)
    albedo: wp.array2d(dtype=wp.float32)
    cluster: wp.array(dtype=wp.int32)
    baked: wp.array(dtype=wp.int32)
    bake: wp.array2d(dtype=wp.float32)


@wp.struct
class ShadeInputs:
    """Lighting of one frame.

    Fields:
        light: distant lighting SH per channel, world frame, (3, n*n) float32.
        cosine_zh: clamped-cosine ZH coefficients (``sh.clamped_cosine_zh(n, "zh")``), (n,).
        window: per-band visibility window ``alpha_l``, (n,) float32 (all 1 = none).
        lh_table: ``L * H(N)`` on a lat-long grid of normals, (rows, cols, 3, n*n) float32
            (table mode; vertex-centred: row 0 = +z pole, last row = -z pole, see
            :func:`latlong_lookup_pos`).
        light_matrix: product matrices ``M_L,c``, (3, n*n, n*n) float32 (product_matrix mode).
        sphere_position, sphere_radius, sphere_radiance: sphere lights, world space, (S,) each.
        lobe_axis_angle: fitted ZH lobe axis angle psi(theta, phi) from N towards the light,
            (T, P) float32; lobe_zh: its ZH coefficients, (T, P, n) float32; grid over
            theta in [0, pi/2] (light angular radius) and phi in [0, pi] (light direction vs N).
    """

    light: wp.array2d(dtype=wp.float32)
    cosine_zh: wp.array(dtype=wp.float32)
    window: wp.array(dtype=wp.float32)
    lh_table: wp.array4d(dtype=wp.float32)
    light_matrix: wp.array3d(dtype=wp.float32)
    sphere_position: wp.array(dtype=wp.vec3)
    sphere_radius: wp.array(dtype=wp.float32)
    sphere_radiance: wp.array(dtype=wp.vec3)
    lobe_axis_angle: wp.array2d(dtype=wp.float32)
    lobe_zh: wp.array3d(dtype=wp.float32)


# ---- self-shadowing replacement rules (sec. 6.2) ----------------------------------------------
@wp.func
def effective_sphere(p: wp.vec3, n: wp.vec3, centre: wp.vec3, radius: float, rule: int) -> wp.vec4:
    """The sphere a receiver accumulates in place of ``(centre, radius)``; w <= 0: none.

    With ``hc = (P - p).N`` the signed height of the centre over the tangent plane ``T_p``:

    * a sphere entirely behind ``T_p`` (``hc <= -r``), of non-positive or non-finite radius,
      or with a non-finite centre, is dropped;
    * receiver inside the sphere: dropped if the centre is behind ``T_p``, else shrunk (same
      centre) until tangent to ``T_p`` (radius ``hc``);
    * receiver outside, sphere entirely in front (``hc >= r``): kept;
    * receiver outside, sphere straddling ``T_p``: replaced by a sphere ``S'`` tangent to
      ``T_p`` at ``q1`` (the projection of the centre), in front of it. The paper: ``S'`` has
      diameter ``|q0 - q1| = h = hc + r`` (``q0`` the point of S farthest in front), scaled
      by ``a = max(1, (|p - q1| - d) / d)`` with ``d = sqrt(r^2 - (r - h)^2)`` the radius of
      the disc S cuts from ``T_p`` (rule "paper"; the scaled radius is capped at r, which the
      text leaves open, so the replacement never outgrows the sphere it replaces). At the
      sphere boundary ``|p - q1| = d`` this jumps from the inside rule's sphere (none, or
      radius ``hc``) to radius ``h/2``; rule "continuous" instead blends the radius linearly
      from the inside rule's ``max(hc, 0)`` at ``|p - q1| = d`` to ``h/2`` at ``2d`` and
      continues with the paper's ``a`` beyond, so shading is continuous across the boundary.
    * rule "none": spheres containing the receiver are dropped, all others kept as they are.

    Returns:
        ``(centre', radius')``; radius' <= 0 means the sphere is not accumulated.
    """
    none = wp.vec4(0.0, 0.0, 0.0, -1.0)
    if not (radius > 0.0 and radius < 1.0e30):
        return none
    if not (wp.isfinite(centre[0]) and wp.isfinite(centre[1]) and wp.isfinite(centre[2])):
        return none
    offset = centre - p
    dist = wp.length(offset)
    if rule == 0:
        if dist <= radius:
            return none
        return wp.vec4(centre[0], centre[1], centre[2], radius)
    hc = wp.dot(offset, n)
    if hc <= -radius:
        return none
    if dist < radius:
        if hc <= 0.0:
            return none
        return wp.vec4(centre[0], centre[1], centre[2], hc)
    if hc >= radius:
        return wp.vec4(centre[0], centre[1], centre[2], radius)
    h = hc + radius
    q1 = centre - hc * n
    d = wp.sqrt(wp.max(radius * radius - hc * hc, 0.0))
    along = wp.length(p - q1)
    r_new = float(0.0)
    if d <= 1.0e-7 * radius:
        r_new = radius
    else:
        t = (along - d) / d
        if rule == 1:
            r_new = wp.min(wp.max(1.0, t) * 0.5 * h, radius)
        else:
            if t < 1.0:
                r_in = wp.max(hc, 0.0)
                r_new = r_in + wp.max(t, 0.0) * (0.5 * h - r_in)
            else:
                r_new = wp.min(t * 0.5 * h, radius)
    c_new = q1 + r_new * n
    return wp.vec4(c_new[0], c_new[1], c_new[2], r_new)


@wp.kernel
def effective_sphere_kernel(
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    centres: wp.array(dtype=wp.vec3),
    radii: wp.array(dtype=wp.float32),
    rule: int,
    out: wp.array(dtype=wp.vec4),
):
    """Row i: :func:`effective_sphere` of sphere i seen from receiver i (for checks)."""
    i = wp.tid()
    out[i] = effective_sphere(points[i], wp.normalize(normals[i]), centres[i], radii[i], rule)


#: Receivers closer than this fraction of a plane blocker's radius to its plane lie on it (the
#: ground's own vertices) and do not accumulate it.
PLANE_ON_SURFACE = 1.0e-3


@wp.func
def plane_cap(p: wp.vec3, centre: wp.vec3, normal: wp.vec3, radius: float) -> wp.vec4:
    """(axis, theta) of the blocking cap of a planar blocker seen from p; theta <= 0: none.

    The plane (a static open mesh such as a ground) is modelled as a disc of radius R about its
    centre; from a receiver at height h over it, it blocks the cap of half-angle
    ``atan(R / |h|)`` about the direction towards the plane (``-sign(h) N``). Receivers on the
    plane itself (``|h| < PLANE_ON_SURFACE R``) get nothing. This extends the paper, whose
    blockers are spheres only: without it, receivers on moving geometry would see through the
    ground (their static blockers must be accumulated every frame, sec. 7).
    """
    h = wp.dot(p - centre, normal)
    if not (radius > 0.0) or wp.abs(h) < float(PLANE_ON_SURFACE) * radius:
        return wp.vec4(0.0, 0.0, 1.0, -1.0)
    axis = -normal
    if h < 0.0:
        axis = normal
    return wp.vec4(axis[0], axis[1], axis[2], wp.atan(radius / wp.abs(h)))


@wp.func
def sphere_angle(p: wp.vec3, sphere: wp.vec4) -> wp.vec4:
    """(s, theta): unit direction from p to the sphere's centre and its angular radius."""
    offset = wp.vec3(sphere[0], sphere[1], sphere[2]) - p
    dist = wp.length(offset)
    s = offset / wp.max(dist, 1.0e-30)
    theta = wp.asin(wp.clamp(sphere[3] / wp.max(dist, 1.0e-30), 0.0, 1.0))
    return wp.vec4(s[0], s[1], s[2], theta)


@wp.func
def latlong_lookup_pos(d: wp.vec3, rows: int, cols: int) -> wp.vec3:
    """(row, column) position of a unit direction on the vertex-centred z-up lat-long grid.

    Grid node (i, j) is the direction at polar angle ``i pi / (rows - 1)`` (rows 0 and
    rows - 1 are the poles, so normals at the poles are exact) and azimuth ``j 2 pi / cols``.
    """
    theta = wp.acos(wp.clamp(d[2], -1.0, 1.0))
    phi = wp.atan2(d[1], d[0])
    if phi < 0.0:
        phi = phi + 2.0 * wp.pi
    v = theta / wp.pi * float(rows - 1)
    u = phi / (2.0 * wp.pi) * float(cols)
    return wp.vec3(v, u, 0.0)


@functools.lru_cache(maxsize=None)
def receiver_kernel(order: int, method: str = "hyb", shade: str = "direct", accumulate: str = "log"):
    """The per-receiver SHEXP kernel of one configuration (compiled once per configuration).

    Signature: ``(blockers: BlockerSet, receivers: ReceiverSet, shading: ShadeInputs,
    tables: SHTables, exp_tables: SHExpTables, degree: int, rule: int, start: int,
    radiance: array2d(float32) (V, 3), visibility: array2d(float32) (V, n*n),
    store_visibility: int, fallbacks: array(int32) (1,))``; thread ``i`` handles receiver
    ``start + i``. ``visibility`` gets the windowed visibility vector g when
    ``store_visibility`` is 1. Receivers whose g leaves the bound of a visibility function
    (norm > :data:`VISIBILITY_NORM_LIMIT`, or not finite -- the truncated series far outside
    its domain) are shaded with ``exp(mean log visibility) * 1`` instead and counted in
    ``fallbacks[0]``.

    Args:
        order: SH order n of accumulation, exponentiation and shading.
        method: exp method (:data:`warpshade.basis.sh.EXP_METHODS`), for ``accumulate="log"``.
        shade: one of :data:`SHADE_MODES`.
        accumulate: "log" (SHEXP) or "product" (the Zhou et al. baseline).
    """
    if method not in sh.EXP_METHODS:
        raise ValueError(f"shexp: method must be one of {sh.EXP_METHODS}, got {method!r}")
    if shade not in SHADE_MODES:
        raise ValueError(f"shexp: shade must be one of {SHADE_MODES}, got {shade!r}")
    if accumulate not in ACCUMULATE:
        raise ValueError(f"shexp: accumulate must be one of {ACCUMULATE}, got {accumulate!r}")
    k = sh_kernels(order)
    vec_t, bands_t = k.vec, k.bands
    ORDER = order
    N = order * order
    zh_to_sh, product, dot = k.zh_to_sh, k.product, k.dot
    scale_bands, one = k.scale_bands, k.one
    log_cap_zh, cap_zh_blocked, zh_accumulate = k.log_cap_zh, k.cap_zh_blocked, k.zh_accumulate
    exp_ps, exp_ps_star, exp_ol, exp_hyb = k.exp_ps, k.exp_ps_star, k.exp_ol, k.exp_hyb
    LOG = accumulate == "log"
    METHOD = method
    SHADE = shade

    @wp.func
    def exponentiate(f: vec_t, degree: int, tables: SHTables, exp_tables: SHExpTables) -> vec_t:
        if wp.static(METHOD == "ps"):
            return exp_ps(f, degree, tables)
        elif wp.static(METHOD == "ps_star"):
            return exp_ps_star(f, degree, tables)
        elif wp.static(METHOD == "ol"):
            return exp_ol(f, exp_tables)
        else:
            return exp_hyb(f, tables, exp_tables)

    @wp.func
    def cosine_lobe(n: wp.vec3, shading: ShadeInputs) -> vec_t:
        zh = bands_t()
        for l in range(ORDER):
            zh[l] = shading.cosine_zh[l]
        return zh_to_sh(n, zh)

    @wp.func
    def light_row(shading: ShadeInputs, c: int) -> vec_t:
        v = vec_t()
        for i in range(N):
            v[i] = shading.light[c, i]
        return v

    @wp.func
    def table_dot(shading: ShadeInputs, n: wp.vec3, g: vec_t) -> wp.vec3:
        # bilinear L_H(N) . g on the lat-long normal grid (wrap in azimuth, clamp at the poles)
        rows = shading.lh_table.shape[0]
        cols = shading.lh_table.shape[1]
        pos = latlong_lookup_pos(n, rows, cols)
        r0 = wp.clamp(int(pos[0]), 0, rows - 2)
        r1 = r0 + 1
        fv = wp.clamp(pos[0] - float(r0), 0.0, 1.0)
        c0 = wp.clamp(int(pos[1]), 0, cols - 1)
        fu = wp.clamp(pos[1] - float(c0), 0.0, 1.0)
        c1 = (c0 + 1) % cols
        w00 = (1.0 - fv) * (1.0 - fu)
        w01 = (1.0 - fv) * fu
        w10 = fv * (1.0 - fu)
        w11 = fv * fu
        out = wp.vec3(0.0)
        for c in range(3):
            acc = float(0.0)
            for i in range(N):
                lh = (
                    w00 * shading.lh_table[r0, c0, c, i]
                    + w01 * shading.lh_table[r0, c1, c, i]
                    + w10 * shading.lh_table[r1, c0, c, i]
                    + w11 * shading.lh_table[r1, c1, c, i]
                )
                acc += lh * g[i]
            out[c] = acc
        return out

    @wp.func
    def matrix_dot(shading: ShadeInputs, x: vec_t, g: vec_t) -> wp.vec3:
        # (M_L,c g) . X
        out = wp.vec3(0.0)
        for c in range(3):
            acc = float(0.0)
            for i in range(N):
                row = float(0.0)
                for j in range(N):
                    row += shading.light_matrix[c, i, j] * g[j]
                acc += row * x[i]
            out[c] = acc
        return out

    @wp.func
    def lobe_lookup(shading: ShadeInputs, theta: float, phi: float) -> vec_t:
        # bilinear (psi, z_l) of the fitted single-ZH lobe; returned packed as
        # (z_0 .. z_{n-1}, psi) in the first n+1 slots of a coefficient vector
        rows = shading.lobe_axis_angle.shape[0]
        cols = shading.lobe_axis_angle.shape[1]
        v = wp.clamp(theta / (0.5 * wp.pi), 0.0, 1.0) * float(rows - 1)
        u = wp.clamp(phi / wp.pi, 0.0, 1.0) * float(cols - 1)
        r0 = wp.min(int(v), rows - 2)
        c0 = wp.min(int(u), cols - 2)
        fv = v - float(r0)
        fu = u - float(c0)
        w00 = (1.0 - fv) * (1.0 - fu)
        w01 = (1.0 - fv) * fu
        w10 = fv * (1.0 - fu)
        w11 = fv * fu
        out = vec_t()
        for l in range(ORDER):
            out[l] = (
                w00 * shading.lobe_zh[r0, c0, l] + w01 * shading.lobe_zh[r0, c0 + 1, l]
                + w10 * shading.lobe_zh[r0 + 1, c0, l] + w11 * shading.lobe_zh[r0 + 1, c0 + 1, l]
            )
        out[ORDER] = (
            w00 * shading.lobe_axis_angle[r0, c0] + w01 * shading.lobe_axis_angle[r0, c0 + 1]
            + w10 * shading.lobe_axis_angle[r0 + 1, c0] + w11 * shading.lobe_axis_angle[r0 + 1, c0 + 1]
        )
        return out

    @wp.func
    def k_cap(theta: float) -> bands_t:
        # cap indicator (not blocked): sqrt(4 pi) delta_l0 - blocked visibility
        vis = cap_zh_blocked(theta)
        out = bands_t()
        for l in range(ORDER):
            out[l] = -vis[l]
        out[0] = out[0] + 2.0 * wp.sqrt(wp.pi)
        return out

    @wp.func
    def sphere_lights(shading: ShadeInputs, p: wp.vec3, n: wp.vec3, g: vec_t, t: vec_t, exact: int) -> wp.vec3:
        # sum over sphere lights of L_e,c (L_s, g, X): exact through t = g * X, or through the
        # fitted single-lobe L_H(theta, phi) (sec. 7)
        total = wp.vec3(0.0)
        for s in range(shading.sphere_position.shape[0]):
            offset = shading.sphere_position[s] - p
            dist = wp.length(offset)
            radius = shading.sphere_radius[s]
            value = float(0.0)
            if dist <= radius:
                # receiver inside the light: uniform radiance over the sphere, (1, g, X)
                value = dot(one(), t)
                if exact == 0:
                    value = dot(cosine_lobe(n, shading), g)
            else:
                d = offset / dist
                theta = wp.asin(wp.min(radius / dist, 1.0))
                if exact != 0:
                    value = dot(zh_to_sh(d, k_cap(theta)), t)
                else:
                    phi = wp.acos(wp.clamp(wp.dot(d, n), -1.0, 1.0))
                    packed = lobe_lookup(shading, theta, phi)
                    tangent = d - wp.dot(d, n) * n
                    tl = wp.length(tangent)
                    axis = n
                    if tl > 1.0e-6:
                        psi = packed[ORDER]
                        axis = wp.cos(psi) * n + wp.sin(psi) * (tangent / tl)
                    zh = bands_t()
                    for l in range(ORDER):
                        zh[l] = packed[l]
                    value = dot(zh_to_sh(axis, zh), g)
            total += shading.sphere_radiance[s] * value
        return total

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def kernel(
        blockers: BlockerSet,
        receivers: ReceiverSet,
        shading: ShadeInputs,
        tables: SHTables,
        exp_tables: SHExpTables,
        degree: int,
        rule: int,
        start: int,
        radiance: wp.array2d(dtype=wp.float32),
        visibility: wp.array2d(dtype=wp.float32),
        store_visibility: int,
        fallbacks: wp.array(dtype=wp.int32),
    ):
        v = start + wp.tid()
        p = receivers.points[v]
        n = wp.normalize(receivers.normals[v])
        baked = receivers.baked[v]
        cluster = receivers.cluster[v]
        count = blockers.cut_count[cluster]
        acc = vec_t()
        dc_log = float(0.0)  # product path: sum of log mean visibilities (the fallback)
        if wp.static(not LOG):
            acc = one()
        planes = 0
        if baked == 0:
            planes = blockers.plane_radius.shape[0]
        # one loop over the cut's spheres, then the plane blockers, with a single accumulate
        # call site (the unrolled ZH rule is large; one copy keeps compile time down)
        for e in range(count + planes):
            s = wp.vec3(0.0, 0.0, 1.0)
            theta = float(-1.0)
            weighted = int(0)
            if e < count:
                node = blockers.cut_nodes[cluster, e]
                if node < 0:
                    continue
                if baked != 0 and blockers.is_static[node] != 0:
                    continue
                sphere = effective_sphere(p, n, blockers.centres[node], blockers.radii[node], rule)
                if sphere[3] <= 0.0:
                    continue
                st = sphere_angle(p, sphere)
                s = wp.vec3(st[0], st[1], st[2])
                theta = st[3]
                weighted = blockers.weighted
            else:
                k = e - count
                pc = plane_cap(p, blockers.plane_centre[k], blockers.plane_normal[k], blockers.plane_radius[k])
                s = wp.vec3(pc[0], pc[1], pc[2])
                theta = pc[3]
            if theta <= 0.0:
                continue
            if wp.static(LOG):
                zh = log_cap_zh(theta, exp_tables)
                if weighted != 0:
                    for l in range(ORDER):
                        zh[l] = zh[l] * blockers.cut_weights[cluster, e, l]
                acc = zh_accumulate(acc, s, zh)
            else:
                vis = cap_zh_blocked(theta)
                dc_log += wp.log(wp.max(vis[0] * float(INV_SQRT_4PI), 1.0e-30))
                acc = product(acc, zh_accumulate(vec_t(), s, vis), tables)
        g = acc
        if wp.static(LOG):
            g = exponentiate(acc, degree, tables, exp_tables)
            dc_log = acc[0] * float(INV_SQRT_4PI)
        # A visibility function lies in [0, 1], so its projection has norm <= sqrt(4 pi)
        # (Bessel). Far outside the series' domain (thousands of overlapping blockers) the
        # truncated exp/product leaves that bound: fall back to the scalar estimate
        # exp(mean log visibility) * 1 and count the receiver.
        g_norm = wp.length(g)
        if not (g_norm <= float(VISIBILITY_NORM_LIMIT)):
            g = one() * wp.exp(wp.min(dc_log, 0.0))
            wp.atomic_add(fallbacks, 0, 1)
        window = bands_t()
        for l in range(ORDER):
            window[l] = shading.window[l]
        g = scale_bands(g, window)
        if store_visibility != 0:
            for i in range(N):
                visibility[v, i] = g[i]

        x = vec_t()
        if baked != 0:
            for i in range(N):
                x[i] = receivers.bake[v, i]
        else:
            x = cosine_lobe(n, shading)
        rgb = wp.vec3(0.0)
        t = vec_t()
        if wp.static(SHADE == "table"):
            if baked != 0:
                t = product(g, x, tables)
                for c in range(3):
                    rgb[c] = dot(light_row(shading, c), t)
            else:
                rgb = table_dot(shading, n, g)
            rgb += sphere_lights(shading, p, n, g, t, baked)
        elif wp.static(SHADE == "product_matrix"):
            rgb = matrix_dot(shading, x, g)
            if baked != 0:
                t = product(g, x, tables)
            rgb += sphere_lights(shading, p, n, g, t, baked)
        else:
            t = product(g, x, tables)
            for c in range(3):
                rgb[c] = dot(light_row(shading, c), t)
            rgb += sphere_lights(shading, p, n, g, t, 1)
        for c in range(3):
            value = receivers.albedo[v, c] * float(INV_PI) * wp.max(rgb[c], 0.0)
            if not wp.isfinite(value):
                value = 0.0
            radiance[v, c] = value

    return kernel


@functools.lru_cache(maxsize=None)
def lh_table_kernel(order: int):
    """Kernel filling ``L * H(N)`` on a lat-long grid of normals: thread = texel.

    Signature ``(light: array2d (3, n*n), cosine_zh: array (n,), tables: SHTables,
    table: array4d (rows, cols, 3, n*n))``; texel (i, j) holds the direction at polar angle
    ``(i + 0.5) pi / rows`` and azimuth ``(j + 0.5) 2 pi / cols`` (z up).
    """
    k = sh_kernels(order)
    vec_t, bands_t, zh_to_sh, product = k.vec, k.bands, k.zh_to_sh, k.product
    ORDER = order
    N = order * order

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def kernel(
        light: wp.array2d(dtype=wp.float32),
        cosine_zh: wp.array(dtype=wp.float32),
        tables: SHTables,
        table: wp.array4d(dtype=wp.float32),
    ):
        i, j = wp.tid()
        rows = table.shape[0]
        cols = table.shape[1]
        theta = float(i) * wp.pi / float(rows - 1)
        phi = float(j) * 2.0 * wp.pi / float(cols)
        n = wp.vec3(wp.sin(theta) * wp.cos(phi), wp.sin(theta) * wp.sin(phi), wp.cos(theta))
        zh = bands_t()
        for l in range(ORDER):
            zh[l] = cosine_zh[l]
        h = zh_to_sh(n, zh)
        for c in range(3):
            lc = vec_t()
            for q in range(N):
                lc[q] = light[c, q]
            lh = product(lc, h, tables)
            for q in range(N):
                table[i, j, c, q] = lh[q]

    return kernel


@functools.lru_cache(maxsize=None)
def ratio_kernel(order: int):
    """Kernel computing the per-band ratio vectors of eq. 37 for every cut entry.

    Thread (c, e): cut entry e of cluster c with node i. At the cluster's representative point
    ``p*``, ``f_b = F(theta_i) y(s_i)`` of the node's bounding sphere and ``f_d`` = the sum of
    the same over the leaves of i (``leaf_first[i] .. leaf_first[i] + leaf_count[i]`` of
    ``leaf_index``) whose angular radius is at least ``theta_min``; then per band
    ``w_l = sum_m f_b,lm f_d,lm / sum_m f_b,lm^2`` (1 for leaves and where ``f_b`` vanishes).

    Signature ``(rep_points: array(vec3) (clusters,), node_centres, node_radii,
    leaf_first: array(int32), leaf_count: array(int32), leaf_index: array(int32),
    cut_nodes: array2d(int32), cut_count: array(int32), theta_min: float,
    exp_tables: SHExpTables, out: array3d(float32) (clusters, capacity, n))``.
    """
    k = sh_kernels(order)
    vec_t, log_cap_zh, zh_accumulate = k.vec, k.log_cap_zh, k.zh_accumulate
    ORDER = order

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def kernel(
        rep_points: wp.array(dtype=wp.vec3),
        node_centres: wp.array(dtype=wp.vec3),
        node_radii: wp.array(dtype=wp.float32),
        leaf_first: wp.array(dtype=wp.int32),
        leaf_count: wp.array(dtype=wp.int32),
        leaf_index: wp.array(dtype=wp.int32),
        cut_nodes: wp.array2d(dtype=wp.int32),
        cut_count: wp.array(dtype=wp.int32),
        theta_min: float,
        exp_tables: SHExpTables,
        out: wp.array3d(dtype=wp.float32),
    ):
        c, e = wp.tid()
        for l in range(ORDER):
            out[c, e, l] = 1.0
        if e >= cut_count[c]:
            return
        node = cut_nodes[c, e]
        if node < 0:
            return
        if leaf_count[node] <= 1:
            return
        p = rep_points[c]
        sb = sphere_angle(p, wp.vec4(node_centres[node][0], node_centres[node][1], node_centres[node][2], node_radii[node]))
        fb = zh_accumulate(vec_t(), wp.vec3(sb[0], sb[1], sb[2]), log_cap_zh(sb[3], exp_tables))
        fd = vec_t()
        first = leaf_first[node]
        for q in range(first, first + leaf_count[node]):
            leaf = leaf_index[q]
            sl = sphere_angle(p, wp.vec4(node_centres[leaf][0], node_centres[leaf][1], node_centres[leaf][2], node_radii[leaf]))
            if sl[3] >= theta_min:
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


@wp.func
def sphere_occluded(origin: wp.vec3, d: wp.vec3, blockers: BlockerSet, cluster: int, n: wp.vec3, baked: int, rule: int) -> int:
    # any-hit of the ray origin + t d (t > 0) against the receiver's replaced blocker spheres
    for e in range(blockers.cut_count[cluster]):
        node = blockers.cut_nodes[cluster, e]
        if node < 0:
            break
        if baked != 0 and blockers.is_static[node] != 0:
            continue
        sphere = effective_sphere(origin, n, blockers.centres[node], blockers.radii[node], rule)
        r = sphere[3]
        if r <= 0.0:
            continue
        oc = wp.vec3(sphere[0], sphere[1], sphere[2]) - origin
        b = wp.dot(oc, d)
        c2 = wp.dot(oc, oc) - r * r
        if b > 0.0 and b * b - c2 > 0.0:
            return 1
    if baked == 0:
        for k in range(blockers.plane_radius.shape[0]):
            pc = plane_cap(origin, blockers.plane_centre[k], blockers.plane_normal[k], blockers.plane_radius[k])
            if pc[3] > 0.0 and wp.dot(d, wp.vec3(pc[0], pc[1], pc[2])) > wp.cos(pc[3]):
                return 1
    return 0


@wp.func
def _frame_dir(axis: wp.vec3, x: float, y: float, z: float) -> wp.vec3:
    # (x, y, z) in the orthonormal basis (tangent, bitangent, axis) of a unit axis
    t = onb_tangent(axis)
    b = wp.cross(axis, t)
    return wp.normalize(x * t + y * b + z * axis)


@functools.lru_cache(maxsize=None)
def sphere_trace_kernel(order: int):
    """Ray-traced shading against the blocker spheres instead of the mesh (paper Fig. 7b).

    Per receiver, ``iterations`` MIS iterations (one cosine-weighted and one environment
    importance-sampled ray each, balance heuristic, as :mod:`warpshade.reference`) estimate
    ``albedo / pi * integral L(s) V_spheres(s) max(0, N.s) ds`` with the environment itself,
    and the same rays' cosine-weighted directions estimate the SH transfer
    ``t = integral V_spheres(s) max(0, N.s) y(s) ds`` (no 1/pi), so the spheres can also be
    shaded with the order-n SH lighting (``albedo / pi * dot(L_c, t)``) -- this separates the
    sphere approximation from SH truncation. V uses the same replaced spheres as SHEXP.

    Signature ``(blockers, receivers, env: EnvironmentMap, iterations: int, seed: int,
    rule: int, start: int, radiance: array(vec3), stderr: array(vec3),
    transfer: array2d(float32) (V, n*n))``.
    """
    k = sh_kernels(order)
    sh_eval, vec_t = k.eval, k.vec
    N = order * order

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def kernel(
        blockers: BlockerSet,
        receivers: ReceiverSet,
        env: EnvironmentMap,
        iterations: int,
        seed: int,
        rule: int,
        start: int,
        radiance: wp.array(dtype=wp.vec3),
        stderr: wp.array(dtype=wp.vec3),
        transfer: wp.array2d(dtype=wp.float32),
    ):
        v = start + wp.tid()
        p = receivers.points[v]
        n = wp.normalize(receivers.normals[v])
        cluster = receivers.cluster[v]
        baked = receivers.baked[v]
        rho = wp.vec3(receivers.albedo[v, 0], receivers.albedo[v, 1], receivers.albedo[v, 2])
        base = int(wp.rand_init(seed, v))
        mean = wp.vec3(0.0)
        m2 = wp.vec3(0.0)
        t_acc = vec_t()
        for it in range(iterations):
            state = wp.rand_init(base, it)
            u1 = wp.randf(state)
            u2 = wp.randf(state)
            r = wp.sqrt(u1)
            phi = 2.0 * wp.pi * u2
            d = _frame_dir(n, r * wp.cos(phi), r * wp.sin(phi), wp.sqrt(wp.max(0.0, 1.0 - u1)))
            x = wp.vec3(0.0)
            if sphere_occluded(p, d, blockers, cluster, n, baked, rule) == 0:
                # cosine-weighted pdf cos/pi: transfer sample = pi * y(d)
                t_acc = t_acc + sh_eval(d) * wp.pi
                c = wp.max(wp.dot(n, d), 0.0)
                x += env_radiance(env, d) * (c / wp.pi) / (c / wp.pi + env_pdf(env, d))
            s = env_sample(env, wp.randf(state), wp.randf(state), wp.randf(state), wp.randf(state))
            d2 = wp.vec3(s[0], s[1], s[2])
            c2 = wp.dot(n, d2)
            if c2 > 0.0 and s[3] > 0.0:
                if sphere_occluded(p, d2, blockers, cluster, n, baked, rule) == 0:
                    x += env_radiance(env, d2) * (c2 / wp.pi) / (s[3] + c2 / wp.pi)
            x = wp.cw_mul(rho, x)
            delta = x - mean
            mean += delta / float(it + 1)
            m2 += wp.cw_mul(delta, x - mean)
        radiance[v] = mean
        var = m2 / float(wp.max((iterations - 1) * iterations, 1))
        stderr[v] = wp.vec3(wp.sqrt(wp.max(var[0], 0.0)), wp.sqrt(wp.max(var[1], 0.0)), wp.sqrt(wp.max(var[2], 0.0)))
        for i in range(N):
            transfer[v, i] = t_acc[i] / float(iterations)

    return kernel


@wp.kernel
def vec3_to_rows_kernel(src: wp.array(dtype=wp.vec3), dst: wp.array2d(dtype=wp.float32)):
    """dst[i] = src[i] as a (count, 3) float32 array."""
    i = wp.tid()
    v = src[i]
    dst[i, 0] = v[0]
    dst[i, 1] = v[1]
    dst[i, 2] = v[2]


def cosine_zh(order: int) -> np.ndarray:
    """Clamped-cosine ZH coefficients (``"zh"`` normalisation) as float32, shape (n,)."""
    return sh.clamped_cosine_zh(order, "zh").astype(np.float32)
