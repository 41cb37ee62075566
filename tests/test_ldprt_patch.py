"""LDPRT texture patches (warpshade.methods.ldprt._patch, patch_warp): kernels against their float64
mirrors, a flat patch against unshadowed shading, the lobes' rotation against SH rotation, the
displaced geometry of the ground truth, and the failure cases."""

from __future__ import annotations

import numpy as np
import pytest
from tolerances import ATOL_FLOAT64, ATOL_ZH_FLOAT32, assert_close

from warpshade._wp import wp
from warpshade.basis import sh
from warpshade.methods.ldprt import _mirror as mirror
from warpshade.methods.ldprt import _patch as lp
from warpshade.methods.ldprt import _patch_warp as pw
from warpshade.graph import StageError

#: Order of the small patches of these tests.
ORDER = 3
#: float32 patch shading against float64: four texels' lobe sums (|g*| <= pi, |y| <= 1.1,
#: |L| <= 1) with bilinear weights, relative to radiances of order 1.
ATOL_PATCH_FLOAT32 = 20 * ATOL_ZH_FLOAT32
#: Monte Carlo transfer of an almost flat patch (256 rays per texel) against the exact clamped
#: cosine: the spherical Fibonacci estimate of the DC and linear coefficients (measured 2e-3).
ATOL_TRACED_FLAT = 1e-2
#: Height of the parallax march's hit against the height field there, in patch widths: one secant
#: step over a march step of a bilinear 8^2 patch of relief 0.3 (measured 8.2e-3 at 80 degrees).
ATOL_PARALLAX_HIT = 1.5e-2
#: float32 march against float64: coordinates of order 1 through 32 steps and a secant step.
ATOL_PARALLAX_FLOAT32 = 2e-4


def _random_frames(rng, count):
    q, _ = np.linalg.qr(rng.normal(size=(count, 3, 3)))
    q *= np.sign(np.linalg.det(q))[:, None, None]
    return q  # proper rotations, rows (t, b, n)


@pytest.fixture(scope="module")
def weave():
    heights = lp.patch_heights("weave", 8, 0.3)
    model, report = lp.bake_patch(heights, ORDER, 128, 3, 0.05, tiles=3, device="cpu", restarts=0)
    return model


@pytest.fixture
def light(rng):
    return rng.normal(size=(3, ORDER * ORDER)) * 0.3 + 0.5 * (np.arange(ORDER * ORDER) == 0)


def _shade_vertices(model, tiling, normals, tangents, bitangents, uvs, patched, albedo, light, device):
    count = normals.shape[0]
    surface = pw.patch_surface(np.zeros((1, 3), np.int32), uvs, patched, albedo, device)
    surface.tangents = wp.array(np.asarray(tangents, np.float32), dtype=wp.vec3, device=device)
    surface.bitangents = wp.array(np.asarray(bitangents, np.float32), dtype=wp.vec3, device=device)
    texture = pw.patch_texture(model, tiling, device)
    shade_vertices, _ = pw.patch_kernels(model.order)
    out = wp.zeros((count, 3), dtype=wp.float32, device=device)
    wp.launch(shade_vertices, dim=count, device=device,
              inputs=[wp.array(np.asarray(normals, np.float32), dtype=wp.vec3, device=device), surface, texture,
                      wp.array(np.asarray(light, np.float32), dtype=wp.float32, device=device), out])
    return out.numpy()


