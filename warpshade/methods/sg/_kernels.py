"""Warp kernels of the SG/SSDF method: the shading of eq. 39/41 (environment) and 42/43 (local
lights) at a point, per vertex and per pixel.

At a shading point with normal ``n``, view ``o`` (toward the eye) and SSDF visibility ``V^d``:

* diffuse, eq. 39 and 42: ``R_d = sum_k (C*(n) (x) L*_k) . V^d`` over the environment's SG lobes
  ``L*_k`` and the local lights' lobes (eq. 32-33); each product lobe ``(p, lambda, mu)`` against
  the visibility is ``mu f_h(V^d(p), lambda)`` (eq. 30);
* specular, eq. 41: the BRDF slice ``rho*_s(i; o)`` (the NDF lobe warped to the view, eq. 17-22),
  times the clamped cosine, times the visibility by eq. 31 (amplitude scaled by
  ``f_h / f_h(pi/2)`` at the lobe axis), then integrated with the environment through the
  prefiltered table: ``mu Gamma_L(p, lambda)`` (eq. 35); eq. 43 for local lights: the lobe product
  with the light lobe, integrated against the visibility by eq. 30;
* a light lobe much narrower than the BRDF slice (a sun taken out of the sky, a small lamp):
  with ``st.exact_model`` set, its specular term is the BRDF itself at the light's direction times
  the light's irradiance and cosine, with the light lobe's visible fraction (eq. 31 for the light
  lobe), instead of the product with the warped slice (eq. 43), whose isotropic shape is least
  accurate at oblique views;
* radiance ``kd / pi R_d + ks R_s`` (``component`` selects either or both).

Visibility at a point between vertices. The SSDF of each of the triangle's three vertices is
evaluated in that vertex's own tangent frame at the world direction asked for, and the three
values are blended with the barycentric weights: the SSDFs are interpolated as spherical
functions in world space, which is the paper's per-pixel interpolation of PCA coefficients
(linear in the coefficients) without requiring the three tangent frames to agree about the
rotation around the normal. The per-vertex SSDFs are decoded from their PCA coefficients once
(:mod:`._model`) into ``(V, R, R)`` maps, so a look-up is a bilinear fetch; ``ssdf = "pca"``
reconstructs from the coefficients at every look-up (the paper's GPU path; ``terms`` fetches).
"""

from __future__ import annotations

from ..._wp import wp
from ...basis.sg_warp import SG, sg_hemisphere_integral, sg_integral, sg_make, sg_product, sg_rotate, sg_visible_fraction
from ...scene._materials_warp import BRDFParams, brdf_eval, brdf_with_tangent, concentric_footprint, tangent_frame
from ...transfer._ssdf_warp import local_to_concentric, ssdf_eval
from ._brdf_warp import specular_slice
from ._lighting_warp import PrefilteredTable, gamma_lookup, point_light_sg
from ._lobes_warp import NDFLobes, warped_lobe
from ._svbrdf_warp import SVBRDFTextureWarp, svbrdf_texel, svbrdf_warped_lobe

wp.set_module_options({"enable_backward": False})

__all__ = ["COMPONENTS", "interpolate_materials_kernel", "shade_pixels_kernel", "shade_vertices_kernel", "turn_lobes_kernel"]

#: What the shading returns: the specular term, the diffuse term, or their sum.
COMPONENTS = ("specular", "diffuse", "both")
_INV_PI = wp.constant(0.3183098861837907)


@wp.struct
class Material:
    """Per-point material: diffuse albedo, specular colour, microfacet roughness (exponent for Blinn-Phong)."""

    albedo: wp.vec3
    specular: wp.vec3
    roughness: float


@wp.struct
class Lights:
    """The frame's lights as the kernels see them (world frame).

    env_axes / env_sharpness / env_amplitude: the environment's SG mixture, turned to the frame
    (K lobes); table: the prefiltered environment (eq. 35) in the map frame, ``env_to_world[0]`` the
    frame's map-to-world rotation; sphere_*: sphere (point) lights of the frame; distant_*: distant lights as lobes.
    """

    env_axes: wp.array(dtype=wp.vec3)
    env_sharpness: wp.array(dtype=float)
    env_amplitude: wp.array(dtype=wp.vec3)
    env_count: int
    table: PrefilteredTable
    has_table: int
    env_to_world: wp.array(dtype=wp.mat33)
    sphere_position: wp.array(dtype=wp.vec3)
    sphere_radius: wp.array(dtype=float)
    sphere_radiance: wp.array(dtype=wp.vec3)
    sphere_count: int
    distant_axes: wp.array(dtype=wp.vec3)
    distant_sharpness: wp.array(dtype=float)
    distant_amplitude: wp.array(dtype=wp.vec3)
    distant_count: int


