"""Warp kernels of reflectance product operators (eq. 11).

Per receiver ``v`` with tangent frame ``F`` (rows tangent, bitangent, normal; a local direction
``a`` is ``F^T a`` in the world), position ``p`` and the eye ``e``:

1. ``wo = F normalize(e - p)`` (local); a view at or below the horizon gives 0 (counted);
2. the material slot ``s = material[v]`` (a colour BRDF: slots ``s, s+1, s+2``, one per channel,
   steps 2-5 once per channel): view weights ``u_b = w_b . y(wo)`` (view order m) and
   ``F(wo) = sum_b u_b u_b^light`` (the operator form, ``evaluation = "gaunt"``), or
   ``t = sum_b u_b (M_b v)`` with the dense operators (``"matrices"``, the paper's shader);
3. the visibility ``v`` (local SH; world-frame input is turned by ``F`` first), times the clamped
   cosine's product matrix when the BRDF table left the cosine out (``cosine = "product"``);
4. ``t = F(wo) * v`` (one order-n SH product);
5. the lighting: ``t`` turned to the world (one zxzxz rotation) and dotted with each channel of
   the world SH (``lighting = "rotate"``), or the ZH lobes' axes turned into the frame and
   ``sum_j sum_l c_jcl sum_m t_lm y_lm(F a_j)`` (``"zh"``, :mod:`._lighting`);
6. ``radiance_c = specular_c max(0, r_c)``; a negative ``r_c`` (SH truncation) is clamped and
   counted.

Turning the one vector ``t`` instead of the three lighting channels is what makes the full
rotation cost one rotation per receiver; the paper's ZH lighting replaces it by three SH
evaluations at the lobe axes and is still cheaper: 0.52x / 0.61x / 0.75x the kernel time at
n = 3 / 4 / 6 (k = 8, 2-core CPU, ``benchmarks/bench_rpo.py``), while the dense matrices cost
1.06-1.09x the one-product form and re-applying the cosine by eq. 14 1.07-1.58x.
"""

import functools

from ..._wp import wp
from ...basis.sh_warp import SHTables, sh_kernels

wp.set_module_options({"enable_backward": False})

#: ``lighting`` modes of :func:`shade_kernel`.
LIGHTING_MODES = ("rotate", "zh")
#: ``evaluation`` modes of :func:`shade_kernel`.
EVALUATIONS = ("gaunt", "matrices")
#: Bits of the kernel's per-receiver ``flags``: a channel clamped from below zero; the eye at or
#: below the receiver's horizon (shaded 0). One word per receiver: a counter shared by the threads
#: of a chunked CPU launch would be a plain read-modify-write from several cores (Warp's CPU atomics
#: are not atomic across threads).
FLAG_NEGATIVE, FLAG_BELOW_HORIZON = 1, 2


@wp.struct
class Receivers:
    """Receiver vertices of one frame.

    Fields:
        frames: tangent frames, rows tangent, bitangent, normal (world -> local), (V,) mat33.
        points: world positions, (V,) vec3.
        visibility: SH visibility, local or world frame (the kernel's ``visibility_space``),
            (V, n*n) float32.
        material: material slot of each vertex (row of the operator tables), (V,) int32.
    """

    frames: wp.array(dtype=wp.mat33)
    points: wp.array(dtype=wp.vec3)
    visibility: wp.array2d(dtype=wp.float32)
    material: wp.array(dtype=wp.int32)


@wp.struct
class Operators:
    """The reflectance product operators of the material slots and the surface colour.

    Fields:
        light_sh: light factors ``w_b^light`` per slot, (slots, k, n*n) float32 (``"gaunt"``).
        view_sh: view factors ``w_b``, (slots, k, view_order^2) float32.
        rank: factors used per slot, (slots,) int32 (entries at and after it are ignored).
        channels: 1 for a slot whose BRDF shades all three colour channels, 3 for the first of
            three consecutive slots holding a colour BRDF's red, green and blue operators,
            (slots,) int32.
        matrices: dense operators ``M_b``, (slots, k, n*n, n*n) float32 (``"matrices"``; a
            (1, 1, 1, 1) placeholder otherwise).
        cos_sh: clamped cosine SH, (n*n,) float32 (read when ``cosine = "product"``).
        specular: RGB colour multiplying the radiance, linear.
    """

    light_sh: wp.array3d(dtype=wp.float32)
    view_sh: wp.array3d(dtype=wp.float32)
    rank: wp.array(dtype=wp.int32)
    channels: wp.array(dtype=wp.int32)
    matrices: wp.array4d(dtype=wp.float32)
    cos_sh: wp.array(dtype=wp.float32)
    specular: wp.vec3


@wp.struct
class ViewLighting:
    """The viewer and the frame's lighting.

    Fields:
        eye: viewer position, world space, (1,) vec3.
        sh: distant lighting SH per channel, world frame, (3, n*n) float32 (``"rotate"``).
        zh_axes: the frame's ZH lobe axes, world unit vectors, (J,) vec3 (``"zh"``; empty otherwise).
        zh_coeffs: ZH coefficients of each lobe per channel and band, (max(J, 1), 3, n) float32.
    """

    eye: wp.array(dtype=wp.vec3)
    sh: wp.array2d(dtype=wp.float32)
    zh_axes: wp.array(dtype=wp.vec3)
    zh_coeffs: wp.array3d(dtype=wp.float32)


