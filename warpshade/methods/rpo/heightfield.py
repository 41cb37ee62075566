"""Dynamic height fields shaded with reflectance product operators (Nowrouzezahrai et al. 2009,
eq. 4-5 and sec. 7 / Fig. 11, after Snyder and Nowrouzezahrai 2008).

A height field is a regular G x G grid mesh (row-major vertices, row r along +y, column c along
+x, Z-up; :mod:`warpshade.io.heightfield`) whose heights change every frame. Two frame stages:

``rpo.heightfield_visibility`` -- world-frame SH visibility from horizon angles (eq. 4-5), all in
Warp kernels per frame:

1. the frame's heights (the z of ``points``) -> a max pyramid: level k holds the maximum height
   over 2^k x 2^k vertices (:func:`pyramid_levels`);
2. at every texel of an R x R visibility grid (``resolution``: sub-sampled, corners on the grid
   corners) and for each of A azimuths ``phi_i = 2 pi i / A`` (``azimuths``), the horizon: the
   largest slope ``(H - h0) / d`` of the pyramid over a march with doubling distance
   (``d_j = spacing * 2^(j / q)``, q = ``samples_per_octave``), each sample reading the
   maximum of the pyramid cell holding it, on the level whose cell side is ``footprint`` times
   the step to the next sample (:func:`march_plan`; ``footprint = 1`` is conservative: no gaps
   along the march, but the cell's maximum raises the horizon by about 3.5 degrees on the
   water; the default 0.5 halves that bias; ``benchmarks/bench_heightfield.py`` measured
   q = 1, 0.5 as cheapest with no loss against the glossy reference). The march ends at the
   grid's edge: beyond it nothing blocks;
3. the visibility of the azimuthal wedge ``[phi_i - pi/A, phi_i + pi/A]`` is 0 below the horizon
   elevation and 1 above (eq. 4); its SH comes from a canonical wedge about phi = 0 tabulated
   over the sine of the horizon elevation (:func:`wedge_table`, float64 Gauss-Legendre in
   cos(theta) with the azimuthal integral in closed form, built once at set-up) and placed by a
   z-rotation (``sh_rotate_z``); the wedges are summed (eq. 5).

   Below the local tangent plane (``below``): ``"open"`` (default) counts directions under the
   tangent plane as open, the convention of ``rpo.visibility_traced`` and of eq. 1: per wedge
   ``W(z_h) + W(-1) - W(min(z_t, z_h))`` with ``z_t`` the sine of the tangent plane's elevation
   in that azimuth (so an unoccluded texel has V = 1 exactly); ``"blocked"`` keeps what the
   horizon says (the surface's first march step follows its tangent plane, so the lower
   hemisphere is mostly 0). The BRDF light factors vanish there either way; what differs is
   the SH ringing the truncated product sees (measured in ``benchmarks/bench_heightfield.py``).
4. outputs: ``texel_visibility`` (R*R, n*n) and, with ``per_vertex`` (default), ``visibility``
   (V, n*n): bilinear at every grid vertex, world frame, for ``rpo.shade`` with
   ``visibility_space = "world"`` and frames from ``ldprt.frames``.

``rpo.heightfield_shade`` -- eq. 11 at every vertex, arranged for a height field (the paper
shades 512^2 vertices at full resolution over sub-sampled visibility):

* the lighting product ``g_c = l_c * v`` (one order-n SH product per channel) is formed at the
  *visibility* resolution and interpolated bilinearly (it is linear in v, so this equals the
  product of the interpolated visibility); radiance is then ``L_c = F_w(wo) . g_c`` since
  ``l . (F * v) = F . (l * v)`` (the Gaunt coefficients are symmetric);
* per vertex, the tangent frame is chosen about the normal so that the view lies in its x-z
  plane: the local view is ``(sin t, 0, cos t)`` and ``F(wo)`` of the operators (``sum_b (w_b .
  y(wo)) u_b``) is a 1-D table over ``cos t`` (``view_table`` entries, linear interpolation),
  built once per BRDF; for an isotropic BRDF this is the same F as in any other frame about the
  normal. ``factors = "exact"`` tabulates the cosine-weighted BRDF's own SH projection instead
  of its rank-k factors (no SVD truncation, no view-factor fit);
* ``F`` is turned to the world by one SH rotation per vertex (trig-free zxzxz: the cosines and
  sines of the Euler angles come from the frame, the multiple angles by recurrence).

Views at or below a vertex's tangent plane give 0 (counted); negative radiance from SH ringing
is clamped (counted): :meth:`HeightFieldShadeStage.diagnostics`.

The float64 oracles of every kernel are in :mod:`.heightfield_reference`.
"""

# No "from __future__ import annotations": Warp resolves closure types in annotations.

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..._wp import launch_parallel, wp
from ...basis import sh
from ...basis.sh_warp import sh_kernels
from ..common import ShLighting, order_param
from ..stage import FrameStage, Param, Port, StageError, register_stage
from .stages import OPERATORS, SHADE_PARAMS, GlossyStage

wp.set_module_options({"enable_backward": False})

