"""The SG/SSDF method (Wang et al. 2009) end to end: the per-vertex and per-pixel Warp kernels
against the float64 mirror, physics checks against analytic values and the glossy ray-traced
reference, failure modes, and the environment artifact's caching."""

import math

import numpy as np
import pytest

from warpshade.basis import sg
from warpshade.geometry._bvh import Visibility
from warpshade.graph import GraphSpec, StageSpec
from warpshade.measure import reference_model
from warpshade.methods.sg import EnvironmentLighting, decode_maps, shade_f64
from warpshade.methods.sg import _model as sg_model
from warpshade.methods.sg import _stages as sg_stages
from warpshade.methods.sg._lights import directional_light_lobe
from warpshade.methods.sg import PrefilteredEnvironment
from warpshade.graph import StageError
from warpshade.reference import shade_glossy
from warpshade.render import GBuffer, render_gbuffer
from warpshade.scene import Camera, DistantLight, Environment, LightingSource, LightTrack, Mesh, Scene, SphereLight
from warpshade.scene import _materials as M

from grids import ground_grid

# float32 kernel vs the float64 mirror, relative to the largest radiance: the lobe products'
# exp(|l1 p1 + l2 p2| - l1 - l2) in float32 round the exponent by ~lambda * 2^-24, with lambda up
# to 1.2e3 here (the 5 degree distant light; sphere lights and warped slices are broader):
# measured 1.4e-5 (environment, sphere light) to 1.7e-4 (distant light x Blinn-Phong slice).
RTOL_FLOAT32 = 5e-4
# The same for a 0.53 degree distant light: its lobe has sharpness 1.08e5, where one float32 ulp
# of the exponent's terms is 7.8e-3, so the product amplitude carries ~1 % rounding
# (basis/sg_warp.sg_product); measured 9.9e-3 (diffuse 8.7e-3).
RTOL_SHARP_LOBE = 2.5e-2
# ssdf = "pca" (16 terms reconstructed per look-up in float32) vs decoded float32 maps: the
# summation order of the PCA differs; measured 2.1e-7 relative.
RTOL_PCA_VS_MAPS = 1e-4
# A G-buffer hit exactly at a vertex (weight 1 on it) against the per-vertex kernel: the same
# arithmetic except the position/normal rounding of the G-buffer arrays.
RTOL_PIXEL_AT_VERTEX = 1e-5
# Unoccluded plane, constant environment, diffuse: the SG clamped cosine (paper: lambda 2.133,
# mu 1.170) integrated over the upper hemisphere is 2 pi mu (1 - e^-lambda) / lambda = 0.967 pi,
# so R = 0.967 a L; the few-lobe fit of a constant sky adds < 1e-4.  The bound on |R / (a L) - 1|.
DIFFUSE_HEMISPHERE_BOUND = 0.04
RTOL_DIFFUSE_ANALYTIC = 1e-3  # vs 2 pi mu (1 - e^-lambda) / lambda exactly: fit 8e-5 + float32
# Specular of an unoccluded plane under a constant sky vs the glossy reference (Beckmann, 2048
# spp, stderr < 1.5 %), views with n.o in [0.49, 1]: the single-SG clamped cosine (peak 1.17 at
# the normal: +13.5 % at normal view for roughness 0.1), the isotropic warp (eq. 19) and M_o at
# the lobe centre. Measured per vertex 0.77 .. 1.14 of the reference (roughness 0.1 to 0.4),
# relative RMS 7 % (near normal) to 20 % (roughness 0.4).
SPECULAR_RATIO_RANGE = (0.70, 1.20)
SPECULAR_REL_RMS = 0.25
# Grazing views (n.o ~ 0.04): the warp's lobe is far too narrow across the plane of incidence
# and M_o at the centre explodes with 1 / (n.o); measured up to 3.1x the reference at roughness
# 0.1. A documented failure mode: bounded and finite, not accurate.
SPECULAR_GRAZING_MAX_RATIO = 5.0

SKY = Environment.sky(height=16, width=32)
EYE = (0.5, -1.5, 2.0)
BOX_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                      [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


def _box(lo, hi):
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], np.float64)


@pytest.fixture(scope="module")
def blocked():
    """A 7 x 7 ground grid under a floating box (57 vertices): shadowed and open receivers."""
    pts, faces = ground_grid(np.linspace(-1.0, 1.0, 7))
    return Scene.from_meshes([Mesh("/ground", pts, faces), Mesh("/box", _box((-0.3, -0.3, 0.3), (0.3, 0.3, 0.6)), BOX_FACES)],
                             frames=np.arange(3.0))


@pytest.fixture(scope="module")
def plane():
    """A flat 5 x 5 grid alone: nothing occludes anything (SSDF +pi/2 everywhere)."""
    pts, faces = ground_grid(np.linspace(-1.0, 1.0, 5))
    return Scene.from_meshes([Mesh("/ground", pts, faces)])


