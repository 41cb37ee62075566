"""Warp kernels of local, deformable PRT (Sloan, Luna, Snyder 2005).

Per-vertex model (local tangent frame ``F``, rows tangent/bitangent/normal, so a local direction
``a`` is ``F^T a`` in world space):

* ``axes[v, k]`` (vec3, local), ``coeffs[v, k, :]`` (convolution coefficients ``g*``),
  ``counts[v]`` lobes used (padded layout, the rest ignored);
* ``stored[v, 0:4]``: the exactly stored DC and linear SH coefficients (local frame; zero when
  not stored).

Radiance per channel c: ``albedo / pi * (dc e_c,00 + lin_world . e_c,1 + sum_k g*_k . e^_c(F^T a_k))``
with ``e^`` either looked up in the light-specialised table (eq. 24-25) or evaluated directly
from the lighting SH. The linear band turns like a vector: local coefficients
``(f_1,-1, f_1,0, f_1,1)`` correspond to ``w = (-f_1,1, -f_1,-1, f_1,0)``, rotated as ``F^T w``.
"""

import functools

from ..._wp import wp
from ...basis.sh_warp import SHTables, sh_kernels
from ...basis.zh import zh_kernels
from ...scene._materials_warp import concentric_footprint, hemisphere_to_concentric

wp.set_module_options({"enable_backward": False})

INV_PI = 0.3183098861837907


@wp.func
def stored_term(stored: wp.array2d(dtype=wp.float32), v: int, rot: wp.mat33,
                light: wp.array2d(dtype=wp.float32), c: int) -> float:
    """DC + rotated linear band of vertex v dotted with channel c of the world lighting."""
    acc = stored[v, 0] * light[c, 0]
    w = rot * wp.vec3(-stored[v, 3], -stored[v, 1], stored[v, 2])
    if light.shape[1] > 1:
        acc += -w[1] * light[c, 1] + w[2] * light[c, 2] - w[0] * light[c, 3]
    return acc


@wp.kernel
def rotate_axes_kernel(
    frames: wp.array(dtype=wp.mat33),
    axes: wp.array2d(dtype=wp.vec3),
    counts: wp.array(dtype=wp.int32),
    world_axes: wp.array2d(dtype=wp.vec3),
):
    """world_axes[v, k] = F_v^T axes[v, k] for k < counts[v] (eq. 10)."""
    v = wp.tid()
    rot = wp.transpose(frames[v])
    for k in range(counts[v]):
        world_axes[v, k] = rot * axes[v, k]


