"""Spatially varying measured materials for the SG method (Wang et al. 2009, sec. 4.2): the
``.svbrdf`` texture file, the per-texel SG fits of the NDF and the PCA of the shadowing curves
against their error budgets, the Warp look-up and warp kernels against their float64 mirror, the
per-vertex and per-pixel shading against a float64 quadrature of the exact per-texel materials,
and bad or degenerate textures."""

import numpy as np
import pytest

from warpshade.geometry._bvh import Visibility
from warpshade.graph import GraphSpec, StageError, StageSpec
from warpshade.io import bundled_asset_directory
from warpshade.methods.sg import decode_maps, shade_f64
from warpshade.methods.sg._svbrdf import eq13_quadrature_f64, fit_svbrdf, fit_texel_ndfs, shadow_pca, svbrdf_slices_f64
from warpshade.methods.sg._svbrdf_warp import svbrdf_slices, svbrdf_texels, upload_svbrdf
from warpshade.render import render_gbuffer
from warpshade.scene import Camera, Environment, LightingSource, Mesh, Scene, SphereLight
from warpshade.scene._svbrdf import read_svbrdf, write_svbrdf
from warpshade.usd_assets.generator.svbrdf import (SVBRDF_ETA, SVBRDF_FILE, make_svbrdf, svbrdf_material,
                                                   texel_material)

from asset_compare import asset_differences
from grids import ground_grid

BUNDLED = f"{bundled_asset_directory()}/{SVBRDF_FILE}"
# Worst texel's relative L2 error of the NDF fit that the bundled texture's lobe count is chosen
# for (the graph's budget). Measured: 2 lobes, worst texel 0.0499, mean 0.0075; one lobe cannot
# fit the blended texels (worst 0.41).
NDF_BUDGET = 0.06
# The fitted lobes against the EXACT analytic NDF on 721 angles (not the 91 samples they were
# fitted to): the budget plus what linear interpolation between the samples leaves. Measured 0.0498
# (mean 0.0075).
NDF_VS_EXACT = 0.07
# Shadowing PCA budget (RMS over texels and angles) and the rank it gives on the bundled texture
# (measured RMS 4.6e-4 with 3 terms; 2 terms: 2.0e-3). The decoded curves against the exact
# analytic ones on 181 angles: RMS 9.0e-4 (max 0.015).
SHADOW_BUDGET = 1e-3
SHADOW_TERMS = 3
# float32 kernels vs the float64 mirror: warped lobe axes (absolute), sharpness and amplitude
# (relative to the largest): a normalise, a division by 4 o.z, the PCA decode and eq. 13's M_o.
# Measured 8e-8, 2e-7, 5e-6.
ATOL_AXES = 1e-5
RTOL_WARP = 1e-4
# The shading kernels (per vertex and per pixel: sky, a sphere light, diffuse + specular) against
# the float64 mirror shade_f64, relative to the largest radiance: as test_sg_aniso's RTOL_FLOAT32.
# Measured 2.7e-7 (57 vertices) and 2.4e-7 (62 pixels).
RTOL_FLOAT32 = 5e-4
# Per-vertex (and per-pixel) SG shading of an open plane under the procedural sky against the
# float64 quadrature of each texel's exact eq.-13 material (128 x 256 nodes; 256 x 512 changes it
# by 2e-4): relative RMS over all points and channels. Measured 0.102 over 81 vertices at views
# 20-55 degrees (median point 0.090, worst 0.37 on the rough worn texels at 51 degrees); the same
# texture with S = 1 against an S = 1 quadrature: 0.097, so the shadowing's PCA and look-up add
# ~0.005 and the rest is the method's per-lobe warp (M_o at the lobe centre, the one-lobe cosine).
# Per pixel (86 hits of a 16 x 12 image, the texel of the interpolated UV): 0.077. One material for
# all points (the mean of the vertices' radiance) is 0.62 from the oracle.
VS_QUADRATURE = 0.14
SKY = Environment.sky(height=16, width=32)
EYE = np.array([0.5, -1.5, 2.0])


def _plane(count=9):
    pts, faces = ground_grid(np.linspace(-1.0, 1.0, count))
    uvs = 0.03 + 0.94 * (pts[:, :2] * 0.5 + 0.5)  # texel centres away from the texel edges
    return pts, faces, uvs