def _spec(shade=None, ssdf=None, env=None):
    return GraphSpec(stages=[
        StageSpec("ssdf", "sg.ssdf", {"resolution": 8, "supersample": 2, **(ssdf or {})}),
        StageSpec("environment", "sg.environment", {"lobes": 3, **(env or {})}),
        StageSpec("tangents", "ldprt.tangents"),
        StageSpec("shade", "sg.shade", {"eye": EYE, **(shade or {})}),
    ], output="shade.radiance", name="sg-test")


def _compile(device, scene, lights, shade=None, cache_dir=None, **kw):
    return _spec(shade, **kw).compile(scene, device=device, cache_dir=cache_dir, progress=False,
                                      lighting=LightingSource.fixed(list(lights), "Z"))


def _reference(rt, corners=None, weights=None, points=None, normals=None, eye=None, albedo=None, specular=None,
               roughness=None):
    """The float64 mirror fed from what the stage uploaded at this frame (its lights, eye,
    materials, decoded SSDFs, the frame's tangent frames)."""
    st = rt.output_stage()
    p = st.params
    fl = rt.state.lighting
    env = st.environment
    spheres = [SphereLight(pos, float(r), rad) for pos, r, rad in
               zip(fl.sphere_position.numpy(), fl.sphere_radius.numpy(), fl.sphere_radiance.numpy())]
    distant = [directional_light_lobe(DistantLight(d, light.irradiance, light.angle_deg))
               for d, light in zip(fl.distant_direction.numpy(), fl.distant_lights)]
    e2w = fl.environment_to_world.numpy()[0].astype(np.float64) if fl.environments else np.eye(3)
    if env is not None:  # suns taken out of the sky are distant-light lobes turned with it
        axes, lams, amps = env.sun_lobes
        distant += [(e2w @ a, float(lam), amp) for a, lam, amp in zip(axes, lams, amps)]
    return shade_f64(
        rt.state.points.numpy() if points is None else points, rt.state.normals.numpy() if normals is None else normals,
        st._eye.numpy()[0] if eye is None else eye, st._albedo.numpy() if albedo is None else albedo,
        st._spec.numpy() if specular is None else specular, st._rough.numpy() if roughness is None else roughness,
        decode_maps(st.model), rt.frame_outputs["tangents"]["tangents"].numpy().astype(np.float64), p["brdf"], p["f0"],
        env.mixture if env is not None else None, env.table if env is not None else None, e2w, spheres, distant,
        component=p["component"], cosine=p["cosine"], corners=corners, weights=weights, horizon=p["horizon"],
        narrow_lights=p["narrow_lights"])


@pytest.fixture
def mirror():
    """:func:`_reference`, the float64 mirror fed from the stage's buffers."""
    return _reference


def _max_rel(got, want):
    return float(np.abs(got - want).max() / max(np.abs(want).max(), 1e-30))


# ---- 1. the per-vertex kernel against the float64 mirror ------------------------------------

LIGHTS = {
    "environment": [SKY],
    "sphere": [SphereLight([0.8, 0.8, 0.8], 0.1, [5.0, 4.0, 3.0])],
    "distant-5deg": [DistantLight([0.3, 0.2, 1.0], [2.0, 2.0, 2.0], angle_deg=5.0)],
}
MATERIALS = {"beckmann": 0.3, "blinn-phong": 20.0}


@pytest.mark.parametrize("horizon", [True, False])
@pytest.mark.parametrize("brdf", list(MATERIALS))
@pytest.mark.parametrize("component", ["specular", "diffuse", "both"])
@pytest.mark.parametrize("lights", list(LIGHTS))
def test_vertex_kernel_matches_the_float64_mirror(device, blocked, mirror, lights, component, brdf, horizon):
    rt = _compile(device, blocked, LIGHTS[lights], {"component": component, "brdf": brdf, "roughness": MATERIALS[brdf],
                                                    "horizon": horizon})
    out = rt.step(0.0).numpy()
    want = mirror(rt)
    assert np.all(np.isfinite(out)) and np.abs(want).max() > 0.0
    assert _max_rel(out, want) < RTOL_FLOAT32, _max_rel(out, want)


@pytest.mark.parametrize("component", ["specular", "diffuse"])
def test_sharp_distant_light_is_float32_rounding_of_the_lobe_product(device, blocked, mirror, component):
    rt = _compile(device, blocked, [DistantLight([0.3, 0.2, 1.0], [2.0, 2.0, 2.0])], {"component": component})
    out = rt.step(0.0).numpy()
    err = _max_rel(out, mirror(rt))
    assert np.all(np.isfinite(out)) and err < RTOL_SHARP_LOBE, err


