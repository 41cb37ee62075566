"""Warp kernels of the height field: the max pyramid, the horizon march, the wedge sums and the
shading (float32). Their float64 mirrors are in :mod:`._mirror`.

* :data:`heights_kernel`, :data:`reduce_kernel` -- the frame's heights and the max pyramid;
* :func:`horizon_slope`, :data:`horizon_kernel` -- the march's horizon slopes
  (:func:`horizon_slope_quad`: four azimuths in one pass, as the texel kernel marches);
* :func:`visibility_kernels` -- per order: SH visibility at the texels, bilinear to the vertices;
* :func:`light_columns_kernel` -- per order: the frame's product matrices of the lighting;
* :func:`shade_kernels` -- per order: lighting products at the texels, shading at every vertex
  (by runs of :data:`SHADE_RUN` vertices along a grid row);
* :func:`static_sh_funcs` -- straight-line SH z-rotation, frame rotation and product.
"""

# No "from __future__ import annotations": Warp resolves closure types in annotations.

import functools
import math

import numpy as np

from ..._wp import wp
from ...basis import sh
from ...basis.sh_warp import sh_kernels

wp.set_module_options({"enable_backward": False})

__all__ = [
    "FLAG_BELOW_HORIZON",
    "FLAG_NEGATIVE",
    "SHADE_RUN",
    "HorizonMarch",
    "ShadeOutputs",
    "ShadeTexels",
    "ShadeVertices",
    "TexelVisibility",
    "heights_kernel",
    "horizon_kernel",
    "horizon_slope",
    "reduce_kernel",
    "shade_kernels",
    "light_columns_kernel",
    "static_sh_funcs",
    "even_frame_rotation",
    "table_is_even",
    "EVEN_TABLE_RTOL",
    "texel_weights",
    "cosine_indices",
    "visibility_kernels",
]

#: Grid vertices along a row that one thread of the shading kernel shades (:func:`shade_kernels`).
SHADE_RUN = 32

#: Bits of the shading kernel's per-vertex ``flags``: a channel clamped from below zero; the eye
#: at or below the vertex's tangent plane (radiance 0).
FLAG_NEGATIVE, FLAG_BELOW_HORIZON = 1, 2


@wp.struct
class HorizonMarch:
    """The frame's max pyramid and the horizon march over it (see :func:`horizon_slope`).

    Fields:
        pyr: the pyramid's levels, concatenated row-major, (sum of side^2,) float32, scene units.
        steps: ``(d_j, 1 / d_j, 2^-k_j, 0)`` per march sample, (J,) vec4 (vertex units).
        step_level: ``(offset, side)`` in ``pyr`` of each sample's level, (J, 2) int32.
        azimuth: ``(cos phi, sin phi, cos phi / dx, sin phi / dy)`` per azimuth, (A,) vec4.
        size: grid vertices per side.
        dx, dy: grid spacing along x and y, scene units.
    """

    pyr: wp.array(dtype=wp.float32)
    steps: wp.array(dtype=wp.vec4)
    step_level: wp.array2d(dtype=wp.int32)
    azimuth: wp.array(dtype=wp.vec4)
    size: int
    dx: float
    dy: float


@wp.struct
class TexelVisibility:
    """The wedge sums of the texel kernel and where they go (the wedge table, typed by the order,
    is the texel kernel's own argument: see :func:`visibility_kernels`).

    Fields:
        entries: E, the wedge table's entries over ``z0`` on ``linspace(-1, 1, E)``.
        harmonics: ``(cos m phi_i for m < n, sin m phi_i for m < n)`` per azimuth i, (A, 2 n)
            float32: the z-rotation of the canonical wedge to azimuth i.
        full: sum over the azimuths of the whole wedges (open from the nadir), (n*n,) float32.
        open_below: 1 to count directions below the tangent plane as open.
        res: texels per side.
        out: SH visibility per texel, world frame, (res * res, n*n) float32.
    """

    entries: int
    harmonics: wp.array2d(dtype=wp.float32)
    full: wp.array(dtype=wp.float32)
    open_below: int
    res: int
    out: wp.array2d(dtype=wp.float32)