def _compile(device, scene, shade, texture=BUNDLED, lights=(SKY,)):
    spec = GraphSpec(stages=[
        StageSpec("ssdf", "sg.ssdf", {"resolution": 8, "supersample": 2}),
        StageSpec("environment", "sg.environment", {"lobes": 3}),
        StageSpec("tangents", "ldprt.tangents"),
        StageSpec("shade", "sg.shade", {"eye": tuple(EYE), "brdf": "svbrdf", "texture": str(texture), "max_lobes": 3,
                                        "ndf_error_budget": NDF_BUDGET, "specular": (1.0, 1.0, 1.0), **shade}),
    ], output="shade.radiance", name="sg-svbrdf-test")
    return spec.compile(scene, device=device, progress=False, lighting=LightingSource.fixed(list(lights), "Z"))


@pytest.fixture(scope="module")
def table():
    return read_svbrdf(BUNDLED)


@pytest.fixture(scope="module")
def fitted(table):
    return fit_svbrdf(table, None, NDF_BUDGET, 3, SHADOW_BUDGET, 8)


# ---- the file ---------------------------------------------------------------------------------


def test_generator_reproduces_the_bundled_texture(tmp_path, table):
    path = make_svbrdf(str(tmp_path))
    differences = asset_differences(BUNDLED, path)  # header exactly, values within asset_compare.RTOL
    assert not differences, "\n".join(differences)
    theta = table.theta
    d, s = svbrdf_material(theta)
    assert table.ndf.shape == (32, 32, 91) and table.eta == pytest.approx(SVBRDF_ETA, rel=1e-6)
    np.testing.assert_allclose(table.ndf, d, rtol=1e-6, atol=1e-30)
    np.testing.assert_allclose(table.shadow, s, atol=1e-7)


def test_write_and_read_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    d, s = rng.uniform(0.0, 5.0, (3, 4, 10)), rng.uniform(0.0, 1.0, (3, 4, 10))
    t = read_svbrdf(write_svbrdf(tmp_path / "x.svbrdf", d, s, 1.5))
    np.testing.assert_allclose(t.ndf, d.astype(np.float32))
    np.testing.assert_allclose(t.shadow, s.astype(np.float32))
    assert t.eta == pytest.approx(1.5) and t.shape == (3, 4)


@pytest.mark.parametrize("corrupt, message", [
    (lambda raw: b"", "not an SVBRDF texture"),
    (lambda raw: b"NOTMAGIC" + raw[8:], "not an SVBRDF texture"),
    (lambda raw: raw[:8] + np.array([2], "<u4").tobytes() + raw[12:], "version 2"),
    (lambda raw: raw[:-4], "bytes, the header"),
    (lambda raw: raw[:12] + np.array([100000], "<u4").tobytes() + raw[16:], "outside"),
    (lambda raw: raw[:28] + np.array([np.nan], "<f4").tobytes() + raw[32:], "NDF values must be finite"),
    (lambda raw: raw[:-4] + np.array([1.5], "<f4").tobytes(), "shadowing values must be finite and in"),
    (lambda raw: raw[:24] + np.array([0.5], "<f4").tobytes() + raw[28:], "eta"),
])
def test_bad_texture_files_are_refused_naming_the_file(tmp_path, corrupt, message):
    good = write_svbrdf(tmp_path / "good.svbrdf", np.ones((2, 2, 8)), np.ones((2, 2, 8)))
    bad = tmp_path / "bad.svbrdf"
    bad.write_bytes(corrupt(good.read_bytes()))
    with pytest.raises(ValueError, match=message) as err:
        read_svbrdf(bad)
    assert "bad.svbrdf" in str(err.value)


def test_missing_texture_and_missing_parameter_are_stage_errors(device, tmp_path):
    pts, faces, uvs = _plane(3)
    scene = Scene.from_meshes([Mesh("/ground", pts, faces, uvs=uvs)])
    with pytest.raises(StageError, match="nothere.svbrdf.*no such file"):
        _compile(device, scene, {}, tmp_path / "nothere.svbrdf")
    with pytest.raises(StageError, match="needs 'texture'"):
        _compile(device, scene, {"texture": None})
    no_uv = Scene.from_meshes([Mesh("/ground", pts, faces)])
    with pytest.raises(StageError, match="/ground has none"):
        _compile(device, no_uv, {})


