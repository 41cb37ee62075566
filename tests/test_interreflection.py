"""Diffuse interreflection: transfer with k bounces and the k-bounce path-traced reference.

Oracles: an integrating sphere (a spherical cavity with a circular opening under a constant
sky), whose multi-bounce radiance has a closed form from the sphere's constant form factor, with
the opening's view factor per vertex from Lambert's polygon formula (float64); k = 0 against
the direct transfer and reference; transfer against the reference on an open box corner; the
geometric series of the bounces; and the failure cases (albedo 0 and 1, back faces, degenerate
triangles, bad arguments)."""

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from grids import ground_grid
from hang import HANG_S

from warpshade.basis import quadrature
from warpshade.geometry._bvh import Visibility
from warpshade.reference import ReferenceShader, shade
from warpshade.scene import Environment, Mesh, Scene
from warpshade.transfer import MAX_BOUNCES, InterreflectionTracer, compute, sample_rays

from tolerances import ATOL_FLOAT32

ROOT = Path(__file__).resolve().parents[1]
Y00 = 0.5 / np.sqrt(np.pi)
RHO = np.array([0.9, 0.6, 0.3])
CAVITY_OPENING = np.pi / 4  # polar angle of the rim: the opening is ~14.6% of the sphere
CAVITY_SEGMENTS = 64
CAVITY_RINGS = 16

# Cavity, transfer at 2048 rays: the rotated Fibonacci sets cut the opening's sharp rim with an
# error of up to 0.0092 per vertex (radiance ~0.13-0.26 under a unit sky; measured over k = 0, 3
# and seeds 0-5), while the error of the mean over ~1000 vertices stays below 3.4e-4.
TOL_CAVITY_TRANSFER_MAX = 0.012
TOL_CAVITY_TRANSFER_MEAN = 1.0e-3
# Cavity, reference: each value within Z_SCORE reported standard errors (16 replicates: Student's
# t with 15 degrees of freedom, P(|t| > 6) ~ 2e-5 per value), and the mean error over receivers
# within MEAN_Z_SCORE standard errors of the mean plus the closed form's own error (the wall's
# radiance is taken as uniform, while the view factor of the polygonal opening varies by 1% over
# the wall: ~2e-4 on the mean).
Z_SCORE = 6.0
MEAN_Z_SCORE = 4.0
UNIFORM_WALL_SLACK = 3.0e-4
# float32 accumulation vs an exactly representable value.
RTOL_FLOAT32 = 2e-6
# The same rays through two BVHs over the same non-degenerate triangles (one with zero-area
# triangles added): the hits agree, the sums may round differently.
ATOL_SAME_RAYS = 1e-5
# Box corner, transfer (mean of 4 seeds, their spread as noise) vs reference (its stderr): the
# relative RMS difference must be explained by the two noise levels (1.25x for the finite
# number of vertices), plus the interpolation bias of per-vertex transfer at the hit points
# (the path tracer evaluates hits exactly): measured +0.27% on the mean at 12 cells per side,
# falling as h^2 (1.0% at 6, 0.05% at 24).
NOISE_FACTOR = 1.25
INTERPOLATION_SLACK = 0.005
MAX_MEAN_DIFFERENCE = 0.006
# Reported stderr^2 vs the variance across 12 seeds (as tests/test_reference.py): ~100
# receivers x 11 degrees of freedom pooled.
VARIANCE_RATIO_RANGE = (0.7, 1.4)


# ---- scenes and oracles ----------------------------------------------------------------------


def cavity_mesh(opening=CAVITY_OPENING, segments=CAVITY_SEGMENTS, rings=CAVITY_RINGS):
    """A unit UV sphere with the cap above polar angle ``opening`` removed, faces turned inward.

    A thin first ring (0.5 degrees) keeps the rim's vertices, whose transfer sees half the sky,
    out of the wall's interpolation. Returns (points (V, 3), faces (F, 3), rim vertex indices)."""
    thetas = np.concatenate([[opening, opening + np.radians(0.5)], np.linspace(opening, np.pi, rings + 1)[1:-1]])
    phi = np.arange(segments) * 2 * np.pi / segments
    rows = [np.stack([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.full(segments, np.cos(t))], 1) for t in thetas]
    points = np.concatenate(rows + [[[0.0, 0.0, -1.0]]])
    ring = np.arange(segments)
    faces = []
    for i in range(len(thetas) - 1):
        a, b = i * segments + ring, i * segments + (ring + 1) % segments
        c, d = a + segments, b + segments
        faces += [np.stack([a, b, c], 1), np.stack([b, d, c], 1)]  # e_phi x e_theta = -e_r: inward
    last = (len(thetas) - 1) * segments
    faces.append(np.stack([last + ring, last + (ring + 1) % segments, np.full(segments, len(points) - 1)], 1))
    return points, np.concatenate(faces), ring