@wp.struct
class Settings:
    model: int
    f0: float
    cos_sharpness: float
    cos_amplitude: float
    component: int
    pca: int
    terms: int
    resolution: int
    horizon: int
    exact_model: int
    exact_ratio: float
    lobes: NDFLobes
    svbrdf: SVBRDFTextureWarp


@wp.struct
class Visibility:
    """Per-vertex SSDFs: decoded maps (V, R, R) or the PCA (mean (R*R,), basis (N, R*R), coeffs (V, N)),
    and the vertices' tangent frames (rows t, b, n: world -> local)."""

    maps: wp.array3d(dtype=float)
    mean: wp.array(dtype=float)
    basis: wp.array2d(dtype=float)
    coeffs: wp.array2d(dtype=float)
    frames: wp.array(dtype=wp.mat33)


@wp.struct
class Materials:
    """Per-point material arrays (vertices or pixels): diffuse albedo (P,) vec3 and specular colour
    (P,) vec3, linear RGB; microfacet roughness (exponent for Blinn-Phong), (P,) float32."""

    albedo: wp.array(dtype=wp.vec3)
    specular: wp.array(dtype=wp.vec3)
    roughness: wp.array(dtype=float)


@wp.struct
class VertexPoints:
    """The vertices shaded by :func:`shade_vertices_kernel`: world positions and unit shading
    normals, (V,) vec3 each; the viewer, world position, (1,) vec3; tangent directions of the
    multi-lobe materials (``Settings.lobes``), (V,) vec3, world (read only when it has lobes)."""

    position: wp.array(dtype=wp.vec3)
    normal: wp.array(dtype=wp.vec3)
    eye: wp.array(dtype=wp.vec3)
    tangent: wp.array(dtype=wp.vec3)


@wp.struct
class PixelHits:
    """The rays of a G-buffer (:mod:`warpshade.render._raycast`), N rows each.

    Fields:
        hit: 1 where the ray hit, (N,) int32.
        position: world hit point, (N,) vec3; normal: unit shading normal there, (N,) vec3.
        face: hit triangle, (N,) int32; bary: Warp barycentrics of its first two vertices, (N,) vec2.
        faces: the scene's triangles, (F, 3) int32 vertex indices.
        eye: the viewer, world position, (1,) vec3.
        tangent: per-VERTEX tangent directions of the multi-lobe materials, (V,) vec3, world,
            interpolated at the hit with the barycentrics (read only when ``Settings.lobes`` has lobes).
    """

    hit: wp.array(dtype=wp.int32)
    position: wp.array(dtype=wp.vec3)
    normal: wp.array(dtype=wp.vec3)
    face: wp.array(dtype=wp.int32)
    bary: wp.array(dtype=wp.vec2)
    faces: wp.array2d(dtype=wp.int32)
    eye: wp.array(dtype=wp.vec3)
    tangent: wp.array(dtype=wp.vec3)


@wp.func
def ssdf_bilinear(maps: wp.array3d(dtype=float), v: int, ab: wp.vec2, r: int):
    """Bilinear fetch of vertex ``v``'s map at a point ``ab`` of the concentric square."""
    fp = concentric_footprint(ab, r)
    i = int(fp[0])
    j = int(fp[1])
    top = (1.0 - fp[3]) * maps[v, i, j] + fp[3] * maps[v, i, j + 1]
    bottom = (1.0 - fp[3]) * maps[v, i + 1, j] + fp[3] * maps[v, i + 1, j + 1]
    return (1.0 - fp[2]) * top + fp[2] * bottom


@wp.func
def _ssdf_vertex(vis: Visibility, st: Settings, v: int, d_world: wp.vec3):
    d = vis.frames[v] * d_world
    if st.pca == 0:
        return ssdf_bilinear(vis.maps, v, local_to_concentric(d), st.resolution)
    # the paper's path: reconstructed from the PCA at the look-up
    return ssdf_eval(vis.mean, vis.basis, vis.coeffs, v, v, v, 1.0, 0.0, 0.0, d, st.resolution, st.terms)