# ---- fits -------------------------------------------------------------------------------------


def test_ndf_lobe_count_comes_from_the_budget_and_meets_it(table, fitted):
    rep = fitted.report
    assert rep["lobes"] == 2 and rep["ndf_budget_met"] and rep["ndf_error_max"] <= NDF_BUDGET
    assert rep["ndf_tried"][0]["max_error"] > NDF_BUDGET  # one lobe does not fit the blended texels
    assert np.all(np.diff(fitted.sharpness, axis=2) >= 0.0)  # sorted by sharpness (texture interpolation)
    # against the exact NDF on a finer grid than the fit saw
    theta = np.linspace(0.0, 0.5 * np.pi, 721)
    d, _ = svbrdf_material(theta)
    rc = np.stack(np.meshgrid(np.arange(32), np.arange(32), indexing="ij"), -1).reshape(-1, 2)
    got = fitted.ndf_at(rc[:, None, :], np.cos(theta)[None, :])
    w = np.sin(theta)
    err = np.sqrt(np.sum(w * (got - d.reshape(-1, 721)) ** 2, 1) / np.sum(w * d.reshape(-1, 721) ** 2, 1))
    assert err.max() < NDF_VS_EXACT, err.max()


def test_single_lobe_ndf_is_recovered_exactly():
    theta = np.linspace(0.0, 0.5 * np.pi, 91)
    lam = np.array([3.0, 40.0, 800.0])
    d = 2.5 * np.exp(lam[:, None] * (np.cos(theta)[None] - 1.0))
    fit = fit_texel_ndfs(theta, d, lobes=1)
    np.testing.assert_allclose(fit.sharpness[:, 0], lam, rtol=1e-5)
    np.testing.assert_allclose(fit.amplitude[:, 0], 2.5, rtol=1e-5)
    assert fit.error.max() < 1e-6


def test_shadow_pca_rank_follows_the_budget(table, fitted):
    s = table.shadow.reshape(-1, table.shadow.shape[2])
    ranks, previous = [], None
    for budget in (1e-1, 1e-2, 2e-3, 1e-3, 2e-4):
        pca = shadow_pca(s, budget, 8)
        ranks.append(pca.basis.shape[0])
        assert pca.rms <= budget
        # the truncated SVD: the reconstruction's RMS is the tail of the singular values
        assert pca.rms == pytest.approx(pca.curve[pca.basis.shape[0]], rel=1e-6)
        if previous is not None:
            assert pca.basis.shape[0] >= previous
        previous = pca.basis.shape[0]
    assert ranks[0] < ranks[-1]
    assert fitted.terms == SHADOW_TERMS and fitted.report["shadow_rms"] <= SHADOW_BUDGET
    # the decoded curves (clipped, interpolated) against the exact analytic shadowing
    theta = np.linspace(0.0, 0.5 * np.pi, 181)
    _, exact = svbrdf_material(theta)
    rc = np.stack(np.meshgrid(np.arange(32), np.arange(32), indexing="ij"), -1).reshape(-1, 1, 2)
    got = fitted.shadow_at(np.broadcast_to(rc, (1024, 181, 2)), np.cos(theta)[None])
    rms = np.sqrt(np.mean((got - exact.reshape(-1, 181)) ** 2))
    assert rms < 2.0 * SHADOW_BUDGET, rms


# ---- kernels against the mirror --------------------------------------------------------------


def test_lookup_and_warp_kernels_match_the_mirror(device, rng, fitted):
    tex = upload_svbrdf(fitted, None, device)
    uv = rng.uniform(-1.5, 2.5, (400, 2))
    np.testing.assert_array_equal(svbrdf_texels(tex, uv, device), fitted.texel_of(uv))
    rc = np.stack([rng.integers(0, 32, 400), rng.integers(0, 32, 400)], 1)
    v = rng.normal(size=(400, 3))
    v[:300, 2] = np.abs(v[:300, 2]) + 0.02  # 100 views below the horizon: culled
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    axes, lam, amp = svbrdf_slices(tex, rc, v, device)
    want = svbrdf_slices_f64(fitted, rc, v)
    assert np.abs(axes - want[0]).max() < ATOL_AXES
    assert np.abs(lam - want[1]).max() / want[1].max() < RTOL_WARP
    assert np.abs(amp - want[2]).max() / want[2].max() < RTOL_WARP
    assert np.all(amp[v[:, 2] <= 0.0] == 0.0) and np.all(amp[v[:, 2] > 0.0] >= 0.0)


