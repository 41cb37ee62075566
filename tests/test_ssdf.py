"""SSDF visibility (sec. 5): ray-traced hemisphere maps against a float64 brute-force ray caster,
the signed distance against closed forms (a wall: a great-circle boundary; a spherical cap), the
two distance back ends against each other, PCA against an independent SVD, the Warp lookup
against the float64 one, the SG product against ray tracing, and where it breaks."""

import numpy as np
import pytest
import trimesh
from grids import ground_grid

from warpshade.basis import sg
from warpshade.geometry._bvh import Visibility, trace_occlusion_f64
from warpshade.geometry._frames import TangentFrames
from warpshade.scene import Mesh, Scene
from warpshade.transfer import _ssdf as ssdf, _ssdf_pca as ssdf_pca, _ssdf_products as ssdf_products

HALF_PI = 0.5 * np.pi
# Warp's float32 watertight ray test vs float64 Moller-Trumbore on the same rays: grazing rays
# may differ; allow one per hundred texels of a 16x16 map (measured: none differ).
MAX_RAY_DISAGREEMENT = 1e-2
# The fine map's boundary is the staircase of texel edges between centres of opposite visibility:
# every staircase point lies within one fine-texel diameter of the true boundary and vice versa,
# and the boundary is sampled every half texel edge, so the distance error is at most one fine
# texel diameter (ssdf.texel_diameter). Measured on the wall at 64 -> 16: 0.44 of it.
STAIRCASE_FACTOR = 1.0
# ... and on average well under half of it (measured 0.1-0.2).
STAIRCASE_MEAN_FACTOR = 0.35
# The k-d tree (float64) and the Warp kernel (float32 chords, 2 asin(c / 2)) find the same nearest
# boundary sample; float32 rounding of unit vectors gives ~1e-7 rad, asin near 1 amplifies it.
ATOL_DISTANCE_FLOAT32 = 2e-6
# float32 model arrays through ssdf_eval vs float64 arithmetic on the same arrays: terms x taps
# products of O(1) values, ~1e-7 relative each; values are O(1) radians.
ATOL_EVAL_FLOAT32 = 2e-5
# Storing the float64 PCA in float32 changes the RMS error by ~1e-7 rad.
PCA_FLOAT32_SLACK = 1e-5
# The lobe-sampled oracle with 4096 stratified rays: a sharp boundary through the lobe gives
# ~S^-3/4 errors in the visible fraction (< 2e-3 measured); the quadrature f_h is exact.
TOL_ORACLE_FRACTION = 5e-3
# SSDF product (eq. 30) vs the ray-traced integral on the wall (the visible region *is* a
# hemisphere, so only the map's discretisation at 256 -> 64, the erf form of f_h (< 0.4 % of
# f_h(pi/2)) and the lobe's mass below the horizon differ), in units of f_h(pi/2, lambda):
# measured max 0.016 at lambda = 200 (the theta_d error of a fraction of a 256-texel times the
# lobe's slope sqrt(lambda / 2 pi)).
TOL_PRODUCT_FRACTION = 0.04

WALL_X = 0.5
WALL_EXTENT = 1000.0


@pytest.fixture(scope="module")
def wall_scene():
    """A receiver at the origin of a flat ground (normal +z) beside a vertical wall x = 0.5 that
    reaches 1000 units up and sideways: from the origin every upward direction with x > 0 is
    blocked, so the boundary is the great circle x = 0 (to ~5e-4 rad near the horizon) and the
    SSDF is exactly ``-asin(x)`` of the world direction."""
    ground_p, ground_f = ground_grid(np.array([-WALL_EXTENT, -1.0, 0.0, 1.0, WALL_EXTENT]))
    e = WALL_EXTENT
    wall_p = np.array([[WALL_X, -e, 0.0], [WALL_X, e, 0.0], [WALL_X, e, e], [WALL_X, -e, e]])
    wall_f = np.array([[0, 1, 2], [0, 2, 3]])
    scene = Scene.from_meshes([Mesh("ground", ground_p, ground_f), Mesh("wall", wall_p, wall_f)])
    receiver = int(np.flatnonzero(np.all(ground_p == 0.0, axis=1))[0])
    return scene, receiver


