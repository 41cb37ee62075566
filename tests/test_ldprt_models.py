"""Parametric LDPRT models: the thin membrane (eq. 22-23) and the sinusoidal wrinkle table."""

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from warpshade._wp import wp
from warpshade.basis import quadrature, sh, zh
from warpshade.graph import GraphSpec, StageSpec
from warpshade.scene import LightingSource
from warpshade.methods.ldprt import _kernels as kernels
from warpshade.methods.ldprt._membrane import membrane_coefficients, thickness
from warpshade.methods.ldprt._wrinkle import (
    bilinear_weights,
    evaluate_table,
    fit_wrinkle_table,
    groove_transfer,
)
from warpshade.scene import Environment, Mesh, Scene

from tolerances import ATOL_QUADRATURE

# float32 kernels vs float64 mirror (SH order 4 recurrences, sums over 3 lobes), relative to
# the largest radiance.
RTOL_FLOAT32 = 1e-4
# Transfer of a flat groove (depth 0) = the clamped cosine; 256 Fibonacci rays per receiver
# (a deterministic rotated set) estimate it to ~2e-3 of its largest coefficient.
ATOL_FLAT_GROOVE = 1e-2


def test_membrane_coefficients_match_quadrature():
    order = 6
    n = np.array([0.2, 0.3, -0.93]) / np.linalg.norm([0.2, 0.3, -0.93])
    rule = quadrature.gauss_legendre(400)
    for alpha in (0.0, 0.4, 1.0):
        def g(d, alpha=alpha):
            c = d @ n
            return np.where(c >= 0.0, c, -alpha * c)

        projected = sh.project(g, order, rule)
        lobe = zh.to_sh(n[None], membrane_coefficients(alpha, order)[None])
        np.testing.assert_allclose(lobe, projected, atol=ATOL_QUADRATURE)
    # alpha = 1: |s.n| is even, odd bands vanish; eq. 23 (times pi) for the first bands
    c = membrane_coefficients(1.0, 4)
    np.testing.assert_allclose(c, [2 * np.pi, 0.0, 2 * np.pi / 4, 0.0], atol=1e-12)
    with pytest.raises(ValueError, match="translucency"):
        membrane_coefficients(1.5, 3)


@pytest.fixture(scope="module")
def sphere_scene():
    m = trimesh.creation.icosphere(2, radius=0.5)
    return Scene.from_meshes([Mesh("/ball", np.asarray(m.vertices), np.asarray(m.faces))])


def test_thickness_of_a_sphere_is_its_diameter(device, sphere_scene):
    d = thickness(sphere_scene, 0.0, device=device)
    np.testing.assert_allclose(d, 1.0, atol=0.02)  # chord through a faceted sphere


def test_opaque_membrane_is_unshadowed_irradiance(device, sphere_scene):
    """alpha = 0 through ldprt.membrane + ldprt.shade == prt.unshadowed (independent kernels)."""
    light = LightingSource([Environment.sky()], "Z")

    def run(stages):
        spec = GraphSpec(stages=[StageSpec(*s) for s in stages], output="shade.radiance")
        return spec.compile(sphere_scene, device=device, cache_dir=None, progress=False, lighting=light).step(0.0).numpy()

    mem = run([("m", "ldprt.membrane", {"order": 3, "translucency": 0.0}, {}), ("tangents", "ldprt.tangents", {}, {}),
               ("shade", "ldprt.shade", {"order": 3, "lobes": 1, "evaluation": "direct"}, {})])
    ref = run([("shade", "prt.unshadowed", {"order": 3}, {})])
    np.testing.assert_allclose(mem, ref, atol=RTOL_FLOAT32 * np.abs(ref).max())
    lit = run([("m", "ldprt.membrane", {"order": 3, "translucency": 0.8, "thickness_scale": 0.1}, {}),
               ("tangents", "ldprt.tangents", {}, {}), ("shade", "ldprt.shade", {"order": 3, "lobes": 1}, {})])
    # the ball is 10 scale lengths thick: hardly any translucency
    np.testing.assert_allclose(lit, ref, rtol=0.01, atol=1e-3 * np.abs(ref).max())


