"""Local, deformable PRT: kernels vs float64 mirrors, frame conventions, stages, failure modes.

Scenes are tiny synthetic sheets with a groove (local self-occlusion) that bend over a few
frames, so ray tracing and fitting take well under a second.
"""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from warpshade._wp import wp
from warpshade.basis import sh
from warpshade.basis.sh_warp import sh_kernels
from warpshade.geometry._frames import TangentFrames
from warpshade.graph import GraphSpec, StageSpec, load
from warpshade.scene import LightingSource
from warpshade.methods.ldprt import (
    fit_transfer,
    _kernels as kernels,
    local_transfer,
    shade_f64,
    world_transfer_f64,
)
from warpshade.methods.ldprt._mirror import rotate_stored
from warpshade.scene import Environment, Mesh, Scene
from warpshade.transfer import compute

from tolerances import RTOL_TABLE

ROOT = Path(__file__).resolve().parent.parent
ORDER = 3
# float32 kernels vs float64 mirror: SH recurrences of order 3 and sums of a few lobes,
# relative to the largest radiance.
RTOL_FLOAT32 = 5e-5
# zxzxz SH rotation in float32 vs float64 rotation: a few hundred products.
RTOL_ROTATION = 1e-4


def _groove_sheet(bend_angles=(0.0, 0.6, 1.2), size=14):
    """A 2 x 2 sheet with a sinusoidal groove along y, bent about the y axis by the given
    angles (one per frame); a deforming mesh with local occlusion in the groove."""
    u = np.linspace(-1.0, 1.0, size)
    gx, gy = np.meshgrid(u, u, indexing="ij")
    height = 0.35 * np.exp(-(gx / 0.25) ** 2) * np.cos(np.pi * gx / 0.5) ** 2
    rest = np.stack([gx.ravel(), gy.ravel(), -height.ravel()], 1)
    idx = np.arange(gx.size).reshape(gx.shape)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    samples = []
    for angle in bend_angles:
        if angle == 0.0:
            samples.append(rest.copy())
            continue
        radius = 2.0 / angle
        theta = rest[:, 0] / radius
        r = radius + rest[:, 2]
        samples.append(np.stack([r * np.sin(theta), rest[:, 1], r * np.cos(theta) - radius], 1))
    mesh = Mesh("/sheet", rest, faces, animation="deforming", point_samples=np.stack(samples))
    return Scene.from_meshes([mesh], frames=np.arange(len(bend_angles), dtype=float))


@pytest.fixture(scope="module")
def scene():
    return _groove_sheet()


@pytest.fixture(scope="module")
def sky():
    return Environment.sky()


@pytest.fixture(scope="module")
def transfer_local(scene):
    return local_transfer(scene, 0.0, ORDER, 128, device="cpu", seed=3)


@pytest.fixture(scope="module")
def model(transfer_local):
    return fit_transfer(transfer_local, 3, restarts=1)


def _frames(scene, frame, device):
    state = scene.evaluate(frame, device=device)
    tf = TangentFrames.from_scene(scene, device=device)
    return tf.compute(state.points, state.normals)


def test_local_transfer_is_world_transfer_in_tangent_frames(device, scene):
    """transfer.compute(space="local") == the world transfer rotated by the same frames the
    frame stage computes (F w for world w)."""
    frame = 1.0
    world = compute(scene, frame, ORDER, 64, space="world", device=device, seed=5).transfer
    local = compute(scene, frame, ORDER, 64, space="local", device=device, seed=5).transfer
    f = _frames(scene, frame, device).numpy().astype(np.float64)
    u, _, vt = np.linalg.svd(np.swapaxes(f, 1, 2))
    np.testing.assert_allclose(sh.rotate(local.astype(np.float64), u @ vt), world, atol=RTOL_ROTATION * np.abs(world).max())


