"""Static PRT and unshadowed irradiance stages against analytic and float64 oracles."""

import numpy as np
import pytest
import trimesh

from warpshade.basis import sh
from warpshade.graph import GraphSpec, StageSpec
from warpshade.scene import LightingSource
from warpshade.reference import shade
from warpshade.scene import Environment, Mesh, Scene

#: float32 dot products over <= 36 terms of O(1) values
RTOL_FLOAT32 = 1e-4
#: Monte Carlo transfer with 1024 stratified rays per vertex of a smooth, unoccluded integrand
RTOL_TRANSFER_NOISE = 2e-2
#: order-6 PRT of a sunless sky vs ray-traced truth: SH truncation + transfer noise + GT noise
REL_RMS_PRT_SMOOTH_SKY = 0.05


def _sphere_scene(env):
    ico = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    mesh = Mesh("/ball", ico.vertices, ico.faces, albedo=(0.7, 0.5, 0.3))
    return Scene.from_meshes([mesh], lights=[env])


def _graph(order, samples=256, method="prt"):
    if method == "prt":
        stages = [StageSpec("bake", "prt.transfer", {"order": order, "samples": samples}),
                  StageSpec("shade", "prt.shade", {"order": order})]
    else:
        stages = [StageSpec("shade", "prt.unshadowed", {"order": order})]
    return GraphSpec(stages, "shade.radiance", name=f"{method}-n{order}")


def test_white_furnace_convex_object(device):
    """Constant sky, convex object: every vertex sees radiance albedo * L exactly."""
    scene = _sphere_scene(Environment.constant((2.0, 2.0, 2.0)))
    rt = _graph(3, samples=1024).compile(scene, device=device, cache_dir=None, progress=False)
    out = rt.step(0.0).numpy()
    expected = 2.0 * scene.albedo
    np.testing.assert_allclose(out, expected, rtol=RTOL_TRANSFER_NOISE)


def test_unshadowed_matches_float64_irradiance(device):
    env = Environment.sky(sun_radiance=(0.0, 0.0, 0.0))
    scene = _sphere_scene(env)
    order = 3
    rt = _graph(order, method="unshadowed").compile(scene, device=device, cache_dir=None, progress=False)
    out = rt.step(0.0).numpy()
    light = env.to_sh(order)
    conv = sh.clamped_cosine_zh(order)[sh.band_of(order)]
    normals = scene.normals_at(0.0)
    irradiance = sh.basis(normals, order) @ (light * conv[None, :]).T  # (V, 3)
    expected = scene.albedo / np.pi * np.maximum(irradiance, 0.0)
    np.testing.assert_allclose(out, expected, rtol=RTOL_FLOAT32, atol=RTOL_FLOAT32 * expected.max())


def test_prt_matches_ray_traced_truth_on_smooth_sky(device):
    """A box on a plane under a sunless sky: order-6 PRT within a few percent of ray tracing."""
    env = Environment.sky(sun_radiance=(0.0, 0.0, 0.0))
    plane = trimesh.creation.box(extents=(3.0, 3.0, 0.05))
    box = trimesh.creation.box(extents=(0.6, 0.6, 0.6))
    box.apply_translation((0.0, 0.0, 0.33))
    plane = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(plane.vertices, plane.faces, 0.2))
    scene = Scene.from_meshes([Mesh("/plane", plane.vertices, plane.faces), Mesh("/box", box.vertices, box.faces)],
                              lights=[env])
    rt = _graph(6, samples=1024).compile(scene, device=device, cache_dir=None, progress=False)
    out = rt.step(0.0).numpy()
    gt = shade(scene, 0.0, [env], 1024, device=device, seed=3)
    rel = np.sqrt(np.mean((out - gt.radiance) ** 2)) / np.sqrt(np.mean(gt.radiance**2))
    noise = np.sqrt(np.mean(gt.stderr**2)) / np.sqrt(np.mean(gt.radiance**2))
    assert noise < 0.02
    assert rel < REL_RMS_PRT_SMOOTH_SKY, f"relative RMS {rel:.4f} (ground-truth noise {noise:.4f})"


def test_rotating_lighting_equals_rotated_sh_override(device):
    env = Environment.sky()
    scene = _sphere_scene(env)
    scene = Scene.from_meshes(scene.meshes, frames=range(4), lights=[env])
    lighting = LightingSource([env], "Z", degrees_per_frame=30.0)
    rt = _graph(4).compile(scene, device=device, cache_dir=None, progress=False, lighting=lighting)
    rotated = rt.step(3.0).numpy().copy()  # numpy() of a CPU array is a view of the reused buffer
    coeffs = sh.rotate(env.to_sh(4), lighting.rotation(3.0))
    overridden = rt.step(0.0, lighting=coeffs).numpy().copy()
    np.testing.assert_allclose(rotated, overridden, rtol=RTOL_FLOAT32, atol=1e-6)
    # and rotating the sky really changes the shading (the sun moves)
    assert np.abs(rotated - rt.step(0.0).numpy()).max() > 0.05


def test_lighting_override_shape_is_checked(device):
    scene = _sphere_scene(Environment.constant())
    rt = _graph(3).compile(scene, device=device, cache_dir=None, progress=False)
    with pytest.raises(ValueError, match="shape"):
        rt.step(0.0, lighting=np.zeros((3, 4)))


def test_per_channel_transfer_kernel_matches_float64(device, rng):
    from warpshade._wp import wp
    from warpshade.methods.prt import _kernels as kernels
    from warpshade.methods.prt import shade_transfer_f64

    t = rng.normal(size=(50, 3, 9)).astype(np.float32)
    light = rng.normal(size=(3, 9)).astype(np.float32)
    albedo = rng.uniform(0.1, 0.9, (50, 3)).astype(np.float32)
    out = wp.zeros((50, 3), dtype=wp.float32, device=device)
    wp.launch(kernels.shade_transfer_rgb_kernel, dim=50, device=device, inputs=[
        wp.array(t, device=device), wp.array(light, device=device), wp.array(albedo, device=device), out])
    np.testing.assert_allclose(out.numpy(), shade_transfer_f64(t, light, albedo), rtol=1e-5, atol=1e-6)