def test_every_light_at_once_and_a_moving_sphere_light(device, blocked, mirror):
    # the lamp moves from (0.8, 0.8, 0.8) to (-0.8, 0.5, 0.9) over frames 0..2
    tr = np.tile(np.eye(4), (3, 1, 1))
    tr[:, 3, :3] = [[0.8, 0.8, 0.8], [0.0, 0.7, 0.85], [-0.8, 0.5, 0.9]]  # the centre follows the origin
    lamp = SphereLight([0.8, 0.8, 0.8], 0.1, [5.0, 4.0, 3.0], track=LightTrack(np.arange(3.0), tr))
    rt = _compile(device, blocked, [SKY, lamp, DistantLight([0.3, 0.2, 1.0], [1.0, 1.0, 1.0], angle_deg=5.0)],
                          {"component": "both"})
    previous = None
    for frame in (0.0, 1.0, 2.0):
        out = rt.step(frame).numpy().copy()
        np.testing.assert_allclose(rt.state.lighting.sphere_position.numpy()[0], lamp.at(frame).position, atol=1e-6)
        assert _max_rel(out, mirror(rt)) < RTOL_FLOAT32
        if previous is not None:
            assert not np.allclose(out, previous), "the moving lamp must change the shading"
        previous = out


def test_pca_lookups_equal_the_decoded_maps(device, blocked):
    lights = [SKY, SphereLight([0.8, 0.8, 0.8], 0.1, [5.0, 4.0, 3.0])]
    maps = _compile(device, blocked, lights, {"component": "both", "ssdf": "maps"}).step(0.0).numpy()
    pca = _compile(device, blocked, lights, {"component": "both", "ssdf": "pca"}).step(0.0).numpy()
    assert _max_rel(pca, maps) < RTOL_PCA_VS_MAPS, _max_rel(pca, maps)


def test_float64_mirror_shades_blinn_phong_as_called_by_the_stage(device, blocked):
    rt = _compile(device, blocked, [SKY], {"brdf": "blinn-phong", "roughness": 20.0})
    out = rt.step(0.0).numpy()
    assert _max_rel(out, _reference(rt)) < RTOL_FLOAT32


# ---- 2. per pixel ---------------------------------------------------------------------------

def _gbuffer_at_vertices(rt, vertices):
    """A G-buffer whose pixel k hits vertex ``vertices[k]`` exactly (weight 1 on it, Warp's
    barycentrics (u, v) weight the triangle's first two corners)."""
    scene = rt.scene
    bvh = Visibility.from_scene(scene, device=rt.device)
    faces = np.asarray(bvh.faces)
    n = len(vertices)
    gb = GBuffer(n, 1, rt.device, bvh)
    face, bary = np.zeros(n, np.int32), np.zeros((n, 2), np.float32)
    for k, v in enumerate(vertices):
        f, corner = np.argwhere(faces == v)[0]
        face[k] = f
        bary[k] = [(1.0, 0.0), (0.0, 1.0), (0.0, 0.0)][corner]
    gb.hit.assign(np.ones(n, np.int32))
    gb.position.assign(rt.state.points.numpy()[vertices])
    gb.normal.assign(rt.state.normals.numpy()[vertices])
    gb.face.assign(face)
    gb.bary.assign(bary)
    return gb


def _camera_gbuffer(rt, width=12, height=10):
    bvh = Visibility.from_scene(rt.scene, device=rt.device)
    bvh.update(rt.state.points)
    cam = Camera(np.asarray(EYE, np.float64), np.array([0.0, 0.0, 0.2]), np.array([0.0, 0.0, 1.0]), vertical_fov=50.0)
    return render_gbuffer(bvh, rt.state.normals, cam, width, height)


def test_pixels_at_vertices_reproduce_the_vertex_shading(device, blocked):
    rt = _compile(device, blocked, [SKY, SphereLight([0.8, 0.8, 0.8], 0.1, [5.0, 4.0, 3.0])], {"component": "both"})
    per_vertex = rt.step(0.0).numpy().copy()
    vertices = np.arange(0, blocked.vertex_count, 3)
    px = rt.output_stage().render_pixels(_gbuffer_at_vertices(rt, vertices)).numpy()
    assert _max_rel(px, per_vertex[vertices]) < RTOL_PIXEL_AT_VERTEX, _max_rel(px, per_vertex[vertices])


def test_pixels_match_the_mirror_and_explicit_materials_equal_the_interpolated_ones(device, blocked, mirror):
    rt = _compile(device, blocked, [SKY, SphereLight([0.8, 0.8, 0.8], 0.1, [5.0, 4.0, 3.0])], {"component": "both"})
    rt.step(0.0)
    st = rt.output_stage()
    rng = np.random.default_rng(7)
    count = blocked.vertex_count
    st.set_surface(albedo=rng.uniform(0.1, 0.9, (count, 3)), specular=rng.uniform(0.2, 1.0, (count, 3)),
                   roughness=rng.uniform(0.15, 0.5, count))
    gb = _camera_gbuffer(rt)
    hit = gb.hit.numpy().astype(bool)
    assert 10 < hit.sum() < gb.pixel_count, "the view must hit the scene and miss it somewhere"
    default = st.render_pixels(gb).numpy()
    assert np.all(default[~hit] == 0.0)
    faces = gb.faces.numpy()
    f, b = gb.face.numpy()[hit], gb.bary.numpy()[hit].astype(np.float64)
    corners = faces[f]
    weights = np.stack([b[:, 0], b[:, 1], 1.0 - b[:, 0] - b[:, 1]], 1)

    def interp(values):
        v = values.astype(np.float64)
        return np.einsum("pk,pk...->p...", weights, v[corners])

    alb, spc, rgh = interp(st._albedo.numpy()), interp(st._spec.numpy()), interp(st._rough.numpy())
    want = mirror(rt, corners=corners, weights=weights, points=gb.position.numpy()[hit], normals=gb.normal.numpy()[hit],
                  albedo=alb, specular=spc, roughness=rgh)
    assert _max_rel(default[hit], want) < RTOL_FLOAT32, _max_rel(default[hit], want)
    n = gb.pixel_count
    full = {k: np.zeros((n, 3) if k != "roughness" else n, np.float32) for k in ("albedo", "specular", "roughness")}
    full["albedo"][hit], full["specular"][hit], full["roughness"][hit] = alb, spc, rgh
    explicit = st.render_pixels(gb, **full).numpy()
    np.testing.assert_allclose(explicit, default, rtol=RTOL_PIXEL_AT_VERTEX, atol=RTOL_PIXEL_AT_VERTEX * default.max())
    rough = full["roughness"].copy()
    rough[hit] = 0.8
    assert not np.allclose(st.render_pixels(gb, roughness=rough).numpy()[hit], default[hit])