def test_fit_quality_and_lobe_budget(transfer_local):
    fixed = fit_transfer(transfer_local, 3, restarts=0)
    np.testing.assert_allclose(np.linalg.norm(fixed.to_sh() - transfer_local, axis=1) / fixed.scale, fixed.fit_error,
                               atol=1e-5)
    budget = fit_transfer(transfer_local, 4, target_error=0.05, restarts=0)
    assert set(budget.histogram) <= {1, 2, 3, 4} and sum(budget.histogram.values()) == transfer_local.shape[0]
    assert np.all(budget.fit_error[budget.counts < 4] <= 0.05 + 1e-6)
    # flat, unoccluded sheet: the transfer is a clamped cosine, one lobe; the groove needs more
    assert budget.histogram.get(1, 0) > 0 and budget.counts.max() > 1
    assert budget.total_error <= 0.05 + 1e-6


def _model_arrays(model, device):
    v = model.axes.shape[0]
    return (wp.array(model.axes.reshape(v, -1, 3), dtype=wp.vec3, device=device), wp.array(model.coeffs, device=device),
            wp.array(model.counts, device=device), wp.array(model.stored, device=device))


def test_shade_kernels_match_float64_reference(device, scene, model, sky):
    frames = _frames(scene, 2.0, device)
    f64 = frames.numpy().astype(np.float64)
    light = sky.to_sh(ORDER)
    albedo = np.random.default_rng(1).uniform(0.2, 0.9, size=(scene.vertex_count, 3))
    ref = shade_f64(model, f64, light, albedo)
    axes, coeffs, counts, stored = _model_arrays(model, device)
    light_wp = wp.array(light.astype(np.float32), device=device)
    albedo_wp = wp.array(albedo.astype(np.float32), device=device)
    table_k, shade_table, shade_direct, _ = kernels.shade_kernels(ORDER)
    out = wp.zeros((scene.vertex_count, 3), dtype=wp.float32, device=device)
    wp.launch(shade_direct, dim=scene.vertex_count, inputs=[frames, axes, coeffs, counts, stored, light_wp, albedo_wp, out],
              device=device)
    scale = np.abs(ref).max()
    np.testing.assert_allclose(out.numpy(), ref, atol=RTOL_FLOAT32 * scale)
    table = wp.zeros((65, 128, 3, ORDER), dtype=wp.float32, device=device)
    wp.launch(table_k, dim=(65, 128), inputs=[light_wp, wp.ones(1, dtype=wp.int32, device=device), table], device=device)
    wp.launch(shade_table, dim=scene.vertex_count,
              inputs=[frames, axes, coeffs, counts, stored, table, light_wp, albedo_wp, out], device=device)
    np.testing.assert_allclose(out.numpy(), ref, atol=RTOL_TABLE * scale)
    # a disabled rebuild leaves the table as it is (the frame loop skips unchanged lighting)
    before = table.numpy().copy()
    wp.launch(table_k, dim=(65, 128), inputs=[wp.zeros_like(light_wp), wp.zeros(1, dtype=wp.int32, device=device), table],
              device=device)
    np.testing.assert_array_equal(table.numpy(), before)


def test_full_rotation_kernel_matches_sh_rotate(device, scene, transfer_local, sky):
    frames = _frames(scene, 2.0, device)
    f64 = frames.numpy().astype(np.float64)
    u, _, vt = np.linalg.svd(np.swapaxes(f64, 1, 2))
    light = sky.to_sh(ORDER)
    ref = 0.5 / np.pi * sh.rotate(transfer_local.astype(np.float64), u @ vt) @ light.T
    out = wp.zeros((scene.vertex_count, 3), dtype=wp.float32, device=device)
    wp.launch(kernels.shade_kernels(ORDER)[3], dim=scene.vertex_count,
              inputs=[frames, wp.array(transfer_local, device=device), sh_kernels(ORDER).tables(device),
                      wp.array(light.astype(np.float32), device=device),
                      wp.array(np.full((scene.vertex_count, 3), 0.5, np.float32), device=device), out], device=device)
    np.testing.assert_allclose(out.numpy(), ref, atol=RTOL_ROTATION * np.abs(ref).max())