@functools.cache
def shade_kernels(order: int):
    """(table_kernel, shade_table, shade_direct, shade_rotate_full) specialised to an SH order.

    * ``shade_table(frames, axes, coeffs, counts, stored, table, light, albedo, radiance)``:
      one thread per vertex, N bilinear look-ups of ``e^`` and N n-dot products per channel
      (O(nN));
    * ``shade_direct(frames, axes, coeffs, counts, stored, light, albedo, radiance)``: the SH
      basis at every rotated axis, dotted band by band with the lighting (O(n^2 N));
    * ``shade_rotate_full(frames, transfer, tables, light, albedo, radiance)``: the full local SH
      transfer vector rotated to world per vertex with the zxzxz SH rotation, then dotted
      (O(n^3)); the baseline the ZH lobes replace.
    """
    zk = zh_kernels(order)
    shk = sh_kernels(order)
    ORDER = order
    N2 = order * order
    sh_eval = shk.eval
    sh_rotate = shk.rotate
    sh_load = shk.load
    table_lookup = zk.table_lookup
    load_bands = zk.load_bands

    @wp.kernel(enable_backward=False, module="unique")
    def shade_table(
        frames: wp.array(dtype=wp.mat33),
        axes: wp.array2d(dtype=wp.vec3),
        coeffs: wp.array3d(dtype=wp.float32),
        counts: wp.array(dtype=wp.int32),
        stored: wp.array2d(dtype=wp.float32),
        table: wp.array4d(dtype=wp.float32),
        light: wp.array2d(dtype=wp.float32),
        albedo: wp.array2d(dtype=wp.float32),
        radiance: wp.array2d(dtype=wp.float32),
    ):
        v = wp.tid()
        rot = wp.transpose(frames[v])
        acc = wp.vec3(stored_term(stored, v, rot, light, 0), stored_term(stored, v, rot, light, 1),
                      stored_term(stored, v, rot, light, 2))
        for k in range(counts[v]):
            acc += table_lookup(table, rot * axes[v, k]) * load_bands(coeffs, v, k)
        for c in range(3):
            radiance[v, c] = albedo[v, c] * INV_PI * acc[c]

    @wp.kernel(enable_backward=False, module="unique")
    def shade_direct(
        frames: wp.array(dtype=wp.mat33),
        axes: wp.array2d(dtype=wp.vec3),
        coeffs: wp.array3d(dtype=wp.float32),
        counts: wp.array(dtype=wp.int32),
        stored: wp.array2d(dtype=wp.float32),
        light: wp.array2d(dtype=wp.float32),
        albedo: wp.array2d(dtype=wp.float32),
        radiance: wp.array2d(dtype=wp.float32),
    ):
        v = wp.tid()
        rot = wp.transpose(frames[v])
        r = stored_term(stored, v, rot, light, 0)
        gr = stored_term(stored, v, rot, light, 1)
        b = stored_term(stored, v, rot, light, 2)
        for k in range(counts[v]):
            y = sh_eval(rot * axes[v, k])
            for l in range(ORDER):
                gl = coeffs[v, k, l]
                for m in range(-l, l + 1):
                    i = l * l + l + m
                    yg = gl * y[i]
                    r += yg * light[0, i]
                    gr += yg * light[1, i]
                    b += yg * light[2, i]
        radiance[v, 0] = albedo[v, 0] * INV_PI * r
        radiance[v, 1] = albedo[v, 1] * INV_PI * gr
        radiance[v, 2] = albedo[v, 2] * INV_PI * b

    @wp.kernel(enable_backward=False, module="unique")
    def shade_rotate_full(
        frames: wp.array(dtype=wp.mat33),
        transfer: wp.array2d(dtype=wp.float32),
        tables: SHTables,
        light: wp.array2d(dtype=wp.float32),
        albedo: wp.array2d(dtype=wp.float32),
        radiance: wp.array2d(dtype=wp.float32),
    ):
        v = wp.tid()
        t = sh_rotate(sh_load(transfer, v), wp.transpose(frames[v]), tables)
        r = float(0.0)
        gr = float(0.0)
        b = float(0.0)
        for i in range(N2):
            r += t[i] * light[0, i]
            gr += t[i] * light[1, i]
            b += t[i] * light[2, i]
        radiance[v, 0] = albedo[v, 0] * INV_PI * r
        radiance[v, 1] = albedo[v, 1] * INV_PI * gr
        radiance[v, 2] = albedo[v, 2] * INV_PI * b

    return zk.table_kernel, shade_table, shade_direct, shade_rotate_full


@wp.func
def view_factor(factors: wp.array3d(dtype=wp.float32), ab: wp.vec2, j: int) -> float:
    """Bilinear interpolation of view factor j between texel centres of a (res, res, n_b) texture."""
    fp = concentric_footprint(ab, factors.shape[0])
    ia = int(fp[0])
    ib = int(fp[1])
    ta = fp[2]
    tb = fp[3]
    return ((1.0 - ta) * (1.0 - tb) * factors[ia, ib, j] + ta * (1.0 - tb) * factors[ia + 1, ib, j]
            + (1.0 - ta) * tb * factors[ia, ib + 1, j] + ta * tb * factors[ia + 1, ib + 1, j])


@wp.func
def stored_row_term(stored: wp.array3d(dtype=wp.float32), v: int, j: int, rot: wp.mat33,
                    light: wp.array2d(dtype=wp.float32), c: int) -> float:
    """DC + rotated linear band of BRDF row j of vertex v dotted with lighting channel c."""
    acc = stored[v, j, 0] * light[c, 0]
    w = rot * wp.vec3(-stored[v, j, 3], -stored[v, j, 1], stored[v, j, 2])
    if light.shape[1] > 1:
        acc += -w[1] * light[c, 1] + w[2] * light[c, 2] - w[0] * light[c, 3]
    return acc


@wp.struct
class GlossyVertices:
    """Per-vertex inputs of :func:`glossy_kernel`.

    Fields:
        frames: tangent frames, rows tangent, bitangent, normal (world -> local), (V,) mat33.
        points: world positions, (V,) vec3.
        axes: lobe axes, local frame, (V, n_b * lobes) vec3 (n_b BRDF rows x ``lobes``, row-major).
        coeffs: lobe convolution coefficients ``g*``, (V, n_b * lobes, n) float32.
        stored: exactly stored DC and linear SH coefficients per BRDF row, local frame, (V, n_b, 4) float32.
        lobes: lobes per BRDF row.
    """

    frames: wp.array(dtype=wp.mat33)
    points: wp.array(dtype=wp.vec3)
    axes: wp.array2d(dtype=wp.vec3)
    coeffs: wp.array3d(dtype=wp.float32)
    stored: wp.array3d(dtype=wp.float32)
    lobes: int


