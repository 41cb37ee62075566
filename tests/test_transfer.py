"""Ray-traced SH visibility / transfer / AO: the Warp kernel against float64 sums over the same
rays, a float64 brute-force ray caster, closed forms (clamped cosine, spherical-cap occluder),
the local frame, and convergence."""

import numpy as np
import pytest
import trimesh
from grids import ground_grid

from warpshade.basis import sh
from warpshade.geometry._bvh import Visibility, trace_occlusion_f64
from warpshade.scene import Mesh, Scene
from warpshade.transfer import TransferTracer, compute, sample_rays

from tolerances import ATOL_FLOAT32

ORDER = 3
# Brute-force float64 Moller-Trumbore vs Warp's float32 watertight test on the same rays: rays
# grazing an edge may differ; allow one per thousand.
MAX_RAY_DISAGREEMENT = 1e-3
# A randomly rotated Fibonacci set of 4096 points integrates the clamped cosine times order-3
# SH (a kink at the horizon, no jump) very well: measured max error 6.4e-5 over 5 seeds.
TOL_CLAMPED_COSINE_4096 = 3e-4
# Cap-occluder closed forms at 4096 rays: the integrand jumps at the cap edge and at the horizon;
# randomly rotated Fibonacci sets give ~S^-0.75 errors (measured max over 81 receivers and 3
# seeds: 0.012 on v, 0.006 on t, 0.004 on AO), plus a ~5e-4 bias from the faceted sphere
# (icosphere, 4 subdivisions). Values of v and t are ~1.5.
TOL_CAP_V = 0.02
TOL_CAP_T = 0.01
TOL_CAP_AO = 0.007
# Local transfer of a rigidly moved torus at 4096 rays: the world-fixed sample sets see the
# surface from other directions, so only sampling noise differs (measured max 0.0073).
TOL_RIGID_LOCAL_4096 = 0.02
# Error must at least halve when the samples quadruple (MC rate S^-1/2 or better); allow 25%
# for the randomness of a finite set of receivers.
CONVERGENCE_RATIO_MIN = 2.0 * (1.0 - 0.25)

SPHERE_CENTRE = np.array([0.0, 0.0, 1.5])
SPHERE_RADIUS = 0.5


@pytest.fixture(scope="module")
def cap_scene():
    """A wide ground (fine in the middle, coarse outside) under a sphere: every receiver in the
    middle sees the sphere as a cap wholly above its horizon."""
    coords = np.concatenate([[-20.0, -8.0, -4.0], np.linspace(-2.0, 2.0, 17), [4.0, 8.0, 20.0]])
    ground_p, ground_f = ground_grid(coords)
    ball = trimesh.creation.icosphere(4, radius=SPHERE_RADIUS)
    scene = Scene.from_meshes(
        [Mesh("ground", ground_p, ground_f), Mesh("ball", np.asarray(ball.vertices) + SPHERE_CENTRE, ball.faces)]
    )
    receivers = np.where((np.abs(ground_p[:, 0]) <= 1.0) & (np.abs(ground_p[:, 1]) <= 1.0))[0]
    return scene, receivers


@pytest.fixture(scope="module")
def small_scene():
    ball = trimesh.creation.icosphere(1, radius=0.4)
    box = trimesh.creation.box(extents=(0.3, 0.6, 0.2))
    box.apply_translation((0.5, 0.1, 0.35))
    ground_p, ground_f = ground_grid(np.linspace(-1, 1, 6))
    return Scene.from_meshes(
        [
            Mesh("ground", ground_p, ground_f),
            Mesh("ball", np.asarray(ball.vertices) + (0.0, 0.0, 0.5), ball.faces),
            Mesh("box", box.vertices, box.faces),
        ]
    )


def _project_rays(visible, directions, normals, order, frames=None):
    """Float64 sums over given rays: (v, t, ao) per receiver; visible (R, S) bool."""
    s = visible.shape[1]
    d = directions.astype(np.float64)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    local = d if frames is None else np.einsum("rij,rsj->rsi", frames, d)
    y = sh.basis(local, order)  # (R, S, n2)
    cos = np.maximum(np.einsum("rsj,rj->rs", d, normals), 0.0)
    w = 4.0 * np.pi / s
    v = w * np.einsum("rs,rsi->ri", visible, y)
    t = w * np.einsum("rs,rsi->ri", visible * cos, y)
    ao = w * (visible * cos).sum(1) / np.pi
    return v, t, ao