__all__ = [
    "GridLayout",
    "HeightFieldShadeStage",
    "HeightFieldVisibilityStage",
    "grid_layout",
    "march_plan",
    "pyramid_levels",
    "view_table",
    "wedge_table",
]

#: Items per CPU chunk below which a launch is not split over cores.
CPU_CHUNK_MIN = 2048
#: Entries of the canonical wedge table over z0 = sin(horizon elevation) in [-1, 1].
WEDGE_ENTRIES = 257
#: Gauss-Legendre nodes in cos(theta) of the wedge table.
WEDGE_NODES = 64
#: Modes of ``below``.
BELOW_MODES = ("open", "blocked")
#: Modes of ``factors``.
FACTOR_MODES = ("rpo", "exact")
#: Relative tolerance of the regular-grid check (of the grid spacing).
GRID_TOLERANCE = 1e-3
#: ``stats`` entries of the shading kernel.
STAT_NEGATIVE, STAT_BELOW_HORIZON = 0, 1

_ORDER = order_param(4, minimum=2, maximum=6)


# ---- host-side set-up ----------------------------------------------------------------------
@dataclass(frozen=True)
class GridLayout:
    """A regular height-field grid: vertex ``r * size + c`` at ``(x0 + c dx, y0 + r dy)``."""

    size: int
    x0: float
    y0: float
    dx: float
    dy: float


def grid_layout(scene, where: str = "height field") -> GridLayout:
    """Check that the scene is one regular G x G grid whose vertices only move along z.

    Raises:
        ValueError: naming ``where`` and what is wrong.
    """
    v = scene.vertex_count
    g = int(round(math.sqrt(v)))
    if g * g != v or g < 2:
        raise ValueError(f"{where}: needs a regular G x G height-field grid; the scene has {v} vertices, not a square count")
    if scene.up_axis != "Z":
        raise ValueError(f"{where}: height fields are Z-up; the scene is {scene.up_axis}-up")
    for mesh in scene.meshes:
        if mesh.animation in ("skinned",) or (mesh.animation == "rigid" and mesh.transforms.shape[0] > 1):
            raise ValueError(f"{where}: mesh {mesh.path} moves as a whole ({mesh.animation}); a height field only moves "
                             "its heights")
    p = scene.points_at(scene.frames[0])
    x0, y0 = p[0, 0], p[0, 1]
    dx = (p[g - 1, 0] - x0) / (g - 1)
    dy = (p[(g - 1) * g, 1] - y0) / (g - 1)
    if not (dx > 0 and dy > 0):
        raise ValueError(f"{where}: the grid must be row-major with columns along +x and rows along +y "
                         f"(vertex r * G + c at (x0 + c dx, y0 + r dy)); got spacings dx = {dx:g}, dy = {dy:g}")
    r, c = np.divmod(np.arange(v), g)
    tol = GRID_TOLERANCE * min(dx, dy)
    ex = np.abs(p[:, 0] - (x0 + c * dx)).max()
    ey = np.abs(p[:, 1] - (y0 + r * dy)).max()
    if ex > tol or ey > tol:
        raise ValueError(f"{where}: the vertices are not a regular {g} x {g} grid (row-major, x along columns, y along "
                         f"rows): off by up to {max(ex, ey):.3g} (tolerance {tol:.3g})")
    for mesh in scene.meshes:
        if mesh.animation == "deforming":
            xy = np.asarray(mesh.point_samples[:, :, :2], np.float64)
            drift = float(np.abs(xy - xy[:1]).max())
            if drift > tol:
                raise ValueError(f"{where}: mesh {mesh.path} moves its vertices sideways by up to {drift:.3g} over the "
                                 "frames; a height field only moves them along z")
    return GridLayout(g, float(x0), float(y0), float(dx), float(dy))


