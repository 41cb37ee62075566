"""The ray-traced reference on a texture of eq.-13 materials (``brdf = "svbrdf"``): the Warp
per-texel BRDF against its float64 definition, the sampling mixture's pdf (quadrature), a uniform
texture against the same material as one tabulated BRDF, per-vertex radiance on an open plane
against the float64 quadrature of eq. 13, the texel look-ups against the SG shading's, bad
input, and ``dish_sg_svbrdf``'s validate path (per vertex and per pixel)."""

from pathlib import Path

import numpy as np
import pytest

from warpshade._wp import wp
from warpshade.io import bundled_asset_directory
from warpshade.methods.sg._brdf import TabulatedMicrofacet
from warpshade.methods.sg import _brdf as sg_brdf
from warpshade.methods.sg._brdf_warp import fresnel_cook_torrance as shading_fresnel
from warpshade.methods.sg._svbrdf import eq13_quadrature_f64
from warpshade.reference import shade_glossy
from warpshade.reference._svbrdf_warp import (brdf_with_texel, fresnel_dielectric as reference_fresnel, surface_brdf_eval,
                                             surface_brdf_pdf, surface_brdf_sample, upload_svbrdf_material, vertex_texels)
from warpshade.scene import Environment, Mesh, Scene
from warpshade.scene._materials_warp import BRDFParams
from warpshade.scene._svbrdf import SVBRDFMaterial, fresnel_dielectric, nearest_texel_f64, scene_uvs, svbrdf_material
from warpshade.scene._tabulated import TabulatedBRDF
from warpshade.usd_assets.generator.svbrdf import SVBRDF_FILE, smith_shadowing, texel_material

from grids import ground_grid
from tolerances import ATOL_FLOAT32, RTOL_FLOAT32, assert_within_stderr

BUNDLED = f"{bundled_asset_directory()}/{SVBRDF_FILE}"
#: float32 texel BRDF against the float64 one, relative to the largest value (float32 acos of the
#: cosines, the log-linear NDF blend, the Fresnel): measured 3.7e-5 over 20000 pairs.
EVAL_RTOL_FLOAT32 = 2e-4
#: ... and per pair, relative to its own value, at all but the 0.1% nearest the horizon (the
#: float32 cosine of a light 1e-5 above it): measured 99.9th percentile 4.8e-5.
EVAL_RTOL_PAIR = 5e-4
#: Quadrature of the sampling pdf over the sphere (Gauss-Legendre in z x 1024 azimuths) against
#: its closed form (as tests/test_reference_tabulated.py's PDF_INTEGRAL_TOL).
PDF_INTEGRAL_TOL = 1e-3
#: The uniform texture (91 samples per curve, D log-linear in the cosine) against the same eq.-13
#: material tabulated on 90 x 90 x 180 MERL cells and looked up "linear", relative to the largest
#: radiance: the two reconstructions' own error (the table's 6e-4 for a GGX of alpha 0.3 in
#: test_reference_tabulated), with room; the Monte Carlo part of the bound is the stderrs'.
UNIFORM_DISCRETISATION_RTOL = 2e-3
#: The float64 quadrature (160 x 320 nodes) of the sky over the open plane, relative to the
#: largest radiance: the quadrature's own error on the sun disc's edge.
QUADRATURE_RTOL = 2e-3
SKY = Environment.sky(height=16, width=32)
EYE = np.array([0.5, -1.5, 2.0])


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


@wp.kernel
def _eval_kernel(b: BRDFParams, texels: wp.array(dtype=wp.int32), n: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
                 s: wp.array(dtype=wp.vec3), f: wp.array(dtype=float), pdf: wp.array(dtype=float)):
    i = wp.tid()
    bt = brdf_with_texel(b, texels[i])
    f[i] = surface_brdf_eval(bt, n[i], v[i], s[i])
    pdf[i] = surface_brdf_pdf(bt, n[i], v[i], s[i])