def test_kernel_matches_brute_force_on_the_same_rays(device, small_scene):
    scene = small_scene
    samples = 64
    res = compute(scene, 0.0, ORDER, samples, device=device, seed=7)
    origins, dirs = sample_rays(scene, 0.0, samples, device=device, seed=7)
    bvh = Visibility.from_scene(scene, device=device)
    warp_hit = bvh.occluded(origins.reshape(-1, 3), dirs.reshape(-1, 3)).numpy().reshape(origins.shape[:2]).astype(bool)
    ref_hit = trace_occlusion_f64(scene.points_at(0.0), scene.faces, origins.reshape(-1, 3), dirs.reshape(-1, 3))
    ref_hit = ref_hit.reshape(origins.shape[:2])
    assert 0.2 < ref_hit.mean() < 0.8
    assert np.mean(warp_hit != ref_hit) <= MAX_RAY_DISAGREEMENT
    normals = scene.evaluate(0.0, device=device).normals.numpy().astype(np.float64)
    # The kernel's accumulation equals the float64 projection of its own visibility...
    v, t, ao = _project_rays((~warp_hit).astype(float), dirs, normals, ORDER)
    np.testing.assert_allclose(res.visibility, v, atol=ATOL_FLOAT32)
    np.testing.assert_allclose(res.transfer, t, atol=ATOL_FLOAT32)
    np.testing.assert_allclose(res.ambient_occlusion, ao, atol=ATOL_FLOAT32)
    # ...and the brute-force ray caster's wherever every ray agrees.
    v_ref, t_ref, _ = _project_rays((~ref_hit).astype(float), dirs, normals, ORDER)
    same = ~(warp_hit != ref_hit).any(1)
    np.testing.assert_allclose(res.transfer[same], t_ref[same], atol=ATOL_FLOAT32)
    np.testing.assert_allclose(res.visibility[same], v_ref[same], atol=ATOL_FLOAT32)


def test_unoccluded_receiver_gives_clamped_cosine(device):
    tri = Scene.from_meshes([Mesh("tri", [[0, 0, 0], [1, 0, 0], [0.2, 0.9, 0.4]], [[0, 1, 2]])])
    samples = 4096
    res = compute(tri, 0.0, ORDER, samples, device=device)
    normal = np.cross([1, 0, 0], [0.2, 0.9, 0.4])
    normal /= np.linalg.norm(normal)
    expected = sh.zh_to_sh(normal, sh.clamped_cosine_zh(ORDER, "zh"))
    np.testing.assert_allclose(res.transfer, np.tile(expected, (3, 1)), atol=TOL_CLAMPED_COSINE_4096)
    np.testing.assert_allclose(res.ambient_occlusion, 1.0, atol=TOL_CLAMPED_COSINE_4096)
    # the same rays in float64: the kernel adds exactly the upper hemisphere
    _, dirs = sample_rays(tri, 0.0, samples, device=device)
    _, t, _ = _project_rays(np.ones(dirs.shape[:2]), dirs, np.tile(normal, (3, 1)), ORDER)
    np.testing.assert_allclose(res.transfer, t, atol=ATOL_FLOAT32)