@wp.struct
class GlossyShading:
    """The viewer, BRDF and lighting of :func:`glossy_kernel`.

    Fields:
        eye: viewer position, world space, (1,) vec3 (the frame state's viewer).
        factors: BRDF view-factor texture over the concentric square, (res, res, n_b) float32.
        table: light-specialised ZH table (eq. 24-25), (rows, cols, 3, n) float32.
        light: distant lighting SH per channel, world frame, (3, n*n) float32.
        specular: RGB colour multiplying the radiance, linear.
    """

    eye: wp.array(dtype=wp.vec3)
    factors: wp.array3d(dtype=wp.float32)
    table: wp.array4d(dtype=wp.float32)
    light: wp.array2d(dtype=wp.float32)
    specular: wp.vec3


@functools.cache
def glossy_kernel(order: int):
    """``shade_glossy(vertices: GlossyVertices, shading: GlossyShading, radiance)``: glossy LDPRT
    (eq. 16) with the light-specialised table, one thread per vertex; radiance (V, 3) float32 =
    specular * r(v), 0 where the eye is below the vertex's tangent plane (the BRDF vanishes there)."""
    zk = zh_kernels(order)
    table_lookup = zk.table_lookup
    load_bands = zk.load_bands

    @wp.kernel(enable_backward=False, module="unique")
    def shade_glossy(vertices: GlossyVertices, shading: GlossyShading, radiance: wp.array2d(dtype=wp.float32)):
        v = wp.tid()
        f = vertices.frames[v]
        rot = wp.transpose(f)
        view = shading.eye[0] - vertices.points[v]
        vlen = wp.length(view)
        if vlen > 0.0:
            view = view / vlen
        local_view = f * view
        if local_view[2] <= 0.0:
            # the viewer is below the surface's horizon: b(v, s) = 0, nothing is reflected to it
            for c in range(3):
                radiance[v, c] = 0.0
            return
        ab = hemisphere_to_concentric(local_view)
        acc = wp.vec3(0.0)
        for j in range(shading.factors.shape[2]):
            s = wp.vec3(stored_row_term(vertices.stored, v, j, rot, shading.light, 0),
                        stored_row_term(vertices.stored, v, j, rot, shading.light, 1),
                        stored_row_term(vertices.stored, v, j, rot, shading.light, 2))
            for k in range(vertices.lobes):
                slot = j * vertices.lobes + k
                s += table_lookup(shading.table, rot * vertices.axes[v, slot]) * load_bands(vertices.coeffs, v, slot)
            acc += view_factor(shading.factors, ab, j) * s
        for c in range(3):
            # SH truncation rings below zero around a sharp light: clamped, as every SH shading stage does
            radiance[v, c] = shading.specular[c] * wp.max(acc[c], 0.0)

    return shade_glossy


@wp.func
def rotate_z(v: wp.vec3, c: float, s: float) -> wp.vec3:
    return wp.vec3(c * v[0] - s * v[1], s * v[0] + c * v[1], v[2])


@wp.struct
class WrinkleVertices:
    """Per-vertex inputs of the wrinkle shading.

    Fields:
        frames: tangent frames, rows tangent, bitangent, normal (world -> local), (V,) mat33.
        phase: groove phase, (V,) float32 (periods; the table is periodic in it).
        groove_angle: angle of the groove frame about the normal, (V,) float32, radians.
        depth: wrinkle depth, (V,) float32 (groove periods).
        albedo: diffuse albedo, (V, 3) float32, linear RGB.
    """

    frames: wp.array(dtype=wp.mat33)
    phase: wp.array(dtype=wp.float32)
    groove_angle: wp.array(dtype=wp.float32)
    depth: wp.array(dtype=wp.float32)
    albedo: wp.array2d(dtype=wp.float32)


@wp.struct
class WrinkleTable:
    """The fitted 3-lobe wrinkle table over (phase, depth), groove frame.

    Fields:
        axes: lobe axes, (phase_controls, depth_controls, 3) vec3 (normalised after interpolation).
        coeffs: lobe ZH coefficients, (phase_controls, depth_controls, 3, n) float32.
        stored: DC and linear SH coefficients, (phase_controls, depth_controls, 4) float32.
        max_depth: depth of the table's last depth row (groove periods).
    """

    axes: wp.array3d(dtype=wp.vec3)
    coeffs: wp.array4d(dtype=wp.float32)
    stored: wp.array3d(dtype=wp.float32)
    max_depth: float