def pyramid_levels(size: int) -> list[int]:
    """Side length of each max-pyramid level: G, ceil(G / 2), ... down to 1."""
    sizes = [int(size)]
    while sizes[-1] > 1:
        sizes.append((sizes[-1] + 1) // 2)
    return sizes


def march_plan(layout: GridLayout, samples_per_octave: int, footprint: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Distances (world units) and pyramid levels of the horizon march, (J,) float64 and int32.

    ``d_j = s 2^(j / q)`` (s the smaller grid spacing) up to the grid's diagonal; sample j reads
    the finest level whose cell side ``2^k s`` is at least ``footprint (d_{j+1} - d_j)``: with
    ``footprint = 1`` consecutive cells meet (conservative: no blocker is skipped, but the cell's
    maximum over its whole side, across the march too, raises the horizon); smaller footprints
    read finer cells (less bias, gaps between the samples).
    """
    q = int(samples_per_octave)
    s = min(layout.dx, layout.dy)
    diag = math.hypot(layout.dx, layout.dy) * (layout.size - 1)
    count = int(math.ceil(q * math.log2(max(diag / s, 1.0)))) + 1
    j = np.arange(count, dtype=np.float64)
    d = s * 2.0 ** (j / q)
    gap = float(footprint) * d * (2.0 ** (1.0 / q) - 1.0) / s
    top = len(pyramid_levels(layout.size)) - 1
    levels = np.clip(np.ceil(np.log2(np.maximum(gap, 1.0)) - 1e-9), 0, top).astype(np.int32)
    return d, levels


def wedge_table(order: int, azimuths: int, entries: int = WEDGE_ENTRIES, nodes: int = WEDGE_NODES) -> np.ndarray:
    """SH of the canonical wedge ``|phi| <= pi / A``, open above ``z > z0``, for ``z0`` on
    ``linspace(-1, 1, entries)``: (entries, n*n) float64.

    The azimuthal integral is closed form (``int cos(m phi) = 2 sin(m pi / A) / m``; the sine
    terms vanish by symmetry), the polar one Gauss-Legendre over ``[z0, 1]`` with ``nodes``.
    """
    n = int(order)
    half = math.pi / int(azimuths)
    z0 = np.linspace(-1.0, 1.0, int(entries))
    x, w = np.polynomial.legendre.leggauss(int(nodes))
    z = z0[:, None] + (1.0 - z0[:, None]) * 0.5 * (x[None] + 1.0)  # (E, Q)
    wz = 0.5 * (1.0 - z0[:, None]) * w[None]
    dirs = np.stack([np.sqrt(np.maximum(1.0 - z * z, 0.0)), np.zeros_like(z), z], -1)
    y = sh.basis(dirs.reshape(-1, 3), n).reshape(z.shape + (n * n,))  # at phi = 0: the cos(m phi) parts
    phi_int = np.zeros(n * n)
    for l in range(n):
        for m in range(-l, l + 1):
            if m == 0:
                phi_int[l * l + l] = 2.0 * half
            elif m > 0:
                phi_int[l * l + l + m] = 2.0 * math.sin(m * half) / m
    return np.einsum("eq,eqi->ei", wz, y) * phi_int[None]


def view_table(operator, entries: int, factors: str = "rpo", brdf=None) -> np.ndarray:
    """``F(wo)`` at local views ``(sin t, 0, cos t)`` for ``cos t`` on ``linspace(0, 1, entries)``,
    (entries, n*n) float64: the operators' ``sum_b (w_b . y(wo)) u_b`` (``factors = "rpo"``) or
    the cosine-weighted BRDF's own SH projection (``"exact"``, needs ``brdf``)."""
    mu = np.linspace(0.0, 1.0, int(entries))
    views = np.stack([np.sqrt(np.maximum(1.0 - mu * mu, 0.0)), np.zeros_like(mu), mu], 1)
    views[0] = (1.0, 0.0, 1e-6)  # grazing: keep the view a unit vector just above the plane
    views /= np.linalg.norm(views, axis=1, keepdims=True)
    if factors == "exact":
        from ...scene import materials
        from .model import PHI_NODES, Z_NODES

        return materials.brdf_matrix(brdf, operator.order, views, Z_NODES, PHI_NODES, cosine=True)
    return operator.view_weights(views) @ operator.light_sh


# ---- kernels ---------------------------------------------------------------------------------
@wp.kernel(enable_backward=False)
def _heights_kernel(points: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.float32)):
    i = wp.tid()
    out[i] = points[i][2]


@wp.kernel(enable_backward=False)
def _reduce_kernel(pyr: wp.array(dtype=wp.float32), src_off: int, src_size: int, dst_off: int, dst_size: int):
    i = wp.tid()
    r = i // dst_size
    c = i - r * dst_size
    r0 = 2 * r
    c0 = 2 * c
    r1 = wp.min(r0 + 1, src_size - 1)
    c1 = wp.min(c0 + 1, src_size - 1)
    a = wp.max(pyr[src_off + r0 * src_size + c0], pyr[src_off + r0 * src_size + c1])
    b = wp.max(pyr[src_off + r1 * src_size + c0], pyr[src_off + r1 * src_size + c1])
    pyr[dst_off + i] = wp.max(a, b)


@wp.func
def texel_weights(vtx: int, size: int, res: int):
    """Bilinear position of grid vertex ``vtx`` (row-major, size x size) over the res x res texels:
    the first texel's index and the weights of (t00, t00 + 1, t00 + res, t00 + res + 1)."""
    r = vtx // size
    c = vtx - r * size
    scale = float(res - 1) / float(size - 1)
    fu = float(c) * scale
    fv = float(r) * scale
    c0 = wp.min(int(fu), res - 2)
    r0 = wp.min(int(fv), res - 2)
    tu = fu - float(c0)
    tv = fv - float(r0)
    return r0 * res + c0, wp.vec4((1.0 - tu) * (1.0 - tv), tu * (1.0 - tv), (1.0 - tu) * tv, tu * tv)


@wp.func
def _bilinear_height(pyr: wp.array(dtype=wp.float32), size: int, u: float, v: float) -> float:
    fu = wp.clamp(u, 0.0, float(size - 1))
    fv = wp.clamp(v, 0.0, float(size - 1))
    c0 = wp.min(int(fu), size - 2)
    r0 = wp.min(int(fv), size - 2)
    tu = fu - float(c0)
    tv = fv - float(r0)
    h00 = pyr[r0 * size + c0]
    h01 = pyr[r0 * size + c0 + 1]
    h10 = pyr[(r0 + 1) * size + c0]
    h11 = pyr[(r0 + 1) * size + c0 + 1]
    return (1.0 - tv) * ((1.0 - tu) * h00 + tu * h01) + tv * ((1.0 - tu) * h10 + tu * h11)


def _x90_terms(order: int, sign: float) -> list:
    """Nonzero entries ``(row, column, value)`` of the SH rotation matrix of Rx(sign * 90 deg)."""
    c = math.radians(90.0 * sign)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(c), -math.sin(c)], [0.0, math.sin(c), math.cos(c)]])
    m = sh.rotation_matrix(rx, order)
    rows, cols = np.nonzero(np.abs(m) > 1e-12)
    return [(int(i), int(j), float(m[i, j])) for i, j in zip(rows, cols)]