@wp.struct
class ShadeOutputs:
    """What :func:`shade_kernel` writes.

    Fields:
        radiance: radiance toward the eye, (V, 3) float32, linear RGB.
        flags: (V,) int32, per receiver the bits :data:`FLAG_NEGATIVE` and
            :data:`FLAG_BELOW_HORIZON` (counted on the host).
    """

    radiance: wp.array2d(dtype=wp.float32)
    flags: wp.array(dtype=wp.int32)


@wp.kernel
def turn_axes_kernel(frame: wp.array(dtype=wp.int32), turn: wp.array(dtype=wp.mat33), axes0: wp.array(dtype=wp.vec3),
                     axes: wp.array(dtype=wp.vec3)):
    """The ZH lighting lobes of this frame: ``turn[t] axes0[j]`` (the lighting's rotation since the fit)."""
    j = wp.tid()
    axes[j] = turn[wp.min(frame[0], turn.shape[0] - 1)] * axes0[j]


@functools.lru_cache(maxsize=None)
def shade_kernel(order: int, view_order: int, lighting: str = "rotate", cosine: str = "brdf",
                 visibility_space: str = "local", evaluation: str = "gaunt"):
    """The eq. 11 kernel for one configuration (cached): ``kernel(surface: Receivers, ops: Operators,
    light: ViewLighting, tables: SHTables, start, out: ShadeOutputs)``. Launch with ``dim = count`` and
    ``start`` (receivers ``start .. start + count``)."""
    if lighting not in LIGHTING_MODES or evaluation not in EVALUATIONS or cosine not in ("brdf", "product") \
            or visibility_space not in ("local", "world"):
        raise ValueError(f"rpo: bad kernel configuration {(lighting, cosine, visibility_space, evaluation)}")
    shk = sh_kernels(order)
    svk = sh_kernels(view_order)
    N2 = order * order
    NV = view_order * view_order
    ORDER = order
    vec_t = shk.vec
    # the straight-line product where the order allows it (same sums, no table reads)
    sh_eval, sh_rotate, sh_product, sh_load = shk.eval, shk.rotate, shk.product_unrolled, shk.load
    view_eval = svk.eval
    ZH = 1 if lighting == "zh" else 0
    COS_PRODUCT = 1 if cosine == "product" else 0
    VIS_WORLD = 1 if visibility_space == "world" else 0
    MATRICES = 1 if evaluation == "matrices" else 0

    @wp.func
    def _channel_radiance(ops: Operators, light: ViewLighting, tables: SHTables, f: wp.mat33, yo: svk.vec,
                          vis: vec_t, s: int):
        """Steps 2-5 for material slot ``s``: the RGB radiance before the colour and the clamp."""
        t = vec_t()
        if MATRICES == 1:
            for b in range(ops.rank[s]):
                ub = float(0.0)
                for i in range(NV):
                    ub += ops.view_sh[s, b, i] * yo[i]
                for i in range(N2):
                    acc = float(0.0)
                    for j in range(N2):
                        acc += ops.matrices[s, b, i, j] * vis[j]
                    t[i] = t[i] + ub * acc
        else:
            fo = vec_t()
            for b in range(ops.rank[s]):
                ub = float(0.0)
                for i in range(NV):
                    ub += ops.view_sh[s, b, i] * yo[i]
                for i in range(N2):
                    fo[i] = fo[i] + ub * ops.light_sh[s, b, i]
            t = sh_product(fo, vis, tables)
        r = wp.vec3(0.0, 0.0, 0.0)
        if ZH == 1:
            for j in range(light.zh_axes.shape[0]):
                y = sh_eval(f * light.zh_axes[j])
                for l in range(ORDER):
                    acc = float(0.0)
                    for m in range(2 * l + 1):
                        acc += t[l * l + m] * y[l * l + m]
                    r = r + acc * wp.vec3(light.zh_coeffs[j, 0, l], light.zh_coeffs[j, 1, l], light.zh_coeffs[j, 2, l])
        else:
            tw = sh_rotate(t, wp.transpose(f), tables)
            for i in range(N2):
                r = r + tw[i] * wp.vec3(light.sh[0, i], light.sh[1, i], light.sh[2, i])
        return r

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(surface: Receivers, ops: Operators, light: ViewLighting, tables: SHTables, start: int, out: ShadeOutputs):
        v = wp.tid() + start
        f = surface.frames[v]
        d = light.eye[0] - surface.points[v]
        dl = wp.length(d)
        wo = wp.vec3(0.0, 0.0, 1.0)
        if dl > 0.0:
            wo = f * (d / dl)
        if wo[2] <= 0.0:
            out.radiance[v, 0] = 0.0
            out.radiance[v, 1] = 0.0
            out.radiance[v, 2] = 0.0
            out.flags[v] = FLAG_BELOW_HORIZON
            return
        s = surface.material[v]
        yo = view_eval(wo)
        vis = sh_load(surface.visibility, v)
        if VIS_WORLD == 1:
            vis = sh_rotate(vis, f, tables)
        if COS_PRODUCT == 1:
            c = vec_t()
            for i in range(N2):
                c[i] = ops.cos_sh[i]
            vis = sh_product(vis, c, tables)
        nch = ops.channels[s]
        r = wp.vec3(0.0, 0.0, 0.0)
        for ch in range(nch):
            rc = _channel_radiance(ops, light, tables, f, yo, vis, s + ch)
            if nch == 1:
                r = rc
            else:
                r[ch] = rc[ch]
        neg = int(0)
        for c in range(3):
            x = r[c]
            if x < 0.0:
                x = 0.0
                neg = 1
            out.radiance[v, c] = ops.specular[c] * x
        out.flags[v] = neg * FLAG_NEGATIVE

    return kernel
