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
   "direct" mode, through the single-ZH-lobe fit of ``H * L_s`` (sec. 7, :mod:`._tables`) in
   the other modes.

Conventions follow :mod:`warpshade.methods.prt`: H here has no 1/pi (it is the transfer of an
unshadowed receiver, ``H_lm = A_l y_lm(N)``), so with no blockers the radiance equals
``prt.unshadowed`` exactly (paper eq. 9 puts the 1/pi into H instead).

Also here: the blocker geometry shared with the other SHEXP kernels (:func:`effective_sphere`,
:func:`plane_cap`, :func:`sphere_angle`) and the lighting-table kernel. The ray-traced reference
against the same spheres is :mod:`._trace_kernels`; the ratio vectors of the hierarchy cut are
:mod:`._cut_kernels`.
"""

# No "from __future__ import annotations": Warp resolves closure types in annotations.

import functools
import math

import numpy as np

from ..._wp import wp
from ...basis import sh
from ...basis.sh_warp import SHExpTables, SHTables, sh_kernels

wp.set_module_options({"enable_backward": False})

__all__ = [
    "RULES",
    "SHADE_MODES",
    "ACCUMULATE",
    "MODULE_OPTIONS",
    "BlockerSet",
    "ReceiverSet",
    "ShadeInputs",
    "ReceiverOutputs",
    "effective_sphere",
    "effective_sphere_kernel",
    "plane_cap",
    "PLANE_ON_SURFACE",
    "receiver_kernel",
    "lh_table_kernel",
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


@wp.struct
class ReceiverOutputs:
    """Per-receiver outputs of :func:`receiver_kernel`.

    Fields:
        radiance: outgoing radiance, (V, 3) float32, linear RGB.
        visibility: windowed visibility vector g, world frame, (V, n*n) float32 (written only
            when ``store_visibility`` is 1; a (1, n*n) placeholder otherwise).
        store_visibility: 1 to write ``visibility``.
        fallbacks: (1,) int32, incremented once per receiver shaded with the scalar fallback.
    """

    radiance: wp.array2d(dtype=wp.float32)
    visibility: wp.array2d(dtype=wp.float32)
    store_visibility: int
    fallbacks: wp.array(dtype=wp.int32)


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
def blocker_cap(blockers: BlockerSet, p: wp.vec3, n: wp.vec3, cluster: int, count: int, baked: int, rule: int,
                e: int) -> wp.vec4:
    """(s, theta) of entry e of a receiver's blocker list; theta <= 0: nothing to accumulate.

    Entries ``0 .. count - 1`` are the cut of the receiver's cluster (``count =
    blockers.cut_count[cluster]``): the sphere after the self-shadowing ``rule``
    (:func:`effective_sphere`), seen as the cap :func:`sphere_angle`; static spheres are
    skipped for ``baked`` receivers. Entries from ``count`` on are the plane blockers
    (:func:`plane_cap`), which only unbaked receivers walk.
    """
    if e < count:
        node = blockers.cut_nodes[cluster, e]
        if node < 0:
            return wp.vec4(0.0, 0.0, 1.0, -1.0)
        if baked != 0 and blockers.is_static[node] != 0:
            return wp.vec4(0.0, 0.0, 1.0, -1.0)
        sphere = effective_sphere(p, n, blockers.centres[node], blockers.radii[node], rule)
        if sphere[3] <= 0.0:
            return wp.vec4(0.0, 0.0, 1.0, -1.0)
        return sphere_angle(p, sphere)
    k = e - count
    return plane_cap(p, blockers.plane_centre[k], blockers.plane_normal[k], blockers.plane_radius[k])


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
    tables: SHTables, exp_tables: SHExpTables, out: ReceiverOutputs, degree: int, rule: int,
    start: int)``; thread ``i`` handles receiver ``start + i`` (``rule``: index into
    :data:`RULES`). ``out.visibility`` gets the windowed visibility vector g when
    ``out.store_visibility`` is 1. Receivers whose g leaves the bound of a visibility function
    (norm > :data:`VISIBILITY_NORM_LIMIT`, or not finite -- the truncated series far outside
    its domain) are shaded with ``exp(mean log visibility) * 1`` instead and counted in
    ``out.fallbacks[0]``.

    The kernel runs the phases of the module docstring as ``@wp.func`` helpers: gathering
    (:func:`blocker_cap`, steps 1-2), accumulation (``accumulate_blockers``, step 3),
    exponentiation, fallback and window (``visibility_vector``, step 4), and shading
    (``shade_receiver``, step 5).

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

    @wp.func
    def accumulate_blockers(blockers: BlockerSet, p: wp.vec3, n: wp.vec3, cluster: int, baked: int, rule: int,
                            tables: SHTables, exp_tables: SHExpTables):
        # step 3: (f, dc_log) -- the log visibility sum f (log) or the visibility product g
        # (product, with dc_log the sum of the caps' log mean visibilities, its fallback)
        count = blockers.cut_count[cluster]
        acc = vec_t()
        dc_log = float(0.0)
        if wp.static(not LOG):
            acc = one()
        planes = 0
        if baked == 0:
            planes = blockers.plane_radius.shape[0]
        # one loop over the cut's spheres, then the plane blockers, with a single accumulate
        # call site (the unrolled ZH rule is large; one copy keeps compile time down)
        for e in range(count + planes):
            cap = blocker_cap(blockers, p, n, cluster, count, baked, rule, e)
            theta = cap[3]
            if theta <= 0.0:
                continue
            s = wp.vec3(cap[0], cap[1], cap[2])
            if wp.static(LOG):
                zh = log_cap_zh(theta, exp_tables)
                if e < count and blockers.weighted != 0:
                    for l in range(ORDER):
                        zh[l] = zh[l] * blockers.cut_weights[cluster, e, l]
                acc = zh_accumulate(acc, s, zh)
            else:
                vis = cap_zh_blocked(theta)
                dc_log += wp.log(wp.max(vis[0] * float(INV_SQRT_4PI), 1.0e-30))
                acc = product(acc, zh_accumulate(vec_t(), s, vis), tables)
        return acc, dc_log

    @wp.func
    def visibility_vector(acc: vec_t, dc_log: float, degree: int, shading: ShadeInputs, tables: SHTables,
                          exp_tables: SHExpTables, fallbacks: wp.array(dtype=wp.int32)) -> vec_t:
        # step 4: the windowed visibility vector g from the accumulated f (or product)
        g = acc
        mean_log = dc_log
        if wp.static(LOG):
            g = exponentiate(acc, degree, tables, exp_tables)
            mean_log = acc[0] * float(INV_SQRT_4PI)
        # A visibility function lies in [0, 1], so its projection has norm <= sqrt(4 pi)
        # (Bessel). Far outside the series' domain (thousands of overlapping blockers) the
        # truncated exp/product leaves that bound: fall back to the scalar estimate
        # exp(mean log visibility) * 1 and count the receiver.
        g_norm = wp.length(g)
        if not (g_norm <= float(VISIBILITY_NORM_LIMIT)):
            g = one() * wp.exp(wp.min(mean_log, 0.0))
            wp.atomic_add(fallbacks, 0, 1)
        window = bands_t()
        for l in range(ORDER):
            window[l] = shading.window[l]
        return scale_bands(g, window)

    @wp.func
    def shade_receiver(receivers: ReceiverSet, shading: ShadeInputs, tables: SHTables, v: int, p: wp.vec3, n: wp.vec3,
                       baked: int, g: vec_t) -> wp.vec3:
        # step 5: (L_c, g, X) + sphere lights, per channel, before albedo / pi and the clamp
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
        return rgb

    @wp.kernel(enable_backward=False, module="unique", module_options=MODULE_OPTIONS)
    def kernel(
        blockers: BlockerSet,
        receivers: ReceiverSet,
        shading: ShadeInputs,
        tables: SHTables,
        exp_tables: SHExpTables,
        out: ReceiverOutputs,
        degree: int,
        rule: int,
        start: int,
    ):
        v = start + wp.tid()
        p = receivers.points[v]
        n = wp.normalize(receivers.normals[v])
        baked = receivers.baked[v]
        acc, dc_log = accumulate_blockers(blockers, p, n, receivers.cluster[v], baked, rule, tables, exp_tables)
        g = visibility_vector(acc, dc_log, degree, shading, tables, exp_tables, out.fallbacks)
        if out.store_visibility != 0:
            for i in range(N):
                out.visibility[v, i] = g[i]
        rgb = shade_receiver(receivers, shading, tables, v, p, n, baked, g)
        for c in range(3):
            value = receivers.albedo[v, c] * float(INV_PI) * wp.max(rgb[c], 0.0)
            if not wp.isfinite(value):
                value = 0.0
            out.radiance[v, c] = value

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