def polygon_view_factor(points, normals, polygon):
    """(1/pi) * integral of max(0, n.s) over the planar polygon seen from each point (Lambert's
    formula, float64); the polygon must lie wholly above each point's horizon."""
    u = polygon[None] - points[:, None]
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    w = np.roll(u, -1, axis=1)
    g = np.cross(u, w)
    g /= np.linalg.norm(g, axis=-1, keepdims=True)
    angle = np.arccos(np.clip(np.sum(u * w, -1), -1.0, 1.0))
    return np.abs(0.5 * np.sum(angle * np.einsum("rkj,rj->rk", g, normals), 1)) / np.pi


def cavity_view_factors(points, normals, faces, rim):
    """Per-vertex view factor F of the opening, and the wall's mean F (area-weighted) as the
    per-vertex transfer sees it (F of the vertices, linearly interpolated) and as a path tracer
    sees it (F at points inside the facets, with interpolated shading normals)."""
    on_rim = np.zeros(len(points), bool)
    on_rim[rim] = True
    view = np.empty(len(points))
    view[~on_rim] = polygon_view_factor(points[~on_rim], normals[~on_rim], points[rim])
    view[on_rim] = 0.5 * (1.0 + normals[on_rim, 2])  # a rim vertex sees the half-space above the rim
    area = 0.5 * np.linalg.norm(np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]]), axis=1)
    interpolated = np.sum(area * view[faces].mean(1)) / area.sum()
    m = 6  # centroids of the m*m sub-triangles of each facet
    bary = [[(i + 1 / 3) / m, (j + 1 / 3) / m] for i in range(m) for j in range(m - i)]
    bary += [[(i + 2 / 3) / m, (j + 2 / 3) / m] for i in range(m) for j in range(m - i - 1)]
    bary = np.array([[a, b, 1.0 - a - b] for a, b in bary])
    q = np.einsum("sk,fkj->fsj", bary, points[faces]).reshape(-1, 3)
    nq = np.einsum("sk,fkj->fsj", bary, normals[faces]).reshape(-1, 3)
    nq /= np.linalg.norm(nq, axis=1, keepdims=True)
    exact = np.sum(area * polygon_view_factor(q, nq, points[rim]).reshape(len(faces), -1).mean(1)) / area.sum()
    return view, interpolated, exact


def cavity_radiance(view, wall_view, albedo, sky, bounces):
    """Closed form after k bounces, wall radiance uniform: W_b = rho (L f + (1 - f) W_{b-1}),
    L_o(x) = rho (L F_x + (1 - F_x) W_{k-1}), W_{-1} = 0 (the sphere's form factor from any point
    to a wall element is dA / (4 pi R^2), so the rest of the hemisphere sees the wall uniformly)."""
    wall = np.zeros(3)
    for _ in range(bounces):
        wall = albedo * (sky * wall_view + (1.0 - wall_view) * wall)
    return albedo * (sky * view[:, None] + (1.0 - view[:, None]) * wall)


@pytest.fixture(scope="module")
def cavity():
    points, faces, rim = cavity_mesh()
    scene = Scene.from_meshes([Mesh("cavity", points, faces, albedo=RHO)])
    normals = scene.evaluate(0.0, device="cpu").normals.numpy().astype(np.float64)
    view, wall_interpolated, wall_exact = cavity_view_factors(points, normals, faces, rim)
    receivers = np.arange(2 * CAVITY_SEGMENTS, scene.vertex_count)  # not the rim and its thin ring
    return scene, receivers, view, wall_interpolated, wall_exact