def test_normal_map_replaces_the_shading_normals(device, blocked, mirror):
    """A per-pixel normal map: the interpolated normals given explicitly change nothing; tilted
    normals shade as the float64 mirror does with those normals (the clamped cosine and the BRDF
    slice turned per pixel), with the vertices' visibility."""
    rt = _compile(device, blocked, [SKY, SphereLight([0.8, 0.8, 0.8], 0.1, [5.0, 4.0, 3.0])], {"component": "both"})
    rt.step(0.0)
    st = rt.output_stage()
    gb = _camera_gbuffer(rt)
    hit = gb.hit.numpy().astype(bool)
    base = gb.normal.numpy()
    np.testing.assert_array_equal(st.render_pixels(gb, normals=base).numpy(), st.render_pixels(gb).numpy())
    tilt = base + 0.3 * np.array([1.0, -0.5, 0.0], np.float32)
    tilt /= np.linalg.norm(tilt, axis=1, keepdims=True)
    got = st.render_pixels(gb, normals=tilt).numpy()
    assert not np.allclose(got[hit], st.render_pixels(gb).numpy()[hit])
    faces = gb.faces.numpy()
    f, b = gb.face.numpy()[hit], gb.bary.numpy()[hit].astype(np.float64)
    corners = faces[f]
    weights = np.stack([b[:, 0], b[:, 1], 1.0 - b[:, 0] - b[:, 1]], 1)
    mats = st.pixel_materials(gb)
    want = mirror(rt, corners=corners, weights=weights, points=gb.position.numpy()[hit], normals=tilt[hit].astype(np.float64),
                  albedo=mats["albedo"][hit], specular=mats["specular"][hit], roughness=mats["roughness"][hit])
    assert _max_rel(got[hit], want) < RTOL_FLOAT32, _max_rel(got[hit], want)
    with pytest.raises(StageError, match="render_pixels normals"):
        st.render_pixels(gb, normals=2.0 * base)


@pytest.mark.parametrize("name, value", [("albedo", np.ones((5, 3))), ("specular", np.ones(7)), ("roughness", np.ones((7, 3))),
                                         ("albedo", "negative"), ("roughness", "nan")])
def test_render_pixels_refuses_bad_material_arrays(device, blocked, name, value):
    rt = _compile(device, blocked, [SKY])
    rt.step(0.0)
    gb = _camera_gbuffer(rt, 4, 3)
    n = gb.pixel_count
    if isinstance(value, str):
        value = np.full((n, 3) if name != "roughness" else n, -1.0 if value == "negative" else np.nan)
    with pytest.raises(StageError, match=f"render_pixels {name}"):
        rt.output_stage().render_pixels(gb, **{name: value})


# ---- 3. physics against independent values ---------------------------------------------------

def test_unoccluded_plane_diffuse_is_the_sg_cosine_hemisphere_integral(device, plane):
    radiance = np.array([0.7, 1.0, 1.3])
    rt = _compile(device, plane, [Environment.constant(radiance, height=8, width=16)], {"component": "diffuse"})
    out = rt.step(0.0).numpy()
    st = rt.output_stage()
    np.testing.assert_array_equal(decode_maps(st.model), np.float32(np.pi / 2))  # no boundary: +pi/2 everywhere
    ratio = out / (st._albedo.numpy() * radiance)
    _, lam, mu = sg.clamped_cosine(np.array([0.0, 0.0, 1.0]), "paper")
    analytic = 2.0 * float(mu) * (1.0 - math.exp(-float(lam))) / float(lam)  # / pi * pi
    np.testing.assert_allclose(ratio, analytic, rtol=RTOL_DIFFUSE_ANALYTIC)
    assert np.all(np.abs(ratio - 1.0) < DIFFUSE_HEMISPHERE_BOUND), ratio.min()


