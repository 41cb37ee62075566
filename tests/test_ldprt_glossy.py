"""Glossy LDPRT: BRDF-specialised rows, the Warp kernel vs float64, and the unshadowed case
against brute-force quadrature of the BRDF-times-lighting integral."""

import numpy as np
import pytest

from warpshade._wp import wp
from warpshade.basis import sh
from warpshade.geometry._frames import TangentFrames
from warpshade.graph import GraphSpec, StageSpec
from warpshade.measure import measure_error
from warpshade.scene import LightingSource
from warpshade.methods.ldprt import _kernels as kernels
from warpshade.methods.ldprt._glossy import fit_glossy, glossy_rows
from warpshade.methods.ldprt._mirror import shade_glossy_f64
from warpshade.scene import Environment, Mesh, Scene
from warpshade.scene import _materials as M

ORDER = 3
# float32 kernel vs float64 mirror (table look-ups, 65 x 128, order 3, against exact SH in
# the reference; view-factor interpolation in float32), relative to the largest radiance:
# measured 2.3e-4.
RTOL_KERNEL = 1e-3
# Unshadowed glossy LDPRT vs quadrature: full-rank SVD (n_b = 9), rows fitted exactly (3 lobes
# + stored DC/linear represent any order-3 row), so what remains is the 32 x 32 bilinear view
# interpolation and the e^ table; measured 0.08 % relative RMS under the smooth sky (random
# order-4 lighting gives ~1 %, tests/test_materials.py).
RTOL_UNSHADOWED = 5e-3
BRDF = M.Microfacet(0.4, "ggx", f0=0.5)
# Glossy LDPRT vs the glossy ray-traced reference (2048 spp) under a constant sky (only the DC
# of the lighting: no SH truncation), Phong exponent 10, order 3, full rank: what remains is the
# 16 x 16 view interpolation, the fit and the reference noise; measured 3.5 % relative RMS (with
# the paper's traced visibility below the horizon: 15 %).
RTOL_VS_GLOSSY_REFERENCE = 0.06


@pytest.fixture(scope="module")
def sheet():
    """An open, gently curved 9 x 9 sheet: nothing occludes anything (V = 1 everywhere)."""
    u = np.linspace(-1.0, 1.0, 9)
    gx, gy = np.meshgrid(u, u, indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel(), 0.1 * gx.ravel() ** 2 - 0.05 * gy.ravel() ** 2], 1)
    idx = np.arange(81).reshape(9, 9)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return Scene.from_meshes([Mesh("/sheet", pts, faces)])


@pytest.fixture(scope="module")
def factorization():
    return M.factorize(BRDF, ORDER, ORDER * ORDER, resolution=32)


def test_rows_of_an_unoccluded_point_are_the_brdf_rows(factorization):
    vis = np.zeros((2, ORDER * ORDER))
    vis[:, 0] = np.sqrt(4.0 * np.pi)  # V(s) = 1 everywhere: T = identity
    rows = glossy_rows(vis, factorization)
    np.testing.assert_allclose(rows, np.broadcast_to(factorization.rows, rows.shape), atol=1e-10)


def test_glossy_kernel_and_unshadowed_case(device, sheet, factorization):
    vis = np.zeros((sheet.vertex_count, ORDER * ORDER))
    vis[:, 0] = np.sqrt(4.0 * np.pi)
    model = fit_glossy(vis, factorization, 3, restarts=0)
    assert model.total_error < 1e-4
    sky = Environment.sky()
    light = sky.to_sh(ORDER)
    eye = np.array([0.4, -1.5, 2.5])
    state = sheet.evaluate(0.0, device=device)
    tf = TangentFrames.from_scene(sheet, device=device)
    frames = tf.compute(state.points, state.normals)
    f64 = frames.numpy().astype(np.float64)
    points = state.points.numpy().astype(np.float64)
    view = eye - points
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    ref = shade_glossy_f64(model, f64, view, light)

    v = sheet.vertex_count
    table = wp.zeros((65, 128, 3, ORDER), dtype=wp.float32, device=device)
    light_wp = wp.array(light.astype(np.float32), device=device)
    wp.launch(kernels.shade_kernels(ORDER)[0], dim=(65, 128),
              inputs=[light_wp, wp.ones(1, dtype=wp.int32, device=device), table], device=device)
    out = wp.zeros((v, 3), dtype=wp.float32, device=device)
    vertices = kernels.GlossyVertices()
    vertices.frames, vertices.points = frames, state.points
    vertices.axes = wp.array(model.axes.reshape(v, -1, 3), dtype=wp.vec3, device=device)
    vertices.coeffs = wp.array(model.coeffs.reshape(v, -1, ORDER), device=device)
    vertices.stored, vertices.lobes = wp.array(model.stored, device=device), model.lobe_count
    shading = kernels.GlossyShading()
    shading.eye = wp.array([wp.vec3(*eye)], dtype=wp.vec3, device=device)
    shading.factors = wp.array(factorization.view_factors.astype(np.float32), device=device)
    shading.table, shading.light, shading.specular = table, light_wp, wp.vec3(1.0, 1.0, 1.0)
    wp.launch(kernels.glossy_kernel(ORDER), dim=v, inputs=[vertices, shading, out], device=device)
    np.testing.assert_allclose(out.numpy(), ref, atol=RTOL_KERNEL * np.abs(ref).max())

    # brute force: integral_H b(v_local, s_local) L(F^T s_local) s_z ds, per vertex
    brute = np.empty((v, 3))
    for i in range(v):
        def radiance(d_local, i=i):
            return sh.basis(d_local @ f64[i], ORDER) @ light.T  # world direction = F^T d_local
        brute[i] = M.shade_unshadowed(BRDF, (f64[i] @ view[i])[None], radiance, 48, 96)[0]
    err = np.sqrt(np.mean((out.numpy() - brute) ** 2)) / np.sqrt(np.mean(brute**2))
    assert err < RTOL_UNSHADOWED, err


