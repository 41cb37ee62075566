"""Glossy ground truth for tabulated (MERL-layout) BRDFs: the Warp table lookup against the float64
:class:`TabulatedBRDF`, the sampling mixture's pdf (quadrature) and its samples, the reference on
a tabulated GGX against the reference on GGX itself, and a colour table per channel (per vertex
and per pixel) against three single-channel runs."""

import numpy as np
import pytest
from grids import ground_grid

from warpshade._wp import wp
from warpshade.reference import reference_image, shade_glossy
from warpshade.scene import Camera, Environment, Mesh, Scene, _materials as materials
from warpshade.scene._materials_warp import (BRDFParams, brdf_eval, brdf_pdf, brdf_sample, check_reference_brdf, table_lobe,
                                            upload_brdf, upload_brdf_passes)
from warpshade.scene._tabulated import TabulatedBRDF, read_merl, write_merl

from tolerances import assert_within_stderr

#: float32 lookup against the float64 one, "linear": the blend of eight float32 cells with
#: float32 weights (angles from atan2 of float32 vectors), relative to the table's largest value.
TABLE_RTOL_FLOAT32 = 1e-5
#: "nearest": a direction within float32 rounding of a cell boundary may fall in the neighbouring
#: cell; at most this fraction of random directions may (measured: none of 20000).
NEAREST_BOUNDARY_FRACTION = 2e-3
#: Quadrature of the sampling pdf over the sphere (Gauss-Legendre in z x 1024 azimuths) against
#: its integral in closed form up to one quadrature of the half vectors: 1 less the lobe's
#: probability times the GGX half vectors facing away from the viewer (they reflect to a direction
#: that brdf_pdf does not count; 0.6% at 30 degrees, 3% at 60). The two quadratures' own error.
PDF_INTEGRAL_TOL = 1e-3
#: Sample moments against pdf moments (2e5 samples, quadrature): about 5 sigma.
PDF_MOMENT_TOL = 0.02
#: A GGX tabulated on 90 x 90 x 180 cells and looked up "linear" against GGX itself, relative to the
#: largest radiance: the table's own reconstruction error (float64 quadrature of both under this
#: sky and these views: 6e-4), with room; the Monte Carlo part of the bound is the stderr's.
TABLE_DISCRETISATION_RTOL = 2e-3

UP = wp.constant(wp.vec3(0.0, 0.0, 1.0))
EYE = np.array([0.3, -2.0, 1.5])
GGX = materials.Microfacet(roughness=0.3, distribution="ggx", f0=0.1)


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


@wp.kernel
def _eval_kernel(b: BRDFParams, n: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3), s: wp.array(dtype=wp.vec3),
                 f: wp.array(dtype=float), pdf: wp.array(dtype=float)):
    i = wp.tid()
    f[i] = brdf_eval(b, n[i], v[i], s[i])
    pdf[i] = brdf_pdf(b, n[i], v[i], s[i])