@pytest.fixture(scope="module")
def enclosure():
    """A 3 x 3 sheet (9 vertices) inside a closed box: every ray from the sheet hits a wall."""
    inner, faces = ground_grid(np.linspace(-0.3, 0.3, 3))
    inner[:, 2] = 0.1
    return Scene.from_meshes([Mesh("/inner", inner, faces), Mesh("/box", _box((-0.5, -0.5, -0.2), (0.5, 0.5, 0.6)), BOX_FACES)])


def _enclosed_diffuse(device, enclosure, lights):
    rt = _compile(device, enclosure, lights, {"component": "diffuse", "eye": (0.0, -0.2, 0.4)})
    out = rt.step(0.0).numpy()[:9]
    st = rt.output_stage()
    np.testing.assert_array_equal(decode_maps(st.model)[:9], np.float32(-np.pi / 2))  # fully blocked
    return out, st._albedo.numpy()[:9]


def test_enclosed_receiver_diffuse_is_bounded_by_the_cosine_lobe_leak(device, enclosure):
    """Fully blocked (SSDF -pi/2): a sharp light gives 0; a constant sky leaves what eq. 30 puts in
    the hemisphere opposite the product lobe, f_h(-pi/2, lambda) / f_h(pi/2, lambda) = 11.8 % of
    the open value for the cosine lobe (lambda 2.133): the SG cosine's tail below the horizon."""
    out, _ = _enclosed_diffuse(device, enclosure, [DistantLight([0.2, 0.1, 1.0], [3.0, 3.0, 3.0], angle_deg=5.0)])
    assert np.all(out == 0.0) or np.abs(out).max() < 1e-12
    radiance = np.array([0.7, 1.0, 1.3])
    out, albedo = _enclosed_diffuse(device, enclosure, [Environment.constant(radiance, height=8, width=16)])
    _, lam, mu = sg.clamped_cosine(np.array([0.0, 0.0, 1.0]), "paper")
    leak = float(mu) * float(sg.hemisphere_integral(-np.pi / 2, lam)) / np.pi
    np.testing.assert_allclose(out / (albedo * radiance), leak, rtol=5e-3)
    assert leak < 0.12


@pytest.mark.xfail(strict=True, reason="method limitation, not a code slip: eq. 30 at theta_d = -pi/2 integrates "
                   "the product lobe over the opposite hemisphere; for the broad cosine lobe that is 11.8 % of the "
                   "unoccluded diffuse where a receiver inside a closed box should get ~0")
def test_enclosed_receiver_under_a_sky_is_dark(device, enclosure):
    radiance = np.array([0.7, 1.0, 1.3])
    out, albedo = _enclosed_diffuse(device, enclosure, [Environment.constant(radiance, height=8, width=16)])
    assert np.all(out / (albedo * radiance) < 0.02)


def _specular_vs_glossy(device, plane, eye, roughness):
    env = Environment.constant((1.0, 1.0, 1.0), height=8, width=16)
    rt = _compile(device, plane, [env], {"eye": eye, "roughness": roughness, "f0": 0.04})
    out = rt.step(0.0).numpy()
    ref = reference_model(rt)
    assert ref["brdf"].distribution == "beckmann" and ref["brdf"].roughness == roughness
    truth = shade_glossy(plane, 0.0, ref["brdf"], eye=ref["eye"], lighting=[env], samples=2048, color=ref["color"],
                         device=device)
    view = np.asarray(eye) - plane.points_at(0.0)
    cos = view[:, 2] / np.linalg.norm(view, axis=1)
    return out, truth.radiance.astype(np.float64), truth.stderr, cos


@pytest.mark.parametrize("roughness", [0.1, 0.2, 0.4])
@pytest.mark.parametrize("eye", [(0.0, -0.5, 2.0), (0.0, -1.5, 1.5)])
def test_specular_of_an_open_plane_against_the_glossy_reference(device, plane, eye, roughness):
    out, truth, stderr, cos = _specular_vs_glossy(device, plane, eye, roughness)
    assert cos.min() > 0.45
    assert np.all(stderr < 0.015 * truth)
    ratio = out / truth
    assert SPECULAR_RATIO_RANGE[0] < ratio.min() and ratio.max() < SPECULAR_RATIO_RANGE[1], (ratio.min(), ratio.max())
    rel_rms = np.sqrt(np.mean((out - truth) ** 2) / np.mean(truth**2))
    assert rel_rms < SPECULAR_REL_RMS, rel_rms


@pytest.mark.parametrize("roughness", [0.1, 0.4])
def test_specular_at_grazing_views_is_bounded_and_worse(device, plane, roughness):
    out, truth, _, cos = _specular_vs_glossy(device, plane, (0.0, -4.0, 0.15), roughness)
    assert cos.max() < 0.06
    near, _, _, _ = _specular_vs_glossy(device, plane, (0.0, -0.5, 2.0), roughness)
    ratio = out / truth
    assert np.all(np.isfinite(out)) and np.all(out >= 0.0)
    assert ratio.max() < SPECULAR_GRAZING_MAX_RATIO, ratio.max()
    assert np.abs(ratio - 1.0).max() > 0.1  # the documented failure: not accurate at grazing