@pytest.mark.parametrize("textured", [False, True])
def test_patch_kernel_matches_float64_mirror(device, weave, light, rng, textured):
    from dataclasses import replace

    if textured:  # a per-texel albedo factor (a 'texture' patch)
        weave = replace(weave, albedo=rng.uniform(0.1, 1.0, size=weave.albedo.shape).astype(np.float32))
    count = 64
    frames = _random_frames(rng, count)
    uvs = rng.uniform(-2.0, 3.0, size=(count, 2))
    albedo = rng.uniform(0.2, 0.9, size=(count, 3))
    # raw dP/du, dP/dv: the frame's tangent and bitangent, scaled and tilted out of the plane
    tangents = frames[:, 0] * 2.5 + frames[:, 2] * 0.7
    bitangents = frames[:, 1] * 0.3 - frames[:, 2] * 0.2
    got = _shade_vertices(weave, 2.0, frames[:, 2], tangents, bitangents, uvs, np.ones(count), albedo, light, device)
    built = mirror.patch_tangent_frames_f64(frames[:, 2], tangents, bitangents)
    assert_close(built, frames, atol=1e-12, what="frame from raw dP/du, dP/dv")
    want = mirror.shade_patch_f64(weave, uvs, frames, light, albedo, 2.0)
    assert_close(got, want, atol=ATOL_PATCH_FLOAT32, what="patch shading, kernel vs float64")