def plate(origin, e1, e2, cells, albedo):
    """A square plate origin + [0,1] e1 + [0,1] e2 facing e1 x e2, ``cells`` per side."""
    p, f = ground_grid(np.linspace(0.0, 1.0, cells + 1))
    return Mesh(f"plate{np.round(origin, 2)}", origin + p[:, :1] * e1 + p[:, 1:2] * e2, f, albedo=albedo)


def corner_scene(cells=12):
    """An open box corner: a floor and two walls, each 0.05 clear of the others so that no vertex
    lies on another surface (a vertex on a touching plate is self-occluded, and interpolating its
    dark transfer across the adjacent triangles is a bias the path tracer does not have)."""
    x, y, z = np.eye(3)
    gap = 0.05
    return Scene.from_meshes([
        plate(np.zeros(3), x, y, cells, (0.8, 0.8, 0.8)),
        plate(gap * (y + z), y, z, cells, (0.85, 0.3, 0.25)),
        plate(gap * (z + x), z, x, cells, (0.25, 0.5, 0.85)),
    ])


def gradient_sky():
    """A smooth sky linear in the direction (SH order 2 up to the bilinear texel lookup)."""
    d = quadrature.latlong_directions(64, 128)
    image = (0.6 + 0.4 * d[..., 2:3]) * np.array([0.9, 1.0, 1.1]) + 0.2 * d[..., 0:1]
    return Environment(image.astype(np.float32))


def shaded(result, albedo, light_sh):
    """rho_c / pi * dot(L_c, t_c), float64, shape (receiver_count, 3)."""
    return albedo / np.pi * np.einsum("vci,ci->vc", result.per_channel().astype(np.float64), light_sh)


def constant_sky_radiance(result, albedo, sky=1.0):
    """Outgoing radiance under a constant sky: only the DC transfer counts (L_00 = sky / Y00)."""
    return albedo / np.pi * result.per_channel()[:, :, 0].astype(np.float64) * (sky / Y00)


# ---- (a) closed form -------------------------------------------------------------------------


def test_integrating_sphere_transfer_closed_form(device, cavity):
    scene, receivers, view, wall_interpolated, _ = cavity
    for bounces in (0, 1, 3):
        res = compute(scene, 0.0, 1, 2048, device=device, bounces=bounces, seed=1)
        got = constant_sky_radiance(res, RHO)[receivers]
        exact = cavity_radiance(view, wall_interpolated, RHO, 1.0, bounces)[receivers]
        assert np.abs(got - exact).max() < TOL_CAVITY_TRANSFER_MAX, bounces
        assert np.abs((got - exact).mean(0)).max() < TOL_CAVITY_TRANSFER_MEAN, bounces
    # three bounces are a visible part of the answer
    assert (exact - cavity_radiance(view, wall_interpolated, RHO, 1.0, 0)[receivers]).mean() > 0.05


def test_integrating_sphere_reference_closed_form(device, cavity):
    scene, receivers, view, _, wall_exact = cavity
    env = Environment.constant((1.0, 1.0, 1.0))
    pick = receivers[::3]
    for bounces, method in ((1, "mis"), (3, "cosine")):
        res = shade(scene, 0.0, env, 1024, device=device, method=method, vertices=pick, bounces=bounces, seed=4)
        exact = cavity_radiance(view, wall_exact, RHO, 1.0, bounces)[pick]
        err = res.radiance - exact
        assert np.all(np.abs(err) <= Z_SCORE * res.stderr + RTOL_FLOAT32), (bounces, method)
        mean_noise = np.sqrt(np.mean(res.stderr.astype(np.float64) ** 2, 0) / len(pick))
        assert np.all(np.abs(err.mean(0)) <= MEAN_Z_SCORE * mean_noise + UNIFORM_WALL_SLACK), (bounces, method)
    assert res.bounces == 3 and "bounces=3" in repr(res)


def test_white_integrating_sphere_converges_to_the_sky(device, cavity):
    """Albedo 1 (a white furnace with an opening): k bounces give about L (1 - (1 - f)^(k+1)),
    bounded by the sky's radiance and finite."""
    scene, receivers, view, wall_interpolated, _ = cavity
    white = np.ones(3)
    bounces = 24
    res = compute(scene, 0.0, 1, 512, device=device, bounces=bounces, albedo=white)
    got = constant_sky_radiance(res, white)[receivers]
    exact = cavity_radiance(view, wall_interpolated, white, 1.0, bounces)[receivers]
    assert np.all(np.isfinite(res.transfer_rgb))
    assert exact.min() > 0.97  # (1 - 0.146)^25 ~ 0.02
    assert np.abs(got - exact).max() < TOL_CAVITY_TRANSFER_MAX


