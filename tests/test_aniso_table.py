"""Tabulated anisotropic BRDFs (scene/tabulated_aniso.py, scene/tabulated_aniso_warp.py) and the
measured anisotropic SG material (methods/sg/measured_aniso.py): the file layout, the float32
device look-up against the float64 one, the table against the model it samples, the sampling
mixture's pdf, the ray-traced reference over the table against the one over the analytic model,
eq. 13's extraction, and the graph stage."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from grids import ground_grid
from tolerances import assert_within_stderr

from warpshade._wp import wp
from warpshade.io import bundled_asset_directory
from warpshade.methods.sg._measured_aniso import AnisotropicMeasured, aniso_measured_material, extract_anisotropic
from warpshade.reference import shade_glossy
from warpshade.scene import Environment, Mesh, Scene, _materials as materials
from warpshade.scene._materials_warp import BRDFParams, brdf_eval, brdf_pdf, brdf_sample, upload_brdf
from warpshade.scene._tabulated_aniso import (ANISO_HEADER_BYTES, AnisotropicTable, aniso_cell_centres,
                                             read_anisotropic_table, tabulate_anisotropic, write_anisotropic_table)
from warpshade.scene._tabulated import half_diff_directions
from warpshade.usd_assets.generator.aniso_table import ANISO_DIMS, ANISO_FILE, aniso_model, make_aniso_table

from asset_compare import asset_differences

#: float32 look-up ("linear": 16 float32 cells and weights, angles from atan2 of float32 vectors in a
#: float32 tangent frame) against float64, relative to the table's largest value.
LINEAR_RTOL_FLOAT32 = 2e-5
#: "nearest": a direction within float32 rounding of a cell boundary may land in the neighbour;
#: at most this fraction of random directions may (measured: none of 20000).
NEAREST_BOUNDARY_FRACTION = 2e-3
#: The table at its own cell centres against the model: float32 storage (relative).
STORAGE_RTOL = 1e-6
#: Quadrature of the sampling pdf over the sphere (Gauss-Legendre in z x 512 azimuths): the
#: mixture integrates to 1 less the lobe's half vectors that reflect below the horizon, so in
#: (1 - weight, 1]; its quadrature error with a lobe of slope 0.08 is far below this.
PDF_INTEGRAL_TOL = 2e-3
#: Sample moments (2e5 samples) against the pdf's moments by quadrature: about 5 sigma.
PDF_MOMENT_TOL = 0.02
#: The reference over the bundled table ("linear", 24 x 24 x 48 x 12) against the one over the
#: analytic model, relative to the largest radiance: the table's reconstruction error integrated
#: under the sky, beside the combined standard errors. Measured at 16384 spp per vertex: 0.033 (tangent
#: +x) and 0.042 (diagonal), 9-14 standard errors there, so a floor, not noise (the look-up's relative
#: RMS over random direction pairs is 0.052, usd_assets/generator/aniso_table.py).
TABLE_DISCRETISATION_RTOL = 0.05
#: Turning the tangent a quarter turn changes the floor's reference by more than this, relative to its
#: largest radiance (measured 0.68 and 0.88): the tangent frames are honoured.
TANGENT_EFFECT = 0.3
#: Eq. 13 extraction of an exact eq.-13 table (anisotropic Beckmann D, Smith S of slope 0.35, which is
#: exactly 1 below 61 degrees, so the scale convention holds): D relative to itself over the cells above
#: 5 % of the peak, S below 75 degrees. Measured 0.073 and 0.032: the second-difference penalty on log S
#: rounds the knee of S at 61 degrees, and D takes up the rest (with S = 1 both are exact to 1e-6).
EXACT_D_RTOL = 0.08
EXACT_S_ATOL = 0.04
#: The bundled table is not of eq. 13's form (Schlick Fresnel, azimuth-dependent Smith masking): the
#: extracted D over the analytic Beckmann D, on the cells above 5 % of the peak, normalised by its
#: median, lies within this band for 90 % of them (measured with eta 2: 5-95 % range 0.80 to 1.22).
BUNDLED_D_BAND = (0.7, 1.3)

#: The SG shading (4 lobes) of the table on the test floor against the table's reference (1024 spp),
#: relative RMS per vertex: measured 0.087 (reference noise 0.022).
STAGE_VS_REFERENCE = 0.15

EYE = np.array([0.3, -2.0, 1.5])
SMALL = (10, 12, 16, 8)


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _pairs(rng, n):
    v = rng.normal(size=(n, 3))
    s = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    s[:, 2] = np.abs(s[:, 2]) + 0.05
    return _unit(v), _unit(s)


@pytest.fixture(scope="module")
def small_table():
    return AnisotropicTable(tabulate_anisotropic(materials.AnisotropicMicrofacet(0.15, 0.4, 0.3), SMALL))


# ---- the file layout ------------------------------------------------------------------------------


def test_file_round_trip(tmp_path, small_table):
    path = write_anisotropic_table(tmp_path / "t.anisobrdf", small_table.table)
    back = read_anisotropic_table(path, interpolation="nearest")
    assert back.dims == SMALL and back.source == str(path)
    np.testing.assert_array_equal(back.table, small_table.table.astype(np.float32).astype(np.float64))
    assert path.stat().st_size == ANISO_HEADER_BYTES + 4 * int(np.prod(SMALL))
    rgb = np.stack([small_table.table[0] * c for c in (1.0, 0.5, 0.25)])
    rgb[:, small_table.table[0] < 0] = -1.0
    back = read_anisotropic_table(write_anisotropic_table(tmp_path / "c.anisobrdf", rgb), channel="g")
    np.testing.assert_allclose(back.scalar_table(), np.where(rgb[1] < 0, -1, rgb[1]), rtol=1e-6, atol=1e-37)


@pytest.mark.parametrize("damage, message", [
    (lambda b: b[:-4], "expected"),
    (lambda b: b[:20], "shorter than"),
    (lambda b: b"XXXXXXXX" + b[8:], "bad magic"),
    (lambda b: b[:8] + np.uint32(2).tobytes() + b[12:], "version 2"),
    (lambda b: b[:12] + np.uint32(2).tobytes() + b[16:], "2 channels"),
    (lambda b: b[:16] + np.uint32(0).tobytes() + b[20:], "header dims"),
    (lambda b: b[:40] + np.float32(np.nan).tobytes() + b[44:], "non-finite"),
])
def test_corrupt_files_are_refused_naming_the_file(tmp_path, small_table, damage, message):
    good = write_anisotropic_table(tmp_path / "good.anisobrdf", small_table.table).read_bytes()
    bad = tmp_path / "bad.anisobrdf"
    bad.write_bytes(damage(good))
    with pytest.raises(ValueError, match=message) as info:
        read_anisotropic_table(bad)
    assert str(bad) in str(info.value)
    with pytest.raises(ValueError, match="no such file"):
        read_anisotropic_table(tmp_path / "missing.anisobrdf")


def test_generator_reproduces_the_bundled_table(tmp_path):
    written = make_aniso_table(str(tmp_path))
    # its header exactly, its values within asset_compare.RTOL (bytes differ by ulps between machines)
    differences = asset_differences(f"{bundled_asset_directory()}/{ANISO_FILE}", written)
    assert not differences, "\n".join(differences)


# ---- the table against the model -----------------------------------------------------------------


@pytest.mark.parametrize("interpolation", ["nearest", "linear"])
def test_table_reproduces_the_model_at_its_cells(interpolation, rng):
    model = aniso_model()
    table = dataclasses.replace(read_anisotropic_table(f"{bundled_asset_directory()}/{ANISO_FILE}"),
                                interpolation=interpolation)
    th, ph, td, pd = aniso_cell_centres(ANISO_DIMS)
    idx = [rng.integers(0, n, 400) for n in ANISO_DIMS]
    v, s = half_diff_directions(th[idx[0]], td[idx[2]], pd[idx[3]], ph[idx[1]])
    ok = (v[:, 2] > 1e-3) & (s[:, 2] > 1e-3)
    # and its symmetries: a half-turn about the normal, and reciprocity
    half_turn = np.diag([-1.0, -1.0, 1.0])
    for a, b in ((v, s), (v @ half_turn, s @ half_turn), (s, v)):
        np.testing.assert_allclose(table.evaluate(a, b)[ok], model.evaluate(v, s)[ok], rtol=STORAGE_RTOL,
                                   atol=STORAGE_RTOL * float(table.table.max()))


@wp.kernel
def _eval_kernel(b: BRDFParams, n: wp.array(dtype=wp.vec3), t: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
                 s: wp.array(dtype=wp.vec3), f: wp.array(dtype=float), pdf: wp.array(dtype=float)):
    i = wp.tid()
    bb = b
    bb.tangent = t[i]
    f[i] = brdf_eval(bb, n[i], v[i], s[i])
    pdf[i] = brdf_pdf(bb, n[i], v[i], s[i])


def _device_eval(params, n, t, v, s, device):
    arrays = [wp.array(np.asarray(x, np.float32), dtype=wp.vec3, device=device) for x in (n, t, v, s)]
    f = wp.zeros(len(n), dtype=float, device=device)
    pdf = wp.zeros(len(n), dtype=float, device=device)
    wp.launch(_eval_kernel, dim=len(n), inputs=[params, *arrays, f, pdf], device=device)
    return f.numpy().astype(np.float64), pdf.numpy().astype(np.float64)


@pytest.mark.parametrize("interpolation", ["nearest", "linear"])
def test_device_lookup_matches_the_float64_table_in_tangent_frames(device, small_table, interpolation, rng):
    """World normals and tangents at random: the device look-up in the tangent frame against the float64
    one of the same local directions."""
    table = dataclasses.replace(small_table, interpolation=interpolation)
    n_pts = 20000
    normals = _unit(rng.normal(size=(n_pts, 3)))
    tangents = rng.normal(size=(n_pts, 3))
    t = _unit(tangents - np.sum(tangents * normals, -1, keepdims=True) * normals)
    frames = np.stack([t, np.cross(normals, t), normals], 1)  # rows t, b, n
    vl, sl = _pairs(rng, n_pts)
    v = np.einsum("nij,ni->nj", frames, vl)
    s = np.einsum("nij,ni->nj", frames, sl)
    f, pdf = _device_eval(upload_brdf(table, device), normals, tangents, v, s, device)
    expected = table.evaluate(vl, sl)
    assert np.all(pdf > 0.0)
    if interpolation == "linear":
        np.testing.assert_allclose(f, expected, rtol=0, atol=LINEAR_RTOL_FLOAT32 * table.table.max())
    else:
        off = np.abs(f - expected) > LINEAR_RTOL_FLOAT32 * table.table.max()
        assert off.mean() <= NEAREST_BOUNDARY_FRACTION, off.sum()


def test_sampling_pdf_integrates_to_at_most_one(device, small_table):
    params = upload_brdf(small_table, device)
    x, wx = np.polynomial.legendre.leggauss(256)
    phi = (np.arange(512) + 0.5) * 2 * np.pi / 512
    zz, pp = np.meshgrid(x, phi, indexing="ij")
    r = np.sqrt(1 - zz**2)
    d = np.stack([r * np.cos(pp), r * np.sin(pp), zz], -1).reshape(-1, 3)
    w = np.repeat(wx * 2 * np.pi / 512, 512)
    for view in (_unit(np.array([0.2, 0.1, 1.0])), _unit(np.array([0.8, -0.5, 0.4]))):
        m = len(d)
        _, pdf = _device_eval(params, np.tile([0, 0, 1.0], (m, 1)), np.tile([1.0, 0, 0], (m, 1)), np.tile(view, (m, 1)),
                              d, device)
        total = float(np.sum(pdf * w))
        assert 1.0 - params.f0 - PDF_INTEGRAL_TOL <= total <= 1.0 + PDF_INTEGRAL_TOL, total


@wp.kernel
def _sample_kernel(b: BRDFParams, v: wp.vec3, u: wp.array(dtype=wp.vec2), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = brdf_sample(b, wp.vec3(0.0, 0.0, 1.0), v, u[i][0], u[i][1])


def test_samples_follow_the_pdf(device, small_table, rng):
    """The mixture's samples against its pdf: moments of the samples (those brdf_pdf counts: a lobe
    half vector facing away from the viewer reflects below the horizon) against quadrature moments."""
    params = upload_brdf(small_table, device)
    view = _unit(np.array([0.5, 0.3, 0.8]))
    x, wx = np.polynomial.legendre.leggauss(256)
    phi = (np.arange(512) + 0.5) * 2 * np.pi / 512
    zz, pp = np.meshgrid(x, phi, indexing="ij")
    r = np.sqrt(1 - zz**2)
    d = np.stack([r * np.cos(pp), r * np.sin(pp), zz], -1).reshape(-1, 3)
    w = np.repeat(wx * 2 * np.pi / 512, 512)
    m = len(d)
    _, pdf = _device_eval(params, np.tile([0, 0, 1.0], (m, 1)), np.tile([1.0, 0, 0], (m, 1)), np.tile(view, (m, 1)), d,
                          device)
    u = rng.random((200000, 2)).astype(np.float32)
    out = wp.zeros(len(u), dtype=wp.vec3, device=device)
    wp.launch(_sample_kernel, dim=len(u), inputs=[params, wp.vec3(*view), wp.array(u, dtype=wp.vec2, device=device), out],
              device=device)
    s = out.numpy().astype(np.float64)
    k = len(s)
    _, pdf_s = _device_eval(params, np.tile([0, 0, 1.0], (k, 1)), np.tile([1.0, 0, 0], (k, 1)), np.tile(view, (k, 1)), s,
                            device)
    counted = pdf_s > 0.0
    assert np.all(s[~counted, 2] < 0.0)
    moments = lambda a: np.stack([a[:, 0], a[:, 1], a[:, 2], a[:, 0] ** 2, a[:, 1] ** 2, a[:, 0] * a[:, 1]], 1)  # noqa: E731
    expected = np.sum(moments(d) * (pdf * w)[:, None], axis=0)
    np.testing.assert_allclose((moments(s) * counted[:, None]).mean(axis=0), expected, atol=PDF_MOMENT_TOL)


# ---- the ray-traced reference ---------------------------------------------------------------------


def test_reference_over_the_table_matches_the_analytic_model(device):
    """The bundled table ("linear") and the model it was written from, each shaded by the glossy
    reference on a floor under the sky with a tangent along +x and one along a diagonal."""
    env = Environment.sky(height=32, width=64)
    points, faces = ground_grid(np.linspace(-1.0, 1.0, 4))
    scene = Scene.from_meshes([Mesh("floor", points, faces)], lights=[env])
    table = read_anisotropic_table(f"{bundled_asset_directory()}/{ANISO_FILE}")
    for tangent in ((1.0, 0.0, 0.0), (0.6, 0.8, 0.0)):
        ref = shade_glossy(scene, 0.0, aniso_model(), eye=EYE, samples=2048, device=device, tangents=tangent)
        res = shade_glossy(scene, 0.0, table, eye=EYE, samples=2048, device=device, seed=5, tangents=tangent)
        assert np.all(res.stderr > 0)
        assert_within_stderr(res.radiance, ref.radiance, np.hypot(res.stderr, ref.stderr),
                             floor=TABLE_DISCRETISATION_RTOL * ref.radiance.max(), what=f"table vs model, tangent {tangent}")
        turned = shade_glossy(scene, 0.0, table, eye=EYE, samples=256, device=device, tangents=(-tangent[1], tangent[0], 0.0))
        assert np.abs(turned.radiance - res.radiance).max() > TANGENT_EFFECT * res.radiance.max()


# ---- eq. 13 ---------------------------------------------------------------------------------------


def _beckmann_grid(dims, ax, ay):
    th, ph, _, _ = aniso_cell_centres(dims)
    tt, pp = np.meshgrid(th, ph, indexing="ij")
    h = np.stack([np.sin(tt) * np.cos(pp), np.sin(tt) * np.sin(pp), np.cos(tt)], -1)
    return th, ph, materials.AnisotropicMicrofacet(ax, ay)._d(h)


def test_extraction_recovers_an_exact_eq13_table():
    from warpshade.usd_assets.generator.measured import measured_shadowing

    dims = (16, 16, 24, 8)
    th, ph, d = _beckmann_grid(dims, 0.12, 0.35)
    theta = np.linspace(0.0, 0.5 * np.pi, 91)
    truth = AnisotropicMeasured(th, ph, d, theta, measured_shadowing(theta), 1.8, 0.0, 0)
    got = extract_anisotropic(tabulate_anisotropic(truth, dims)[0], eta=1.8)
    big = d > 0.05 * d.max()
    np.testing.assert_allclose(got.ndf_values[big], d[big], rtol=EXACT_D_RTOL)
    low = theta < np.radians(75.0)
    np.testing.assert_allclose(got.shadow[low], truth.shadow[low], atol=EXACT_S_ATOL)


def test_extraction_from_the_bundled_table_follows_the_analytic_ndf():
    got = aniso_measured_material(f"{bundled_asset_directory()}/{ANISO_FILE}", eta=2.0)
    _, _, d = _beckmann_grid(ANISO_DIMS, 0.08, 0.32)
    big = d > 0.05 * d.max()
    ratio = got.ndf_values[big] / d[big]
    ratio /= np.median(ratio)
    inside = (ratio > BUNDLED_D_BAND[0]) & (ratio < BUNDLED_D_BAND[1])
    assert inside.mean() >= 0.9, np.percentile(ratio, [5, 50, 95])
    # the NDF is anisotropic the way the model is: narrower along the tangent (x) than across
    along = got.ndf(np.array([np.sin(0.15), 0.0, np.cos(0.15)]))
    across = got.ndf(np.array([0.0, np.sin(0.15), np.cos(0.15)]))
    assert across > 5.0 * along


def _polar_floor(count=9):
    """A z = 0 grid over [-1, 1]^2 with polar UVs about a pole outside it (circular UV tangents)."""
    pts, faces = ground_grid(np.linspace(-1.0, 1.0, count))
    rel = pts[:, :2] + np.array([1.6, 1.4])
    uvs = np.stack([np.arctan2(rel[:, 1], rel[:, 0]) / (2 * np.pi), np.hypot(rel[:, 0], rel[:, 1])], -1)
    return Scene.from_meshes([Mesh("/floor", pts, faces, uvs=uvs)])


def test_stage_shades_the_table_near_its_reference():
    """sg.shade with brdf = 'tabulated-aniso' on a floor with circular UV tangents under the sky: the
    lobes reported, and the specular term per vertex against the glossy reference of the table in
    the same UV tangent frames (what --validate measures)."""
    from warpshade.graph import GraphSpec, StageSpec
    from warpshade.scene import LightingSource

    scene = _polar_floor()
    sky = Environment.sky(height=16, width=32)
    spec = GraphSpec(stages=[
        StageSpec("ssdf", "sg.ssdf", {"resolution": 8, "supersample": 2}),
        StageSpec("environment", "sg.environment", {"lobes": 3}),
        StageSpec("tangents", "ldprt.tangents"),
        StageSpec("shade", "sg.shade", {"eye": tuple(EYE), "brdf": "tabulated-aniso", "eta": 2.0, "lobes": 4,
                                        "table": f"bundled:{ANISO_FILE}", "tangent": "uv"}),
    ], output="shade.radiance", name="aniso-table-test")
    rt = spec.compile(scene, device="cpu", progress=False, lighting=LightingSource.fixed([sky], "Z"))
    rt.step(0.0)
    out = rt.output.numpy().astype(np.float64)
    st = rt.output_stage()
    lobes = st.diagnostics()["ndf_lobes"]
    assert lobes["model"] == "tabulated-anisotropic" and lobes["lobes"] == 4
    model = st.reference_model()
    assert isinstance(model["brdf"], AnisotropicTable) and model["tangents"] == "uv"
    ref = shade_glossy(scene, 0.0, model["brdf"], eye=model["eye"], samples=1024, color=model["color"], device="cpu",
                       tangents="uv", lighting=[sky])
    err = np.sqrt(np.mean((out - ref.radiance) ** 2) / np.mean(ref.radiance**2))
    assert np.all(np.isfinite(out)) and err < STAGE_VS_REFERENCE, err


def test_bundled_graph_loads():
    import warpshade.graph as graph

    spec = graph.load(Path(__file__).resolve().parents[1] / "stages" / "dish_sg_aniso_measured.toml")
    shade = next(st for st in spec.stages if st.type == "sg.shade")
    assert shade.params["brdf"] == "tabulated-aniso" and shade.params["table"] == f"bundled:{ANISO_FILE}"


@pytest.mark.parametrize("damage, message", [
    (lambda b: b"XXXXXXXX" + b[8:], "bad magic"),
    (lambda b: b[:8] + np.uint32(2).tobytes() + b[12:], "version 2"),
    (lambda b: b[:16] + np.uint32(0).tobytes() + b[20:], "header dims"),
    (lambda b: b[:-4], "expected"),
    (lambda b: b[:40] + np.float32(np.nan).tobytes() + b[44:], "non-finite"),
])
def test_bad_table_is_refused_before_the_ssdf_bake_and_the_environment(tmp_path, small_table, sg_bake_refused, damage,
                                                                       message):
    """Issue 39: sg.shade reads its .anisobrdf (the reader's checks) when the graph is compiled,
    before the SSDF bake and the environment's preparation (both raise here if reached), and names
    the stage and the file."""
    from warpshade.graph import GraphSpec, StageError, StageSpec
    from warpshade.scene import LightingSource

    Baked = sg_bake_refused
    good = write_anisotropic_table(tmp_path / "good.anisobrdf", small_table.table)
    bad = tmp_path / "bad.anisobrdf"
    bad.write_bytes(damage(good.read_bytes()))

    def compile_with(table):
        spec = GraphSpec(stages=[
            StageSpec("ssdf", "sg.ssdf", {"resolution": 8, "supersample": 2}),
            StageSpec("environment", "sg.environment", {"lobes": 3}),
            StageSpec("tangents", "ldprt.tangents"),
            StageSpec("shade", "sg.shade", {"eye": tuple(EYE), "brdf": "tabulated-aniso", "table": str(table),
                                            "tangent": "uv"}),
        ], output="shade.radiance", name="aniso-table-refusal")
        spec.compile(_polar_floor(), device="cpu", cache_dir=None, progress=False,
                     lighting=LightingSource.fixed([Environment.sky(height=16, width=32)], "Z"))

    with pytest.raises(StageError, match=message) as info:
        compile_with(bad)
    assert str(info.value).startswith("stage 'shade': table ") and str(bad) in str(info.value)
    with pytest.raises(StageError, match="no such file"):
        compile_with(tmp_path / "missing.anisobrdf")
    with pytest.raises(Baked):  # a sound table passes the check and the bake is reached
        compile_with(good)