def test_lobe_rotation_matches_sh_rotation(weave, light, rng):
    """A texel's lobes turned by the frame equal its reconstructed SH transfer rotated by
    ``sh.rotate`` (texel centres: one texel, weight 1)."""
    r = weave.resolution
    texels = rng.integers(0, r * r, size=16)
    uv = np.stack([(texels % r + 0.5) / r, (texels // r + 0.5) / r], 1)
    frames = _random_frames(rng, texels.size)
    got = mirror.shade_patch_f64(weave, uv, frames, light, np.full((texels.size, 3), np.pi), 1.0)
    local = weave.to_sh()[texels]
    rotated = np.stack([sh.rotate(local[k], frames[k].T) for k in range(texels.size)])
    assert_close(got, rotated @ light.T, atol=1e-9, what="lobes turned by the frame vs SH rotation")


def test_flat_patch_is_unshadowed_shading(device, light, rng):
    flat, report = lp.bake_patch(lp.patch_heights("flat", 8, 0.5), ORDER, 64, 3, 0.05, device="cpu")
    assert report["histogram"] == {1: 64}
    count = 32
    frames = _random_frames(rng, count)
    albedo = rng.uniform(0.2, 0.9, size=(count, 3))
    uvs = rng.uniform(0, 1, size=(count, 2))
    got = _shade_vertices(flat, 3.0, frames[:, 2], frames[:, 0], frames[:, 1], uvs, np.ones(count), albedo, light, device)
    want = mirror.shade_unshadowed_f64(frames[:, 2], light, albedo)
    assert_close(got, want, atol=ATOL_PATCH_FLOAT32, what="flat patch vs unshadowed")
    # a patch flattened (detail = "none") is the same
    from dataclasses import replace

    flattened = replace(flat, axes=flat.axes * 0 + np.array([1.0, 0.0, 0.0], np.float32)).flattened()
    got_flattened = _shade_vertices(flattened, 3.0, frames[:, 2], frames[:, 0], frames[:, 1], uvs, np.ones(count), albedo,
                                    light, device)
    assert_close(got_flattened, want, atol=ATOL_PATCH_FLOAT32, what="flattened patch vs unshadowed")
    # unpatched vertices take the same unshadowed shading
    got0 = _shade_vertices(flat, 3.0, frames[:, 2], frames[:, 0], frames[:, 1], uvs, np.zeros(count), albedo, light, device)
    assert_close(got0, want, atol=ATOL_PATCH_FLOAT32, what="unpatched vertices")


def test_traced_low_patch_approaches_the_clamped_cosine():
    heights = lp.patch_heights("bumps", 8, 1e-4)
    t = lp.patch_transfer(heights, ORDER, 256, tiles=3, device="cpu")
    cosine = sh.zh_to_sh(np.array([0.0, 0.0, 1.0]), sh.clamped_cosine_zh(ORDER, "zh"))
    assert_close(t[:, :4], np.broadcast_to(cosine[:4], (64, 4)), atol=ATOL_TRACED_FLAT, what="near-flat transfer")


def test_occlusion_darkens_valleys_more_than_peaks():
    heights = lp.patch_heights("waffle", 16, 0.4)
    t = lp.patch_transfer(heights, ORDER, 256, tiles=3, device="cpu")
    flat = heights.ravel() < 0.05 * heights.max()
    top = heights.ravel() > 0.95 * heights.max()
    assert t[flat, 0].mean() < 0.9 * t[top, 0].mean()


def test_vertex_tangents_kernel_matches_mirror(device, rng):
    n = 6
    g = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="xy"), -1).reshape(-1, 2).astype(np.float64)
    points = np.concatenate([g * 0.3, rng.normal(size=(g.shape[0], 1)) * 0.05], 1)
    uvs = g / (n - 1) + rng.normal(size=g.shape) * 0.01
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    patched = np.ones(n * n, np.int32)
    surface = pw.patch_surface(faces, uvs, patched, np.ones((n * n, 3)), device)
    pw.update_tangents(wp.array(points.astype(np.float32), dtype=wp.vec3, device=device), surface, device)
    t, b_ = mirror.patch_vertex_tangents_f64(points, faces, uvs, patched)
    assert_close(surface.tangents.numpy(), t, atol=1e-4, rtol=1e-4, what="dP/du")
    assert_close(surface.bitangents.numpy(), b_, atol=1e-4, rtol=1e-4, what="dP/dv")
    # a plane x = 0.3 u (n - 1), y = 0.3 v (n - 1): dP/du along +x, dP/dv along +y
    assert np.all(t[:, 0] > 0) and np.all(b_[:, 1] > 0)


def test_degenerate_frames_are_bounded(device, weave, light):
    nan = np.nan
    normals = np.array([[0, 0, 1], [0, 0, 0], [nan, 0, 1], [0, 0, 1], [0, 0, 1], [1e-30, 0, 0], [0, 0, 1]], np.float64)
    tangents = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 0], [0, 0, 5], [nan, nan, nan], [0, 1, 0], [1e38, 1e38, 0]])
    bitangents = np.array([[0, 1, 0], [0, 1, 0], [0, 1, 0], [0, 1, 0], [nan, 0, 0], [0, 0, 0], [0, 1, 0]])
    count = normals.shape[0]
    uvs = np.array([[0.1, 0.2], [0.3, 0.4], [nan, 0.5], [1e30, 0.0], [0.5, 0.5], [0.2, 0.2], [0.7, 0.1]])
    got = _shade_vertices(weave, 4.0, normals, tangents, bitangents, uvs, np.ones(count), np.full((count, 3), 0.5),
                          light, device)
    assert np.all(np.isfinite(got))
    frames = mirror.patch_tangent_frames_f64(normals, tangents, bitangents)
    assert np.all(np.isfinite(frames))
    assert_close(np.einsum("nij,nkj->nik", frames, frames), np.broadcast_to(np.eye(3), frames.shape), atol=1e-9,
                 what="orthonormal fallback frames")
    want = mirror.shade_patch_f64(weave, uvs, frames, light, np.full((count, 3), 0.5), 4.0)
    assert_close(got, want, atol=ATOL_PATCH_FLOAT32, what="degenerate frames, kernel vs float64")


def test_heights_and_periodic_lookup():
    for shape in ("bumps", "waffle", "weave", "swirl"):
        h = lp.patch_heights(shape, 16, 0.2)
        assert h.shape == (16, 16) and np.isclose(h.min(), 0.0) and np.isclose(h.max(), 0.2)
    h = lp.patch_heights("swirl", 16, 0.2)
    uv = np.random.default_rng(0).uniform(-3, 3, size=(50, 2))
    assert_close(lp.sample_heights(h, uv), lp.sample_heights(h, uv + np.array([2.0, -1.0])), atol=ATOL_FLOAT64 * 1e3,
                 what="periodic look-up")
    c = (np.arange(16) + 0.5) / 16
    assert_close(lp.sample_heights(h, np.stack([c[[3, 5]], c[[7, 2]]], 1)), h[[7, 2], [3, 5]], atol=1e-12,
                 what="texel centres")
    img = np.zeros((64, 64, 3))
    img[:32] = 1.0  # top half bright: high v high
    ht = lp.patch_heights("texture", 8, 1.0, image=img)
    assert np.all(ht[4:] == 1.0) and np.all(ht[:4] == 0.0)