# ---- 4. failure modes -------------------------------------------------------------------------

def test_sphere_light_inside_a_hull_is_reported(device, blocked):
    tr = np.tile(np.eye(4), (3, 1, 1))
    tr[:, 3, :3] = [[0.8, 0.8, 0.8], [0.0, 0.0, 0.45], [0.8, 0.8, 0.8]]  # frame 1: at the box's centre
    lamp = SphereLight([0.8, 0.8, 0.8], 0.05, [5.0, 4.0, 3.0], track=LightTrack(np.arange(3.0), tr))
    rt = _compile(device, blocked, [SKY, lamp], {"component": "both"})
    report = rt.output_stage().diagnostics()["lights_inside_hull"]
    assert report == [{"mesh": "/box", "light": 0, "frames": [1], "count": 1}]
    for frame in (0.0, 1.0, 2.0):
        assert np.all(np.isfinite(rt.step(frame).numpy()))
    outside = _compile(device, blocked, [SKY, SphereLight([0.8, 0.8, 0.8], 0.05, [5.0, 4.0, 3.0])])
    assert outside.output_stage().diagnostics()["lights_inside_hull"] == []


def test_sphere_light_inside_a_hull_at_the_bake_pose_is_reported_with_a_warning(device, blocked):
    with pytest.warns(RuntimeWarning, match="inside the convex hull"):
        rt = _compile(device, blocked, [SKY, SphereLight([0.0, 0.0, 0.45], 0.05, [5.0, 4.0, 3.0])], {"component": "both"})
    assert rt.output_stage().diagnostics()["lights_inside_hull"][0]["frames"] == [0]
    assert np.all(np.isfinite(rt.step(0.0).numpy()))


@pytest.mark.parametrize("roughness", [1e-3, 2.0])
def test_extreme_roughness_is_finite(device, blocked, roughness):
    lights = [SKY, SphereLight([0.8, 0.8, 0.8], 0.1, [5.0, 4.0, 3.0]), DistantLight([0.3, 0.2, 1.0], [1.0, 1.0, 1.0])]
    rt = _compile(device, blocked, lights, {"component": "both", "roughness": roughness})
    out = rt.step(0.0).numpy()
    assert np.all(np.isfinite(out)) and np.all(out >= 0.0) and out.max() < 1e4


def test_validation_refusals(device, blocked):
    with pytest.raises(StageError, match="'both' has no single reference"):
        reference_model(_compile(device, blocked, [SKY], {"component": "both"}))
    assert reference_model(_compile(device, blocked, [SKY], {"component": "diffuse"})) is None
    cook = _compile(device, blocked, [SKY], {"brdf": "cook-torrance", "roughness": 0.3})
    assert np.all(np.isfinite(cook.step(0.0).numpy()))
    with pytest.raises(StageError, match="cook-torrance.*cannot be validated"):
        reference_model(cook)
    # Ward (isotropic here) has an exact model in the reference (:mod:`warpshade.scene._materials_warp`)
    ward = _compile(device, blocked, [SKY], {"brdf": "ward", "roughness": 0.3})
    assert reference_model(ward)["brdf"].alpha_x == 0.3 and reference_model(ward)["brdf"].alpha_y == 0.3
    with pytest.raises(StageError, match="exponent"):
        _compile(device, blocked, [SKY], {"brdf": "blinn-phong", "roughness": 0.5})


def test_ssdf_of_another_scene_is_refused(device, blocked, plane, monkeypatch):
    other = sg_model.bake_ssdf_model(plane, 0.0, 8, 2, 0.02, 64, device)

    def wrong(self, ctx, inputs):
        return {"ssdf": other.arrays()}

    monkeypatch.setattr(sg_stages.SgSsdfStage, "precompute", wrong)
    with pytest.raises(StageError, match=f"SSDFs of {plane.vertex_count} vertices for a scene of {blocked.vertex_count}"):
        _compile(device, blocked, [SKY])


def test_set_surface_checks_and_takes_effect_next_frame(device, blocked):
    rt = _compile(device, blocked, [SKY], {"component": "both"})
    st = rt.output_stage()
    count = blocked.vertex_count
    before = rt.step(0.0).numpy().copy()
    for kwargs, match in [({"albedo": np.ones((count - 1, 3))}, "albedo"), ({"specular": -np.ones((count, 3))}, "specular"),
                          ({"roughness": np.zeros(count)}, "roughness"), ({"roughness": np.full(count, np.inf)}, "roughness")]:
        with pytest.raises(StageError, match=f"set_surface {match}"):
            st.set_surface(**kwargs)
    np.testing.assert_array_equal(rt.step(0.0).numpy(), before)  # refused edits change nothing
    st.set_surface(roughness=np.full(count, 0.15), albedo=np.full((count, 3), 0.2))
    edited = rt.step(0.0).numpy().copy()
    assert not np.allclose(edited, before)
    fresh = _compile(device, blocked, [SKY], {"component": "both", "roughness": 0.15})
    fresh.output_stage().set_surface(albedo=np.full((count, 3), 0.2))
    np.testing.assert_allclose(edited, fresh.step(0.0).numpy(), rtol=1e-6, atol=1e-7)