@wp.kernel
def _sample_kernel(b: BRDFParams, v: wp.vec3, u: wp.array(dtype=wp.vec2), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = brdf_sample(b, UP, v, u[i][0], u[i][1])


def _eval(params, n, v, s, device):
    arrays = [wp.array(np.ascontiguousarray(x, np.float32), dtype=wp.vec3, device=device) for x in (n, v, s)]
    f = wp.zeros(len(s), dtype=float, device=device)
    pdf = wp.zeros(len(s), dtype=float, device=device)
    wp.launch(_eval_kernel, dim=len(s), inputs=[params, *arrays, f, pdf], device=device)
    return f.numpy().astype(np.float64), pdf.numpy().astype(np.float64)


def _frame_to(n):
    """Rows (t, b, n): an orthonormal frame per unit normal (world -> local with n as +z)."""
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t = _unit(np.cross(helper, n))
    return np.stack([t, np.cross(n, t), n], axis=1)


def _random_table(rng, dims):
    """A table that varies along all three angles, with invalid cells (-1) and a colour."""
    th, td, pd = np.meshgrid(*(np.linspace(0.0, 1.0, d) for d in dims), indexing="ij")
    base = np.exp(-8.0 * th) * (1.0 + 0.5 * np.cos(2 * np.pi * pd)) * (1.0 + td) + 0.05
    table = np.stack([base * (1.0 + 0.3 * rng.random(dims)) * c for c in (1.0, 0.7, 0.4)])
    invalid = rng.random(dims) < 0.05
    return np.where(invalid[None], -1.0, table)


@pytest.mark.parametrize("interpolation", ["nearest", "linear"])
def test_warp_table_matches_the_float64_lookup(device, rng, interpolation):
    """Random normals (the lookup is built from world vectors), views and lights above the horizon,
    every channel of a table with phi_d dependence and invalid cells."""
    tab = TabulatedBRDF(_random_table(rng, (12, 10, 16)), "rgb", interpolation)
    count = 20000
    n = _unit(rng.normal(size=(count, 3)))
    local_v = _unit(rng.normal(size=(count, 3)))
    local_s = _unit(rng.normal(size=(count, 3)))
    local_v[:, 2], local_s[:, 2] = np.abs(local_v[:, 2]), np.abs(local_s[:, 2])
    frame = _frame_to(n)
    v, s = np.einsum("nij,ni->nj", frame, local_v), np.einsum("nij,ni->nj", frame, local_s)
    ref = tab.rgb(local_v, local_s)
    passes = upload_brdf_passes(tab, device)
    assert len(passes) == 3
    for c, (params, weights) in enumerate(passes):
        np.testing.assert_array_equal(weights, np.eye(3)[c])
        f, _ = _eval(params, n, v, s, device)
        err = np.abs(f - ref[:, c]) / ref[:, c].max()
        if interpolation == "linear":
            assert err.max() < TABLE_RTOL_FLOAT32, (c, err.max())
        else:
            assert np.mean(err > TABLE_RTOL_FLOAT32) <= NEAREST_BOUNDARY_FRACTION, (c, np.mean(err > TABLE_RTOL_FLOAT32))
    # below either horizon: 0
    f, _ = _eval(passes[0][0], n, v, -s, device)
    assert np.all(f == 0.0)


def test_single_channels_and_luminance_upload_one_table(device, rng):
    table = _random_table(rng, (6, 5, 8))
    for c, name in enumerate("rgb"):
        (params, weights), = upload_brdf_passes(TabulatedBRDF(table, name), device)
        np.testing.assert_array_equal(params.table_array.numpy(), table[c].reshape(-1).astype(np.float32))
        np.testing.assert_array_equal(weights, np.ones(3))
    (params, _), = upload_brdf_passes(TabulatedBRDF(table, "luminance"), device)
    lum = np.tensordot([0.2126, 0.7152, 0.0722], np.maximum(table, 0.0), axes=1)
    np.testing.assert_allclose(params.table_array.numpy(), np.where(table[0] < 0, -1.0, lum).reshape(-1), rtol=1e-6)
    # channels with different invalid cells: the luminance as three weighted passes
    table[1, 0, 0, 0] = -1.0 if table[0, 0, 0, 0] >= 0 else 0.5
    passes = upload_brdf_passes(TabulatedBRDF(table, "luminance"), device)
    np.testing.assert_allclose([w for _, w in passes], np.repeat([[0.2126], [0.7152], [0.0722]], 3, axis=1))
    with pytest.raises(ValueError, match="per channel"):
        upload_brdf(TabulatedBRDF(table, "rgb"), device)
    check_reference_brdf(TabulatedBRDF(table, "rgb"))
    with pytest.raises(ValueError, match="does not shade"):
        check_reference_brdf(object())


def test_the_fitted_lobe_follows_the_table():
    """A tabulated GGX's fitted alpha is near its own; a Lambert table is sampled mostly by cosine."""
    for alpha in (0.1, 0.3):
        table = TabulatedBRDF.from_brdf(materials.Microfacet(roughness=alpha, distribution="ggx"), dims=(90, 30, 4)).table
        fit, weight = table_lobe(table[1])
        assert 0.7 * alpha < fit < 1.4 * alpha and weight >= 0.8, (alpha, fit, weight)
    fit, weight = table_lobe(TabulatedBRDF.from_brdf(materials.Lambert(0.5), dims=(30, 30, 4)).table[0])
    assert weight == pytest.approx(0.1)


@pytest.mark.parametrize("theta_deg", [0.0, 30.0, 60.0])
def test_sampling_pdf_integrates_to_one_and_matches_its_samples(device, rng, theta_deg):
    tab = TabulatedBRDF.from_brdf(GGX, dims=(90, 30, 8), channel="g")
    params = upload_brdf(tab, device)
    t = np.radians(theta_deg)
    view = np.array([np.sin(t), 0.0, np.cos(t)])
    # quadrature over the whole sphere: Gauss-Legendre in z (both hemispheres), uniform azimuth
    z, wz = np.polynomial.legendre.leggauss(512)
    phi = (np.arange(1024) + 0.5) / 1024 * 2 * np.pi
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(1 - zz ** 2)
    d = np.stack([r * np.cos(pp), r * np.sin(pp), zz], -1).reshape(-1, 3)
    w = (wz[:, None] * np.full(phi.shape, 2 * np.pi / phi.size)[None]).reshape(-1)
    ones = np.tile([0.0, 0.0, 1.0], (len(d), 1))
    _, pdf = _eval(params, ones, np.tile(view, (len(d), 1)), d, device)
    # the GGX half vectors facing away from the viewer: quadrature over the upper hemisphere of h
    cos_h = d[:, 2]
    a2 = params.roughness ** 2
    ggx = a2 / (np.pi * (cos_h ** 2 * (a2 - 1.0) + 1.0) ** 2) * cos_h
    away = float(np.sum(np.where((cos_h > 0) & (d @ view <= 0), ggx, 0.0) * w))
    assert np.sum(pdf * w) == pytest.approx(1.0 - params.f0 * away, abs=PDF_INTEGRAL_TOL), away
    # the samples are distributed by it: moments of the samples = moments of the pdf
    u = rng.random((200000, 2)).astype(np.float32)
    out = wp.zeros(len(u), dtype=wp.vec3, device=device)
    wp.launch(_sample_kernel, dim=len(u), inputs=[params, wp.vec3(*view), wp.array(u, dtype=wp.vec2, device=device), out],
              device=device)
    s = out.numpy().astype(np.float64)
    f_s, pdf_s = _eval(params, np.tile([0.0, 0.0, 1.0], (len(s), 1)), np.tile(view, (len(s), 1)), s, device)
    # a half vector facing away from the viewer reflects below the horizon, where brdf_pdf does not
    # count it (nor does the table give it any value): left out on both sides
    counted = pdf_s > 0.0
    assert np.all(f_s[~counted] == 0.0) and np.all(s[~counted, 2] < 0.0)
    moments = lambda x: np.stack([x[:, 0], x[:, 1], x[:, 2], x[:, 2] ** 2, x[:, 0] * x[:, 2]], 1)  # noqa: E731
    expected = np.sum(moments(d) * (pdf * w)[:, None], axis=0)
    np.testing.assert_allclose((moments(s) * counted[:, None]).mean(axis=0), expected, atol=PDF_MOMENT_TOL)


def _floor_scene(env):
    points, faces = ground_grid(np.linspace(-1.0, 1.0, 4))
    return Scene.from_meshes([Mesh("floor", points, faces)], lights=[env])


def test_reference_of_a_tabulated_ggx_matches_the_analytic_reference(device, tmp_path):
    """The table written from GGX (write_merl, read back in colour, "linear") against GGX itself,
    both by the ray-traced reference (different sampling lobes, so Monte Carlo agreement)."""
    env = Environment.sky(height=32, width=64)
    scene = _floor_scene(env)
    write_merl(tmp_path / "ggx.binary", GGX, rgb=(1.0, 0.5, 0.25))
    tab = read_merl(tmp_path / "ggx.binary", interpolation="linear")
    ref = shade_glossy(scene, 0.0, GGX, eye=EYE, samples=2048, color=(1.0, 0.5, 0.25), device=device)
    res = shade_glossy(scene, 0.0, tab, eye=EYE, samples=2048, device=device, seed=5)
    assert np.all(res.stderr > 0)
    both = np.hypot(res.stderr, ref.stderr)
    assert_within_stderr(res.radiance, ref.radiance, both, floor=TABLE_DISCRETISATION_RTOL * ref.radiance.max(),
                         what="tabulated GGX vs GGX reference")


def _colour_table():
    """Channels of different shapes: GGX 0.2, 0.35 and 0.6."""
    parts = [TabulatedBRDF.from_brdf(materials.Microfacet(roughness=a, distribution="ggx", f0=0.1), dims=(45, 30, 30),
                                     interpolation="linear").table[0] for a in (0.2, 0.35, 0.6)]
    return TabulatedBRDF(np.stack(parts), "rgb", "linear")


def test_colour_table_per_vertex_is_three_single_channel_runs(device):
    """Channel c of a colour table's reference equals the run with table channel c alone, times
    channel c of the colour (same seed, same random streams: identical)."""
    env = Environment.sky(height=16, width=32)
    scene = _floor_scene(env)
    colour = _colour_table()
    tint = (0.9, 0.6, 0.3)
    res = shade_glossy(scene, 0.0, colour, eye=EYE, samples=64, color=tint, device=device, seed=3)
    for c, part in enumerate(colour.color_channels()):
        one = shade_glossy(scene, 0.0, part, eye=EYE, samples=64, color=tint, device=device, seed=3)
        np.testing.assert_array_equal(res.radiance[:, c], one.radiance[:, c])
        np.testing.assert_array_equal(res.stderr[:, c], one.stderr[:, c])
    assert not np.allclose(res.radiance[:, 0] / tint[0], res.radiance[:, 2] / tint[2], rtol=0.05), "channels differ"


def test_colour_table_per_pixel_is_three_single_channel_runs(device):
    env = Environment.sky(height=16, width=32)
    scene = _floor_scene(env)
    camera = Camera(position=EYE, target=np.zeros(3), up=np.array([0.0, 0.0, 1.0]), vertical_fov=50.0)
    colour = _colour_table()
    kw = dict(camera=camera, width=12, height=9, samples=32, include=("specular",), device=device, seed=4, eye=EYE)
    res = reference_image(scene, 0.0, colour, **kw)
    assert res.mask.any()
    for c, part in enumerate(colour.color_channels()):
        one = reference_image(scene, 0.0, part, **kw)
        np.testing.assert_array_equal(res.radiance[..., c], one.radiance[..., c])