def _mirror(rt, texels, corners=None, weights=None, points=None, normals=None):
    """:func:`shade_f64` fed from what the stage uploaded, with the SVBRDF's texels."""
    st = rt.output_stage()
    p = st.params
    fl = rt.state.lighting
    env = st.environment
    spheres = [SphereLight(pos, float(r), rad) for pos, r, rad in
               zip(fl.sphere_position.numpy(), fl.sphere_radius.numpy(), fl.sphere_radiance.numpy())]
    e2w = fl.environment_to_world.numpy()[0].astype(np.float64)

    def rows(buf):
        v = buf.numpy().astype(np.float64)
        return v if corners is None else np.einsum("pk,pk...->p...", weights, v[corners])

    count = len(texels)
    return shade_f64(
        rt.state.points.numpy() if points is None else points, rt.state.normals.numpy() if normals is None else normals,
        st._eye.numpy()[0], rows(st._albedo), rows(st._spec), np.zeros(count), decode_maps(st.model),
        rt.frame_outputs["tangents"]["tangents"].numpy().astype(np.float64), "beckmann", p["f0"], env.mixture, env.table, e2w,
        spheres, component=p["component"], cosine=p["cosine"], corners=corners, weights=weights, horizon=p["horizon"],
        narrow_lights=p["narrow_lights"], svbrdf=(st.svbrdf, texels))


def test_vertex_and_pixel_kernels_match_the_float64_mirror(device):
    pts, faces, uvs = _plane(7)
    box = np.array([[x, y, z] for x in (-0.3, 0.3) for y in (-0.3, 0.3) for z in (0.3, 0.6)])
    box_faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                          [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    scene = Scene.from_meshes([Mesh("/ground", pts, faces, uvs=uvs),
                               Mesh("/box", box, box_faces, uvs=0.1 + 0.8 * box[:, :2] / 0.6 + 0.4)])
    rt = _compile(device, scene, {"component": "both"},
                  lights=(SKY, SphereLight([0.8, 0.8, 0.8], 0.1, [5.0, 4.0, 3.0])))
    out = rt.step(0.0).numpy().astype(np.float64)
    st = rt.output_stage()
    all_uv = np.concatenate([uvs, 0.1 + 0.8 * box[:, :2] / 0.6 + 0.4])
    want = _mirror(rt, st.svbrdf.texel_of(all_uv))
    assert np.all(np.isfinite(out)) and np.abs(want).max() > 0.0
    assert np.abs(out - want).max() / np.abs(want).max() < RTOL_FLOAT32
    bvh = Visibility.from_scene(scene, device=rt.device)
    bvh.update(rt.state.points)
    cam = Camera(EYE, np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), vertical_fov=50.0)
    gb = render_gbuffer(bvh, rt.state.normals, cam, 12, 10)
    hit = gb.hit.numpy().astype(bool)
    px = st.render_pixels(gb).numpy().astype(np.float64)[hit]
    b = gb.bary.numpy()[hit].astype(np.float64)
    w = np.stack([b[:, 0], b[:, 1], 1.0 - b[:, 0] - b[:, 1]], 1)
    corners = gb.faces.numpy()[gb.face.numpy()[hit]]
    texels = st.svbrdf.texel_of(np.einsum("pk,pkc->pc", w, all_uv[corners]))
    want_px = _mirror(rt, texels, corners, w, gb.position.numpy()[hit], gb.normal.numpy()[hit])
    assert np.abs(px - want_px).max() / np.abs(want_px).max() < RTOL_FLOAT32


# ---- shading against quadrature of the exact per-texel materials -----------------------------


def _oracle(points, normals, uvs, fitted):
    rc = fitted.texel_of(uvs)
    views = EYE[None] - points
    views /= np.linalg.norm(views, axis=1, keepdims=True)
    return eq13_quadrature_f64(normals, views, [texel_material(r, c) for r, c in rc], SVBRDF_ETA, SKY.radiance)


