"""Warp kernels of LDPRT texture patches (:mod:`._patch`), per vertex and per pixel.

A point of a patched surface with UV ``uv`` looks up the patch at ``uv * tiling`` (periodic):
the four texels around it (bilinear weights over texel centres) each give the exit radiance of
their ZH lobes rotated into the point's tangent frame ``F`` (rows t, b, n; a patch-frame
direction ``a`` is ``F^T a`` in world space) and dotted with the frame's world SH lighting::

    radiance_c = albedo_c / pi * sum_k w_k a_k,c (stored_k . e_c + sum_i g*_ki . e^_c(F^T a_ki))

(the stored DC and linear band as :func:`._kernels.stored_term`; ``a_k`` the texel's albedo factor). Blending the four radiances,
not the lobes, keeps the interpolation exact for lobes that do not correspond between texels.
The frame: ``t`` the surface's dP/du (accumulated per vertex over its triangles, UV-area
weighted, interpolated at the pixel) made orthogonal to the shading normal, ``b = +-n x t`` on
the side of dP/dv; a degenerate or non-finite dP/du gives any tangent perpendicular to ``n`` and
a degenerate normal +z, so a frame is always orthonormal and finite. Points of meshes without
the patch get the unshadowed diffuse shading (the clamped cosine about ``n``).
"""

import functools

from ..._wp import wp
from ...basis.sh_warp import sh_kernels
from ._kernels import stored_term

__all__ = [
    "PatchSurface",
    "PatchTexture",
    "patch_kernels",
    "patch_surface",
    "patch_texture",
    "update_tangents",
]

wp.set_module_options({"enable_backward": False})

INV_PI = 0.3183098861837907
#: |dP/du| (after removing its normal part) below which the tangent is taken as degenerate.
TANGENT_EPS = 1e-12
#: UV magnitude beyond which (or non-finite) a look-up falls back to uv = 0.
UV_LIMIT = 1e6
#: Steps of the per-pixel parallax march through the height field (then one secant step).
PARALLAX_STEPS = 32
#: Largest |n . d| treated as grazing: the march's view ray is steepened to this (bounds the shift
#: to (height range) / PARALLAX_MIN_COSINE patch widths).
PARALLAX_MIN_COSINE = 0.1


@wp.struct
class PatchTexture:
    """The patch on the device: per texel (``j * R + i``) ZH lobes in the patch frame.

    Fields:
        axes: (T, L) vec3 lobe axes; coeffs: (T, L, n) float ``g*``; counts: (T,) int32 lobes;
        stored: (T, 4) float DC + linear SH; albedo: (T,) vec3 per-texel albedo factor; cosine: (n,) float clamped-cosine ``A_l`` (the
        unpatched shading); resolution: R; tiling: patches per unit of UV; heights: (R, R) float
        texel heights (patch widths) with their mean, min and max; parallax: 1 to march the view
        ray through the heights per pixel (the texel seen), 0 for the paper's look-up at the UV.
    """

    axes: wp.array2d(dtype=wp.vec3)
    coeffs: wp.array3d(dtype=wp.float32)
    counts: wp.array(dtype=wp.int32)
    stored: wp.array2d(dtype=wp.float32)
    albedo: wp.array(dtype=wp.vec3)
    cosine: wp.array(dtype=wp.float32)
    resolution: int
    tiling: float
    heights: wp.array2d(dtype=wp.float32)
    height_mean: float
    height_min: float
    height_max: float
    parallax: int


@wp.struct
class PatchSurface:
    """The surface the patch is mapped on (per vertex of the scene).

    Fields:
        faces: (F, 3) int32; uvs: (V,) vec2 (0 on unpatched meshes); patched: (V,) int32, 1 on
        meshes carrying the patch; tangents, bitangents: (V,) vec3 accumulated dP/du, dP/dv of
        the current frame; albedo: (V, 3) float diffuse albedo.
    """

    faces: wp.array2d(dtype=wp.int32)
    uvs: wp.array(dtype=wp.vec2)
    patched: wp.array(dtype=wp.int32)
    tangents: wp.array(dtype=wp.vec3)
    bitangents: wp.array(dtype=wp.vec3)
    albedo: wp.array2d(dtype=wp.float32)


@wp.func
def any_perpendicular(n: wp.vec3) -> wp.vec3:
    """A unit vector perpendicular to the unit vector n."""
    a = wp.vec3(1.0, 0.0, 0.0)
    if wp.abs(n[0]) > 0.9:
        a = wp.vec3(0.0, 1.0, 0.0)
    return wp.normalize(a - n * wp.dot(n, a))