def test_glossy_stages_run(device, sheet):
    spec = GraphSpec(stages=[
        StageSpec("fit", "ldprt.glossy_fit", {"order": ORDER, "lobes": 2, "rank": 3, "samples": 32, "view_resolution": 8,
                                              "restarts": 0}),
        StageSpec("tangents", "ldprt.tangents"),
        StageSpec("shade", "ldprt.glossy_shade", {"order": ORDER, "lobes": 2, "rank": 3, "view_resolution": 8,
                                                  "eye": (0.0, -2.0, 2.0)}),
    ], output="shade.radiance", name="glossy-test")
    rt = spec.compile(sheet, device=device, cache_dir=None, progress=False,
                      lighting=LightingSource([Environment.sky()], sheet.up_axis))
    out = rt.step(0.0).numpy()
    assert out.shape == (sheet.vertex_count, 3) and np.all(np.isfinite(out)) and out.max() > 0.0


def test_glossy_stage_without_camera_or_eye_shades_toward_the_framing_camera(device, sheet):
    spec = GraphSpec(stages=[
        StageSpec("fit", "ldprt.glossy_fit", {"order": 2, "lobes": 1, "rank": 2, "samples": 16, "view_resolution": 4}),
        StageSpec("tangents", "ldprt.tangents"),
        StageSpec("shade", "ldprt.glossy_shade", {"order": 2, "lobes": 1, "rank": 2, "view_resolution": 4}),
    ], output="shade.radiance")
    rt = spec.compile(sheet, device=device, cache_dir=None, progress=False,
                      lighting=LightingSource([Environment.sky()], sheet.up_axis))
    assert rt.stages[-1].diagnostics()["viewer"]["source"] == "framing"


def _glossy_validation_runtime(device, sheet, eye, below_horizon="visible"):
    spec = GraphSpec(stages=[
        StageSpec("fit", "ldprt.glossy_fit", {"order": ORDER, "lobes": 3, "rank": 9, "samples": 64,
                                              "view_resolution": 16, "brdf": "phong", "exponent": 10.0,
                                              "below_horizon": below_horizon}),
        StageSpec("tangents", "ldprt.tangents"),
        StageSpec("shade", "ldprt.glossy_shade", {"order": ORDER, "lobes": 3, "rank": 9, "view_resolution": 16,
                                                  "eye": eye, "specular": (1.0, 0.5, 0.25)}),
    ], output="shade.radiance", name="glossy-validate")
    rt = spec.compile(sheet, device=device, cache_dir=None, progress=False,
                      lighting=LightingSource([Environment.constant((1.0, 1.0, 1.0))], sheet.up_axis))
    rt.run([0.0], warmup=False)
    return rt


def test_validation_uses_the_glossy_reference_and_back_faces_send_nothing(device, sheet):
    eye = (0.0, -2.0, 0.05)  # grazing: part of the curved sheet faces away from the viewer
    rt = _glossy_validation_runtime(device, sheet, eye)
    measured = measure_error(rt, [0.0], samples=256, cache_dir=None)
    err = measured.error
    assert err["reference"].startswith("glossy") and "phong" in err["reference"]
    out, ref = rt.results[0.0], measured.references[0.0]
    facing = np.einsum("ij,ij->i", np.asarray(eye) - sheet.points_at(0.0), sheet.normals_at(0.0)) > 0
    assert 0 < facing.sum() < sheet.vertex_count, "the case must have back-facing vertices"
    assert np.all(out[~facing] == 0.0) and np.all(ref[~facing] == 0.0)
    np.testing.assert_allclose(out[facing, 1] / out[facing, 0], 0.5, rtol=1e-5)  # the specular colour


def test_open_horizon_visibility_removes_the_horizon_ringing(device, sheet):
    eye = (0.3, -0.5, 2.0)
    errors = {bh: measure_error(rt, [0.0], samples=2048, cache_dir=None).error["mean"]["rel_rms"]
              for bh in ("visible", "traced") for rt in [_glossy_validation_runtime(device, sheet, eye, bh)]}
    assert errors["visible"] < RTOL_VS_GLOSSY_REFERENCE
    # the paper's V (0 below the horizon) times the BRDF rows, truncated at order 3, rings
    assert errors["traced"] > 2.0 * errors["visible"], errors