def test_vertices_and_pixels_match_quadrature_of_the_exact_materials(device):
    pts, faces, uvs = _plane(9)
    scene = Scene.from_meshes([Mesh("/ground", pts, faces, uvs=uvs)])
    rt = _compile(device, scene, {"shadow_error_budget": SHADOW_BUDGET})
    out = rt.step(0.0).numpy().astype(np.float64)
    st = rt.output_stage()
    tex = st.svbrdf
    assert st.diagnostics()["svbrdf"]["lobes"] == 2
    want = _oracle(pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1)), uvs, tex)
    rel = np.sqrt(np.mean((out - want) ** 2) / np.mean(want**2))
    assert rel < VS_QUADRATURE, rel
    # per pixel: the texel of the UV interpolated at each hit
    bvh = Visibility.from_scene(scene, device=rt.device)
    bvh.update(rt.state.points)
    cam = Camera(EYE, np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), vertical_fov=50.0)
    gb = render_gbuffer(bvh, rt.state.normals, cam, 16, 12)
    hit = gb.hit.numpy().astype(bool)
    assert hit.sum() > 60
    px = st.render_pixels(gb).numpy().astype(np.float64)[hit]
    b = gb.bary.numpy()[hit].astype(np.float64)
    w = np.stack([b[:, 0], b[:, 1], 1.0 - b[:, 0] - b[:, 1]], 1)
    corners = gb.faces.numpy()[gb.face.numpy()[hit]]
    puv = np.einsum("pk,pkc->pc", w, uvs[corners])
    pos = gb.position.numpy()[hit].astype(np.float64)
    want_px = _oracle(pos, np.tile([0.0, 0.0, 1.0], (len(pos), 1)), puv, tex)
    rel_px = np.sqrt(np.mean((px - want_px) ** 2) / np.mean(want_px**2))
    assert rel_px < VS_QUADRATURE, rel_px
    # the texture matters: one material for all (the mean texel's) is further from the oracle
    assert rel < 0.5 * np.sqrt(np.mean((out.mean(0) - want) ** 2) / np.mean(want**2))


# ---- degenerate texels -----------------------------------------------------------------------


def test_degenerate_texels_are_bounded_not_nan(device, tmp_path):
    theta = np.linspace(0.0, 0.5 * np.pi, 91)
    d, s = svbrdf_material(theta, (4, 4))
    d[0, 0] = 0.0  # no NDF at all
    s[0, 1] = 0.0  # fully shadowed
    s[1, 0] = 0.37  # constant shadowing
    d[1, 1] = 1e-30  # a vanishing NDF
    path = write_svbrdf(tmp_path / "degenerate.svbrdf", d, s)
    fit = fit_svbrdf(read_svbrdf(path), None, NDF_BUDGET, 3, 1e-3, 8)
    for a in (fit.sharpness, fit.amplitude, fit.shadow_coeffs, fit.shadow_basis):
        assert np.all(np.isfinite(a))
    assert np.all(fit.amplitude[0, 0] == 0.0) and fit.report["ndf_error_max"] <= NDF_BUDGET
    # shaded on a plane whose vertices cover the 4 x 4 texels
    pts, faces = ground_grid(np.linspace(-1.0, 1.0, 9))
    uvs = 0.01 + 0.98 * (pts[:, :2] * 0.5 + 0.5)
    scene = Scene.from_meshes([Mesh("/ground", pts, faces, uvs=uvs)])
    rt = _compile(device, scene, {}, path)
    out = rt.step(0.0).numpy().astype(np.float64)
    assert np.all(np.isfinite(out)) and out.min() >= 0.0
    rc = fit.texel_of(uvs)
    no_ndf = (rc[:, 0] == 0) & (rc[:, 1] == 0)
    shadowed = (rc[:, 0] == 0) & (rc[:, 1] == 1)
    assert no_ndf.any() and shadowed.any()
    assert np.all(out[no_ndf] == 0.0)  # no NDF: no specular
    assert out[shadowed].max() <= 1e-2 * out.max()  # S = 0, up to the PCA's error (clipped at 0)
    rest = ~(no_ndf | shadowed)
    assert out.max() < 10.0 * out[rest].mean()