@wp.func
def ssdf_at(vis: Visibility, st: Settings, i0: int, i1: int, i2: int, w: wp.vec3, d_world: wp.vec3, n: wp.vec3):
    """The signed angular distance (radians) at a world direction, blended over three vertices;
    with ``st.horizon`` the tangent plane of ``n`` is a boundary too (``min(V^d, elevation)``)."""
    s = w[0] * _ssdf_vertex(vis, st, i0, d_world)
    if w[1] > 0.0:
        s += w[1] * _ssdf_vertex(vis, st, i1, d_world)
    if w[2] > 0.0:
        s += w[2] * _ssdf_vertex(vis, st, i2, d_world)
    if st.horizon != 0:
        s = wp.min(s, wp.asin(wp.clamp(wp.dot(d_world, n), -1.0, 1.0)))
    return s


@wp.func
def _basis_of(n: wp.vec3):
    # Duff et al.'s branchless orthonormal basis; rows (t, b, n): world -> local
    sign = 1.0
    if n[2] < 0.0:
        sign = -1.0
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    t = wp.vec3(1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0])
    bt = wp.vec3(b, sign + n[1] * n[1] * a, -n[1])
    return wp.mat33(t[0], t[1], t[2], bt[0], bt[1], bt[2], n[0], n[1], n[2])


@wp.func
def _specular_env(slice_w: SG, lights: Lights, vis: Visibility, st: Settings, i0: int, i1: int, i2: int, w: wp.vec3,
                  n: wp.vec3):
    """One slice lobe (times the cosine) against the prefiltered environment, with its visible fraction (eq. 31, 35)."""
    theta = ssdf_at(vis, st, i0, i1, i2, w, slice_w.axis, n)
    fraction = sg_visible_fraction(theta, slice_w.sharpness)
    return fraction * wp.cw_mul(slice_w.amplitude, gamma_lookup(lights.table, wp.transpose(lights.env_to_world[0]), slice_w.axis,
                                                                slice_w.sharpness))


@wp.func
def _lobe_count(st: Settings) -> int:
    if st.svbrdf.lobes > 0:
        return st.svbrdf.lobes
    return st.lobes.count


@wp.func
def _slice_lobe(st: Settings, texel: wp.vec2i, k: int, o_local: wp.vec3) -> SG:
    """Lobe ``k`` of the material warped to the local view: the texel's (SVBRDF) or the material's."""
    g = SG()
    if st.svbrdf.lobes > 0:
        g = svbrdf_warped_lobe(st.svbrdf, texel, k, o_local)
    else:
        g = warped_lobe(st.lobes, k, o_local)
    return g


@wp.func
def point_texel(st: Settings, uv: wp.vec2) -> wp.vec2i:
    """The SVBRDF texel at texture coordinates ``uv`` ((0, 0) without an SVBRDF)."""
    t = wp.vec2i(0, 0)
    if st.svbrdf.lobes > 0:
        t = svbrdf_texel(st.svbrdf, uv)
    return t