# ---- the kernel against float64 sums over the same rays ---------------------------------------


def test_bounce_matches_a_float64_gather_over_the_same_rays(device):
    """One bounce = t0 + (4 / S) sum over rays above the horizon that hit a front face of
    rho(q) cos t0(q), with q's albedo and t0 interpolated by the hit's barycentrics (float64)."""
    scene = corner_scene(6)
    order, samples = 3, 64
    res = compute(scene, 0.0, order, samples, device=device, bounces=1, seed=5)
    t0 = res.transfer.astype(np.float64)
    origins, dirs = sample_rays(scene, 0.0, samples, device=device, seed=5)
    hits = Visibility.from_scene(scene, device=device).closest_hits(origins.reshape(-1, 3), dirs.reshape(-1, 3))
    normals = scene.evaluate(0.0, device=device).normals.numpy().astype(np.float64)
    cos = np.einsum("vsj,vj->vs", dirs.astype(np.float64), normals).reshape(-1)
    front = (hits["face"] >= 0) & (hits["cosine"] < 0.0) & (cos > 0.0)
    assert 0.1 < front.mean() < 0.5
    corners = scene.faces[hits["face"][front]]  # (H, 3)
    u, v = hits["bary"][front, 0].astype(np.float64), hits["bary"][front, 1].astype(np.float64)
    weights = np.stack([u, v, 1.0 - u - v], 1)
    albedo = np.einsum("hk,hkc->hc", weights, scene.albedo.astype(np.float64)[corners])
    gathered = np.einsum("hk,hki->hi", weights, t0[corners])
    receiver = np.repeat(np.arange(scene.vertex_count), samples)[front]
    expected = np.repeat(t0[:, None], 3, 1)
    np.add.at(expected, receiver, (4.0 / samples) * (albedo * cos[front][:, None])[:, :, None] * gathered[:, None, :])
    np.testing.assert_allclose(res.transfer_rgb, expected, atol=ATOL_FLOAT32)


# ---- (b) k = 0 -------------------------------------------------------------------------------


def test_zero_bounces_is_the_direct_transfer(device):
    scene = corner_scene(4)
    direct = compute(scene, 0.0, 3, 64, device=device, seed=2)
    assert direct.transfer_rgb is None and direct.bounces == 0
    np.testing.assert_array_equal(direct.per_channel(), np.repeat(direct.transfer[:, None], 3, 1))
    tracer = InterreflectionTracer(scene, 3, 64, 0, device=device, seed=2, vertices=[3, 1, 40])
    tracer.trace(0.0)
    res = tracer.result()
    assert res.bounces == 0
    np.testing.assert_array_equal(res.transfer_rgb, np.repeat(direct.transfer[[3, 1, 40], None], 3, 1))
    np.testing.assert_array_equal(res.visibility, direct.visibility[[3, 1, 40]])
    # the bounces keep the direct quantities as they are
    bounced = compute(scene, 0.0, 3, 64, device=device, seed=2, bounces=2)
    np.testing.assert_array_equal(bounced.transfer, direct.transfer)
    np.testing.assert_array_equal(bounced.ambient_occlusion, direct.ambient_occlusion)
    assert np.abs(bounced.transfer_rgb - bounced.per_channel()).max() == 0.0


def test_bounces_add_nothing_where_no_ray_hits(device):
    """A convex ball (no ray above a vertex's horizon hits the ball) and the direct part's
    random streams: every bounce count gives bit-identical transfer and reference."""
    import trimesh

    ball = trimesh.creation.icosphere(2, radius=1.0)
    scene = Scene.from_meshes([Mesh("ball", ball.vertices, ball.faces, albedo=RHO)])
    sky = gradient_sky()
    ref0 = shade(scene, 0.0, sky, 64, device=device, seed=3)
    t0 = compute(scene, 0.0, 3, 64, device=device)
    for bounces in (1, 4):
        ref = shade(scene, 0.0, sky, 64, device=device, seed=3, bounces=bounces)
        np.testing.assert_array_equal(ref.radiance, ref0.radiance)
        np.testing.assert_array_equal(ref.stderr, ref0.stderr)
        np.testing.assert_array_equal(compute(scene, 0.0, 3, 64, device=device, bounces=bounces).transfer_rgb, t0.per_channel())