def test_stored_linear_band_rotates_like_sh(rng):
    stored = rng.normal(size=(4, 4))
    rot = Rotation.random(4, random_state=2).as_matrix()
    full = np.zeros((4, 9))
    full[:, :4] = stored
    np.testing.assert_allclose(rotate_stored(stored, rot, 3), sh.rotate(full, rot), atol=1e-12)


def test_rigid_motion_with_lighting_is_invariant(device, model, scene, sky):
    """Rotating a frame's geometry and the lighting together leaves LDPRT shading unchanged."""
    f0 = _frames(scene, 1.0, device).numpy().astype(np.float64)
    rot = Rotation.from_rotvec([0.3, -1.1, 0.5]).as_matrix()
    light = sky.to_sh(ORDER)
    albedo = np.full((scene.vertex_count, 3), 0.7)
    a = shade_f64(model, f0, light, albedo)
    b = shade_f64(model, f0 @ rot.T, sh.rotate(light, rot), albedo)
    np.testing.assert_allclose(a, b, atol=1e-9 * np.abs(a).max())


def _graph(device, stages, scene, sky):
    spec = GraphSpec(stages=[StageSpec(*s) for s in stages], output="shade.radiance", name="ldprt-test")
    return spec.compile(scene, device=device, cache_dir=None, progress=False,
                        lighting=LightingSource([sky], scene.up_axis))


def test_stages_run_and_beat_undeformed_prt(device, scene, sky):
    """Through the runtime: at the bake frame LDPRT == static PRT; on the bent frame LDPRT is
    closer to freshly traced PRT of that frame than the undeformed PRT is (local groove)."""
    fit = {"order": ORDER, "lobes": 3, "samples": 128, "seed": 3, "restarts": 0}
    ld = _graph(device, [("fit", "ldprt.fit", fit, {}), ("tangents", "ldprt.tangents", {}, {}),
                         ("shade", "ldprt.shade", {"order": ORDER, "lobes": 3}, {})], scene, sky)
    direct = _graph(device, [("fit", "ldprt.fit", fit, {}), ("tangents", "ldprt.tangents", {}, {}),
                             ("shade", "ldprt.shade", {"order": ORDER, "lobes": 3, "evaluation": "direct"}, {})], scene, sky)
    rot = _graph(device, [("bake", "ldprt.transfer", {"order": ORDER, "samples": 128, "seed": 3}, {}),
                          ("tangents", "ldprt.tangents", {}, {}), ("shade", "ldprt.shade_rotated", {"order": ORDER}, {})], scene, sky)
    prt = _graph(device, [("bake", "prt.transfer", {"order": ORDER, "samples": 128, "seed": 3}, {}),
                          ("shade", "prt.shade", {"order": ORDER}, {"transfer": "bake.transfer"})], scene, sky)
    light = sky.to_sh(ORDER)
    albedo = scene.albedo.astype(np.float64)
    for frame in (0.0, 2.0):
        est = {name: g.step(frame).numpy().copy() for name, g in
               (("table", ld), ("direct", direct), ("rotated", rot), ("prt", prt))}
        assert all(np.all(np.isfinite(v)) for v in est.values())
        truth = albedo / np.pi * (compute(scene, frame, ORDER, 128, space="world", device=device, seed=3).transfer @ light.T)
        scale = np.abs(truth).max()
        np.testing.assert_allclose(est["table"], est["direct"], atol=RTOL_TABLE * scale)
        if frame == 0.0:
            np.testing.assert_allclose(est["rotated"], truth, atol=RTOL_ROTATION * scale)
            np.testing.assert_allclose(est["prt"], truth, atol=RTOL_FLOAT32 * scale)
        else:
            err = {k: np.sqrt(np.mean((v - truth) ** 2)) for k, v in est.items()}
            assert err["rotated"] < 0.5 * err["prt"] and err["table"] < 0.5 * err["prt"], err