@wp.func
def shade_point(x: wp.vec3, n: wp.vec3, o: wp.vec3, mat: Material, lights: Lights, vis: Visibility, st: Settings,
                i0: int, i1: int, i2: int, w: wp.vec3, tangent: wp.vec3, texel: wp.vec2i):
    """Outgoing radiance toward ``o`` at ``x`` (eq. 39, 41, 42, 43), linear RGB. With
    ``st.lobes.count > 0`` the specular slice is the material's NDF lobes warped to the view in the
    tangent frame of ``tangent`` (:mod:`._lobes_warp`); with ``st.svbrdf.lobes > 0`` the lobes of
    SVBRDF texel ``texel`` (row, column; :mod:`._svbrdf_warp`, isotropic about the normal); else the
    single lobe of ``st.model``."""
    cosine = sg_make(n, st.cos_sharpness, wp.vec3(st.cos_amplitude))
    rd = wp.vec3(0.0)
    rs = wp.vec3(0.0)
    want_d = st.component != 0
    want_s = st.component != 1
    slice_w = sg_make(n, 0.0, wp.vec3(0.0))
    facing = wp.dot(o, n) > 0.0
    lobe_count = _lobe_count(st)
    multi = lobe_count > 0
    frame = _basis_of(n)
    if st.lobes.count > 0:
        probe = BRDFParams()
        probe.tangent = tangent
        frame = tangent_frame(probe, n)
    o_local = frame * o
    slice_sharpness = float(0.0)
    if want_s and facing:
        if multi:
            # the sharpest live lobe decides what counts as a narrow light below
            for k in range(lobe_count):
                g = _slice_lobe(st, texel, k, o_local)
                if g.amplitude[0] > 0.0:
                    gw = sg_product(cosine, sg_rotate(g, wp.transpose(frame)))
                    slice_sharpness = wp.max(slice_sharpness, gw.sharpness)
                    if lights.has_table != 0:
                        rs += _specular_env(gw, lights, vis, st, i0, i1, i2, w, n)
        else:
            local = sg_rotate(specular_slice(o_local, st.model, mat.roughness, st.f0), wp.transpose(frame))
            slice_w = sg_product(cosine, local)
            slice_sharpness = slice_w.sharpness
            if lights.has_table != 0:
                rs += _specular_env(slice_w, lights, vis, st, i0, i1, i2, w, n)
    if want_d:
        for k in range(lights.env_count):
            g = sg_product(cosine, sg_make(lights.env_axes[k], lights.env_sharpness[k], lights.env_amplitude[k]))
            theta = ssdf_at(vis, st, i0, i1, i2, w, g.axis, n)
            rd += g.amplitude * sg_hemisphere_integral(theta, g.sharpness)
    # local and distant lights: eq. 42-43 (the light lobe times the cosine, then the visibility)
    for k in range(lights.sphere_count + lights.distant_count):
        light = SG()
        if k < lights.sphere_count:
            light = point_light_sg(lights.sphere_position[k], lights.sphere_radius[k], lights.sphere_radiance[k], x)
        else:
            j = k - lights.sphere_count
            light = sg_make(lights.distant_axes[j], lights.distant_sharpness[j], lights.distant_amplitude[j])
        lc = sg_product(light, cosine)
        if want_d:
            theta = ssdf_at(vis, st, i0, i1, i2, w, lc.axis, n)
            rd += lc.amplitude * sg_hemisphere_integral(theta, lc.sharpness)
        if want_s and facing:
            if st.exact_model >= 0 and light.sharpness > st.exact_ratio * slice_sharpness:
                # a light much narrower than the BRDF slice: the BRDF itself at the light's
                # direction times its irradiance, visibility as the light lobe's visible fraction
                b = BRDFParams()
                b.model = st.exact_model
                b.scale = 1.0
                b.exponent = mat.roughness
                b.roughness = mat.roughness
                b.f0 = st.f0
                if multi:
                    b = brdf_with_tangent(st.lobes.exact, tangent)
                theta = ssdf_at(vis, st, i0, i1, i2, w, light.axis, n)
                cos_l = wp.max(wp.dot(n, light.axis), 0.0)
                rs += sg_integral(light) * (brdf_eval(b, n, o, light.axis) * cos_l * sg_visible_fraction(theta, light.sharpness))
            elif multi:
                for k in range(lobe_count):
                    g0 = _slice_lobe(st, texel, k, o_local)
                    if g0.amplitude[0] > 0.0:
                        g = sg_product(light, sg_product(cosine, sg_rotate(g0, wp.transpose(frame))))
                        theta = ssdf_at(vis, st, i0, i1, i2, w, g.axis, n)
                        rs += g.amplitude * sg_hemisphere_integral(theta, g.sharpness)
            else:
                # eq. 43: the slice already holds the cosine, so the light multiplies it once
                g = sg_product(light, slice_w)
                theta = ssdf_at(vis, st, i0, i1, i2, w, g.axis, n)
                rs += g.amplitude * sg_hemisphere_integral(theta, g.sharpness)
    return wp.cw_mul(mat.albedo, rd) * _INV_PI + wp.cw_mul(mat.specular, rs)


@wp.kernel
def turn_lobes_kernel(axes0: wp.array(dtype=wp.vec3), rotation: wp.array(dtype=wp.mat33), slot: int,
                      axes: wp.array(dtype=wp.vec3)):
    """Environment lobes into the frame: ``axes = R axes0`` with the frame's environment rotation."""
    k = wp.tid()
    axes[k] = rotation[slot] * axes0[k]