@wp.struct
class ShadeVertices:
    """The grid vertices the shading kernel shades.

    Fields:
        points: world positions, (size * size,) vec3; normals: unit normals, (size * size,) vec3.
        eye: viewer position, world space, (1,) vec3.
        size: grid vertices per side.
    """

    points: wp.array(dtype=wp.vec3)
    normals: wp.array(dtype=wp.vec3)
    eye: wp.array(dtype=wp.vec3)
    size: int


@wp.struct
class ShadeTexels:
    """The grid of the lighting products and the BRDF's colour (the per-order coefficient arrays,
    typed by the order, are the shading kernel's own arguments: see :func:`shade_kernels`).

    Fields:
        res: texels per side.
        specular: RGB colour multiplying the radiance, linear.
    """

    res: int
    specular: wp.vec3


@wp.struct
class ShadeOutputs:
    """What the shading kernel writes: radiance toward the eye, (size * size, 3) float32, linear
    RGB; ``flags`` (size * size,) int32, per vertex the bits :data:`FLAG_NEGATIVE` and
    :data:`FLAG_BELOW_HORIZON` (one word per vertex: no counter shared by the CPU threads of a
    chunked launch, whose plain adds would race and whose cache line would bounce between cores)."""

    radiance: wp.array2d(dtype=wp.float32)
    flags: wp.array(dtype=wp.int32)


@wp.kernel(enable_backward=False)
def heights_kernel(points: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.float32)):
    i = wp.tid()
    out[i] = points[i][2]


@wp.kernel(enable_backward=False)
def reduce_kernel(pyr: wp.array(dtype=wp.float32), src_off: int, src_size: int, dst_off: int, dst_size: int):
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


#: order -> ``rotate_frame_even`` (made by :func:`static_sh_funcs`).
_EVEN_ROTATION: dict = {}


def even_frame_rotation(order: int):
    """``rotate_frame_even(f, R)``: :func:`static_sh_funcs`' ``rotate_frame`` for an ``f`` whose
    sine coefficients (``m < 0``) are zero, as the view factors of an isotropic BRDF in the frame
    with the view in its x-z plane are: the same cosines and sines, half the first z-rotation."""
    static_sh_funcs(order)
    return _EVEN_ROTATION[order]


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
    def rotate_z_even(f: vec_t, c1: float, s1: float) -> vec_t:
        # rotate_z_cs of an f without sine terms (f[l, -m] = 0, m > 0): half the products
        out = f
        c = float(1.0)
        s = float(0.0)
        for m in range(1, ORDER):
            cn = c * c1 - s * s1
            s = s * c1 + c * s1
            c = cn
            for l in range(m, ORDER):
                a = f[l * l + l + m]
                out[l * l + l + m] = c * a
                out[l * l + l - m] = s * a
        return out

    @wp.func
    def frame_euler(r: wp.mat33):
        # R = Rz(alpha) Ry(beta) Rz(gamma): (cos, sin) of alpha, beta, gamma
        sb = wp.sqrt(r[0, 2] * r[0, 2] + r[1, 2] * r[1, 2])
        cb = r[2, 2]
        ca = float(1.0)
        sa = float(0.0)
        cg = float(1.0)
        sg = float(0.0)
        if sb > 1.0e-6:
            q = 1.0 / sb
            ca = r[0, 2] * q
            sa = r[1, 2] * q
            cg = -r[2, 0] * q
            sg = r[2, 1] * q
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
        return ca, sa, cb, sb, cg, sg

    @wp.func
    def rotate_frame(f: vec_t, r: wp.mat33) -> vec_t:
        # R = Rz(alpha) Ry(beta) Rz(gamma) = Rz(alpha) Rx(-90) Rz(beta) Rx(90) Rz(gamma)
        ca, sa, cb, sb, cg, sg = frame_euler(r)
        out = rotate_z_cs(f, cg, sg)
        out = x90p(out)
        out = rotate_z_cs(out, cb, sb)
        out = x90m(out)
        return rotate_z_cs(out, ca, sa)

    @wp.func
    def rotate_frame_even(f: vec_t, r: wp.mat33) -> vec_t:
        # rotate_frame of an f without sine terms (an isotropic lobe with the view in the x-z plane)
        ca, sa, cb, sb, cg, sg = frame_euler(r)
        out = rotate_z_even(f, cg, sg)
        out = x90p(out)
        out = rotate_z_cs(out, cb, sb)
        out = x90m(out)
        return rotate_z_cs(out, ca, sa)

    _EVEN_ROTATION[order] = rotate_frame_even

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
                  u5: float, v5: float, h0: float, az: wp.vec4, top: float, floor: float) -> float:
    """Largest ``(H - h0) / d`` over the march from (u5 - 0.5, v5 - 0.5) (vertex units) along one
    azimuth; -1e30 when no sample is inside the grid.

    ``steps[j] = (d_j, 1 / d_j, 2^-k_j, -)``, ``step_level[j] = (offset, side)`` of level k_j in
    ``pyr``, ``az = (cos phi, sin phi, cos phi / dx, sin phi / dy)``, ``top`` the grid's highest
    height (the pyramid's last level): the march ends once ``(top - h0) / d_j`` cannot beat the
    slope found so far nor ``floor`` (the distances grow, so no later sample could either). With
    ``floor = -1e30`` the result is that of marching to the edge; otherwise it is that result
    wherever that exceeds ``floor`` and at most ``floor`` elsewhere (a caller that only needs
    slopes above a threshold, like the texel kernel's band above the tangent plane)."""
    best = float(-1.0e30)
    rise = top - h0
    for j in range(steps.shape[0]):
        st = steps[j]
        if rise * st[1] <= wp.max(best, floor):
            break
        n_k = step_level[j, 1]
        ci = int(wp.floor((u5 + st[0] * az[2]) * st[2]))
        ri = int(wp.floor((v5 + st[0] * az[3]) * st[2]))
        if ci < 0 or ri < 0 or ci >= n_k or ri >= n_k:
            break
        best = wp.max(best, (pyr[step_level[j, 0] + ri * n_k + ci] - h0) * st[1])
    return best