# ---- (c) transfer vs reference ---------------------------------------------------------------


def test_interreflected_transfer_matches_the_reference(device):
    scene = corner_scene(12)
    sky = gradient_sky()
    order = 3
    light_sh = sky.to_sh(order)
    albedo = scene.albedo.astype(np.float64)
    direct_ref = shade(scene, 0.0, sky, 1024, device=device, seed=8)
    for bounces in (1, 2):
        runs = np.stack([shaded(compute(scene, 0.0, order, 1024, device=device, bounces=bounces, seed=s), albedo, light_sh)
                         for s in range(4)])
        ours, ours_noise = runs.mean(0), runs.std(0, ddof=1) / 2.0
        ref = shade(scene, 0.0, sky, 1024, device=device, bounces=bounces, seed=8)
        scale = np.sqrt(np.mean(ref.radiance.astype(np.float64) ** 2))
        diff = ours - ref.radiance
        noise = np.sqrt(np.mean(ref.stderr.astype(np.float64) ** 2 + ours_noise**2))
        rel_rms = np.sqrt(np.mean(diff**2)) / scale
        assert rel_rms < NOISE_FACTOR * noise / scale + INTERPOLATION_SLACK, bounces
        assert abs(diff.mean() / ref.radiance.mean()) < MAX_MEAN_DIFFERENCE, bounces
        # the bounces are a large part of the answer: losing a fifth of them would fail the mean
        indirect = ref.radiance - direct_ref.radiance
        assert indirect.mean() > 5.0 * MAX_MEAN_DIFFERENCE * ref.radiance.mean(), bounces


def test_reference_stderr_with_bounces_matches_spread_across_seeds(device):
    scene = corner_scene(6)
    sky = gradient_sky()
    pick = np.arange(0, scene.vertex_count, 1)
    runs = [shade(scene, 0.0, sky, 64, device=device, bounces=2, seed=s, vertices=pick) for s in range(12)]
    values = np.stack([r.radiance for r in runs]).astype(np.float64)
    reported = np.stack([r.stderr for r in runs]).astype(np.float64) ** 2
    ratio = values.var(axis=0, ddof=1).sum() / reported.mean(axis=0).sum()
    assert VARIANCE_RATIO_RANGE[0] < ratio < VARIANCE_RATIO_RANGE[1]


# ---- (d) energy ------------------------------------------------------------------------------


def test_more_bounces_never_darken_and_converge_geometrically(device):
    scene = corner_scene(8)
    albedo = scene.albedo.astype(np.float64)
    samples = 256
    radiance = np.stack([constant_sky_radiance(compute(scene, 0.0, 2, samples, device=device, bounces=k), albedo)
                         for k in range(7)])
    steps = np.diff(radiance, axis=0)
    assert steps.min() >= -RTOL_FLOAT32 * radiance.max()
    # |t^(b+1) - t^(b)| <= rho_max * c_max * |t^(b) - t^(b-1)|, c the cosine quadrature of the rays
    normals = scene.evaluate(0.0, device=device).normals.numpy().astype(np.float64)
    _, dirs = sample_rays(scene, 0.0, samples, device=device)
    c_max = (4.0 / samples * np.maximum(np.einsum("vsj,vj->vs", dirs, normals), 0.0).sum(1)).max()
    bound = albedo.max() * c_max
    per_step = steps.max(axis=(1, 2))
    assert per_step[0] > 0.05  # the first bounce is substantial
    assert np.all(per_step[1:] <= bound * per_step[:-1] * (1.0 + 1e-5))
    assert per_step[-1] < 0.1 * per_step[0]  # converging
    # the reference with the same seed reuses its paths: sample by sample, more bounces add light
    sky = Environment.constant((1.0, 1.0, 1.0))
    previous = None
    for k in range(4):
        ref = shade(scene, 0.0, sky, 64, device=device, method="cosine", bounces=k, seed=6).radiance
        if previous is not None:
            assert np.all(ref >= previous * (1.0 - RTOL_FLOAT32))
        previous = ref