def test_set_material_beckmann_is_used_and_ggx_refused(device, blocked):
    rt = _compile(device, blocked, [SKY], {"roughness": 0.3})
    first = rt.step(0.0).numpy().copy()
    rt.set_material(M.Microfacet(roughness=0.15, distribution="beckmann"))
    swapped = rt.step(0.0).numpy().copy()
    want = _compile(device, blocked, [SKY], {"roughness": 0.15}).step(0.0).numpy()
    np.testing.assert_allclose(swapped, want, rtol=1e-6, atol=1e-7)
    assert not np.allclose(swapped, first)
    with pytest.raises(ValueError, match="beckmann"):
        rt.set_material(M.Microfacet(roughness=0.15, distribution="ggx"))


# ---- 5. the environment artifact --------------------------------------------------------------

def test_environment_artifact_is_read_back_from_the_cache(device, blocked, tmp_path, monkeypatch):
    builds = []
    original = PrefilteredEnvironment.build.__func__

    def counting(cls, *args, **kwargs):
        builds.append(1)
        return original(cls, *args, **kwargs)

    monkeypatch.setattr(PrefilteredEnvironment, "build", classmethod(counting))
    env = Environment.sky(height=16, width=24)  # not built earlier in this process
    monkeypatch.setattr(sg_model, "_CACHE", {})
    first = _compile(device, blocked, [env], {"component": "both"}, cache_dir=tmp_path)
    assert first.timings["environment"].cache == "miss" and len(builds) == 1
    out = first.step(0.0).numpy().copy()
    monkeypatch.setattr(sg_model, "_CACHE", {})  # nothing in process: only the disk can answer
    second = _compile(device, blocked, [env], {"component": "both"}, cache_dir=tmp_path)
    assert second.timings["environment"].cache == "hit" and second.timings["ssdf"].cache == "hit"
    assert len(builds) == 1, "the second compile must read the table, not build it"
    np.testing.assert_array_equal(second.step(0.0).numpy(), out)