def test_bilinear_weights_partition_of_unity_and_periodic():
    x = np.array([0.0, 0.3, 0.99, 1.0, 0.5])
    d = np.array([0.0, 0.1, 0.5, 0.0, 0.7])
    w = bilinear_weights(x, d, 8, 4, 0.5).toarray()
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    np.testing.assert_allclose(w[0], w[3])  # phase 0 == phase 1
    assert np.all(w >= 0.0)


@pytest.fixture(scope="module")
def groove():
    order, sx, max_depth = 4, 12, 0.5
    depths = np.linspace(0.0, max_depth, 4)
    t = groove_transfer(order, sx, depths, samples=256, device="cpu")
    table = fit_wrinkle_table(t, max_depth, phase_controls=6, depth_controls=3, max_iterations=60)
    return t, table, depths


def test_flat_groove_is_a_clamped_cosine(groove):
    t, _, _ = groove
    cosine = sh.zh_to_sh(np.array([0.0, 0.0, 1.0]), sh.clamped_cosine_zh(4, "zh"))
    np.testing.assert_allclose(t[0], np.broadcast_to(cosine, t[0].shape), atol=ATOL_FLAT_GROOVE)
    # deeper grooves occlude more: less light reaches the bottom (phase 0.5)
    assert t[-1, 6, 0] < t[1, 6, 0] < t[0, 6, 0]


def test_wrinkle_fit_reports_and_improves(groove):
    t, table, depths = groove
    assert table.sample_error < table.initial_error
    assert table.sample_error < 0.1
    ph = np.arange(12) / 12
    rec = evaluate_table(table, np.tile(ph, 4), np.repeat(depths, 12))
    err = np.sqrt(np.sum((rec - t.reshape(-1, 16)) ** 2) / np.sum(t**2))
    assert err == pytest.approx(table.sample_error, rel=1e-6)


def test_wrinkle_kernel_matches_float64(device, groove):
    _, table, _ = groove
    rng = np.random.default_rng(4)
    count = 40
    phase = rng.uniform(0, 3, count)
    depth = rng.uniform(-0.1, 0.6, count)  # outside [0, max_depth] is clamped
    angle = rng.uniform(-np.pi, np.pi, count)
    frames = Rotation.random(count, random_state=5).as_matrix()
    light = Environment.sky().to_sh(4)
    albedo = rng.uniform(0.3, 0.9, (count, 3))
    # reference: table (groove frame) -> Rz(angle) -> F^T
    t_groove = evaluate_table(table, phase, np.clip(depth, 0.0, table.max_depth))
    rz = Rotation.from_rotvec(np.outer(angle, [0.0, 0.0, 1.0])).as_matrix()
    t_world = sh.rotate(t_groove, np.swapaxes(frames, 1, 2) @ rz)
    ref = albedo / np.pi * (t_world @ light.T)
    depth_k, shade = kernels.wrinkle_kernels(4)
    out = wp.zeros((count, 3), dtype=wp.float32, device=device)
    f32 = lambda a: wp.array(np.asarray(a, np.float32), device=device)
    vertices = kernels.WrinkleVertices()
    vertices.frames = wp.array(frames.astype(np.float32), dtype=wp.mat33, device=device)
    vertices.phase, vertices.groove_angle = f32(phase), f32(angle)
    vertices.depth, vertices.albedo = f32(np.clip(depth, 0.0, table.max_depth)), f32(albedo)
    tab = kernels.WrinkleTable()
    tab.axes = wp.array(table.axes.astype(np.float32), dtype=wp.vec3, device=device)
    tab.coeffs, tab.stored, tab.max_depth = f32(table.coeffs), f32(table.stored), table.max_depth
    wp.launch(shade, dim=count, inputs=[vertices, tab, f32(light), out], device=device)
    np.testing.assert_allclose(out.numpy(), ref, atol=RTOL_FLOAT32 * np.abs(ref).max())
    # depth from compression along the axis
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.8], [1.0, 0.0, 0.0]])
    depth_out = wp.zeros(3, dtype=wp.float32, device=device)
    wp.launch(depth_k, dim=3, inputs=[wp.array(pts.astype(np.float32), dtype=wp.vec3, device=device),
                                      wp.array(np.array([1, 0, -1], np.int32), device=device), f32([1.0, 0.8, 1.0]),
                                      f32([0.1, 0.1, 0.2]), 2.0, 0.5, depth_out], device=device)
    np.testing.assert_allclose(depth_out.numpy(), [0.1 + 2.0 * 0.2, 0.1, 0.2], atol=1e-6)