def test_degenerate_frames_give_finite_smooth_shading(device, model, sky):
    """Zero-area triangles, a pole fan, flipped normals and an isolated vertex: no NaN, and the
    shading changes continuously when the degenerate geometry is perturbed slightly."""
    ring = 8
    angles = np.linspace(0.0, 2.0 * np.pi, ring, endpoint=False)
    cap = np.concatenate([[[0.0, 0.0, 1.0]], np.stack([0.4 * np.cos(angles), 0.4 * np.sin(angles),
                                                       np.full(ring, 0.9)], 1)])
    points = np.concatenate([cap, [[2.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 0.0, 0.0], [5.0, 5.0, 5.0]]])
    fan = np.array([[0, 1 + i, 1 + (i + 1) % ring] for i in range(ring)])
    faces = np.concatenate([fan, [[9, 10, 11]], [[0, 2, 1]]])  # zero-area triangle; a flipped face
    mesh = Mesh("/degenerate", points, faces)
    deg = Scene.from_meshes([mesh])
    v = deg.vertex_count
    picked = np.arange(v) % model.axes.shape[0]
    m = type(model)(model.axes[picked], model.coeffs[picked], model.counts[picked], model.stored[picked],
                    model.fit_error[picked], model.scale, model.total_error, model.restarted[picked], model.seconds)
    tf = TangentFrames.from_scene(deg, device=device)
    light = wp.array(sky.to_sh(ORDER).astype(np.float32), device=device)
    table_k, shade_table, _, _ = kernels.shade_kernels(ORDER)
    table = wp.zeros((65, 128, 3, ORDER), dtype=wp.float32, device=device)
    wp.launch(table_k, dim=(65, 128), inputs=[light, wp.ones(1, dtype=wp.int32, device=device), table], device=device)
    axes, coeffs, counts, stored = _model_arrays(m, device)
    albedo = wp.array(np.full((v, 3), 0.8, np.float32), device=device)

    def shade(pts, normals):
        frames = tf.compute(wp.array(pts.astype(np.float32), dtype=wp.vec3, device=device),
                            wp.array(normals.astype(np.float32), dtype=wp.vec3, device=device))
        out = wp.zeros((v, 3), dtype=wp.float32, device=device)
        wp.launch(shade_table, dim=v, inputs=[frames, axes, coeffs, counts, stored, table, light, albedo, out], device=device)
        return frames.numpy(), out.numpy()

    normals = tf.rule.rest_normals.copy()
    normals[2] *= -1.0  # flipped normal
    normals[12] = 0.0  # isolated vertex with no normal
    frames, base = shade(points, normals)
    assert np.all(np.isfinite(frames)) and np.all(np.isfinite(base))
    np.testing.assert_allclose(np.einsum("vij,vkj->vik", frames, frames), np.broadcast_to(np.eye(3), frames.shape),
                               atol=1e-5)
    moved = points.copy()
    moved[9:12] += 1e-4 * np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    _, nudged = shade(moved, normals)
    assert np.all(np.isfinite(nudged))
    assert np.abs(nudged - base).max() < 0.05 * np.abs(base).max()


@pytest.mark.parametrize("name", ["figure_ldprt", "bend_ldprt"])
def test_bundled_graphs_validate(name):
    spec = load(ROOT / "stages" / f"{name}.toml")
    stages, wiring = spec.build({"V": 10, "T": 60, "F": 10})
    assert [s.type_name for s in stages][-1] == "ldprt.shade"
    assert wiring["shade"]["axes"].provider == "fit"


def test_bad_parameters_are_reported():
    with pytest.raises(ValueError, match="stored_bands"):
        fit_transfer(np.ones((3, 9)), 1, stored_bands="all")
    with pytest.raises(ValueError, match="evaluation"):
        GraphSpec(stages=[StageSpec("s", "ldprt.shade", {"evaluation": "fast"})], output="s.radiance").build()


def test_world_transfer_reference_is_consistent(device, model, scene):
    f = _frames(scene, 1.0, device).numpy().astype(np.float64)
    t = world_transfer_f64(model, f)
    u, _, vt = np.linalg.svd(np.swapaxes(f, 1, 2))
    np.testing.assert_allclose(t, sh.rotate(model.to_sh(), u @ vt), atol=1e-4 * np.abs(t).max())