@wp.func
def tangent_frame(normal: wp.vec3, tangent: wp.vec3, bitangent: wp.vec3) -> wp.mat33:
    """Orthonormal frame, rows (t, b, n), from a shading normal and raw dP/du, dP/dv (module docstring)."""
    nl = wp.length(normal)
    n = wp.vec3(0.0, 0.0, 1.0)
    if nl > TANGENT_EPS and nl < 1.0e30:
        n = normal / nl
    t = tangent - n * wp.dot(n, tangent)
    tl = wp.length(t)
    if tl > TANGENT_EPS and tl < 1.0e30:
        t = t / tl
    else:
        t = any_perpendicular(n)
    b = wp.cross(n, t)
    if wp.dot(b, bitangent) < 0.0:
        b = -b
    return wp.mat33(t[0], t[1], t[2], b[0], b[1], b[2], n[0], n[1], n[2])


@wp.func
def wrap_texel(k: int, r: int) -> int:
    m = k % r
    if m < 0:
        m += r
    return m


@wp.func
def finite_coordinate(x: float) -> float:
    if wp.abs(x) < UV_LIMIT:
        return x
    return 0.0


@wp.func
def patch_height(patch: PatchTexture, x: float, y: float) -> float:
    """Bilinear, periodic height at patch coordinates (x, y) (patch widths; period 1)."""
    r = patch.resolution
    fx = (x - wp.floor(x)) * float(r) - 0.5
    fy = (y - wp.floor(y)) * float(r) - 0.5
    x0 = wp.floor(fx)
    y0 = wp.floor(fy)
    tx = fx - x0
    ty = fy - y0
    i0 = wrap_texel(int(x0), r)
    j0 = wrap_texel(int(y0), r)
    i1 = wrap_texel(i0 + 1, r)
    j1 = wrap_texel(j0 + 1, r)
    h = patch.heights
    return ((1.0 - tx) * (1.0 - ty) * h[j0, i0] + tx * (1.0 - ty) * h[j0, i1] + (1.0 - tx) * ty * h[j1, i0]
            + tx * ty * h[j1, i1])


@wp.func
def parallax_uv(patch: PatchTexture, uv: wp.vec2, frame: wp.mat33, direction: wp.vec3) -> wp.vec2:
    """The UV of the point of the displaced surface (heights about their mean, along the frame's
    normal) a view ray through the base point ``uv`` meets first: ``PARALLAX_STEPS`` steps from
    the highest to the lowest height, then a secant step (ray directions with ``n . d`` above
    ``-PARALLAX_MIN_COSINE`` are steepened to it)."""
    u = finite_coordinate(uv[0] * patch.tiling)
    v = finite_coordinate(uv[1] * patch.tiling)
    d = frame * direction
    dl = wp.length(d)
    if not (dl > TANGENT_EPS and dl < 1.0e30):
        return wp.vec2(u / patch.tiling, v / patch.tiling)
    d = d / dl
    dz = wp.min(d[2], -PARALLAX_MIN_COSINE)
    top = patch.height_max - patch.height_mean
    bottom = patch.height_min - patch.height_mean
    s0 = top / dz
    s1 = bottom / dz
    prev_s = s0
    prev_f = dz * s0 - (patch_height(patch, u + s0 * d[0], v + s0 * d[1]) - patch.height_mean)
    hit_s = s1
    found = int(0)
    for k in range(1, PARALLAX_STEPS + 1):
        s = s0 + (s1 - s0) * float(k) / float(PARALLAX_STEPS)
        f = dz * s - (patch_height(patch, u + s * d[0], v + s * d[1]) - patch.height_mean)
        if found == 0 and f <= 0.0:
            t = float(1.0)
            if prev_f - f > 0.0:
                t = prev_f / (prev_f - f)
            hit_s = prev_s + (s - prev_s) * t
            found = 1
        prev_s = s
        prev_f = f
    return wp.vec2((u + hit_s * d[0]) / patch.tiling, (v + hit_s * d[1]) / patch.tiling)


@wp.kernel
def clear_tangents_kernel(surface: PatchSurface):
    v = wp.tid()
    surface.tangents[v] = wp.vec3(0.0)
    surface.bitangents[v] = wp.vec3(0.0)


@wp.kernel
def accumulate_tangents_kernel(points: wp.array(dtype=wp.vec3), surface: PatchSurface):
    """Per triangle of a patched mesh: dP/du and dP/dv times the UV area, added to its corners."""
    f = wp.tid()
    a = surface.faces[f, 0]
    b = surface.faces[f, 1]
    c = surface.faces[f, 2]
    if surface.patched[a] == 0:
        return
    e1 = points[b] - points[a]
    e2 = points[c] - points[a]
    d1 = surface.uvs[b] - surface.uvs[a]
    d2 = surface.uvs[c] - surface.uvs[a]
    det = d1[0] * d2[1] - d2[0] * d1[1]
    s = wp.sign(det)
    dpdu = (e1 * d2[1] - e2 * d1[1]) * s
    dpdv = (e2 * d1[0] - e1 * d2[0]) * s
    for k in range(3):
        v = surface.faces[f, k]
        wp.atomic_add(surface.tangents, v, dpdu)
        wp.atomic_add(surface.bitangents, v, dpdv)