@wp.func
def horizon_slope_quad(pyr: wp.array(dtype=wp.float32), steps: wp.array(dtype=wp.vec4),
                       step_level: wp.array2d(dtype=wp.int32), u5: float, v5: float, h0: float, az1: wp.vec4,
                       az2: wp.vec4, az3: wp.vec4, az4: wp.vec4, top: float, floors: wp.vec4, count: int) -> wp.vec4:
    """:func:`horizon_slope` along the first ``count`` (1 to 4) of four azimuths in one pass over
    the march's samples (independent chains of work per sample), per-azimuth ``floors``."""
    best1 = float(-1.0e30)
    best2 = float(-1.0e30)
    best3 = float(-1.0e30)
    best4 = float(-1.0e30)
    on1 = int(1)
    on2 = int(0)
    on3 = int(0)
    on4 = int(0)
    if count > 1:
        on2 = 1
    if count > 2:
        on3 = 1
    if count > 3:
        on4 = 1
    rise = top - h0
    for j in range(steps.shape[0]):
        st = steps[j]
        n_k = step_level[j, 1]
        off = step_level[j, 0]
        bound = rise * st[1]
        if on1 == 1:
            ci = int(wp.floor((u5 + st[0] * az1[2]) * st[2]))
            ri = int(wp.floor((v5 + st[0] * az1[3]) * st[2]))
            if bound <= wp.max(best1, floors[0]) or ci < 0 or ri < 0 or ci >= n_k or ri >= n_k:
                on1 = 0
            else:
                best1 = wp.max(best1, (pyr[off + ri * n_k + ci] - h0) * st[1])
        if on2 == 1:
            ci = int(wp.floor((u5 + st[0] * az2[2]) * st[2]))
            ri = int(wp.floor((v5 + st[0] * az2[3]) * st[2]))
            if bound <= wp.max(best2, floors[1]) or ci < 0 or ri < 0 or ci >= n_k or ri >= n_k:
                on2 = 0
            else:
                best2 = wp.max(best2, (pyr[off + ri * n_k + ci] - h0) * st[1])
        if on3 == 1:
            ci = int(wp.floor((u5 + st[0] * az3[2]) * st[2]))
            ri = int(wp.floor((v5 + st[0] * az3[3]) * st[2]))
            if bound <= wp.max(best3, floors[2]) or ci < 0 or ri < 0 or ci >= n_k or ri >= n_k:
                on3 = 0
            else:
                best3 = wp.max(best3, (pyr[off + ri * n_k + ci] - h0) * st[1])
        if on4 == 1:
            ci = int(wp.floor((u5 + st[0] * az4[2]) * st[2]))
            ri = int(wp.floor((v5 + st[0] * az4[3]) * st[2]))
            if bound <= wp.max(best4, floors[3]) or ci < 0 or ri < 0 or ci >= n_k or ri >= n_k:
                on4 = 0
            else:
                best4 = wp.max(best4, (pyr[off + ri * n_k + ci] - h0) * st[1])
        if on1 + on2 + on3 + on4 == 0:
            break
    return wp.vec4(best1, best2, best3, best4)