def test_zero_height_patch_is_exact_and_flat_reference_is_the_surface():
    h = lp.patch_heights("bumps", 8, 0.0)
    assert np.all(h == 0.0)
    t = lp.patch_transfer(h, ORDER, 64)
    cosine = sh.zh_to_sh(np.array([0.0, 0.0, 1.0]), sh.clamped_cosine_zh(ORDER, "zh"))
    assert_close(t, np.broadcast_to(cosine, t.shape), atol=ATOL_FLOAT64, what="zero-height transfer")


def test_displaced_geometry_moves_the_surface_by_the_heights():
    from warpshade.scene import Mesh, Scene

    n = 5
    g = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="xy"), -1).reshape(-1, 2) / (n - 1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    plane = Mesh("/plane", np.concatenate([g * 2.0, np.zeros((n * n, 1))], 1), faces, uvs=g)
    scene = Scene.from_meshes([plane])
    heights = lp.patch_heights("bumps", 8, 0.2)
    geo = lp.PatchGeometry(scene, heights, 2.0, ["/plane"])
    # median first-edge length in UV (sides 1/4, diagonals sqrt(2)/4): 0.30 -> 3 halvings to one
    # texel (1/16: 8 texels, tiled twice)
    assert geo.levels["/plane"] == 3
    assert np.isclose(geo.patch_size["/plane"], 1.0)  # 2 world units per UV unit, two patches
    fine = geo.scene_at(0.0).meshes[0]
    uv_fine = fine.points[:, :2] / 2.0
    want = (lp.sample_heights(heights, uv_fine * 2.0) - heights.mean()) * 1.0
    assert_close(fine.points[:, 2], want, atol=1e-9, what="displacement along +z")
    # a patch albedo multiplies the fine vertices' albedo (bilinear at their UVs)
    tex = np.random.default_rng(3).uniform(0.2, 1.0, size=(8, 8, 3))
    tinted = lp.PatchGeometry(scene, heights, 2.0, ["/plane"], albedo=tex).scene_at(0.0).meshes[0]
    want = np.stack([lp.sample_heights(tex[..., c], uv_fine * 2.0) for c in range(3)], 1) * fine.albedo
    assert_close(tinted.albedo, want, atol=1e-6, what="tinted albedo")


def test_bad_inputs_are_named():
    with pytest.raises(ValueError, match="'heights'.*non-finite"):
        lp.bake_patch(np.full((8, 8), np.nan), ORDER, 16, 2, 0.05)
    with pytest.raises(ValueError, match="'shape'"):
        lp.patch_heights("knit", 8, 0.1)
    with pytest.raises(ValueError, match="'texture'"):
        lp.patch_heights("texture", 8, 0.1)
    with pytest.raises(ValueError, match="'texture'"):
        lp.patch_heights("texture", 8, 0.1, image=np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="'height'"):
        lp.patch_heights("bumps", 8, float("nan"))
    with pytest.raises(ValueError, match="'tiles'"):
        lp.tiled_mesh(np.zeros((4, 4)), 2)
    bad = {"heights": np.zeros((4, 4)), "axes": np.zeros((16, 2, 3)), "coeffs": np.zeros((16, 2, 3)),
           "counts": np.full(16, 3), "stored": np.zeros((16, 4)), "fit_error": np.zeros(16), "albedo": np.ones((16, 3))}
    with pytest.raises(ValueError, match="lobe counts"):
        lp.PatchModel.from_arrays(bad)


def test_uvless_mesh_is_refused():
    from warpshade.scene import Mesh, Scene

    tri = Mesh("/tri", np.eye(3), np.array([[0, 1, 2]]))
    scene = Scene.from_meshes([tri])
    with pytest.raises(ValueError, match="no mesh .* has UVs"):
        lp.patch_prims(scene, "")
    with pytest.raises(ValueError, match="'/tri' has no UVs"):
        lp.patch_prims(scene, "/tri")
    with pytest.raises(ValueError, match="no mesh '/other'"):
        lp.patch_prims(scene, "/other")


def test_stage_refuses_nan_texture_and_uvless_scene(tmp_path):
    import warpshade.graph as graph

    np.save(tmp_path / "nan.npy", np.full((8, 8), np.nan))
    toml = tmp_path / "g.toml"
    toml.write_text('[graph]\nname = "g"\nscene = "bundled:bend"\noutput = "shade.radiance"\n'
                    '[[stage]]\nname = "patch"\ntype = "ldprt.patch"\nshape = "texture"\ntexture = "nan.npy"\n'
                    'resolution = 8\nsamples = 16\n'
                    '[[stage]]\nname = "shade"\ntype = "ldprt.patch_shade"\n')
    with pytest.raises(StageError, match="parameter 'texture'.*non-finite"):
        graph.load(toml).compile(device="cpu", progress=False, cache_dir=None)
    # heights from an albedo image (PNG, the paper's way): the bright half is high
    from PIL import Image

    img = np.zeros((16, 16, 3), np.uint8)
    img[:, 8:] = 200
    Image.fromarray(img).save(tmp_path / "albedo.png")
    toml2 = tmp_path / "g2.toml"
    toml2.write_text(toml.read_text().replace("nan.npy", "albedo.png").replace("bundled:bend", "bundled:cloth"))
    rt = graph.load(toml2).compile(device="cpu", progress=False, cache_dir=None)
    patch = next(s for s in rt.stages if s.name == "shade").patch
    assert np.all(patch.heights[:, 4:] > patch.heights[:, :4].max())
    # and its albedo, sRGB-decoded: 200/255 -> 0.578 on the bright half, 0 on the dark half
    albedo = patch.albedo.reshape(8, 8, 3)
    assert_close(albedo[:, 4:], np.full((8, 4, 3), ((200 / 255 + 0.055) / 1.055) ** 2.4), atol=1e-5, what="albedo")
    assert np.all(albedo[:, :4] == 0.0)
    toml.write_text(toml.read_text().replace('shape = "texture"\ntexture = "nan.npy"\n', 'shape = "flat"\n'))
    with pytest.raises(StageError, match="stage 'shade'.*no mesh .* has UVs"):
        graph.load(toml).compile(device="cpu", progress=False, cache_dir=None)


def _parallax_kernel(model, tiling, uvs, frames, directions, device):
    """UVs after the per-pixel parallax march (a one-off kernel over ``patch_warp.parallax_uv``)."""
    texture = pw.patch_texture(model, tiling, device, parallax=True)

    @wp.kernel
    def march(patch: pw.PatchTexture, uv: wp.array(dtype=wp.vec2), frame: wp.array(dtype=wp.mat33),
              direction: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.vec2)):
        i = wp.tid()
        out[i] = pw.parallax_uv(patch, uv[i], frame[i], direction[i])

    count = uvs.shape[0]
    out = wp.zeros(count, dtype=wp.vec2, device=device)
    wp.launch(march, dim=count, device=device,
              inputs=[texture, wp.array(uvs.astype(np.float32), dtype=wp.vec2, device=device),
                      wp.array(frames.astype(np.float32), dtype=wp.mat33, device=device),
                      wp.array(directions.astype(np.float32), dtype=wp.vec3, device=device), out])
    return out.numpy()