def _cap_oracle(scene, receivers, offset, order):
    """Closed-form v, t, AO of ground receivers (normal +z) under the sphere, ground below."""
    origin = scene.points_at(0.0)[receivers] + (0.0, 0.0, offset)
    to_c = SPHERE_CENTRE - origin
    dist = np.linalg.norm(to_c, axis=1)
    axis = to_c / dist[:, None]
    alpha = np.arcsin(SPHERE_RADIUS / dist)
    up = np.array([0.0, 0.0, 1.0])
    assert np.all(np.arccos(axis[:, 2]) + alpha < np.pi / 2)  # caps wholly above the horizon
    v = sh.zh_to_sh(up, sh.cap_zh(np.pi / 2, order)) - sh.zh_to_sh(axis, sh.cap_zh(alpha, order))
    ao = 1.0 - np.sin(alpha) ** 2 * axis[:, 2]
    # t = clamped cosine minus the cap's integral of cos * y: Gauss-Legendre in the cap's own
    # polar angle (the integrand is a polynomial there) -- exact to rounding.
    z, wz = np.polynomial.legendre.leggauss(16)
    phi = (np.arange(32) + 0.5) * (2 * np.pi / 32)
    t = np.empty((len(receivers), order * order))
    for k in range(len(receivers)):
        c = np.cos(alpha[k])
        zc = 0.5 * (1 - c) * z + 0.5 * (1 + c)
        e1 = np.cross(axis[k], [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis[k], e1)
        rr = np.sqrt(1 - zc**2)[:, None, None]
        dirs = rr * (np.cos(phi)[None, :, None] * e1 + np.sin(phi)[None, :, None] * e2) + zc[:, None, None] * axis[k]
        weights = (0.5 * (1 - c) * wz)[:, None] * np.full(32, 2 * np.pi / 32)[None, :]
        cap = np.einsum("ab,ab,abi->i", weights, dirs[..., 2], sh.basis(dirs, order))
        t[k] = sh.zh_to_sh(up, sh.clamped_cosine_zh(order, "zh")) - cap
    return v, t, ao


def test_spherical_cap_occluder_closed_form(device, cap_scene):
    scene, receivers = cap_scene
    res = compute(scene, 0.0, ORDER, 4096, device=device, vertices=receivers)
    v, t, ao = _cap_oracle(scene, receivers, res.offset, ORDER)
    assert np.abs(res.visibility - v).max() < TOL_CAP_V
    assert np.abs(res.transfer - t).max() < TOL_CAP_T
    assert np.abs(res.ambient_occlusion - ao).max() < TOL_CAP_AO
    assert ao.min() < 0.92  # the occluder matters


def test_local_frame_rotates_the_world_vectors(device, small_scene):
    scene = small_scene
    world = compute(scene, 0.0, ORDER, 128, device=device, seed=3)
    tracer = TransferTracer(scene, ORDER, 128, space="local", device=device, seed=3)
    tracer.trace(0.0)
    local = tracer.result()
    frames = tracer.tangent_frames.frames.numpy().astype(np.float64)
    # identical rays, so sample by sample y(F s) = D(F) y(s): local = D(F) world
    np.testing.assert_allclose(local.transfer, sh.rotate(world.transfer, frames), atol=ATOL_FLOAT32)
    np.testing.assert_allclose(local.visibility, sh.rotate(world.visibility, frames), atol=ATOL_FLOAT32)
    np.testing.assert_array_equal(local.ambient_occlusion, world.ambient_occlusion)


def test_local_transfer_is_invariant_under_rigid_motion(device):
    """A self-shadowing torus turned rigidly keeps its local transfer (up to sampling noise),
    while its world transfer turns with it: what local deformable PRT relies on."""
    from scipy.spatial.transform import Rotation

    torus = trimesh.creation.torus(1.0, 0.35, major_sections=24, minor_sections=12)
    transforms = np.stack([np.eye(4), np.eye(4)])
    transforms[1, :3, :3] = Rotation.from_euler("xyz", [0.8, -0.4, 1.3]).as_matrix().T  # row vectors
    transforms[1, 3, :3] = (0.5, -1.0, 2.0)
    scene = Scene.from_meshes([Mesh("torus", torus.vertices, torus.faces, animation="rigid", transforms=transforms)], frames=[0.0, 1.0])
    before = compute(scene, 0.0, ORDER, 4096, space="local", device=device)
    after = compute(scene, 1.0, ORDER, 4096, space="local", device=device)
    assert before.ambient_occlusion.min() < 0.75  # it does shadow itself
    assert np.abs(after.transfer - before.transfer).max() < TOL_RIGID_LOCAL_4096
    world_before = compute(scene, 0.0, ORDER, 4096, device=device)
    world_after = compute(scene, 1.0, ORDER, 4096, device=device)
    assert np.abs(world_after.transfer - world_before.transfer).max() > 0.5


def test_receiver_subsets_and_chunking_do_not_change_results(device, small_scene):
    full = compute(small_scene, 0.0, ORDER, 64, device=device, workers=1)
    chunked = TransferTracer(small_scene, ORDER, 64, device=device, workers=2, chunks=5, chunk_min_rays=0)
    chunked.trace(0.0)
    np.testing.assert_array_equal(full.transfer, chunked.result().transfer)
    pick = np.array([40, 3, 17, 3])
    sub = compute(small_scene, 0.0, ORDER, 64, device=device, vertices=pick)
    np.testing.assert_array_equal(sub.vertices, pick)
    np.testing.assert_array_equal(sub.visibility, full.visibility[pick])
    np.testing.assert_array_equal(sub.ambient_occlusion, full.ambient_occlusion[pick])


def test_visible_fraction_counts_the_same_rays(device, small_scene):
    tracer = TransferTracer(small_scene, 1, 64, device=device)
    tracer.trace(0.0)
    state = small_scene.evaluate(0.0, device=device)
    fraction = tracer.visible_fraction(state.points, state.normals)
    y00 = 0.5 / np.sqrt(np.pi)
    np.testing.assert_allclose(tracer.result().visibility[:, 0], fraction * 4 * np.pi * y00, atol=ATOL_FLOAT32)


def test_per_frame_refit_matches_fresh_compute(device):
    grid_p, grid_f = ground_grid(np.linspace(-1, 1, 5))
    ball = trimesh.creation.icosphere(1, radius=0.3)
    frames = np.array([0.0, 1.0])
    samples_pts = np.stack([np.asarray(ball.vertices) + (0, 0, 0.5), np.asarray(ball.vertices) * 1.3 + (0.4, 0, 0.6)])
    scene = Scene.from_meshes(
        [Mesh("ground", grid_p, grid_f), Mesh("blob", ball.vertices, ball.faces, animation="deforming", point_samples=samples_pts)],
        frames=frames,
    )
    tracer = TransferTracer(scene, ORDER, 64, device=device)
    tracer.trace(0.0)
    first = tracer.result()
    tracer.trace(1.0)
    second = tracer.result()
    np.testing.assert_array_equal(second.transfer, compute(scene, 1.0, ORDER, 64, device=device).transfer)
    assert np.abs(second.transfer - first.transfer).max() > 0.1  # the blob moved


def test_transfer_converges_as_samples_quadruple(device, cap_scene):
    scene, receivers = cap_scene
    ref = compute(scene, 0.0, ORDER, 16384, device=device, vertices=receivers, seed=99).transfer
    errors = [
        np.sqrt(np.mean((compute(scene, 0.0, ORDER, s, device=device, vertices=receivers, seed=1).transfer - ref) ** 2))
        for s in (64, 256, 1024)
    ]
    assert errors[0] / errors[1] >= CONVERGENCE_RATIO_MIN
    assert errors[1] / errors[2] >= CONVERGENCE_RATIO_MIN


def test_bad_arguments_are_reported(small_scene):
    with pytest.raises(ValueError, match="order"):
        compute(small_scene, 0.0, 0, 16)
    with pytest.raises(ValueError, match="samples"):
        compute(small_scene, 0.0, 2, 0)
    with pytest.raises(ValueError, match="space"):
        compute(small_scene, 0.0, 2, 16, space="tangent")
    with pytest.raises(ValueError, match="vertices"):
        compute(small_scene, 0.0, 2, 16, vertices=[small_scene.vertex_count])
    with pytest.raises(ValueError, match="frame"):
        compute(small_scene, 0.5, 2, 16)


def test_visibility_open_below_the_horizon(device):
    """below_horizon="visible": a convex ball (which only occludes itself) has V = 1 exactly in
    every direction -- its SH projection is the constant's, up to the Fibonacci quadrature error --
    while transfer and ambient occlusion, which carry the cosine, do not change."""
    ball = trimesh.creation.icosphere(2, radius=1.0)
    scene = Scene.from_meshes([Mesh("ball", ball.vertices, ball.faces)])
    traced = compute(scene, 0.0, 4, 1024, space="local", device=device)
    open_ = compute(scene, 0.0, 4, 1024, space="local", device=device, below_horizon="visible")
    const = np.zeros(16)
    const[0] = np.sqrt(4 * np.pi)
    np.testing.assert_allclose(open_.visibility, np.broadcast_to(const, open_.visibility.shape), atol=0.02)
    # traced: the upper hemisphere (DC sqrt(pi)) plus the grazing rays that slip past the facets
    assert traced.visibility[:, 0].max() < 0.7 * np.sqrt(4 * np.pi)
    np.testing.assert_array_equal(open_.transfer, traced.transfer)
    np.testing.assert_array_equal(open_.ambient_occlusion, traced.ambient_occlusion)
    with pytest.raises(ValueError, match="below_horizon"):
        compute(scene, 0.0, 2, 16, below_horizon="open", device=device)