def test_wrinkle_stages_on_a_bending_tube(device):
    """Table + frames + wrinkle shading through the runtime on a small tube that bends: finite,
    grooves visible (shading varies with phase where deep), depth grows where compressed."""
    m = trimesh.creation.cylinder(radius=0.2, height=2.0, sections=24, segment=np.array([[0, 0, 0], [0, 0, 2.0]]))
    m = m.subdivide().subdivide()
    pts = np.asarray(m.vertices)
    angle = 0.8 * np.clip(pts[:, 2] - 1.0, 0.0, None)  # bend the upper half about x
    bent = pts.copy()
    bent[:, 1] = pts[:, 1] * np.cos(angle) - np.maximum(pts[:, 2] - 1.0, 0) * np.sin(angle)
    bent[:, 2] = np.minimum(pts[:, 2], 1.0) + pts[:, 1] * np.sin(angle) + np.maximum(pts[:, 2] - 1.0, 0) * np.cos(angle)
    mesh = Mesh("/tube", pts, np.asarray(m.faces), animation="deforming", point_samples=np.stack([pts, bent]))
    scene = Scene.from_meshes([mesh], frames=[0.0, 1.0])
    table = {"order": 4, "samples": 64, "phase_samples": 8, "depth_samples": 3, "phase_controls": 4,
             "depth_controls": 3, "max_depth": 0.4, "iterations": 20}
    spec = GraphSpec(stages=[
        StageSpec("table", "ldprt.wrinkle_table", table),
        StageSpec("tangents", "ldprt.tangents"),
        StageSpec("shade", "ldprt.wrinkle_shade", {"order": 4, "phase_controls": 4, "depth_controls": 3,
                                                   "max_depth": 0.4, "grooves": 4, "depth_range": (0.0, 0.4),
                                                   "compression_gain": 3.0}),
    ], output="shade.radiance")
    rt = spec.compile(scene, device=device, cache_dir=None, progress=False,
                      lighting=LightingSource([Environment.constant()], "Z"))
    rest = rt.step(0.0).numpy().copy()
    depth_rest = rt.frame_outputs["shade"]["depth"].numpy().copy()
    bent_out = rt.step(1.0).numpy()
    depth_bent = rt.frame_outputs["shade"]["depth"].numpy()
    assert np.all(np.isfinite(rest)) and np.all(np.isfinite(bent_out))
    side = np.abs(scene.normals_at(0.0)[:, 2]) < 0.5
    top = side & (pts[:, 2] > 1.5)
    low = side & (pts[:, 2] < 0.3)
    # under constant light, deep grooves (top) darken and vary with phase; shallow ones (bottom) do not
    assert rest[top, 0].std() > 3 * rest[low, 0].std()
    assert rest[top, 0].mean() < rest[low, 0].mean()
    assert depth_bent.max() > depth_rest.max() - 1e-6 and np.any(depth_bent > depth_rest + 1e-3)