def test_parallax_march_matches_mirror_and_lands_on_the_surface(device, weave, rng):
    count = 64
    frames = _random_frames(rng, count)
    uvs = rng.uniform(0.0, 1.0, size=(count, 2))
    # view rays toward the surface, 20-80 degrees from the normal
    theta, phi = rng.uniform(0.35, 1.4, count), rng.uniform(0, 2 * np.pi, count)
    local = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), -np.cos(theta)], 1)
    directions = np.einsum("nji,nj->ni", frames, local)
    got = _parallax_kernel(weave, 2.0, uvs, frames, directions, device)
    want = mirror.parallax_uv_f64(weave.heights, uvs, frames, directions, 2.0)
    assert_close(got, want, atol=ATOL_PARALLAX_FLOAT32, what="parallax UV, kernel vs float64")
    # the point found lies on the displaced surface: ray height == patch height there
    shift = (want - uvs) * 2.0
    along = np.sum(shift * local[:, :2], axis=1) / np.sum(local[:, :2] ** 2, axis=1)  # ray parameter s
    ray_z = along * local[:, 2]
    surface_z = lp.sample_heights(weave.heights, want * 2.0) - weave.heights.mean()
    assert_close(ray_z, surface_z, atol=ATOL_PARALLAX_HIT, what="march lands on the height field")