@functools.cache
def patch_kernels(order: int):
    """(shade_vertices, shade_pixels) specialised to an SH order.

    * ``shade_vertices(points_normals, surface, patch, light, radiance)``: per vertex, the patch at
      the vertex's UV (radiance (V, 3) float32);
    * ``shade_pixels(hit, normal, face, bary, direction, surface, patch, light, pixel_albedo,
      use_albedo, start, out)``: per G-buffer ray (``start`` + thread: CPU chunks), UV, dP/du, dP/dv and albedo interpolated with the
      hit's barycentrics (or the per-pixel albedo when ``use_albedo``), the UV moved along the
      ray ``direction`` through the heights when ``patch.parallax``; out (N,) vec3, 0 for misses.
    """
    shk = sh_kernels(order)
    sh_eval = shk.eval
    ORDER = order

    @wp.func
    def lobes_dot_light(patch: PatchTexture, texel: int, rot: wp.mat33, light: wp.array2d(dtype=wp.float32)) -> wp.vec3:
        acc = wp.vec3(stored_term(patch.stored, texel, rot, light, 0), stored_term(patch.stored, texel, rot, light, 1),
                      stored_term(patch.stored, texel, rot, light, 2))
        for k in range(patch.counts[texel]):
            y = sh_eval(rot * patch.axes[texel, k])
            for l in range(ORDER):
                gl = patch.coeffs[texel, k, l]
                for m in range(-l, l + 1):
                    i = l * l + l + m
                    yg = gl * y[i]
                    acc += wp.vec3(yg * light[0, i], yg * light[1, i], yg * light[2, i])
        return acc

    @wp.func
    def unshadowed(patch: PatchTexture, n: wp.vec3, light: wp.array2d(dtype=wp.float32)) -> wp.vec3:
        y = sh_eval(n)
        acc = wp.vec3(0.0)
        for l in range(ORDER):
            al = patch.cosine[l]
            for m in range(-l, l + 1):
                i = l * l + l + m
                ya = al * y[i]
                acc += wp.vec3(ya * light[0, i], ya * light[1, i], ya * light[2, i])
        return acc

    @wp.func
    def patch_lookup(patch: PatchTexture, uv: wp.vec2, frame: wp.mat33, light: wp.array2d(dtype=wp.float32)) -> wp.vec3:
        r = patch.resolution
        u = uv[0] * patch.tiling
        v = uv[1] * patch.tiling
        if not (wp.abs(u) < UV_LIMIT):
            u = 0.0
        if not (wp.abs(v) < UV_LIMIT):
            v = 0.0
        x = (u - wp.floor(u)) * float(r) - 0.5
        y = (v - wp.floor(v)) * float(r) - 0.5
        x0 = wp.floor(x)
        y0 = wp.floor(y)
        fx = x - x0
        fy = y - y0
        i0 = wrap_texel(int(x0), r)
        j0 = wrap_texel(int(y0), r)
        i1 = wrap_texel(i0 + 1, r)
        j1 = wrap_texel(j0 + 1, r)
        rot = wp.transpose(frame)
        t00 = j0 * r + i0
        t01 = j0 * r + i1
        t10 = j1 * r + i0
        t11 = j1 * r + i1
        acc = wp.cw_mul(patch.albedo[t00], lobes_dot_light(patch, t00, rot, light)) * ((1.0 - fx) * (1.0 - fy))
        acc += wp.cw_mul(patch.albedo[t01], lobes_dot_light(patch, t01, rot, light)) * (fx * (1.0 - fy))
        acc += wp.cw_mul(patch.albedo[t10], lobes_dot_light(patch, t10, rot, light)) * ((1.0 - fx) * fy)
        acc += wp.cw_mul(patch.albedo[t11], lobes_dot_light(patch, t11, rot, light)) * (fx * fy)
        return acc

    @wp.kernel(enable_backward=False, module="unique")
    def shade_vertices(
        normals: wp.array(dtype=wp.vec3),
        surface: PatchSurface,
        patch: PatchTexture,
        light: wp.array2d(dtype=wp.float32),
        radiance: wp.array2d(dtype=wp.float32),
    ):
        v = wp.tid()
        frame = tangent_frame(normals[v], surface.tangents[v], surface.bitangents[v])
        e = wp.vec3(0.0)
        if surface.patched[v] != 0:
            e = patch_lookup(patch, surface.uvs[v], frame, light)
        else:
            e = unshadowed(patch, wp.vec3(frame[2, 0], frame[2, 1], frame[2, 2]), light)
        for c in range(3):
            radiance[v, c] = surface.albedo[v, c] * INV_PI * e[c]

    @wp.kernel(enable_backward=False, module="unique")
    def shade_pixels(
        hit: wp.array(dtype=wp.int32),
        normal: wp.array(dtype=wp.vec3),
        face: wp.array(dtype=wp.int32),
        bary: wp.array(dtype=wp.vec2),
        direction: wp.array(dtype=wp.vec3),
        surface: PatchSurface,
        patch: PatchTexture,
        light: wp.array2d(dtype=wp.float32),
        pixel_albedo: wp.array(dtype=wp.vec3),
        use_albedo: int,
        start: int,
        out: wp.array(dtype=wp.vec3),
    ):
        p = wp.tid() + start
        if hit[p] == 0:
            out[p] = wp.vec3(0.0)
            return
        f = face[p]
        a = surface.faces[f, 0]
        b = surface.faces[f, 1]
        c = surface.faces[f, 2]
        wa = bary[p][0]
        wb = bary[p][1]
        wc = 1.0 - wa - wb
        t = surface.tangents[a] * wa + surface.tangents[b] * wb + surface.tangents[c] * wc
        bt = surface.bitangents[a] * wa + surface.bitangents[b] * wb + surface.bitangents[c] * wc
        frame = tangent_frame(normal[p], t, bt)
        e = wp.vec3(0.0)
        if surface.patched[a] != 0:
            uv = surface.uvs[a] * wa + surface.uvs[b] * wb + surface.uvs[c] * wc
            if patch.parallax != 0:
                uv = parallax_uv(patch, uv, frame, direction[p])
            e = patch_lookup(patch, uv, frame, light)
        else:
            e = unshadowed(patch, wp.vec3(frame[2, 0], frame[2, 1], frame[2, 2]), light)
        albedo = pixel_albedo[p]
        if use_albedo == 0:
            albedo = wp.vec3(0.0)
            for k in range(3):
                albedo[k] = (surface.albedo[a, k] * wa + surface.albedo[b, k] * wb + surface.albedo[c, k] * wc)
        out[p] = wp.cw_mul(albedo, e) * INV_PI

    return shade_vertices, shade_pixels