def _product_terms(order: int) -> list:
    """The Gaunt entries with ``j <= k`` as ``(i, j, k, weight)`` (``(f * g)_i = sum w (f_j g_k +
    f_k g_j)``, diagonal weights halved)."""
    idx, val = sh.triple_product_tensor(order)
    out = []
    for (i, j, k), v in zip(idx, val):
        if j <= k:
            out.append((int(i), int(j), int(k), float(v) * (0.5 if j == k else 1.0)))
    return out


@functools.lru_cache(maxsize=None)
def static_sh_funcs(order: int):
    """Straight-line SH functions of one order (constants folded into the code): ``(rotate_z_cs,
    rotate_frame, product)``.

    * ``rotate_z_cs(f, c, s)``: coefficients of ``f(Rz(a)^-1 s)`` given ``cos a, sin a``;
    * ``rotate_frame(f, R)``: coefficients of ``f(R^-1 s)`` by zxzxz with the Euler angles'
      cosines and sines read off R (no trigonometric calls, no table loads);
    * ``product(f, g)``: the order-n truncated SH product, unrolled over the Gaunt entries.
    """
    shk = sh_kernels(order)
    N2 = order * order
    ORDER = order
    vec_t = shk.vec
    XP = _x90_terms(order, 1.0)
    XM = _x90_terms(order, -1.0)
    NXP, NXM = len(XP), len(XM)
    PT = _product_terms(order)
    NPT = len(PT)

    @wp.func
    def rotate_z_cs(f: vec_t, c1: float, s1: float) -> vec_t:
        out = f
        c = float(1.0)
        s = float(0.0)
        for m in range(1, ORDER):
            cn = c * c1 - s * s1
            s = s * c1 + c * s1
            c = cn
            for l in range(m, ORDER):
                a = f[l * l + l + m]
                b = f[l * l + l - m]
                out[l * l + l + m] = c * a - s * b
                out[l * l + l - m] = s * a + c * b
        return out

    @wp.func
    def x90p(f: vec_t) -> vec_t:
        out = vec_t()
        for e in range(wp.static(NXP)):
            out[wp.static(XP[e][0])] += wp.static(XP[e][2]) * f[wp.static(XP[e][1])]
        return out

    @wp.func
    def x90m(f: vec_t) -> vec_t:
        out = vec_t()
        for e in range(wp.static(NXM)):
            out[wp.static(XM[e][0])] += wp.static(XM[e][2]) * f[wp.static(XM[e][1])]
        return out

    @wp.func
    def rotate_frame(f: vec_t, r: wp.mat33) -> vec_t:
        # R = Rz(alpha) Ry(beta) Rz(gamma) = Rz(alpha) Rx(-90) Rz(beta) Rx(90) Rz(gamma)
        sb = wp.sqrt(r[0, 2] * r[0, 2] + r[1, 2] * r[1, 2])
        cb = r[2, 2]
        ca = float(1.0)
        sa = float(0.0)
        cg = float(1.0)
        sg = float(0.0)
        if sb > 1.0e-6:
            ca = r[0, 2] / sb
            sa = r[1, 2] / sb
            cg = -r[2, 0] / sb
            sg = r[2, 1] / sb
        else:
            sb = 0.0
            if cb > 0.0:
                cb = 1.0
                ca = r[0, 0]
                sa = r[1, 0]
            else:
                cb = -1.0
                ca = r[1, 1]
                sa = -r[1, 0]
            q = wp.sqrt(ca * ca + sa * sa)
            if q > 0.0:
                ca = ca / q
                sa = sa / q
            else:
                ca = 1.0
                sa = 0.0
        out = rotate_z_cs(f, cg, sg)
        out = x90p(out)
        out = rotate_z_cs(out, cb, sb)
        out = x90m(out)
        return rotate_z_cs(out, ca, sa)

    @wp.func
    def product(f: vec_t, g: vec_t) -> vec_t:
        out = vec_t()
        for e in range(wp.static(NPT)):
            out[wp.static(PT[e][0])] += wp.static(PT[e][3]) * (f[wp.static(PT[e][1])] * g[wp.static(PT[e][2])] +
                                                               f[wp.static(PT[e][2])] * g[wp.static(PT[e][1])])
        return out

    return rotate_z_cs, rotate_frame, product