@wp.kernel
def _sample_kernel(b: BRDFParams, texel: int, v: wp.vec3, u: wp.array(dtype=wp.vec2), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = surface_brdf_sample(brdf_with_texel(b, texel), wp.vec3(0.0, 0.0, 1.0), v, u[i][0], u[i][1])


def _eval(params, texels, n, v, s, device):
    arrays = [wp.array(np.ascontiguousarray(x, np.float32), dtype=wp.vec3, device=device) for x in (n, v, s)]
    f = wp.zeros(len(s), dtype=float, device=device)
    pdf = wp.zeros(len(s), dtype=float, device=device)
    tex = wp.array(np.asarray(texels, np.int32), dtype=wp.int32, device=device)
    wp.launch(_eval_kernel, dim=len(s), inputs=[params, tex, *arrays, f, pdf], device=device)
    return f.numpy().astype(np.float64), pdf.numpy().astype(np.float64)


@pytest.fixture(scope="module")
def material():
    return svbrdf_material(BUNDLED)


def test_device_texel_brdf_matches_float64(device, rng, material):
    """Random texels, local views and lights (half of them near the mirror direction, where the
    NDF's peak is read), the normal +z: the Warp eq. 13 against :meth:`evaluate_texels`."""
    count = 20000
    v = _unit(rng.normal(size=(count, 3)))
    s = _unit(rng.normal(size=(count, 3)))
    half = count // 2
    s[:half] = _unit(v[:half] * [-1.0, -1.0, 1.0] + 0.05 * rng.normal(size=(half, 3)))
    v[:, 2], s[:, 2] = np.abs(v[:, 2]), np.abs(s[:, 2])
    v, s = (x.astype(np.float32).astype(np.float64) for x in (v, s))
    h, w = material.shape
    rc = np.stack([rng.integers(0, h, count), rng.integers(0, w, count)], 1)
    params = upload_svbrdf_material(material, device)
    f, pdf = _eval(params, rc[:, 0] * w + rc[:, 1], np.tile([0.0, 0.0, 1.0], (count, 1)), v, s, device)
    ref = material.evaluate_texels(rc, v, s)
    assert ref.max() > 10.0 and np.all(f >= 0.0)
    assert np.abs(f - ref).max() < EVAL_RTOL_FLOAT32 * ref.max(), np.abs(f - ref).max() / ref.max()
    rel = np.abs(f - ref) / np.maximum(ref, 1e-30)
    assert np.percentile(rel, 99.9) < EVAL_RTOL_PAIR, np.percentile(rel, 99.9)
    assert np.all(pdf[f > 0.0] > 0.0), "the sampling pdf covers the BRDF"
    # below either horizon: 0
    f_below, _ = _eval(params, rc[:, 0] * w + rc[:, 1], np.tile([0.0, 0.0, 1.0], (count, 1)), v, -s, device)
    assert np.all(f_below == 0.0)


def test_texel_curves_between_samples(material):
    """D is log-linear in cos theta_h (exact for one SG lobe about the normal), S linear in theta."""
    theta = np.linspace(0.0, 0.5 * np.pi, 91)
    ndf = 2.0 * np.exp(30.0 * (np.cos(theta) - 1.0))
    sg = SVBRDFMaterial(np.broadcast_to(ndf, (1, 1, 91)), np.ones((1, 1, 91)) * 0.5, 1.33)
    c = np.cos(np.linspace(0.0, 0.5 * np.pi, 1001))
    np.testing.assert_allclose(sg.ndf_at(np.zeros((c.size, 2), int), c), 2.0 * np.exp(30.0 * (c - 1.0)), rtol=1e-12)
    mid = 0.5 * (theta[10] + theta[11])
    s = material.shadow_at([[3, 4]], np.cos([mid]))
    np.testing.assert_allclose(s, 0.5 * (material.shadow[3, 4, 10] + material.shadow[3, 4, 11]), rtol=1e-12)
    with pytest.raises(ValueError, match="per texel"):
        material.evaluate([0.0, 0.0, 1.0], [0.0, 0.0, 1.0])


@wp.kernel
def _fresnel_kernel(c: wp.array(dtype=float), eta: wp.array(dtype=float), reference: wp.array(dtype=float),
                    shading: wp.array(dtype=float)):
    i = wp.tid()
    reference[i] = reference_fresnel(c[i], eta[i])
    shading[i] = shading_fresnel(c[i], eta[i])


def _fresnel_cases():
    c, eta = np.meshgrid(np.linspace(0.0, 1.0, 257), [1.01, 1.33, 1.5, 2.4, 4.0, 10.0], indexing="ij")
    return c.ravel(), eta.ravel()


def test_fresnel_is_the_dielectric_reflectance():
    """The texture's Fresnel (s- and p-polarised amplitudes) at analytic points: normal incidence
    ``((eta - 1) / (eta + 1))^2``, grazing 1, and Brewster's angle (``tan theta = eta``: no
    p-polarised reflection) ``((eta^2 - 1) / (eta^2 + 1))^2 / 2``."""
    eta = np.array([1.01, 1.33, 1.5, 2.4, 4.0, 10.0])
    np.testing.assert_allclose(fresnel_dielectric(1.0, eta), ((eta - 1) / (eta + 1)) ** 2, rtol=1e-12)
    np.testing.assert_allclose(fresnel_dielectric(0.0, eta), 1.0, rtol=1e-12)
    brewster = np.cos(np.arctan(eta))
    np.testing.assert_allclose(fresnel_dielectric(brewster, eta), 0.5 * ((eta**2 - 1) / (eta**2 + 1)) ** 2, rtol=1e-12)
    with pytest.raises(ValueError, match="eta"):
        fresnel_dielectric(0.5, 1.0)


def test_the_reference_and_the_sg_shading_agree_on_fresnel(device):
    """Two independent implementations (the reference's s/p amplitudes, the SG shading's eq. 14 of
    Cook and Torrance) agree: float64 to rounding, float32 on the device to its precision."""
    c, eta = _fresnel_cases()
    f64 = fresnel_dielectric(c, eta)
    np.testing.assert_allclose(f64, sg_brdf.fresnel_cook_torrance(c, eta), rtol=1e-12, atol=1e-15)
    arrays = [wp.array(x.astype(np.float32), dtype=float, device=device) for x in (c, eta)]
    reference, shading = (wp.zeros(c.size, dtype=float, device=device) for _ in range(2))
    wp.launch(_fresnel_kernel, dim=c.size, inputs=arrays, outputs=[reference, shading], device=device)
    c32, eta32 = (x.astype(np.float32).astype(np.float64) for x in (c, eta))
    want = fresnel_dielectric(c32, eta32)
    np.testing.assert_allclose(reference.numpy(), want, rtol=RTOL_FLOAT32, atol=ATOL_FLOAT32)
    np.testing.assert_allclose(shading.numpy(), want, rtol=RTOL_FLOAT32, atol=ATOL_FLOAT32)


def test_texel_brdf_at_normal_incidence_is_analytic():
    """View and light along the normal (h = n): eq. 13 is ``F(1) S(0)^2 D(0) / pi`` with the
    file's own first samples and ``F(1) = ((eta - 1) / (eta + 1))^2``; a light past the horizon gives 0."""
    theta = np.linspace(0.0, 0.5 * np.pi, 91)
    ndf = 3.0 * np.exp(20.0 * (np.cos(theta) - 1.0))
    shadow = 1.0 - 0.3 * np.sin(theta)
    texture = SVBRDFMaterial(np.broadcast_to(ndf, (1, 1, 91)), np.broadcast_to(shadow, (1, 1, 91)), 1.5)
    z = np.array([0.0, 0.0, 1.0])
    got = texture.evaluate_texels([[0, 0]], z, z)
    np.testing.assert_allclose(got, ((1.5 - 1.0) / 2.5) ** 2 * shadow[0] ** 2 * ndf[0] / np.pi, rtol=1e-12)
    assert texture.evaluate_texels([[0, 0]], z, [0.0, 0.6, -0.8]) == 0.0


@pytest.mark.parametrize("texel,theta_deg", [((0, 2), 0.0), ((0, 2), 60.0), ((13, 8), 30.0), ((0, 10), 45.0)])
def test_sampling_pdf_integrates_to_one(device, material, texel, theta_deg):
    """The texel's GGX + cosine mixture (texels of the sharpest, a middle and the broadest lobe,
    alpha 0.071, 0.141, 0.309): its pdf over the sphere is 1 less the GGX half vectors
    facing away from the viewer (they reflect below the horizon, where the pdf is not counted);
    its samples land where the pdf says (first moments)."""
    params = upload_svbrdf_material(material, device)
    flat = texel[0] * material.shape[1] + texel[1]
    alpha, weight = (x[flat] for x in material.sampling_lobes())
    t = np.radians(theta_deg)
    view = np.array([np.sin(t), 0.0, np.cos(t)])
    z, wz = np.polynomial.legendre.leggauss(512)
    phi = (np.arange(1024) + 0.5) / 1024 * 2 * np.pi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - zz**2)
    d = np.stack([r * np.cos(pp), r * np.sin(pp), zz], -1).reshape(-1, 3)
    w = (wz[:, None] * np.full(phi.shape, 2 * np.pi / phi.size)[None]).reshape(-1)
    f, pdf = _eval(params, np.full(len(d), flat), np.tile([0.0, 0.0, 1.0], (len(d), 1)), np.tile(view, (len(d), 1)), d,
                   device)
    cos_h = d[:, 2]
    a2 = alpha**2
    ggx = a2 / (np.pi * (cos_h**2 * (a2 - 1.0) + 1.0) ** 2) * cos_h
    away = float(np.sum(np.where((cos_h > 0) & (d @ view <= 0), ggx, 0.0) * w))
    assert np.sum(pdf * w) == pytest.approx(1.0 - weight * away, abs=PDF_INTEGRAL_TOL), away
    assert np.all(pdf[f > 0.0] > 0.0)
    rng = np.random.default_rng(5)
    u = rng.random((100000, 2)).astype(np.float32)
    out = wp.zeros(len(u), dtype=wp.vec3, device=device)
    wp.launch(_sample_kernel, dim=len(u), inputs=[params, flat, wp.vec3(*view), wp.array(u, dtype=wp.vec2, device=device),
                                                  out], device=device)
    s = out.numpy().astype(np.float64)
    f_s, pdf_s = _eval(params, np.full(len(s), flat), np.tile([0.0, 0.0, 1.0], (len(s), 1)), np.tile(view, (len(s), 1)), s,
                       device)
    # a half vector facing away from the viewer reflects to where the pdf is not counted (nor is the BRDF)
    counted = pdf_s > 0.0
    assert np.all(f_s[~counted] == 0.0)
    expected = np.sum(d * (pdf * w)[:, None], axis=0)
    np.testing.assert_allclose((s * counted[:, None]).mean(axis=0), expected, atol=0.01)


