"""Glossy ground truth: the Warp BRDFs against the float64 models, lobe sampling against its pdf,
the estimators against hemisphere quadrature (unoccluded) and float64 brute-force visibility
(occluded), Lambert against the diffuse reference (statistically and as the same estimator), and
bad input."""

import numpy as np
import pytest
import trimesh
from grids import ground_grid

from warpshade._wp import wp
from warpshade.geometry._bvh import trace_occlusion_f64
from warpshade.reference import shade, shade_glossy
from warpshade.scene import DistantLight, Environment, Mesh, Scene, SphereLight, _materials as materials
from warpshade.scene._materials_warp import BRDFParams, brdf_eval, brdf_pdf, brdf_sample, upload_brdf
from warpshade.methods.sg._brdf import AshikhminShirley, Ward

from tolerances import STDERR_SIGMAS, assert_within_stderr

#: float32 evaluation of the BRDFs vs the float64 models, relative to the largest value.
BRDF_RTOL_FLOAT32 = 1e-4
#: Quadrature (48 x 96 nodes) of a discontinuous visibility: its own error, relative.
QUADRATURE_RTOL_OCCLUDED = 0.03
#: Monte Carlo check of the lobe pdf's normalisation (2e5 uniform directions): 5 sigma.
PDF_NORMALISATION_TOL = 0.03
#: Diffuse reference vs the glossy path with a Lambert BRDF, tint = albedo and the same seed: both
#: run the same kernel with the same BRDF parameters, tint and random streams, and a Lambert BRDF
#: reads the view only through its n.v > 0 test, so the results are identical (not merely within
#: float32 rounding) on every receiver that faces the eye.
SAME_ESTIMATOR_ATOL = 0.0
#: Sample moments vs pdf moments, both from 2e5 directions: about 5 sigma of the sharpest lobe.
PDF_MOMENT_TOL = 0.02

MODELS = {
    "lambert": materials.Lambert(0.7),
    "phong": materials.Phong(exponent=20.0),
    "blinn-phong": materials.BlinnPhong(exponent=50.0),
    "ggx": materials.Microfacet(roughness=0.3, distribution="ggx", f0=0.1),
    "beckmann": materials.Microfacet(roughness=0.5, distribution="beckmann", f0=0.04),
    # anisotropic models in the tangent frame of the default tangent (+x; the floor's normal is +z)
    "ward-anisotropic": Ward(alpha_x=0.15, alpha_y=0.4, specular=0.8),
    "ashikhmin-shirley": AshikhminShirley(nu=30.0, nv=150.0, rs=0.1),
    "beckmann-anisotropic": materials.AnisotropicMicrofacet(roughness=0.15, roughness_y=0.45, f0=0.2),
}
EYE = np.array([0.3, -2.0, 1.5])
UP = wp.constant(wp.vec3(0.0, 0.0, 1.0))


@wp.kernel
def _eval_pdf_kernel(b: BRDFParams, v: wp.array(dtype=wp.vec3), s: wp.array(dtype=wp.vec3),
                     f: wp.array(dtype=float), pdf: wp.array(dtype=float)):
    i = wp.tid()
    f[i] = brdf_eval(b, UP, v[i], s[i])
    pdf[i] = brdf_pdf(b, UP, v[i], s[i])