@wp.func
def horizon_slope(pyr: wp.array(dtype=wp.float32), steps: wp.array(dtype=wp.vec4), step_level: wp.array2d(dtype=wp.int32),
                  u5: float, v5: float, h0: float, az: wp.vec4) -> float:
    """Largest ``(H - h0) / d`` over the march from (u5 - 0.5, v5 - 0.5) (vertex units) along one
    azimuth; -1e30 when no sample is inside the grid.

    ``steps[j] = (d_j, 1 / d_j, 2^-k_j, -)``, ``step_level[j] = (offset, side)`` of level k_j in
    ``pyr``, ``az = (cos phi, sin phi, cos phi / dx, sin phi / dy)``."""
    best = float(-1.0e30)
    for j in range(steps.shape[0]):
        st = steps[j]
        n_k = step_level[j, 1]
        ci = int(wp.floor((u5 + st[0] * az[2]) * st[2]))
        ri = int(wp.floor((v5 + st[0] * az[3]) * st[2]))
        if ci < 0 or ri < 0 or ci >= n_k or ri >= n_k:
            break
        best = wp.max(best, (pyr[step_level[j, 0] + ri * n_k + ci] - h0) * st[1])
    return best


@wp.kernel(enable_backward=False)
def horizon_kernel(pyr: wp.array(dtype=wp.float32), steps: wp.array(dtype=wp.vec4), step_level: wp.array2d(dtype=wp.int32),
                   azimuth: wp.array(dtype=wp.vec4), size: int, uv: wp.array(dtype=wp.vec2), out: wp.array2d(dtype=wp.float32)):
    """The horizon slopes of the march at points ``uv`` (vertex units), (P, A): what the texel
    kernel computes before the wedges (tests and diagnostics)."""
    p, i = wp.tid()
    h0 = _bilinear_height(pyr, size, uv[p][0], uv[p][1])
    out[p, i] = horizon_slope(pyr, steps, step_level, uv[p][0] + 0.5, uv[p][1] + 0.5, h0, azimuth[i])


@functools.lru_cache(maxsize=None)
def visibility_kernels(order: int):
    """``(texel_kernel, upsample_kernel)`` of one SH order (cached)."""
    shk = sh_kernels(order)
    N2 = order * order
    vec_t = shk.vec
    rotate_z_cs, _, _ = static_sh_funcs(order)

    @wp.func
    def wedge(table: wp.array2d(dtype=wp.float32), z: float) -> vec_t:
        e = table.shape[0]
        t = (wp.clamp(z, -1.0, 1.0) + 1.0) * 0.5 * float(e - 1)
        i0 = wp.min(int(t), e - 2)
        f = t - float(i0)
        out = vec_t()
        for k in range(N2):
            out[k] = (1.0 - f) * table[i0, k] + f * table[i0 + 1, k]
        return out

    @wp.kernel(enable_backward=False, module="unique")
    def texel_kernel(
        pyr: wp.array(dtype=wp.float32),
        steps: wp.array(dtype=wp.vec4),
        step_level: wp.array2d(dtype=wp.int32),
        azimuth: wp.array(dtype=wp.vec4),
        table: wp.array2d(dtype=wp.float32),
        size: int,
        res: int,
        dx: float,
        dy: float,
        open_below: int,
        start: int,
        out: wp.array2d(dtype=wp.float32),
    ):
        t = wp.tid() + start
        a = t // res
        b = t - a * res
        scale = float(size - 1) / float(res - 1)
        u = float(b) * scale  # column (x), vertex units
        v = float(a) * scale  # row (y)
        h0 = _bilinear_height(pyr, size, u, v)
        gx = (_bilinear_height(pyr, size, u + 1.0, v) - _bilinear_height(pyr, size, u - 1.0, v)) / \
            ((wp.min(u + 1.0, float(size - 1)) - wp.max(u - 1.0, 0.0)) * dx)
        gy = (_bilinear_height(pyr, size, u, v + 1.0) - _bilinear_height(pyr, size, u, v - 1.0)) / \
            ((wp.min(v + 1.0, float(size - 1)) - wp.max(v - 1.0, 0.0)) * dy)
        full = wedge(table, -1.0)
        acc = vec_t()
        for i in range(azimuth.shape[0]):
            az = azimuth[i]
            best = horizon_slope(pyr, steps, step_level, u + 0.5, v + 0.5, h0, az)
            zh = -1.0
            if best > -1.0e29:
                zh = best / wp.sqrt(1.0 + best * best)
            w = wedge(table, zh)
            if open_below == 1:
                tau = gx * az[0] + gy * az[1]
                zt = wp.min(tau / wp.sqrt(1.0 + tau * tau), zh)
                lo = wedge(table, zt)
                for k in range(N2):
                    w[k] = w[k] + full[k] - lo[k]
            acc = acc + rotate_z_cs(w, az[0], az[1])
        for k in range(N2):
            out[t, k] = acc[k]

    @wp.kernel(enable_backward=False, module="unique")
    def upsample_kernel(texels: wp.array2d(dtype=wp.float32), size: int, res: int, start: int,
                        out: wp.array2d(dtype=wp.float32)):
        vtx = wp.tid() + start
        t00, w = texel_weights(vtx, size, res)
        w00, w01, w10, w11 = w[0], w[1], w[2], w[3]
        for k in range(N2):
            out[vtx, k] = w00 * texels[t00, k] + w01 * texels[t00 + 1, k] + w10 * texels[t00 + res, k] + \
                w11 * texels[t00 + res + 1, k]

    return texel_kernel, upsample_kernel