def _plane_scene(count=4, lights=(SKY,)):
    pts, faces = ground_grid(np.linspace(-1.0, 1.0, count))
    uvs = 0.03 + 0.94 * (pts[:, :2] * 0.5 + 0.5)
    return Scene.from_meshes([Mesh("/ground", pts, faces, uvs=uvs)], lights=list(lights))


def test_uniform_texture_matches_the_material_as_one_table(device):
    """Every texel one eq.-13 material (Beckmann NDF of slope 0.25, Smith shadowing of slope 0.35):
    the reference over the texture against the reference over that material tabulated in the MERL
    layout (model 8, its own sampling lobe): Monte Carlo agreement."""
    theta = np.linspace(0.0, 0.5 * np.pi, 721)
    c = np.cos(np.minimum(theta, 0.5 * np.pi - 1e-6))
    ndf = np.exp(-(1.0 - c * c) / (c * c) / 0.25**2) / (np.pi * 0.25**2 * c**4)
    shadow = smith_shadowing(theta, 0.35)
    model = TabulatedMicrofacet(theta_h=theta, ndf_values=ndf, shadow_theta=theta, shadow_values=shadow, eta=1.33)
    table = TabulatedBRDF.from_brdf(model, dims=(90, 90, 180), channel="g", interpolation="linear")
    every = slice(None, None, 8)  # one sample per degree
    texture = SVBRDFMaterial(np.broadcast_to(ndf[every], (3, 3, 91)), np.broadcast_to(shadow[every], (3, 3, 91)), 1.33)
    scene = _plane_scene()
    ref = shade_glossy(scene, 0.0, table, eye=EYE, samples=2048, device=device)
    res = shade_glossy(scene, 0.0, texture, eye=EYE, samples=2048, device=device, seed=5)
    assert np.all(res.stderr > 0)
    assert_within_stderr(res.radiance, ref.radiance, np.hypot(res.stderr, ref.stderr),
                         floor=UNIFORM_DISCRETISATION_RTOL * ref.radiance.max(), what="uniform SVBRDF vs its table")