def _frame_of(scene, vertex, device):
    state = scene.evaluate(scene.frames[0], device=device)
    frames = TangentFrames.from_scene(scene, device=device).compute(state.points, state.normals)
    return frames.numpy()[vertex].astype(np.float64)


def _wall_exact(scene, vertex, resolution, device):
    world = ssdf.texel_directions(resolution) @ _frame_of(scene, vertex, device)  # rows: F^T d_local
    return -np.arcsin(np.clip(world[:, 0], -1.0, 1.0)).reshape(resolution, resolution)


def _cap_map(resolution, centre, radius):
    """Visibility of a blocked cap (angular radius ``radius`` about unit ``centre``) and its exact SSDF."""
    d = ssdf.texel_directions(resolution)
    angle = np.arccos(np.clip(d @ centre, -1.0, 1.0))
    return (angle > radius).reshape(resolution, resolution), angle - radius


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ------------------------------------------------------------------------------------------------
# visibility maps


def test_visibility_matches_float64_ray_caster(device):
    """The bake's rays (texel directions through the tangent frame) against brute force."""
    ball = trimesh.creation.icosphere(1, radius=0.4)
    ground_p, ground_f = ground_grid(np.linspace(-1.0, 1.0, 5))
    scene = Scene.from_meshes([Mesh("ground", ground_p, ground_f),
                               Mesh("ball", np.asarray(ball.vertices) + (0.3, 0.1, 0.6), ball.faces)])
    verts = np.array([6, 12, 18])
    res = 16
    vis = ssdf.bake_visibility(scene, None, resolution=res, vertices=verts, device=device)
    assert vis.shape == (3, res, res) and vis.dtype == np.uint8
    points = scene.points_at(scene.frames[0])
    normals = scene.normals_at(scene.frames[0])
    offset = Visibility.from_scene(scene).offset
    state = scene.evaluate(scene.frames[0], device=device)
    frames = TangentFrames.from_scene(scene, device=device).compute(state.points, state.normals).numpy().astype(np.float64)
    local = ssdf.texel_directions(res)
    for k, v in enumerate(verts):
        dirs = local @ frames[v]
        origins = np.broadcast_to(points[v] + offset * normals[v], dirs.shape)
        blocked = trace_occlusion_f64(points, scene.faces, origins, dirs)
        disagree = np.mean(blocked == (vis[k].ravel() == 1))
        assert disagree <= MAX_RAY_DISAGREEMENT
    assert 0 < vis.sum() < vis.size  # the ball shadows some of them


def test_progress_callable_and_tqdm_object(device, wall_scene):
    scene, v = wall_scene
    calls = []
    ssdf.bake_visibility(scene, None, resolution=4, vertices=[v, v], device=device,
                         progress=lambda done, total: calls.append((done, total)))
    assert calls[-1] == (2, 2)

    class Bar:
        n = 0

        def update(self, k):
            self.n += k

    bar = Bar()
    ssdf.bake_ssdf(scene, None, resolution=4, supersample=2, vertices=[v, v, v], device=device, progress=bar)
    assert bar.n == 3


# ------------------------------------------------------------------------------------------------
# signed distance