@functools.lru_cache(maxsize=None)
def shade_kernels(order: int):
    """``(product_kernel, shade_kernel, rotate_kernel)`` of one SH order (cached)."""
    shk = sh_kernels(order)
    N2 = order * order
    vec_t = shk.vec
    sh_load = shk.load
    _, rotate_frame, product = static_sh_funcs(order)

    @wp.kernel(enable_backward=False, module="unique")
    def product_kernel(vis: wp.array2d(dtype=wp.float32), light: wp.array2d(dtype=wp.float32), start: int,
                       out: wp.array2d(dtype=wp.float32)):
        t = wp.tid() + start
        v = sh_load(vis, t)
        for ch in range(3):
            g = product(sh_load(light, ch), v)
            for k in range(N2):
                out[t, ch * N2 + k] = g[k]

    @wp.kernel(enable_backward=False, module="unique")
    def shade_kernel(
        points: wp.array(dtype=wp.vec3),
        normals: wp.array(dtype=wp.vec3),
        eye: wp.array(dtype=wp.vec3),
        g: wp.array2d(dtype=wp.float32),
        ftable: wp.array2d(dtype=wp.float32),
        size: int,
        res: int,
        specular: wp.vec3,
        start: int,
        radiance: wp.array2d(dtype=wp.float32),
        stats: wp.array(dtype=wp.int32),
    ):
        vtx = wp.tid() + start
        n = normals[vtx]
        d = eye[0] - points[vtx]
        dl = wp.length(d)
        mu = float(0.0)
        if dl > 0.0:
            d = d / dl
            mu = wp.dot(n, d)
        if mu <= 0.0:
            radiance[vtx, 0] = 0.0
            radiance[vtx, 1] = 0.0
            radiance[vtx, 2] = 0.0
            wp.atomic_add(stats, STAT_BELOW_HORIZON, 1)
            return
        # local frame about n with the view in its x-z plane
        x = d - mu * n
        xl = wp.length(x)
        if xl > 1.0e-6:
            x = x / xl
        else:
            x = wp.vec3(1.0, 0.0, 0.0) - n[0] * n
            if wp.length(x) < 1.0e-3:
                x = wp.vec3(0.0, 1.0, 0.0) - n[1] * n
            x = wp.normalize(x)
        y = wp.cross(n, x)
        # F(wo) from the table over cos(theta_o)
        e = ftable.shape[0]
        tt = wp.min(mu, 1.0) * float(e - 1)
        i0 = wp.min(int(tt), e - 2)
        fr = tt - float(i0)
        f = vec_t()
        for k in range(N2):
            f[k] = (1.0 - fr) * ftable[i0, k] + fr * ftable[i0 + 1, k]
        # to the world: f(F s) with F rows (x, y, n), i.e. the rotation R = F^T
        rt = wp.mat33(x[0], y[0], n[0], x[1], y[1], n[1], x[2], y[2], n[2])
        fw = rotate_frame(f, rt)
        # g at the vertex (bilinear over the visibility texels)
        t00, w = texel_weights(vtx, size, res)
        w00, w01, w10, w11 = w[0], w[1], w[2], w[3]
        neg = int(0)
        for ch in range(3):
            acc = float(0.0)
            for k in range(N2):
                col = ch * N2 + k
                gk = w00 * g[t00, col] + w01 * g[t00 + 1, col] + w10 * g[t00 + res, col] + w11 * g[t00 + res + 1, col]
                acc += fw[k] * gk
            if acc < 0.0:
                acc = 0.0
                neg = 1
            radiance[vtx, ch] = specular[ch] * acc
        if neg == 1:
            wp.atomic_add(stats, STAT_NEGATIVE, 1)

    @wp.kernel(enable_backward=False, module="unique")
    def rotate_kernel(f: wp.array2d(dtype=wp.float32), rot: wp.array(dtype=wp.mat33), out: wp.array2d(dtype=wp.float32)):
        i = wp.tid()
        o = rotate_frame(sh_load(f, i), rot[i])
        for k in range(N2):
            out[i, k] = o[k]

    @wp.kernel(enable_backward=False, module="unique")
    def pair_product_kernel(f: wp.array2d(dtype=wp.float32), h: wp.array2d(dtype=wp.float32), out: wp.array2d(dtype=wp.float32)):
        i = wp.tid()
        o = product(sh_load(f, i), sh_load(h, i))
        for k in range(N2):
            out[i, k] = o[k]

    return product_kernel, shade_kernel, rotate_kernel, pair_product_kernel


# ---- stages ----------------------------------------------------------------------------------
def _layout(stage, ctx) -> GridLayout:
    try:
        return grid_layout(ctx.scene, f"stage {stage.name!r} ({stage.type_name})")
    except ValueError as exc:
        raise StageError(str(exc)) from None