@wp.kernel
def shade_vertices_kernel(points: VertexPoints, mats: Materials, lights: Lights, vis: Visibility, st: Settings, start: int,
                          radiance: wp.array2d(dtype=float)):
    """One vertex (``wp.tid() + start``): radiance toward the eye, (V, 3) float32, linear RGB."""
    v = wp.tid() + start
    x = points.position[v]
    o = wp.normalize(points.eye[0] - x)
    mat = Material()
    mat.albedo = mats.albedo[v]
    mat.specular = mats.specular[v]
    mat.roughness = mats.roughness[v]
    tangent = wp.vec3(1.0, 0.0, 0.0)
    if st.lobes.count > 0:
        tangent = points.tangent[v]
    texel = point_texel(st, st.svbrdf.uv[v % st.svbrdf.uv.shape[0]])
    c = shade_point(x, points.normal[v], o, mat, lights, vis, st, v, v, v, wp.vec3(1.0, 0.0, 0.0), tangent, texel)
    radiance[v, 0] = c[0]
    radiance[v, 1] = c[1]
    radiance[v, 2] = c[2]


@wp.kernel
def shade_pixels_kernel(hits: PixelHits, mats: Materials, lights: Lights, vis: Visibility, st: Settings, start: int,
                        out: wp.array(dtype=wp.vec3)):
    """One pixel of a G-buffer (:mod:`warpshade.render._raycast`): per-pixel normal, material from
    the per-pixel arrays (textures sampled by the caller), visibility blended over the hit triangle."""
    p = wp.tid() + start
    if hits.hit[p] == 0:
        out[p] = wp.vec3(0.0)
        return
    f = hits.face[p]
    b = hits.bary[p]
    w = wp.vec3(b[0], b[1], 1.0 - b[0] - b[1])
    x = hits.position[p]
    o = wp.normalize(hits.eye[0] - x)
    mat = Material()
    mat.albedo = mats.albedo[p]
    mat.specular = mats.specular[p]
    mat.roughness = mats.roughness[p]
    i0 = hits.faces[f, 0]
    i1 = hits.faces[f, 1]
    i2 = hits.faces[f, 2]
    tangent = wp.vec3(1.0, 0.0, 0.0)
    if st.lobes.count > 0:
        tangent = w[0] * hits.tangent[i0] + w[1] * hits.tangent[i1] + w[2] * hits.tangent[i2]
    texel = wp.vec2i(0, 0)
    if st.svbrdf.lobes > 0:
        uv = st.svbrdf.uv
        texel = svbrdf_texel(st.svbrdf, w[0] * uv[i0] + w[1] * uv[i1] + w[2] * uv[i2])
    out[p] = shade_point(x, hits.normal[p], o, mat, lights, vis, st, i0, i1, i2, w, tangent, texel)


@wp.kernel
def interpolate_materials_kernel(hits: PixelHits, vertex: Materials, pixel: Materials):
    """Per-vertex materials interpolated at each pixel's hit (Warp barycentrics); misses are left as they are."""
    p = wp.tid()
    if hits.hit[p] == 0:
        return
    f = hits.face[p]
    b = hits.bary[p]
    a = hits.faces[f, 0]
    c = hits.faces[f, 1]
    d = hits.faces[f, 2]
    w2 = 1.0 - b[0] - b[1]
    pixel.albedo[p] = b[0] * vertex.albedo[a] + b[1] * vertex.albedo[c] + w2 * vertex.albedo[d]
    pixel.specular[p] = b[0] * vertex.specular[a] + b[1] * vertex.specular[c] + w2 * vertex.specular[d]
    pixel.roughness[p] = b[0] * vertex.roughness[a] + b[1] * vertex.roughness[c] + w2 * vertex.roughness[d]


@wp.kernel
def distant_axes_kernel(directions: wp.array(dtype=wp.vec3), light_count: int, sun_axes0: wp.array(dtype=wp.vec3),
                        env_to_world: wp.array(dtype=wp.mat33), axes: wp.array(dtype=wp.vec3)):
    """The frame's distant-light lobe axes: the scene's distant lights, then the suns taken out of
    the environment (map frame) turned with it."""
    k = wp.tid()
    if k < light_count:
        axes[k] = directions[k]
    else:
        axes[k] = env_to_world[0] * sun_axes0[k - light_count]