# ---- (e) failure cases -----------------------------------------------------------------------


def test_black_surfaces_reflect_nothing(device):
    scene = corner_scene(4)
    black = Scene.from_meshes([replace(m, albedo=(0.0, 0.0, 0.0)) for m in scene.meshes])
    res = compute(scene, 0.0, 3, 64, device=device, bounces=3, albedo=np.zeros(3))
    np.testing.assert_array_equal(res.transfer_rgb, np.repeat(res.transfer[:, None], 3, 1))
    sky = gradient_sky()
    # a black receiver reflects nothing at all; a white receiver among black walls only direct light
    assert np.all(shade(black, 0.0, sky, 64, device=device, bounces=3).radiance == 0.0)
    partly = Scene.from_meshes([replace(scene.meshes[0])] + [replace(m, albedo=(0.0, 0.0, 0.0)) for m in scene.meshes[1:]])
    floor = np.arange(scene.meshes[0].vertex_count)
    direct = shade(partly, 0.0, sky, 64, device=device, vertices=floor, seed=1)
    bounced = shade(partly, 0.0, sky, 64, device=device, vertices=floor, seed=1, bounces=3)
    np.testing.assert_array_equal(bounced.radiance, direct.radiance)


def test_closed_white_sphere_stays_dark_and_finite(device):
    """Albedo 1 inside a closed sphere: no light gets in, however many bounces."""
    points, faces, ring = cavity_mesh(opening=1e-3, segments=16, rings=8)
    north = len(points)
    cap = np.stack([ring, np.full(16, north), (ring + 1) % 16], 1)  # closes the pinhole, inward
    closed = Mesh("sphere", np.vstack([points, [[0.0, 0.0, 1.0]]]), np.concatenate([faces, cap]), albedo=(1.0, 1.0, 1.0))
    scene = Scene.from_meshes([closed])
    res = compute(scene, 0.0, 2, 256, device=device, bounces=8)
    assert np.all(np.isfinite(res.transfer_rgb)) and np.abs(res.transfer_rgb).max() < 1e-3
    ref = shade(scene, 0.0, Environment.constant((1.0, 1.0, 1.0)), 64, device=device, bounces=8)
    assert np.all(np.isfinite(ref.radiance)) and ref.radiance.max() < 1e-3


def test_back_faces_reflect_nothing(device):
    ground_p, ground_f = ground_grid(np.linspace(-1.0, 1.0, 6))
    roof_p, roof_f = ground_grid(np.linspace(-0.6, 0.6, 4))
    roof_p = roof_p + (0.0, 0.0, 0.4)
    facing_up = Scene.from_meshes([Mesh("ground", ground_p, ground_f), Mesh("roof", roof_p, roof_f)])
    facing_down = Scene.from_meshes([Mesh("ground", ground_p, ground_f), Mesh("roof", roof_p, roof_f[:, ::-1])])
    ground = np.arange(len(ground_p))
    sky = Environment.constant((1.0, 1.0, 1.0))
    up = compute(facing_up, 0.0, 2, 256, device=device, bounces=2, vertices=ground)
    np.testing.assert_array_equal(up.transfer_rgb, np.repeat(up.transfer[:, None], 3, 1))
    np.testing.assert_array_equal(shade(facing_up, 0.0, sky, 64, device=device, bounces=2, vertices=ground, seed=2).radiance,
                                  shade(facing_up, 0.0, sky, 64, device=device, vertices=ground, seed=2).radiance)
    down = compute(facing_down, 0.0, 2, 256, device=device, bounces=2, vertices=ground)
    assert (down.transfer_rgb[:, :, 0] - down.transfer[:, None, 0]).max() > 0.1  # the lit underside reflects