@register_stage
class HeightFieldVisibilityStage(FrameStage):
    type_name = "rpo.heightfield_visibility"
    description = ("world-frame SH visibility of a dynamic height field from horizon angles (eq. 4-5): max pyramid, "
                   "horizon march per azimuth, tabulated wedges z-rotated and summed, sub-sampled")
    parameters = {
        "order": _ORDER,
        "resolution": Param(128, int, "visibility texels per side (sub-sampled; bilinear to the vertices)", minimum=2,
                            maximum=4096),
        "azimuths": Param(16, int, "azimuthal directions (wedges) of the horizon", minimum=4, maximum=128),
        "samples_per_octave": Param(1, int, "horizon-march samples per doubling of the distance", minimum=1, maximum=8),
        "footprint": Param(0.5, float, "pyramid cell side relative to the step to the next sample (1: conservative)",
                           minimum=0.05, maximum=4.0),
        "below": Param("open", str, "directions below the local tangent plane: 'open' or as the horizon says ('blocked')",
                       choices=BELOW_MODES),
        "per_vertex": Param(True, bool, "also write the (V, n*n) per-vertex visibility (for rpo.shade)"),
        "table_entries": Param(WEDGE_ENTRIES, int, "entries of the wedge table over sin(horizon elevation)", minimum=16,
                               maximum=65536),
    }

    def dims(self):
        return {"C": self.params["order"] ** 2, "S": self.params["resolution"] ** 2}

    def input_ports(self):
        return {"points": Port("vec3", ("V",))}

    def output_ports(self):
        out = {"texel_visibility": Port("float32", ("S", "C"), "SH visibility at the R x R texels, world frame")}
        if self.params["per_vertex"]:
            out["visibility"] = Port("float32", ("V", "C"), "SH visibility at every grid vertex (bilinear), world frame")
        return out

    def setup(self, ctx, inputs):
        p = self.params
        dev = ctx.device
        lay = _layout(self, ctx)
        if p["resolution"] > lay.size:
            raise StageError(f"stage {self.name!r}: resolution {p['resolution']} exceeds the {lay.size} x {lay.size} grid")
        self.layout = lay
        n = p["order"]
        sizes = pyramid_levels(lay.size)
        offs = np.concatenate([[0], np.cumsum([s * s for s in sizes])]).astype(np.int64)
        self._sizes = sizes
        self._offs = offs
        self._pyr = wp.zeros(int(offs[-1]), dtype=wp.float32, device=dev)
        d, lev = march_plan(lay, p["samples_per_octave"], p["footprint"])
        self.march = (d, lev)
        steps = np.stack([d, 1.0 / d, 2.0 ** -lev.astype(np.float64), np.zeros_like(d)], 1)
        self._steps = wp.array(steps.astype(np.float32), dtype=wp.vec4, device=dev)
        self._step_level = wp.array(np.stack([offs[lev], np.asarray(sizes)[lev]], 1).astype(np.int32), dtype=wp.int32,
                                    device=dev)
        a = p["azimuths"]
        phi = 2.0 * np.pi * np.arange(a) / a
        az = np.stack([np.cos(phi), np.sin(phi), np.cos(phi) / lay.dx, np.sin(phi) / lay.dy], 1)
        self._azimuth = wp.array(az.astype(np.float32), dtype=wp.vec4, device=dev)
        self.table = wedge_table(n, a, p["table_entries"])
        self._table = wp.array(self.table.astype(np.float32), dtype=wp.float32, device=dev)
        self._points = inputs["points"]
        r = p["resolution"]
        self._texels = wp.zeros((r * r, n * n), dtype=wp.float32, device=dev)
        self._texel_kernel, self._upsample_kernel = visibility_kernels(n)
        out = {"texel_visibility": self._texels}
        self._vertex = None
        if p["per_vertex"]:
            self._vertex = wp.zeros((ctx.dims["V"], n * n), dtype=wp.float32, device=dev)
            out["visibility"] = self._vertex
        return out

    def launch(self, state):
        p, lay = self.params, self.layout
        dev = self._pyr.device
        g = lay.size
        wp.launch(_heights_kernel, dim=g * g, inputs=[self._points, self._pyr], device=dev)
        for k in range(1, len(self._sizes)):
            s = self._sizes[k]
            wp.launch(_reduce_kernel, dim=s * s, inputs=[self._pyr, int(self._offs[k - 1]), self._sizes[k - 1],
                                                         int(self._offs[k]), s], device=dev)
        r = p["resolution"]
        open_below = 1 if p["below"] == "open" else 0

        def texel_inputs(start, stop):
            return [self._pyr, self._steps, self._step_level, self._azimuth, self._table, g, r, lay.dx, lay.dy,
                    open_below, start, self._texels]

        launch_parallel(self._texel_kernel, r * r, texel_inputs, dev, min_count=CPU_CHUNK_MIN)
        if self._vertex is not None:
            def up_inputs(start, stop):
                return [self._texels, g, r, start, self._vertex]

            launch_parallel(self._upsample_kernel, g * g, up_inputs, dev, min_count=CPU_CHUNK_MIN)

    def horizons(self, uv) -> np.ndarray:
        """The march's horizon slopes of the current pyramid at points ``uv`` (P, 2) (column,
        row in vertex units), (P, A) float32 (host; after a frame has run)."""
        uv = np.asarray(uv, np.float32).reshape(-1, 2)
        dev = self._pyr.device
        out = wp.zeros((uv.shape[0], self.params["azimuths"]), dtype=wp.float32, device=dev)
        wp.launch(horizon_kernel, dim=out.shape, inputs=[self._pyr, self._steps, self._step_level, self._azimuth,
                                                         self.layout.size, wp.array(uv, dtype=wp.vec2, device=dev), out],
                  device=dev)
        return out.numpy()

    def diagnostics(self) -> dict:
        d, lev = self.march
        return {"grid": self.layout.size, "levels": len(self._sizes), "march_samples": int(d.size),
                "march_levels": [int(x) for x in lev]}

    def model_bytes(self) -> int:
        return int(self._table.capacity + self._steps.capacity + self._step_level.capacity)