def test_environment_lighting_round_trip(device):
    lighting = sg_model.environment_lighting(SKY, 3, None, "lbfgsb", device)
    back = EnvironmentLighting.from_arrays(lighting.arrays())
    assert back.image_hash == lighting.image_hash == sg_model.environment_hash(SKY)
    np.testing.assert_array_equal(back.mixture.axes, lighting.mixture.axes)
    np.testing.assert_array_equal(back.mixture.sharpness, lighting.mixture.sharpness)
    np.testing.assert_array_equal(back.mixture.amplitude, np.asarray(lighting.mixture.amplitude).reshape(-1, 3))
    np.testing.assert_array_equal(back.table.levels, lighting.table.levels)
    rng = np.random.default_rng(3)
    d = rng.normal(size=(32, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    lam = rng.uniform(0.2, 500.0, 32)
    np.testing.assert_array_equal(back.table.lookup(d, lam), lighting.table.lookup(d, lam))
    for key in ("axes", "image_hash"):
        broken = {k: v for k, v in lighting.arrays().items() if k != key}
        with pytest.raises(ValueError, match=repr(key)):
            EnvironmentLighting.from_arrays(broken)
    bad = lighting.arrays()
    bad["amplitude"] = -bad["amplitude"]
    with pytest.raises(ValueError, match="amplitude"):
        EnvironmentLighting.from_arrays(bad)


# ---- a sun taken out of the sky ---------------------------------------------------------------

def _sun_sky(height=32, width=64):
    img = np.full((height, width, 3), 0.3, np.float32)
    img[height // 4, width // 3] = 4.0e4  # one texel: a sun about 4 degrees across at this size
    img[height // 4, width // 3 + 1] = 2.0e4
    return Environment(img)


def test_split_sun_conserves_energy_and_leaves_soft_skies_alone():
    from warpshade.basis import quadrature

    sky = _sun_sky()
    residual, lobe = sg_model.split_sun(sky)
    q = quadrature.latlong(32, 64)
    total = (sky.image.reshape(-1, 3).astype(np.float64) * q.weights[:, None]).sum(0)
    rest = (residual.image.reshape(-1, 3).astype(np.float64) * q.weights[:, None]).sum(0)
    carried = lobe.amplitude[0] * sg.integral(lobe.sharpness[0])
    np.testing.assert_allclose(rest + carried, total, rtol=1e-5)  # float32 image
    assert residual.image.max() < 1.0 and lobe.sharpness[0] > 100.0
    assert sg_model.split_sun(SKY)[1] is None  # the soft procedural sun stays in the sky


def test_separated_sun_is_shaded_as_a_distant_lobe(device, blocked, mirror):
    sky = _sun_sky()
    for component in ("specular", "diffuse"):
        rt = _compile(device, blocked, [sky], {"component": component}, env={"sun": "separate"})
        out = rt.step(0.0).numpy()
        assert rt.output_stage().diagnostics()["environment_suns"] == 1
        assert _max_rel(out, mirror(rt)) < RTOL_SHARP_LOBE, _max_rel(out, mirror(rt))
        keep = _compile(device, blocked, [sky], {"component": component}, env={"sun": "keep"}).step(0.0).numpy()
        assert np.all(np.isfinite(out)) and not np.allclose(out, keep)


def test_textured_materials_are_validated_per_vertex_and_per_pixel(device, tmp_path):
    """The bundled sunlit scene's UsdPreviewSurface roughness reaches the vertices and the
    per-vertex reference (a roughness and colour per vertex), and the per-pixel reference."""
    from warpshade.io import load_scene
    from warpshade.measure import measure_error
    from warpshade.measure._pixels import measure_pixels
    from warpshade.scene import up_rotation

    scene = load_scene("bundled:sunlit")
    sky = Environment.sky(height=16, width=32, to_world=up_rotation(scene.up_axis))
    spec = GraphSpec(stages=[
        StageSpec("ssdf", "sg.ssdf", {"resolution": 8, "supersample": 2}),
        StageSpec("environment", "sg.environment", {"lobes": 3}),
        StageSpec("tangents", "ldprt.tangents"),
        StageSpec("shade", "sg.shade", {"textures": True, "roughness": 0.3}),
    ], output="shade.radiance", name="sg-textured")
    rt = spec.compile(scene, device=device, cache_dir=tmp_path, progress=False, lighting=LightingSource.fixed([sky], "Z"))
    rt.run([0.0])
    model = rt.output_stage().reference_model()
    rough = model["roughness"]
    assert rough.shape == (scene.vertex_count,) and 0.07 < rough.min() < 0.1 and 0.45 < rough.max() < 0.51
    assert model["color"].shape == (scene.vertex_count, 3)
    err = measure_error(rt, [0.0], samples=16, cache_dir=tmp_path).error["mean"]
    assert np.isfinite(err["rel_rms"]) and err["rel_rms"] < 1.0
    px = measure_pixels(rt, tmp_path, [0.0], width=24, height=18, samples=16)["frames"][0.0]
    assert np.isfinite(px["rel_rms"]) and px["rel_rms"] < 1.0 and px["pixels"] > 50


@pytest.mark.parametrize("shade, message", [
    ({"brdf": "beckmann", "table": "bundled:brushed_aniso.anisobrdf"},
     r"parameter 'table' is for brdf = 'tabulated-ndf' or 'tabulated-aniso', not 'beckmann'"),
    ({"brdf": "ward", "roughness_y": 0.2, "tangent": "direction", "tangent_direction": (1.0, 0.0, 0.0),
      "table": "bundled:measured_coating.binary"}, r"parameter 'table' is for brdf = .*, not 'ward'"),
    ({"brdf": "beckmann", "texture": "bundled:svbrdf_rings.svbrdf"}, r"parameter 'texture' is for brdf = 'svbrdf', not 'beckmann'"),
    ({"brdf": "tabulated-aniso"}, r"brdf = 'tabulated-aniso' needs 'table'"),
    ({"brdf": "svbrdf"}, r"brdf = 'svbrdf' needs 'texture'"),
    ({"brdf": "tabulated-aniso", "table": "bundled:measured_coating.binary"}, r"measured_coating\.binary.*bad magic"),
    ({"brdf": "tabulated-ndf", "table": "bundled:brushed_aniso.anisobrdf"}, r"brushed_aniso\.anisobrdf.*header dims"),
    ({"brdf": "svbrdf", "texture": "bundled:svbrdf_rings.svbrdf"}, r"brdf = 'svbrdf': .* /ground has none"),
    ({"brdf": "ward", "roughness": 0.3, "roughness_y": 0.2, "tangent": "uv"}, r"tangent = 'uv' needs UVs .* /ground has none"),
    ({"brdf": "ward", "roughness": 0.3, "roughness_y": 0.2, "tangent": "direction"}, r"needs tangent_direction"),
    ({"brdf": "blinn-phong", "roughness": 0.5}, r"'roughness' carries the exponent"),
    ({"roughness": 3.0}, r"parameter 'roughness' must be <= 2"),
    ({"specular": (1.0, -1.0, 0.0)}, r"parameter 'specular' needs three non-negative numbers"),
    ({"eye": (1.0, 2.0)}, r"parameter 'eye' needs three finite numbers"),
])
def test_parameter_file_and_scene_problems_are_refused_before_the_ssdf_bake(blocked, sg_bake_refused, shade, message):
    """Issue 38: every check of sg.shade that needs only its parameters, file headers and the scene
    runs when the graph is compiled, before the SSDF bake and the environment's preparation (here
    both raise if reached)."""

    Baked = sg_bake_refused
    with pytest.raises(StageError, match=rf"stage 'shade': .*{message}"):
        _compile("cpu", blocked, [SKY], shade)
    with pytest.raises(Baked):  # with nothing to refuse, the bake is reached
        _compile("cpu", blocked, [SKY])