def test_per_vertex_reference_matches_the_eq13_quadrature(device, material):
    """An open plane (nothing occludes) with the bundled texture: each vertex's reference against
    :func:`eq13_quadrature_f64` of its texel's EXACT analytic material (the generator's, not the
    file's samples), within the reference's standard error."""
    scene = _plane_scene(count=5)
    res = shade_glossy(scene, 0.0, material, eye=EYE, samples=4096, device=device)
    flat = vertex_texels(material, scene, device).numpy()
    rows, cols = np.divmod(flat, material.shape[1])
    assert len(set(zip(rows, cols))) > 10  # the vertices see many texels
    pts = scene.meshes[0].points
    views = _unit(EYE[None] - pts)
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    oracle = eq13_quadrature_f64(normals, views, [texel_material(r, c) for r, c in zip(rows, cols)], material.eta,
                                 SKY.radiance, None, 160, 320)
    assert_within_stderr(res.radiance, oracle, res.stderr, floor=QUADRATURE_RTOL * oracle.max(),
                         what="per-vertex reference vs eq.-13 quadrature")


def test_pixel_texels_are_the_nearest_texel_of_the_interpolated_uv(device, material):
    """Per camera hit, the texel of the UV interpolated with the G-buffer's barycentrics (the SG
    pixel kernel's expression) against the float64 look-up of the float64 interpolation; and the
    per-pixel reference of an SVBRDF runs with them."""
    from warpshade.geometry._bvh import Visibility
    from warpshade.reference import reference_image
    from warpshade.reference._svbrdf_warp import hit_texels
    from warpshade.render import render_gbuffer
    from warpshade.scene import Camera

    scene = _plane_scene(count=6)
    camera = Camera(position=EYE, target=np.zeros(3), up=np.array([0.0, 0.0, 1.0]), vertical_fov=50.0)
    state = scene.evaluate(0.0, device=device)
    bvh = Visibility.from_scene(scene, device=device)
    bvh.update(state.points)
    gb = render_gbuffer(bvh, state.normals, camera, 64, 48)
    hit = gb.hit.numpy().astype(bool)
    got = hit_texels(material, scene, gb, device).numpy()[hit]
    b = gb.bary.numpy()[hit].astype(np.float64)
    w = np.stack([b[:, 0], b[:, 1], 1.0 - b[:, 0] - b[:, 1]], 1)
    uv = np.einsum("pk,pkc->pc", w, scene_uvs(scene)[gb.faces.numpy()[gb.face.numpy()[hit]]])
    rc = np.stack(np.divmod(got, material.shape[1]), -1)
    assert hit.sum() > 1000 and len(np.unique(got)) > 100
    assert np.mean(np.any(rc != nearest_texel_f64(uv, material.shape), axis=1)) < 2e-3  # float32 against float64 at texel edges
    ref = reference_image(scene, 0.0, material, camera=camera, width=16, height=12, samples=16, include=("specular",),
                          device=device, eye=EYE)
    assert ref.mask.any() and np.all(np.isfinite(ref.radiance)) and ref.radiance[ref.mask].max() > 0.0