@wp.kernel
def _sample_kernel(b: BRDFParams, v: wp.vec3, u: wp.array(dtype=wp.vec2), out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = brdf_sample(b, UP, v, u[i][0], u[i][1])


def _eval_pdf(brdf, v, s, device):
    f = wp.zeros(len(s), dtype=float, device=device)
    pdf = wp.zeros(len(s), dtype=float, device=device)
    wp.launch(_eval_pdf_kernel, dim=len(s), inputs=[upload_brdf(brdf), wp.array(v, dtype=wp.vec3, device=device),
                                                     wp.array(s, dtype=wp.vec3, device=device), f, pdf], device=device)
    return f.numpy().astype(np.float64), pdf.numpy().astype(np.float64)


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


@pytest.mark.parametrize("name", list(MODELS))
def test_warp_brdfs_match_the_float64_models(device, rng, name):
    brdf = MODELS[name]
    v = _unit(rng.normal(size=(4000, 3)))
    s = _unit(rng.normal(size=(4000, 3)))
    v[:, 2] = np.abs(v[:, 2])  # views above the horizon; lights on both sides
    f, _ = _eval_pdf(brdf, v, s, device)
    ref = brdf.evaluate(v, s)
    assert np.all(f[s[:, 2] <= 0] == 0.0)
    np.testing.assert_allclose(f, ref, atol=BRDF_RTOL_FLOAT32 * ref.max(), rtol=BRDF_RTOL_FLOAT32)


@pytest.mark.parametrize("name", list(MODELS))
def test_lobe_samples_follow_their_pdf(device, rng, name):
    brdf = MODELS[name]
    view = _unit(np.array([0.5, -0.2, 0.8]))
    # the pdf integrates to 1 over the sphere (uniform-direction Monte Carlo) ...
    d = _unit(rng.normal(size=(200000, 3)))
    _, pdf = _eval_pdf(brdf, np.tile(view, (len(d), 1)), d, device)
    assert 4 * np.pi * pdf.mean() == pytest.approx(1.0, abs=PDF_NORMALISATION_TOL)
    # ... and the samples are distributed by it: E_sample[g / pdf] = integral g for a smooth g
    u = rng.random((200000, 2)).astype(np.float32)
    out = wp.zeros(len(u), dtype=wp.vec3, device=device)
    wp.launch(_sample_kernel, dim=len(u), inputs=[upload_brdf(brdf), wp.vec3(*view), wp.array(u, dtype=wp.vec2, device=device), out],
              device=device)
    s = out.numpy().astype(np.float64)
    f_s, pdf_s = _eval_pdf(brdf, np.tile(view, (len(s), 1)), s, device)
    # a half vector facing away from the viewer reflects below the horizon: such samples carry
    # no radiance (b = 0) and brdf_pdf does not count them (about 1% for GGX at this view)
    zero = pdf_s <= 0
    assert np.mean(zero) < 0.02 and np.all(f_s[zero] == 0.0) and np.all(s[zero, 2] < 0), "sampled direction with zero pdf"
    # moments of the sampled directions = moments of the pdf (uniform-direction quadrature)
    h = lambda x: np.stack([x[:, 0], x[:, 1], x[:, 2], x[:, 2] ** 2, x[:, 0] * x[:, 2]], 1)  # noqa: E731
    expected = 4 * np.pi * np.mean(h(d) * pdf[:, None], axis=0)
    np.testing.assert_allclose(h(s).mean(axis=0), expected, atol=PDF_MOMENT_TOL)


def _quad_scene(env):
    points, faces = ground_grid(np.linspace(-1.0, 1.0, 3))
    return Scene.from_meshes([Mesh("floor", points, faces)], lights=[env])


@pytest.mark.parametrize("name", list(MODELS))
def test_unoccluded_matches_quadrature(device, name):
    env = Environment.sky(height=32, width=64)
    scene = _quad_scene(env)
    res = shade_glossy(scene, 0.0, MODELS[name], eye=EYE, samples=2048, color=(1.0, 0.5, 0.25), device=device)
    views = _unit(EYE - scene.points_at(0.0))
    ref = materials.shade_unshadowed(MODELS[name], views, env.radiance) * np.array([1.0, 0.5, 0.25])
    assert_within_stderr(res.radiance, ref, res.stderr, floor=1e-4 * ref.max(), what=f"{name} radiance vs quadrature")


@pytest.mark.parametrize("method", ["brdf", "light", "mis"])
def test_estimators_agree_and_report_their_noise(device, method):
    env = Environment.sky(height=32, width=64)
    scene = _quad_scene(env)
    brdf = MODELS["phong"]
    res = shade_glossy(scene, 0.0, brdf, eye=EYE, samples=4096, method=method, device=device)
    ref = materials.shade_unshadowed(brdf, _unit(EYE - scene.points_at(0.0)), env.radiance)
    assert_within_stderr(res.radiance, ref, res.stderr, floor=1e-4 * ref.max(), what=f"{method} estimate vs quadrature")
    assert np.all(res.stderr > 0)


def _ball_over_floor():
    points, faces = ground_grid(np.linspace(-1.5, 1.5, 7))
    ball = trimesh.creation.icosphere(2, radius=0.4)
    ball_points = np.asarray(ball.vertices) + [0.2, 0.1, 0.7]
    return Scene.from_meshes([Mesh("floor", points, faces), Mesh("ball", ball_points, np.asarray(ball.faces))],
                             lights=[Environment.constant((1.0, 1.0, 1.0))])


def test_occluded_matches_float64_visibility_quadrature(device):
    scene = _ball_over_floor()
    brdf = MODELS["phong"]
    floor = np.arange(49)[np.linalg.norm(scene.points_at(0.0)[:49, :2] - [0.2, 0.1], axis=1) < 1.0]
    res = shade_glossy(scene, 0.0, brdf, eye=EYE, samples=4096, device=device, vertices=floor)
    pts = scene.points_at(0.0)
    dirs, w = materials.hemisphere_quadrature(48, 96)
    for row, vtx in enumerate(floor):
        view = _unit(EYE - pts[vtx])
        origins = np.tile(pts[vtx] + [0.0, 0.0, 1e-4], (len(dirs), 1))
        visible = ~trace_occlusion_f64(pts, scene.faces, origins, dirs)
        ref = np.sum(brdf.evaluate(view, dirs) * dirs[:, 2] * w * visible)
        assert res.radiance[row, 0] == pytest.approx(ref, rel=QUADRATURE_RTOL_OCCLUDED, abs=STDERR_SIGMAS * float(res.stderr[row, 0]))
    assert res.radiance[:, 0].min() < 0.9 * res.radiance[:, 0].max(), "the ball must shadow some receivers"


def test_lambert_equals_the_diffuse_reference(device):
    scene = _ball_over_floor()
    glossy = shade_glossy(scene, 0.0, materials.Lambert(1.0), eye=EYE, samples=2048, color=(0.8, 0.8, 0.8), device=device)
    diffuse = shade(scene, 0.0, samples=2048, device=device, seed=3)  # albedo 0.8 (the scene default)
    seen = np.einsum("ij,ij->i", EYE - scene.points_at(0.0), scene.normals_at(0.0)) > 0
    both = np.hypot(glossy.stderr, diffuse.stderr)[seen]
    assert_within_stderr(glossy.radiance[seen], diffuse.radiance[seen], both, floor=1e-4, what="Lambert vs diffuse reference")
    assert np.all(glossy.radiance[~seen] == 0.0), "receivers facing away from the viewer send it nothing"


@pytest.mark.parametrize("diffuse_method, glossy_method", [("cosine", "brdf"), ("light", "light"), ("mis", "mis")])
def test_diffuse_reference_is_the_lambert_glossy_path(device, diffuse_method, glossy_method):
    """Same seed, uniform albedo: the diffuse reference is the glossy estimator with Lambert(1) and
    tint = albedo; in particular "cosine" is its BRDF-sampling strategy "brdf"."""
    albedo = (0.9, 0.6, 0.3)
    floor_p, floor_f = ground_grid(np.linspace(-1.5, 1.5, 7))
    ball = trimesh.creation.icosphere(2, radius=0.4)
    scene = Scene.from_meshes([Mesh("floor", floor_p, floor_f, albedo=albedo),
                               Mesh("ball", np.asarray(ball.vertices) + [0.2, 0.1, 0.7], np.asarray(ball.faces), albedo=albedo)])
    # every light kind: environment, delta and disc distant lights, a sphere light some receivers are inside
    lights = [Environment.sky(height=16, width=32, sun_angle_deg=20.0, sun_radiance=(8.0, 7.0, 6.0)),
              DistantLight((0.3, 0.0, 1.0), (2.0, 1.0, 3.0), angle_deg=0.0),
              DistantLight((0.2, -0.4, 1.0), (3.0, 3.0, 3.0), angle_deg=10.0),
              SphereLight(position=(-1.0, -1.0, 0.0), radius=0.6, radiance=(5.0, 4.0, 3.0))]
    eye = np.array([0.0, 0.0, 6.0])
    diffuse = shade(scene, 0.0, lights, 64, device=device, method=diffuse_method, seed=9)
    glossy = shade_glossy(scene, 0.0, materials.Lambert(1.0), eye=eye, lighting=lights, samples=64, color=albedo,
                          device=device, method=glossy_method, seed=9)
    seen = np.einsum("ij,ij->i", eye - scene.points_at(0.0), scene.normals_at(0.0)) > 0
    assert seen.sum() > 49 and diffuse.radiance[seen].min() > 0.0
    np.testing.assert_allclose(glossy.radiance[seen], diffuse.radiance[seen], rtol=0.0, atol=SAME_ESTIMATOR_ATOL)
    np.testing.assert_allclose(glossy.stderr[seen], diffuse.stderr[seen], rtol=0.0, atol=SAME_ESTIMATOR_ATOL)
    assert np.all(glossy.radiance[~seen] == 0.0) and np.all(diffuse.radiance[~seen] > 0.0), "only the glossy path has a viewer"


def test_bad_input(device):
    scene = _quad_scene(Environment.constant())
    with pytest.raises(ValueError, match="no camera"):
        shade_glossy(scene, 0.0, MODELS["phong"], device=device)
    with pytest.raises(ValueError, match="eye"):
        shade_glossy(scene, 0.0, MODELS["phong"], eye=(0.0, np.nan, 1.0), device=device)
    with pytest.raises(ValueError, match="method"):
        shade_glossy(scene, 0.0, MODELS["phong"], eye=EYE, method="cosine", device=device)
    with pytest.raises(ValueError, match="unsupported BRDF"):
        upload_brdf(object())