@functools.cache
def wrinkle_kernels(order: int):
    """(depth_kernel, shade_wrinkle) for the sinusoidal wrinkle model.

    * ``depth_kernel(points, axis_neighbour, rest_length, base_depth, gain, max_depth, depth)``:
      per vertex ``depth = clamp(base_depth + gain * max(0, 1 - |p_k - p_v| / rest_length), 0,
      max_depth)`` with k the vertex's one-ring neighbour most aligned with the groove axis at
      rest (compression along the groove axis deepens the wrinkle); ``axis_neighbour < 0``: base
      depth only.
    * ``shade_wrinkle(vertices: WrinkleVertices, table: WrinkleTable, light, radiance)``: bilinear
      look-up of the 3-lobe parameters at (phase, depth) (periodic in phase), axes normalised,
      turned from the groove frame into the tangent frame by ``groove_angle`` about the normal,
      then to world by ``F^T``; shaded by direct SH evaluation, ``albedo / pi * dot(L, t~)``
      (``light`` the world SH per channel, (3, n*n) float32; radiance (V, 3) float32).
    """
    shk = sh_kernels(order)
    ORDER = order
    sh_eval = shk.eval

    @wp.kernel(enable_backward=False, module="unique")
    def depth_kernel(
        points: wp.array(dtype=wp.vec3),
        axis_neighbour: wp.array(dtype=wp.int32),
        rest_length: wp.array(dtype=wp.float32),
        base_depth: wp.array(dtype=wp.float32),
        gain: float,
        max_depth: float,
        depth: wp.array(dtype=wp.float32),
    ):
        v = wp.tid()
        d = base_depth[v]
        k = axis_neighbour[v]
        if k >= 0 and rest_length[v] > 0.0:
            ratio = wp.length(points[k] - points[v]) / rest_length[v]
            d += gain * wp.max(0.0, 1.0 - ratio)
        depth[v] = wp.clamp(d, 0.0, max_depth)

    @wp.kernel(enable_backward=False, module="unique")
    def shade_wrinkle(vertices: WrinkleVertices, table: WrinkleTable, light: wp.array2d(dtype=wp.float32),
                      radiance: wp.array2d(dtype=wp.float32)):
        v = wp.tid()
        cx = table.axes.shape[0]
        cd = table.axes.shape[1]
        x = vertices.phase[v] - wp.floor(vertices.phase[v])
        fx = x * float(cx)
        i0 = int(wp.floor(fx)) % cx
        i1 = (i0 + 1) % cx
        tx = fx - wp.floor(fx)
        fd = wp.clamp(vertices.depth[v] / table.max_depth, 0.0, 1.0) * float(cd - 1)
        j0 = wp.min(int(wp.floor(fd)), cd - 2)
        td = fd - float(j0)
        w00 = (1.0 - tx) * (1.0 - td)
        w10 = tx * (1.0 - td)
        w01 = (1.0 - tx) * td
        w11 = tx * td
        c = wp.cos(vertices.groove_angle[v])
        s = wp.sin(vertices.groove_angle[v])
        rot = wp.transpose(vertices.frames[v])
        acc = wp.vec3(0.0)
        # stored DC + linear band (groove frame -> tangent frame -> world)
        st = wp.vec4(0.0)
        for q in range(4):
            st[q] = (w00 * table.stored[i0, j0, q] + w10 * table.stored[i1, j0, q]
                     + w01 * table.stored[i0, j0 + 1, q] + w11 * table.stored[i1, j0 + 1, q])
        wv = rot * rotate_z(wp.vec3(-st[3], -st[1], st[2]), c, s)
        for ch in range(3):
            acc[ch] = st[0] * light[ch, 0] - wv[1] * light[ch, 1] + wv[2] * light[ch, 2] - wv[0] * light[ch, 3]
        for k in range(3):
            a = (w00 * table.axes[i0, j0, k] + w10 * table.axes[i1, j0, k] + w01 * table.axes[i0, j0 + 1, k]
                 + w11 * table.axes[i1, j0 + 1, k])
            alen = wp.length(a)
            if alen > 0.0:
                a = a / alen
            else:
                a = wp.vec3(0.0, 0.0, 1.0)
            y = sh_eval(rot * rotate_z(a, c, s))
            for l in range(ORDER):
                g = (w00 * table.coeffs[i0, j0, k, l] + w10 * table.coeffs[i1, j0, k, l]
                     + w01 * table.coeffs[i0, j0 + 1, k, l] + w11 * table.coeffs[i1, j0 + 1, k, l])
                for m in range(-l, l + 1):
                    i = l * l + l + m
                    acc += (g * y[i]) * wp.vec3(light[0, i], light[1, i], light[2, i])
        for ch in range(3):
            radiance[v, ch] = vertices.albedo[v, ch] * INV_PI * acc[ch]

    return depth_kernel, shade_wrinkle