def test_parallax_is_no_shift_from_straight_above_or_on_a_flat_patch(device, weave, rng):
    count = 16
    frames = _random_frames(rng, count)
    uvs = rng.uniform(0.0, 1.0, size=(count, 2))
    got = _parallax_kernel(weave, 3.0, uvs, frames, -frames[:, 2], device)
    # straight down: the march moves along the normal only
    assert_close(got, uvs, atol=1e-5, what="view along -n")
    flat, _ = lp.bake_patch(lp.patch_heights("flat", 8, 0.0), ORDER, 16, 2, 0.05)
    oblique = -frames[:, 2] + 0.8 * frames[:, 0]
    got = _parallax_kernel(flat, 3.0, uvs, frames, oblique / np.linalg.norm(oblique, axis=1, keepdims=True), device)
    assert_close(got, uvs, atol=1e-5, what="flat patch")


def _wavy_sheet(n=12, size=2.0, with_block=False):
    """A deforming, UV-mapped sheet (two frames: flat, then waved) and optionally a UV-less box."""
    from warpshade.scene import Mesh, Scene

    g = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="xy"), -1).reshape(-1, 2) / (n - 1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    flat = np.concatenate([(g - 0.5) * size, np.zeros((n * n, 1))], 1)
    waved = flat.copy()
    waved[:, 2] = 0.15 * np.sin(2.0 * np.pi * g[:, 0]) * np.cos(np.pi * g[:, 1])
    meshes = [Mesh("/sheet", flat, faces, animation="deforming", point_samples=np.stack([flat, waved]), uvs=g,
                   albedo=np.full((n * n, 3), 0.7, np.float32))]
    if with_block:
        box = np.array([[x, y, z] for x in (-0.2, 0.2) for y in (-0.2, 0.2) for z in (0.5, 0.9)], np.float64)
        box_faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                              [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
        meshes.append(Mesh("/block", box, box_faces))
    return Scene.from_meshes(meshes, frames=[0.0, 1.0])


def _patch_run(scene, device, parallax=True):
    from warpshade.graph import GraphSpec, StageSpec
    from warpshade.scene import Environment, LightingSource

    spec = GraphSpec(stages=[
        StageSpec("patch", "ldprt.patch", {"shape": "waffle", "resolution": 8, "height": 0.3, "order": ORDER, "lobes": 3,
                                           "samples": 64, "tiles": 3}),
        StageSpec("shade", "ldprt.patch_shade", {"tiling": 2.0, "parallax": parallax, "prims": "/sheet"}),
    ], output="shade.radiance")
    return spec.compile(scene, device=device, cache_dir=None, progress=False,
                        lighting=LightingSource([Environment.sky(height=16, width=32)], "Z"))


@pytest.mark.parametrize("parallax", [False, True])
def test_stage_shades_pixels_like_the_mirror(device, parallax):
    """``render_pixels`` on a deformed frame: UVs, dP/du, dP/dv and albedo interpolated at the hits,
    the frame from the G-buffer normal, (the parallax march), the four texels -- against float64."""
    from warpshade.geometry._bvh import Visibility
    from warpshade.measure._protocols import PixelStage
    from warpshade.render import render_gbuffer
    from warpshade.scene import Camera

    scene = _wavy_sheet()
    rt = _patch_run(scene, device, parallax)
    stage = next(s for s in rt.stages if s.name == "shade")
    assert isinstance(stage, PixelStage)
    rt.step(1.0)
    state = rt.state
    bvh = Visibility.from_scene(scene, device=device)
    bvh.update(state.points)
    cam = Camera(position=np.array([0.3, -1.6, 1.8]), target=np.zeros(3), up=np.array([0.0, 0.0, 1.0]), vertical_fov=45.0)
    gb = render_gbuffer(bvh, state.normals, cam, 96, 72)  # past PIXEL_CHUNK_MIN: CPU chunks
    got = stage.render_pixels(gb).numpy()
    hit = gb.hit.numpy().astype(bool)
    assert hit.sum() > 100
    face, bary = gb.face.numpy()[hit], gb.bary.numpy()[hit].astype(np.float64)
    w = np.stack([bary[:, 0], bary[:, 1], 1.0 - bary[:, 0] - bary[:, 1]], 1)
    tri = scene.faces[face]
    points = state.points.numpy().astype(np.float64)
    uvs = scene.meshes[0].uvs
    t, b = mirror.patch_vertex_tangents_f64(points, scene.faces, uvs, np.ones(scene.vertex_count))
    frames = mirror.patch_tangent_frames_f64(gb.normal.numpy()[hit], np.einsum("pk,pkc->pc", w, t[tri]),
                                             np.einsum("pk,pkc->pc", w, b[tri]))
    uv = np.einsum("pk,pkc->pc", w, uvs[tri])
    model = stage.patch
    if parallax:
        uv = mirror.parallax_uv_f64(model.heights, uv, frames, gb.direction.numpy()[hit].astype(np.float64), 2.0)
    albedo = np.einsum("pk,pkc->pc", w, np.asarray(scene.albedo, np.float64)[tri])
    light = state.lighting.sh(ORDER).numpy().astype(np.float64)
    want = mirror.shade_patch_f64(model, uv, frames, light, albedo, 2.0)
    assert_close(got[hit], want, atol=ATOL_PATCH_FLOAT32 * 10, what="per-pixel patch shading vs float64")
    assert np.all(got[~hit] == 0.0)


def test_pixels_are_measured_on_the_displaced_geometry(device, tmp_path):
    """``measure_pixels`` traces the stage's displaced sheet (the UV-less block copied as it is) and
    measures the patched prims' pixels; the patch beats the undisplaced shading."""
    from warpshade.measure._pixels import measure_pixels

    scene = _wavy_sheet(with_block=True)
    rt = _patch_run(scene, device)
    model = next(s for s in rt.stages if s.name == "shade").pixel_reference_model()
    assert model["prims"] == ["/sheet"] and model["include"] == ("diffuse",)
    displaced = model["geometry"](1.0)
    assert [m.path for m in displaced.meshes] == ["/sheet", "/block"]
    assert displaced.meshes[0].faces.shape[0] > scene.meshes[0].faces.shape[0]
    rt.spec.name = "sheet"
    errors = {}
    for detail in ("patch", "none"):
        rt.set_parameter("shade", "detail", detail)
        rep = measure_pixels(rt, tmp_path, [1.0], width=32, height=24, samples=32, seed=5)
        errors[detail] = rep["frames"][1.0]["rel_rms"]
        assert 0 < rep["frames"][1.0]["pixels"] < 32 * 24
    assert np.isfinite(errors["patch"]) and errors["patch"] < errors["none"]