def test_wall_closed_form_and_sign(wall_scene, device):
    scene, v = wall_scene
    fine, out = 64, 16
    maps = ssdf.bake_ssdf(scene, None, resolution=out, supersample=fine // out, vertices=[v], device=device)
    assert maps.shape == (1, out, out) and maps.dtype == np.float32
    exact = _wall_exact(scene, v, out, device)
    err = np.abs(maps[0] - exact)
    diameter = ssdf.texel_diameter(fine)
    assert err.max() <= STAIRCASE_FACTOR * diameter
    assert err.mean() <= STAIRCASE_MEAN_FACTOR * diameter
    # sign convention: positive where visible (x < 0, away from the wall), negative where blocked
    clear = np.abs(exact) > diameter
    assert np.all(np.sign(maps[0][clear]) == np.sign(exact[clear]))
    assert np.all(maps[0][exact > diameter] > 0.0)


def test_cap_closed_form_both_methods(device):
    """A blocked cap inside the hemisphere: SSDF = angle to the centre - cap radius."""
    centre = _unit([0.3, -0.2, 0.9])
    vis, _ = _cap_map(128, centre, 0.5)
    _, exact = _cap_map(32, centre, 0.5)
    a = ssdf.signed_distance(vis, 32, method="kdtree")[0]
    b = ssdf.signed_distance(vis, 32, method="warp", device=device)[0]
    np.testing.assert_allclose(b, a, atol=ATOL_DISTANCE_FLOAT32)
    exact = np.clip(exact.reshape(32, 32), -HALF_PI, HALF_PI)
    assert np.abs(a - exact).max() <= STAIRCASE_FACTOR * ssdf.texel_diameter(128)
    assert a.min() < -0.4 and 1.0 < a.max() <= HALF_PI


@pytest.mark.parametrize("supersample", [1, 2, 3])
def test_sign_at_coarse_centres(supersample):
    """Odd supersampling: the sign of the fine texel under the centre; even: the 4 around it."""
    rng = np.random.default_rng(7)
    vis = rng.random((2, 6 * supersample, 6 * supersample)) < 0.5
    out = ssdf.signed_distance(vis, 6)
    assert np.all(np.isfinite(out)) and np.all(np.abs(out) <= HALF_PI)
    if supersample % 2:
        c = supersample // 2
        centre = vis[:, c::supersample, c::supersample]
        assert np.all((out > 0) == centre)  # a texel of its own colour: distance >= half a texel > 0
    else:
        c = supersample // 2
        around = [vis[:, i::supersample, j::supersample] for i in (c - 1, c) for j in (c - 1, c)]
        agree = np.all([a == around[0] for a in around], axis=0)
        assert np.all((out[agree] > 0) == around[0][agree])
        assert np.all(out[~agree] == 0.0)  # the centre is a corner of the boundary


def test_horizon_is_not_a_boundary_and_extremes(device):
    ones = np.ones((16, 16), bool)
    assert ssdf.boundary_points(ones).shape == (0, 3)
    for method in ("kdtree", "warp"):
        both = ssdf.signed_distance(np.stack([ones, ~ones]), 4, method=method, device=device)
        assert np.all(both[0] == np.float32(HALF_PI)) and np.all(both[1] == np.float32(-HALF_PI))
    # a blocked band along one edge of the square: no boundary sample may sit on the horizon
    # except where a boundary edge ends there
    vis = ones.copy()
    vis[:2, :] = False
    pts = ssdf.boundary_points(vis)
    assert pts.shape[0] > 0 and np.all(np.abs(np.linalg.norm(pts, axis=1) - 1.0) < 1e-12)
    on_horizon = pts[:, 2] < 1e-12
    assert on_horizon.sum() == 2  # the two ends of the band's edge


def test_fully_visible_and_fully_blocked_vertices(device):
    """Open sky: +pi/2 everywhere; a receiver inside a closed box: -pi/2 everywhere."""
    ground_p, ground_f = ground_grid(np.linspace(-4.0, 4.0, 9))
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    scene = Scene.from_meshes([Mesh("ground", ground_p, ground_f), Mesh("box", box.vertices, box.faces)])
    inside = int(np.flatnonzero(np.all(ground_p == 0.0, axis=1))[0])
    outside = int(np.flatnonzero(np.all(ground_p == (3.0, 3.0, 0.0), axis=1))[0])
    maps = ssdf.bake_ssdf(scene, None, resolution=8, supersample=2, vertices=[inside], device=device)
    assert np.all(maps == np.float32(-HALF_PI))
    sky = Scene.from_meshes([Mesh("ground", ground_p, ground_f)])
    maps = ssdf.bake_ssdf(sky, None, resolution=8, supersample=2, vertices=[outside], device=device)
    assert np.all(maps == np.float32(HALF_PI))


# ------------------------------------------------------------------------------------------------
# PCA


@pytest.fixture(scope="module")
def cap_maps():
    """SSDFs of caps whose centre and radius vary smoothly: a low-dimensional family."""
    rng = np.random.default_rng(3)
    maps = []
    for _ in range(40):
        centre = _unit([*rng.normal(0.0, 0.4, 2), 1.0])
        vis, _ = _cap_map(48, centre, rng.uniform(0.2, 0.7))
        maps.append(vis)
    return ssdf.signed_distance(np.stack(maps), 16)


def test_pca_curve_and_budget(cap_maps):
    model = ssdf_pca.compress_ssdf(cap_maps, error_budget=0.05, max_terms=24)
    curve = model.error_curve
    assert curve.shape == (24,) and curve.dtype == np.float64
    assert np.all(np.diff(curve) <= 0.0)
    # against the singular values of an independent SVD
    x = cap_maps.reshape(40, -1).astype(np.float64)
    s = np.linalg.svd(x - x.mean(0), compute_uv=False)
    tail = np.sqrt(np.maximum(np.sum(s**2) - np.cumsum(s**2), 0.0) / x.size)
    np.testing.assert_allclose(curve, tail[:24], atol=1e-9, rtol=1e-6)
    n = model.terms
    assert curve[n - 1] <= 0.05 and (n == 1 or curve[n - 2] > 0.05) and model.budget_met
    recon = model.reconstruct()
    rms = np.sqrt(np.mean((recon - cap_maps) ** 2))
    assert rms <= 0.05 + PCA_FLOAT32_SLACK
    assert rms == pytest.approx(model.rms_error, abs=PCA_FLOAT32_SLACK)
    assert model.mean.dtype == model.basis.dtype == model.coeffs.dtype == np.float32
    np.testing.assert_allclose(model.basis @ model.basis.T, np.eye(n), atol=1e-5)


def test_pca_randomized_matches_exact(cap_maps):
    a = ssdf_pca.compress_ssdf(cap_maps, error_budget=0.05, max_terms=12, method="exact")
    b = ssdf_pca.compress_ssdf(cap_maps, error_budget=0.05, max_terms=12, method="randomized")
    np.testing.assert_allclose(b.error_curve, a.error_curve, rtol=1e-3, atol=1e-6)
    assert a.terms == b.terms


def test_pca_extremes_and_round_trip(cap_maps):
    tight = ssdf_pca.compress_ssdf(cap_maps, error_budget=1e-12, max_terms=4)
    assert not tight.budget_met and tight.terms == 4 and np.all(np.isfinite(tight.error_curve))
    full = ssdf_pca.compress_ssdf(cap_maps[:3], error_budget=1e-6, max_terms=10)  # rank 2 after centring
    assert full.error_curve.shape == (10,) and full.error_curve[-1] < 1e-6 and full.terms <= 3
    constant = ssdf_pca.compress_ssdf(np.full((5, 4, 4), HALF_PI, np.float32), error_budget=0.01)
    assert constant.terms == 1 and np.all(constant.reconstruct() == pytest.approx(HALF_PI))
    model = ssdf_pca.compress_ssdf(cap_maps, error_budget=0.05, max_terms=8)
    again = ssdf_pca.SSDFModel.from_arrays(model.arrays(), vertex_count=40)
    assert again.terms == model.terms and again.error_budget == 0.05
    np.testing.assert_array_equal(again.reconstruct(), model.reconstruct())
    bad = dict(model.arrays(), coeffs=np.full_like(model.coeffs, np.nan))
    with pytest.raises(ValueError, match="coeffs"):
        ssdf_pca.SSDFModel.from_arrays(bad)
    with pytest.raises(ValueError, match="mean"):
        ssdf_pca.SSDFModel.from_arrays(dict(model.arrays(), mean=model.mean[:-1]))
    with pytest.raises(ValueError, match="rows"):
        ssdf_pca.SSDFModel.from_arrays(model.arrays(), vertex_count=41)


# ------------------------------------------------------------------------------------------------
# lookups


def test_lookup_at_texel_centres_and_warp_eval(cap_maps, device):
    model = ssdf_pca.compress_ssdf(cap_maps, error_budget=0.02, max_terms=16)
    r = model.resolution
    # at a texel centre the bilinear lookup is that texel of the reconstruction
    dirs = ssdf.texel_directions(r)
    rows = np.repeat(model.coeffs[5:6], dirs.shape[0], axis=0)
    np.testing.assert_allclose(ssdf_products.ssdf_lookup(model, rows, dirs), model.reconstruct([5])[0].ravel(), atol=1e-9)
    # Warp: barycentric blends of three vertices at random directions, some below the horizon
    rng = np.random.default_rng(11)
    p = 500
    ids = rng.integers(0, model.vertex_count, (p, 3))
    ids[:50] = ids[:50, :1]  # single vertices
    w = rng.dirichlet(np.ones(3), p)
    w[:50] = (1.0, 0.0, 0.0)
    d = _unit(rng.normal(size=(p, 3)))
    d[:20, 2] = -np.abs(d[:20, 2])
    blend = np.einsum("pk,pkn->pn", w, model.coeffs[ids].astype(np.float64))
    ref = ssdf_products.ssdf_lookup(model, blend, d)
    got = ssdf_products.evaluate_ssdf_warp(model, ids, w, d, device=device)
    np.testing.assert_allclose(got, ref, atol=ATOL_EVAL_FLOAT32)
    # below the horizon reads the horizon edge
    flat = d[:20].copy()
    flat[:, 2] = 0.0
    np.testing.assert_allclose(ref[:20], ssdf_products.ssdf_lookup(model, blend[:20], flat), atol=1e-12)
    theta, frac = ssdf_products.product_warp(model, ids, w, d, 50.0, device=device)
    ref_frac = ssdf_products.ssdf_product(model, blend, d, 50.0)
    np.testing.assert_allclose(theta, np.clip(ref, -HALF_PI, HALF_PI), atol=ATOL_EVAL_FLOAT32)
    np.testing.assert_allclose(frac, ref_frac, atol=1e-4)


def test_sample_maps_matches_lookup(cap_maps):
    model = ssdf_pca.compress_ssdf(cap_maps, error_budget=1e-9, max_terms=40)  # exact up to float32
    rng = np.random.default_rng(5)
    d = _unit(rng.normal(size=(40, 3)) + (0, 0, 1.5))
    a = ssdf_products.sample_maps(cap_maps, d)
    b = ssdf_products.ssdf_lookup(model, model.coeffs, d)
    np.testing.assert_allclose(b, a, atol=1e-5)


# ------------------------------------------------------------------------------------------------
# the product with an SG lobe (eq. 30-31) against ray tracing


def _visible_quarter_integral(axis_world, lam, nodes=200):
    """``integral G(i; p, lambda, 1)`` over the wall's visible region {x < 0, z > 0}: tensor
    Gauss-Legendre in (z, phi) over z in (0, 1), phi in (pi/2, 3 pi/2), where it is smooth
    (200 nodes agree with 800 to 3e-8 relative for lambda <= 200)."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    z, wz = 0.5 * (x + 1.0), 0.5 * w
    phi, wphi = 0.5 * np.pi * x + np.pi, 0.5 * np.pi * w
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    s = np.sqrt(1.0 - zz * zz)
    d = np.stack([s * np.cos(pp), s * np.sin(pp), zz], -1)
    g = np.exp(lam * (d @ axis_world - 1.0))
    return float(np.einsum("i,j,ij->", wz, wphi, g))


def test_lobe_oracle_against_quadrature(wall_scene, device):
    scene, v = wall_scene
    lam = np.array([10.0, 50.0, 200.0])
    frame = _frame_of(scene, v, device)
    # lobes 45-90 degrees above the horizon, on both sides of the wall's plane
    world = _unit(np.array([[0.0, 0.0, 1.0], [-0.5, 0.2, 0.8], [0.4, -0.3, 0.85], [-0.7, 0.0, 0.72]]))
    axes_local = (world @ frame.T)[None]
    traced = ssdf.trace_lobe_visibility(scene, None, axes_local, lam, samples=4096, vertices=[v], device=device)[0]
    exact = np.array([[_visible_quarter_integral(p, l) for l in lam] for p in world])
    pole = sg.hemisphere_integral(HALF_PI, lam)
    assert np.all(np.abs(traced - exact) <= TOL_ORACLE_FRACTION * pole[None, :])
    # an open sky, axis along the normal: the upper hemisphere, f_h(pi/2, lambda)
    ground_p, ground_f = ground_grid(np.linspace(-1.0, 1.0, 3))
    sky = Scene.from_meshes([Mesh("ground", ground_p, ground_f)])
    open_sky = ssdf.trace_lobe_visibility(sky, None, np.array([[[0.0, 0.0, 1.0]]]), lam, samples=1024, vertices=[4],
                                          device=device)
    # (the lobe's mass below the horizon, e^-lambda of it, falls inside the last of 1024 strata)
    np.testing.assert_allclose(open_sky[0, 0], pole, rtol=1.0 / 1024)


def test_product_against_ray_tracing(wall_scene, device):
    scene, v = wall_scene
    maps = ssdf.bake_ssdf(scene, None, resolution=64, supersample=4, vertices=[v], device=device)
    model = ssdf_pca.compress_ssdf(maps, error_budget=0.01)  # one vertex: the mean is the map
    frame = _frame_of(scene, v, device)
    world = _unit(np.array([[0.0, 0.0, 1.0], [-0.5, 0.2, 0.8], [0.4, -0.3, 0.85], [-0.7, 0.0, 0.72], [0.1, 0.5, 0.85]]))
    axes_local = world @ frame.T
    lam = np.array([10.0, 50.0, 200.0])
    traced = ssdf.trace_lobe_visibility(scene, None, axes_local[None], lam, samples=4096, vertices=[v], device=device)[0]
    rows = np.repeat(model.coeffs, axes_local.shape[0], axis=0)
    for k, l in enumerate(lam):
        approx = ssdf_products.ssdf_integral(model, rows, axes_local, l)
        pole = sg.hemisphere_integral(HALF_PI, l)
        assert np.abs(approx - traced[:, k]).max() / pole <= TOL_PRODUCT_FRACTION
        amp = ssdf_products.ssdf_product(model, rows, axes_local, l, amplitude=2.0)
        np.testing.assert_allclose(amp * pole, 2.0 * approx, rtol=1e-12)  # eq. 31 keeps the integral


def test_product_extreme_sharpness(cap_maps):
    model = ssdf_pca.compress_ssdf(cap_maps, error_budget=0.05)
    rows = model.coeffs[:4]
    d = _unit(np.array([[0.0, 0.0, 1.0], [0.5, 0.0, 0.5], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]))
    for lam in (0.0, 1e-8, 1e4, 1e7):
        out = ssdf_products.ssdf_product(model, rows, d, lam)
        assert np.all(np.isfinite(out)) and np.all(out >= 0.0) and np.all(out <= 2.0 + 1e-12)


def test_sparse_tessellation_misses_the_shadow(device):
    """A floor of two triangles under a small ball: the four corner SSDFs see open sky, so the
    blend at the centre reads visible at the zenith where a vertex there is shadowed. Bounded,
    finite, and wrong -- the tessellation has to sample the visibility signal (sec. 5)."""
    ball = trimesh.creation.icosphere(2, radius=0.15)
    ball_p = np.asarray(ball.vertices) + (0.0, 0.0, 0.5)
    sparse_p, sparse_f = ground_grid(np.array([-1.0, 1.0]))
    dense_p, dense_f = ground_grid(np.linspace(-1.0, 1.0, 5))
    sparse = Scene.from_meshes([Mesh("ground", sparse_p, sparse_f), Mesh("ball", ball_p, ball.faces)])
    dense = Scene.from_meshes([Mesh("ground", dense_p, dense_f), Mesh("ball", ball_p, ball.faces)])
    corners = ssdf.bake_ssdf(sparse, None, resolution=16, supersample=4, vertices=[0, 1, 2, 3], device=device)
    model = ssdf_pca.compress_ssdf(corners, error_budget=1e-4)
    zenith = np.array([[0.0, 0.0, 1.0]])
    blended = ssdf_products.evaluate_ssdf_warp(model, [[0, 3, 3]], [[0.5, 0.5, 0.0]], zenith, device=device)  # the diagonal's midpoint
    centre = int(np.flatnonzero(np.all(dense_p == 0.0, axis=1))[0])
    truth = ssdf.bake_ssdf(dense, None, resolution=16, supersample=4, vertices=[centre], device=device)
    truth_zenith = ssdf_products.sample_maps(truth, zenith)
    assert np.all(np.isfinite(blended)) and abs(float(blended[0])) <= HALF_PI + 1e-6
    assert truth_zenith[0] < 0.0 < blended[0]


# ------------------------------------------------------------------------------------------------
# bad arguments


def test_bad_arguments(wall_scene, cap_maps):
    scene, v = wall_scene
    vis = np.ones((2, 12, 12), bool)
    with pytest.raises(ValueError, match="resolution_out"):
        ssdf.signed_distance(vis, 5)
    with pytest.raises(ValueError, match="resolution_out"):
        ssdf.signed_distance(vis, 1)
    with pytest.raises(ValueError, match="visibility"):
        ssdf.signed_distance(np.full((12, 12), 2), 6)
    with pytest.raises(ValueError, match="visibility"):
        ssdf.signed_distance(np.ones((12, 10)), 2)
    with pytest.raises(ValueError, match="method"):
        ssdf.signed_distance(vis, 6, method="octree")
    with pytest.raises(ValueError, match="error_budget"):
        ssdf_pca.compress_ssdf(cap_maps, error_budget=0.0)
    with pytest.raises(ValueError, match="error_budget"):
        ssdf_pca.compress_ssdf(cap_maps, error_budget=-1.0)
    with pytest.raises(ValueError, match="error_budget"):
        ssdf_pca.compress_ssdf(cap_maps, error_budget=float("nan"))
    with pytest.raises(ValueError, match="max_terms"):
        ssdf_pca.compress_ssdf(cap_maps, max_terms=0)
    with pytest.raises(ValueError, match="maps"):
        ssdf_pca.compress_ssdf(np.full((2, 4, 4), np.nan))
    with pytest.raises(ValueError, match="supersample"):
        ssdf.bake_ssdf(scene, None, resolution=8, supersample=0, vertices=[v])
    with pytest.raises(ValueError, match="resolution"):
        ssdf.bake_visibility(scene, None, resolution=1, vertices=[v])
    with pytest.raises(ValueError, match="vertices"):
        ssdf.bake_visibility(scene, None, resolution=4, vertices=[10**6])
    with pytest.raises(ValueError, match="progress"):
        ssdf.bake_visibility(scene, None, resolution=4, vertices=[v], progress=3)
    model = ssdf_pca.compress_ssdf(cap_maps, error_budget=0.05)
    with pytest.raises(ValueError, match="coeffs_rows"):
        ssdf_products.ssdf_lookup(model, np.zeros((1, model.terms + 1)), [[0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="dirs_local"):
        ssdf_products.ssdf_lookup(model, np.zeros((1, model.terms)), [[0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="sharpness"):
        ssdf_products.ssdf_product(model, np.zeros((1, model.terms)), [[0.0, 0.0, 1.0]], -1.0)
    with pytest.raises(ValueError, match="vertex_ids"):
        ssdf_products.evaluate_ssdf_warp(model, [[0, 0, 99]], [[1.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]])