def test_degenerate_triangles_are_bounded(device):
    """Zero-area triangles (collinear points, repeated indices) are never hit and give finite
    values at their own vertices; every other vertex keeps its transfer."""
    scene = corner_scene(4)
    floor = replace(scene.meshes[0], faces=np.concatenate([scene.meshes[0].faces, [[3, 3, 3], [5, 6, 5]]]))
    slivers = Mesh("slivers", [[0.5, 0.5, 0.3], [0.7, 0.5, 0.3], [0.9, 0.5, 0.3]], [[0, 1, 2], [0, 0, 1]], albedo=(0.8, 0.8, 0.8))
    broken = Scene.from_meshes([floor] + [replace(m) for m in scene.meshes[1:]] + [slivers])  # copies: a scene sets offsets
    res = compute(broken, 0.0, 3, 128, device=device, bounces=3)
    assert np.all(np.isfinite(res.transfer_rgb))
    assert constant_sky_radiance(res, broken.albedo).max() <= 1.0 + 1e-3  # albedo <= 1 under a unit sky
    base = compute(scene, 0.0, 3, 128, device=device, bounces=3)
    np.testing.assert_allclose(res.transfer_rgb[: scene.vertex_count], base.transfer_rgb, atol=ATOL_SAME_RAYS)
    ref = shade(broken, 0.0, gradient_sky(), 64, device=device, bounces=3)
    assert np.all(np.isfinite(ref.radiance)) and np.all(np.isfinite(ref.stderr))


def test_subsets_and_chunks_do_not_change_the_bounces(device):
    scene = corner_scene(6)
    full = compute(scene, 0.0, 3, 128, device=device, bounces=2, workers=1)
    chunked = InterreflectionTracer(scene, 3, 128, 2, device=device, workers=2, chunks=7, chunk_min_rays=0)
    chunked.trace(0.0)
    np.testing.assert_array_equal(chunked.result().transfer_rgb, full.transfer_rgb)
    pick = np.array([40, 3, 17, 3])
    sub = compute(scene, 0.0, 3, 128, device=device, bounces=2, vertices=pick, progress=True)
    np.testing.assert_array_equal(sub.transfer_rgb, full.transfer_rgb[pick])
    np.testing.assert_array_equal(sub.transfer, full.transfer[pick])


def test_bad_arguments_are_reported(device):
    scene = corner_scene(2)
    for bad in (-1, 1.5, MAX_BOUNCES + 1, True):
        with pytest.raises(ValueError, match="bounces"):
            compute(scene, 0.0, 2, 16, device=device, bounces=bad)
        with pytest.raises(ValueError, match="bounces"):
            shade(scene, 0.0, gradient_sky(), 16, device=device, bounces=bad)
    with pytest.raises(ValueError, match="space"):
        compute(scene, 0.0, 2, 16, device=device, bounces=1, space="local")
    with pytest.raises(ValueError, match="albedo"):
        compute(scene, 0.0, 2, 16, device=device, bounces=1, albedo=np.ones((2, 3)))
    with pytest.raises(ValueError, match="albedo"):
        compute(scene, 0.0, 2, 16, device=device, bounces=1, albedo=(0.5, -0.1, 0.5))
    with pytest.raises(ValueError, match="albedo"):
        compute(scene, 0.0, 2, 16, device=device, bounces=1, albedo=(0.5, np.nan, 0.5))
    shader = ReferenceShader(scene, gradient_sky(), 16, device=device, bounces=1)
    with pytest.raises(ValueError, match="update"):
        shader.shade_points(shader.bvh.points, shader.surfaces.normals, shader.tint, shader.receivers, shader.radiance, shader.stderr)


# ---- Mitsuba 3 -------------------------------------------------------------------------------


def test_quick_mitsuba_cross_check_with_one_bounce(tmp_path):
    """benchmarks/validate_mitsuba.py --quick --bounces 1: our one-bounce reference against
    Mitsuba's path integrator at max_depth 3 (tolerances of tests/test_validate_mitsuba.py)."""
    pytest.importorskip("mitsuba", reason="Mitsuba 3 not installed (pip install -e '.[validate]')")
    run = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "validate_mitsuba.py"), "--quick", "--bounces", "1", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=HANG_S, cwd=ROOT,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    report = json.loads(next(tmp_path.glob("mitsuba-*-bounces1-quick.json")).read_text())
    img = report["image"]
    assert img["bounces"] == 1 and img["mitsuba_integrator"]["max_depth"] == 3
    assert img["relative_rms"] < 1.3 * img["relative_rms_expected_from_noise"] + 0.01
    assert abs(img["relative_mean_difference"]) < 0.01
    # without the bounce our image would miss that check by more than twice its tolerance
    assert img["direct_only_vs_mitsuba"]["relative_mean_difference"] < -0.02