def patch_texture(model, tiling: float, device, parallax: bool = False) -> PatchTexture:
    """A :class:`PatchTexture` on ``device`` from a :class:`~._patch.PatchModel`, its tiling and
    whether pixels march their view ray through the heights (``parallax``)."""
    import numpy as np

    from ...basis import sh

    t = PatchTexture()
    t.axes = wp.array(model.axes, dtype=wp.vec3, device=device)
    t.coeffs = wp.array(model.coeffs, dtype=wp.float32, device=device)
    t.counts = wp.array(model.counts, dtype=wp.int32, device=device)
    t.stored = wp.array(model.stored, dtype=wp.float32, device=device)
    t.albedo = wp.array(np.asarray(model.albedo, np.float32), dtype=wp.vec3, device=device)
    t.cosine = wp.array(sh.clamped_cosine_zh(model.order).astype(np.float32), dtype=wp.float32, device=device)
    t.resolution, t.tiling = int(model.resolution), float(tiling)
    h = np.asarray(model.heights, np.float32)
    t.heights = wp.array(h, dtype=wp.float32, device=device)
    t.height_mean, t.height_min, t.height_max = float(h.mean()), float(h.min()), float(h.max())
    t.parallax = int(bool(parallax))
    return t


def patch_surface(faces, uvs, patched, albedo, device) -> PatchSurface:
    """A :class:`PatchSurface` on ``device``: faces (F, 3), uvs (V, 2), patched (V,) flags, albedo
    (V, 3) (NumPy, or for albedo a bound ``wp.array2d``); tangent accumulators zeroed."""
    import numpy as np

    s = PatchSurface()
    s.faces = wp.array(np.asarray(faces, np.int32), dtype=wp.int32, device=device)
    s.uvs = wp.array(np.asarray(uvs, np.float32), dtype=wp.vec2, device=device)
    s.patched = wp.array(np.asarray(patched, np.int32), dtype=wp.int32, device=device)
    count = s.uvs.shape[0]
    s.tangents = wp.zeros(count, dtype=wp.vec3, device=device)
    s.bitangents = wp.zeros(count, dtype=wp.vec3, device=device)
    s.albedo = albedo if isinstance(albedo, wp.array) else wp.array(np.asarray(albedo, np.float32), dtype=wp.float32,
                                                                     device=device)
    return s


def update_tangents(points, surface: PatchSurface, device) -> None:
    """Per-vertex dP/du, dP/dv of the current points (two launches; recordable)."""
    wp.launch(clear_tangents_kernel, dim=surface.tangents.shape[0], inputs=[surface], device=device)
    wp.launch(accumulate_tangents_kernel, dim=surface.faces.shape[0], inputs=[points, surface], device=device)