@wp.kernel(enable_backward=False)
def horizon_kernel(pyr: wp.array(dtype=wp.float32), steps: wp.array(dtype=wp.vec4), step_level: wp.array2d(dtype=wp.int32),
                   azimuth: wp.array(dtype=wp.vec4), size: int, uv: wp.array(dtype=wp.vec2), out: wp.array2d(dtype=wp.float32)):
    """The horizon slopes of the march at points ``uv`` (vertex units), (P, A): what the texel
    kernel computes before the wedges (tests and diagnostics)."""
    p, i = wp.tid()
    h0 = _bilinear_height(pyr, size, uv[p][0], uv[p][1])
    out[p, i] = horizon_slope(pyr, steps, step_level, uv[p][0] + 0.5, uv[p][1] + 0.5, h0, azimuth[i],
                              pyr[pyr.shape[0] - 1], -1.0e30)


def cosine_indices(order: int) -> list:
    """Indices ``l^2 + l + m`` of the cosine coefficients (``m >= 0``) of one order, band by band:
    the columns of an even table (:func:`table_is_even`, :func:`visibility_kernels`)."""
    return [l * l + l + m for l in range(order) for m in range(0, l + 1)]


@functools.lru_cache(maxsize=None)
def visibility_kernels(order: int):
    """``(texel_kernel, upsample_kernel)`` of one SH order (cached): ``texel_kernel(march:
    HorizonMarch, texels: TexelVisibility, table, start)`` and ``upsample_kernel(texels, size,
    res, start, out)``, each over items ``start .. start + dim``.

    ``table`` is the canonical wedge (:func:`._model.wedge_table`, about phi = 0: no sine terms)
    by its cosine coefficients (:func:`cosine_indices`), (E,) vectors of their count: one read
    per entry; the kernel turns each azimuth's wedge difference into place with the azimuth's
    ``cos m phi``, ``sin m phi`` (``TexelVisibility.harmonics``) before adding it."""
    shk = sh_kernels(order)
    N2 = order * order
    ORDER = order
    vec_t = shk.vec
    COS = cosine_indices(order)
    NCOS = len(COS)
    M_OF = [m for l in range(order) for m in range(0, l + 1)]
    SIN = [l * l + l - m for l in range(order) for m in range(0, l + 1)]
    cos_t = wp.types.vector(length=NCOS, dtype=wp.float32)

    @wp.func
    def wedge_at(table: wp.array(dtype=cos_t), e: int, z: float) -> cos_t:
        # the canonical wedge open above z (linear in the table over z0)
        t = (wp.clamp(z, -1.0, 1.0) + 1.0) * 0.5 * float(e - 1)
        i0 = wp.min(int(t), e - 2)
        f = t - float(i0)
        return (1.0 - f) * table[i0] + f * table[i0 + 1]

    @wp.func
    def add_turned(acc: vec_t, w: cos_t, harm: wp.array2d(dtype=wp.float32), i: int) -> vec_t:
        # acc + Rz(phi_i) w for a w without sine terms: (l, m) -> cos(m phi) w, (l, -m) -> sin(m phi) w
        out = acc
        for q in range(wp.static(NCOS)):
            if wp.static(M_OF[q] == 0):
                out[wp.static(COS[q])] += w[q]
            else:
                out[wp.static(COS[q])] += harm[i, wp.static(M_OF[q])] * w[q]
                out[wp.static(SIN[q])] += harm[i, wp.static(ORDER + M_OF[q])] * w[q]
        return out

    @wp.func
    def add_wedge(acc: vec_t, best: float, tau: float, open_below: int, table: wp.array(dtype=cos_t), e: int,
                  harm: wp.array2d(dtype=wp.float32), i: int) -> vec_t:
        # acc + azimuth i's wedge: open below the tangent plane, whole - [tangent, horizon]; or
        # open above the horizon only
        out = acc
        if open_below == 1:
            if best > tau:  # else the band between tangent and horizon is empty
                zh = best / wp.sqrt(1.0 + best * best)
                zt = tau / wp.sqrt(1.0 + tau * tau)
                out = add_turned(acc, wedge_at(table, e, zh) - wedge_at(table, e, zt), harm, i)
        else:
            zh = -1.0
            if best > -1.0e29:
                zh = best / wp.sqrt(1.0 + best * best)
            out = add_turned(acc, wedge_at(table, e, zh), harm, i)
        return out

    @wp.kernel(enable_backward=False, module="unique")
    def texel_kernel(march: HorizonMarch, texels: TexelVisibility, table: wp.array(dtype=cos_t), start: int):
        pyr = march.pyr
        size = march.size
        res = texels.res
        e = texels.entries
        top = pyr[pyr.shape[0] - 1]
        t = wp.tid() + start
        a = t // res
        b = t - a * res
        scale = float(size - 1) / float(res - 1)
        u = float(b) * scale  # column (x), vertex units
        v = float(a) * scale  # row (y)
        h0 = _bilinear_height(pyr, size, u, v)
        gx = (_bilinear_height(pyr, size, u + 1.0, v) - _bilinear_height(pyr, size, u - 1.0, v)) / \
            ((wp.min(u + 1.0, float(size - 1)) - wp.max(u - 1.0, 0.0)) * march.dx)
        gy = (_bilinear_height(pyr, size, u, v + 1.0) - _bilinear_height(pyr, size, u, v - 1.0)) / \
            ((wp.min(v + 1.0, float(size - 1)) - wp.max(v - 1.0, 0.0)) * march.dy)
        acc = vec_t()
        if texels.open_below == 1:
            # each wedge is open above its horizon and below its tangent: whole - [tangent, horizon]
            for k in range(N2):
                acc[k] = texels.full[k]
        na = march.azimuth.shape[0]
        for p in range((na + 3) // 4):
            # azimuths i0 .. i0 + 3 (those below na) in one march
            i0 = 4 * p
            count = wp.min(4, na - i0)
            az1 = march.azimuth[i0]
            az2 = march.azimuth[wp.min(i0 + 1, na - 1)]
            az3 = march.azimuth[wp.min(i0 + 2, na - 1)]
            az4 = march.azimuth[wp.min(i0 + 3, na - 1)]
            taus = wp.vec4(gx * az1[0] + gy * az1[1], gx * az2[0] + gy * az2[1], gx * az3[0] + gy * az3[1],
                           gx * az4[0] + gy * az4[1])
            floors = wp.vec4(-1.0e30, -1.0e30, -1.0e30, -1.0e30)
            if texels.open_below == 1:
                # only a horizon above the tangent plane matters: the march may stop below it
                floors = taus
            best = horizon_slope_quad(pyr, march.steps, march.step_level, u + 0.5, v + 0.5, h0, az1, az2, az3, az4, top,
                                      floors, count)
            for q in range(4):
                if q < count:
                    acc = add_wedge(acc, best[q], taus[q], texels.open_below, table, e, texels.harmonics, i0 + q)
        for k in range(N2):
            texels.out[t, k] = acc[k]

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


#: A view table is even (:func:`table_is_even`) when its sine columns are at most this fraction
#: of its largest entry: far below float32's resolution of the cosine terms they sit beside
#: (the RPO and exact tables of isotropic BRDFs measure ~2e-13).
EVEN_TABLE_RTOL = 1e-9


def table_is_even(table) -> bool:
    """Whether a view table (E, n*n) has no sine coefficients (``m < 0``) to float32 precision:
    an isotropic lobe with the view in the frame's x-z plane is symmetric under y -> -y."""
    t = np.asarray(table, np.float64)
    order = int(round(math.sqrt(t.shape[1])))
    sine = [l * l + l + m for l in range(order) for m in range(-l, 0)]
    top = float(np.abs(t).max())
    return top == 0.0 or float(np.abs(t[:, sine]).max()) <= EVEN_TABLE_RTOL * top


@functools.lru_cache(maxsize=None)
def light_columns_kernel(order: int):
    """``light_columns_kernel(light (3, n*n) float32, cols (3 n*n,) vec)`` of one order (cached),
    3 threads: the order-n SH product with light channel ``c`` as a matrix, stored by columns,
    ``(l_c * v) = sum_j v_j cols[c n*n + j]`` (unrolled over the Gaunt entries): the texel
    products then cost one vector multiply-add per coefficient of ``v``."""
    shk = sh_kernels(order)
    N2 = order * order
    vec_t = shk.vec
    sh_load = shk.load
    PT = _product_terms(order)
    NPT = len(PT)
    mat_t = wp.types.matrix(shape=(N2, N2), dtype=wp.float32)

    @wp.kernel(enable_backward=False, module="unique")
    def light_columns_kernel(light: wp.array2d(dtype=wp.float32), cols: wp.array(dtype=vec_t)):
        ch = wp.tid()
        lc = sh_load(light, ch)
        # m[j] = column j of the product matrix: (l * v)_i = sum_j m[j, i] v_j
        m = mat_t()
        for e in range(wp.static(NPT)):
            m[wp.static(PT[e][2]), wp.static(PT[e][0])] += wp.static(PT[e][3]) * lc[wp.static(PT[e][1])]
            m[wp.static(PT[e][1]), wp.static(PT[e][0])] += wp.static(PT[e][3]) * lc[wp.static(PT[e][2])]
        for j in range(wp.static(N2)):
            cols[ch * N2 + j] = m[j]

    return light_columns_kernel


@functools.lru_cache(maxsize=None)
def shade_kernels(order: int, even: bool = False):
    """``(product_kernel, shade_kernel, rotate_kernel, pair_product_kernel)`` of one SH order
    (cached). With ``even`` the shading kernel reads only the cosine coefficients
    (``m >= 0``) of the view table and rotates with :func:`even_frame_rotation`: for a table whose
    sine columns are zero (:func:`table_is_even`).

    The coefficient arrays are 1-D arrays of order-n vectors (``vec``: n*n float32), so that one
    read fetches a contiguous block and the per-coefficient arithmetic is straight vector code:

    * ``product_kernel(vis (R*R, n*n), cols, start, g (3 R*R,) vec)``: ``g[3 t + c] = l_c * v_t``
      with the product matrices ``cols`` of :func:`light_columns_kernel`;
    * ``shade_kernel(vertices: ShadeVertices, texels: ShadeTexels, g, ftable (E,) vec, start, out:
      ShadeOutputs)``: thread ``start + i`` shades a run of :data:`SHADE_RUN` vertices along a grid
      row (the products interpolated along the texel columns once per column the run crosses).
    """
    shk = sh_kernels(order)
    N2 = order * order
    vec_t = shk.vec
    sh_load = shk.load
    _, rotate_frame, product = static_sh_funcs(order)
    rotate_shade = even_frame_rotation(order) if even else rotate_frame

    @wp.kernel(enable_backward=False, module="unique")
    def product_kernel(vis: wp.array2d(dtype=wp.float32), cols: wp.array(dtype=vec_t), start: int,
                       out: wp.array(dtype=vec_t)):
        t = wp.tid() + start
        v = sh_load(vis, t)
        for ch in range(3):
            g = vec_t()
            for j in range(wp.static(N2)):
                g = g + v[j] * cols[ch * N2 + j]
            out[3 * t + ch] = g

    @wp.kernel(enable_backward=False, module="unique")
    def shade_kernel(vertices: ShadeVertices, texels: ShadeTexels, g: wp.array(dtype=vec_t),
                     ftable: wp.array(dtype=vec_t), start: int, out: ShadeOutputs):
        # one thread per run of SHADE_RUN vertices along a grid row: the lighting products are
        # interpolated along the texel columns once per texel column the run crosses, then
        # along the row per vertex
        item = wp.tid() + start
        size = vertices.size
        res = texels.res
        runs = (size + SHADE_RUN - 1) // SHADE_RUN
        row = item // runs
        c_begin = (item - row * runs) * SHADE_RUN
        c_end = wp.min(c_begin + SHADE_RUN, size)
        scale = float(res - 1) / float(size - 1)
        fv = float(row) * scale
        r0 = wp.min(int(fv), res - 2)
        tv = fv - float(r0)
        sv = 1.0 - tv
        cell = int(-2)
        a0 = vec_t()
        a1 = vec_t()
        a2 = vec_t()
        b0 = vec_t()
        b1 = vec_t()
        b2 = vec_t()
        eye = vertices.eye[0]
        e = ftable.shape[0]
        for c in range(c_begin, c_end):
            vtx = row * size + c
            n = vertices.normals[vtx]
            d = eye - vertices.points[vtx]
            dl = wp.length(d)
            mu = float(0.0)
            if dl > 0.0:
                d = d * (1.0 / dl)
                mu = wp.dot(n, d)
            if mu <= 0.0:
                out.radiance[vtx, 0] = 0.0
                out.radiance[vtx, 1] = 0.0
                out.radiance[vtx, 2] = 0.0
                out.flags[vtx] = FLAG_BELOW_HORIZON
                continue
            # local frame about n with the view in its x-z plane
            x = d - mu * n
            xl = wp.length(x)
            if xl > 1.0e-6:
                x = x * (1.0 / xl)
            else:
                x = wp.vec3(1.0, 0.0, 0.0) - n[0] * n
                if wp.length(x) < 1.0e-3:
                    x = wp.vec3(0.0, 1.0, 0.0) - n[1] * n
                x = wp.normalize(x)
            y = wp.cross(n, x)
            # F(wo) from the table over cos(theta_o)
            tt = wp.min(mu, 1.0) * float(e - 1)
            i0 = wp.min(int(tt), e - 2)
            fr = tt - float(i0)
            f = (1.0 - fr) * ftable[i0] + fr * ftable[i0 + 1]
            # to the world: f(F s) with F rows (x, y, n), i.e. the rotation R = F^T
            fw = rotate_shade(f, wp.mat33(x[0], y[0], n[0], x[1], y[1], n[1], x[2], y[2], n[2]))
            fu = float(c) * scale
            c0 = wp.min(int(fu), res - 2)
            tu = fu - float(c0)
            if c0 != cell:
                if c0 == cell + 1:
                    a0 = b0
                    a1 = b1
                    a2 = b2
                else:
                    ta = 3 * (r0 * res + c0)
                    tb = ta + 3 * res
                    a0 = sv * g[ta] + tv * g[tb]
                    a1 = sv * g[ta + 1] + tv * g[tb + 1]
                    a2 = sv * g[ta + 2] + tv * g[tb + 2]
                ta = 3 * (r0 * res + c0 + 1)
                tb = ta + 3 * res
                b0 = sv * g[ta] + tv * g[tb]
                b1 = sv * g[ta + 1] + tv * g[tb + 1]
                b2 = sv * g[ta + 2] + tv * g[tb + 2]
                cell = c0
            su = 1.0 - tu
            # the six dot products in one pass over the coefficients
            da0 = float(0.0)
            da1 = float(0.0)
            da2 = float(0.0)
            db0 = float(0.0)
            db1 = float(0.0)
            db2 = float(0.0)
            for k in range(wp.static(N2)):
                fk = fw[k]
                da0 += fk * a0[k]
                da1 += fk * a1[k]
                da2 += fk * a2[k]
                db0 += fk * b0[k]
                db1 += fk * b1[k]
                db2 += fk * b2[k]
            rad = wp.vec3(su * da0 + tu * db0, su * da1 + tu * db1, su * da2 + tu * db2)
            neg = int(0)
            for ch in range(3):
                acc = rad[ch]
                if acc < 0.0:
                    acc = 0.0
                    neg = 1
                out.radiance[vtx, ch] = texels.specular[ch] * acc
            out.flags[vtx] = neg * FLAG_NEGATIVE

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