def test_texels_and_options_are_checked(device, material):
    scene = _plane_scene()
    with pytest.raises(ValueError, match="roughness does not apply"):
        shade_glossy(scene, 0.0, material, eye=EYE, samples=8, device=device, roughness=np.full(scene.vertex_count, 0.3))
    from warpshade.reference import GlossyReferenceShader

    shader = GlossyReferenceShader(scene, material, EYE, samples=8, device=device, vertices=[0])
    state = scene.evaluate(0.0, device=device)
    shader.update(state.points, state.normals)
    out = [wp.zeros(1, dtype=wp.vec3, device=device) for _ in range(2)]
    rec = wp.array([0], dtype=wp.int32, device=device)
    with pytest.raises(ValueError, match="needs texels"):
        shader.shade_points(state.points, state.normals, shader.tint, rec, *out)
    with pytest.raises(ValueError, match="texels must be in"):
        shader.shade_points(state.points, state.normals, shader.tint, rec, *out, texels=np.full(scene.vertex_count, 5000))
    no_uv = Scene.from_meshes([Mesh("/bare", *ground_grid(np.linspace(-1.0, 1.0, 3)))], lights=[SKY])
    with pytest.raises(ValueError, match="/bare has none"):
        shade_glossy(no_uv, 0.0, material, eye=EYE, samples=8, device=device)