@register_stage
class HeightFieldShadeStage(GlossyStage):
    type_name = "rpo.heightfield_shade"
    description = ("RPO glossy shading of a height field at every vertex over sub-sampled visibility: lighting "
                   "products at the visibility texels, F(wo) from a per-BRDF table, one SH rotation per vertex")

    parameters = {
        **SHADE_PARAMS,
        "factors": Param("rpo", str, "F(wo) from the rank-k operators ('rpo') or the BRDF's own projection ('exact')",
                         choices=FACTOR_MODES),
        "view_table": Param(128, int, "entries of the F(wo) table over cos(theta_o)", minimum=8, maximum=65536),
    }

    def input_ports(self):
        return {"points": Port("vec3", ("V",)), "normals": Port("vec3", ("V",)),
                "texel_visibility": Port("float32", ("S", "C")), "lighting": Port("lighting")}

    def setup(self, ctx, inputs):
        p = self.params
        self._setup_common(ctx, inputs)
        dev = ctx.device
        lay = _layout(self, ctx)
        self.layout = lay
        texels = inputs["texel_visibility"]
        r = int(round(math.sqrt(texels.shape[0])))
        if r * r != texels.shape[0] or r < 2 or r > lay.size:
            raise StageError(f"stage {self.name!r}: texel_visibility has {texels.shape[0]} rows, not an R x R grid with "
                             f"2 <= R <= {lay.size}")
        self.resolution = r
        n = p["order"]
        self._points, self._normals, self._texels = inputs["points"], inputs["normals"], texels
        self._lighting = ShLighting(inputs["lighting"], n)
        self._g = wp.zeros((r * r, 3 * n * n), dtype=wp.float32, device=dev)
        self._ftable = wp.zeros((p["view_table"], n * n), dtype=wp.float32, device=dev)
        self._stats = wp.zeros(2, dtype=wp.int32, device=dev)
        self._radiance = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=dev)
        self._product, self._shade, _, _ = shade_kernels(n)
        self._upload_material()
        return {"radiance": self._radiance}

    def _current_brdf(self):
        mats = self._state.materials
        brdfs = [mats.brdf_of(m.path, self._brdf) for m in self._scene.meshes]
        descs = [b.describe() for b in brdfs]
        if any(d != descs[0] for d in descs[1:]):
            raise StageError(f"stage {self.name!r}: a height field has one BRDF; the run assigns several")
        return brdfs[0]

    def _upload_material(self) -> None:
        p = self.params
        brdf = self._current_brdf()
        try:
            op = OPERATORS.get(brdf, p["order"], p["rank"], "brdf", p["view_resolution"], p["view_order"])
        except ValueError as exc:
            raise StageError(f"stage {self.name!r}: {exc}") from None
        self.operator = op
        self.brdf = brdf
        self.table = view_table(op, p["view_table"], p["factors"], brdf)
        self._ftable.assign(self.table.astype(np.float32))

    def notify_changed(self, flags) -> bool:
        from ...scene.state import Change

        if flags & Change.PARAMETERS:
            return False
        if flags & Change.MATERIAL:
            self._upload_material()
        return True

    def launch(self, state):
        self._lighting.launch()
        self._stats.zero_()
        dev = self._radiance.device
        r, g = self.resolution, self.layout.size

        def product_inputs(start, stop):
            return [self._texels, self._lighting.light, start, self._g]

        launch_parallel(self._product, r * r, product_inputs, dev, min_count=CPU_CHUNK_MIN)

        def shade_inputs(start, stop):
            return [self._points, self._normals, self._eye, self._g, self._ftable, g, r,
                    self._specular, start, self._radiance, self._stats]

        launch_parallel(self._shade, g * g, shade_inputs, dev, min_count=CPU_CHUNK_MIN)

    def diagnostics(self) -> dict:
        s = self._stats.numpy()
        return {"negative_clamped": int(s[STAT_NEGATIVE]), "below_horizon": int(s[STAT_BELOW_HORIZON]),
                "material": self.brdf.describe(), "factors": self.params["factors"],
                "operator_build_s": round(self.operator.build_s, 4)}

    def model_bytes(self) -> int:
        return int(self._ftable.capacity)