def test_validate_path_runs_on_the_dish_graph(device, tmp_path):
    """``dish_sg_svbrdf`` (SSDF shrunk to 8^2, a small procedural sky of 3 lobes for the bundled
    one, whose prefiltered table takes minutes): its reference is the texture itself, its vertices' texels
    are the stage's, and the per-vertex and per-pixel measurements run."""
    import warpshade.graph as graph
    from warpshade.measure import measure_error, reference_model
    from warpshade.measure._pixels import measure_pixels
    from warpshade.scene import LightingSource, up_rotation
    spec = graph.load(Path(__file__).resolve().parent.parent / "stages" / "dish_sg_svbrdf.toml")
    assert spec.validate_spec.get("samples", 0) >= 256
    for st in spec.stages:
        if st.type == "sg.ssdf":
            st.params.update(resolution=8, supersample=1)
        if st.type == "sg.environment":
            st.params.update(lobes=3)  # the sky's 8-lobe fit takes tens of seconds
    scene = spec.load_scene()
    sky = LightingSource.fixed([Environment.sky(height=16, width=32, to_world=up_rotation(scene.up_axis))], scene.up_axis)
    rt = spec.compile(scene, device=device, cache_dir=tmp_path, progress=False, lighting=sky)
    rt.run([0.0])
    brdf = reference_model(rt)["brdf"]
    assert isinstance(brdf, SVBRDFMaterial) and brdf.source.endswith(SVBRDF_FILE)
    texture = rt.output_stage().svbrdf
    want = texture.texel_of(scene_uvs(rt.scene))
    got = np.stack(np.divmod(vertex_texels(brdf, rt.scene, device).numpy(), brdf.shape[1]), -1)
    assert np.mean(np.any(got != want, axis=1)) < 1e-3  # float32 against float64 at texel edges
    err = measure_error(rt, [0.0], samples=16, cache_dir=tmp_path).error["mean"]
    assert np.isfinite(err["rel_rms"]) and err["rel_rms"] < 1.0
    px = measure_pixels(rt, tmp_path, [0.0], width=24, height=18, samples=16)["frames"][0.0]
    assert np.isfinite(px["rel_rms"]) and px["rel_rms"] < 1.0 and px["pixels"] > 50
