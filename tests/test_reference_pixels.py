"""Per-pixel ground truth (warpshade.reference._pixels): against the per-vertex references at a
vertex hit by a pixel centre, as the same estimator as shade_points, per-pixel roughness and
colour maps against uniform runs, a glossy plane under a constant sky against the BRDF's
directional albedo (hemisphere quadrature), the box filter against its float64 mirror, the
exposed hits, extreme roughness and bad input."""

import numpy as np
import pytest
import trimesh
from grids import ground_grid

from warpshade._wp import wp
from warpshade.io import read_exr
from warpshade.reference import GlossyReferenceShader, pixel_hits, reference_image, shade, shade_glossy
from warpshade.reference._pixels import _box_filter_kernel, _coverage_kernel, box_filter_f64
from warpshade.scene import Camera, Environment, Mesh, Scene, _materials as materials

from tolerances import RTOL_FLOAT32, STDERR_SIGMAS, assert_within_stderr

#: Hemisphere quadrature (Gauss-Legendre 160 x 320) of the directional albedo: its own error for
#: alpha >= 0.15 (measured against 320 x 640 nodes: below 2e-4), relative.
QUADRATURE_RTOL = 1e-3
#: A pixel-centre ray aimed at a vertex hits it up to float32 rounding of the ray (world units).
HIT_ATOL = 1e-5

SKY = Environment.sky(16, 32, sun_angle_deg=25.0, sun_radiance=(6.0, 5.5, 5.0))
GGX = materials.Microfacet(roughness=0.3, distribution="ggx", f0=0.2)


def _occluded_ground(uvs=False):
    points, faces = ground_grid(np.linspace(-2.0, 2.0, 9))
    ball = trimesh.creation.icosphere(2, radius=0.45)
    ground = Mesh("ground", points, faces, albedo=(0.6, 0.5, 0.4), uvs=points[:, :2] * 0.25 + 0.5 if uvs else None)
    blocker = Mesh("ball", np.asarray(ball.vertices) + [0.5, 0.35, 0.6], np.asarray(ball.faces), albedo=(0.3, 0.7, 0.2))
    return Scene.from_meshes([ground, blocker], lights=[SKY])


def _camera(position=(0.0, -2.5, 2.0), target=(0.0, 0.0, 0.0), fov=40.0):
    return Camera(position=np.array(position, float), target=np.array(target, float), up=np.array([0.0, 0.0, 1.0]),
                  vertical_fov=fov)


def _big_plane():
    points, faces = ground_grid(np.linspace(-60.0, 60.0, 3))
    return Scene.from_meshes([Mesh("plane", points, faces, albedo=(0.5, 0.25, 0.125))])


def _directional_albedo(brdf, cos_view, z_nodes=160, phi_nodes=320):
    """``integral b(v, s) s_z ds`` for views at the given n.v, by hemisphere quadrature (float64)."""
    dirs, w = materials.hemisphere_quadrature(z_nodes, phi_nodes)
    c = np.clip(np.asarray(cos_view, np.float64), 1e-9, 1.0)
    views = np.stack([np.sqrt(1.0 - c * c), np.zeros_like(c), c], -1)
    out = np.empty(len(c))
    for i in range(0, len(c), 16):
        vals = brdf.evaluate(views[i:i + 16, None, :], dirs[None, :, :])
        out[i:i + 16] = vals @ (w * dirs[:, 2])
    return out


def test_box_filter_and_coverage_kernels_match_their_reference(device, rng):
    width, height, factor = 5, 3, 3
    values = rng.normal(size=(width * height * factor * factor, 3)).astype(np.float32)
    hit = (rng.random(values.shape[0]) > 0.4).astype(np.int32)
    for rss in (0, 1):
        out = wp.empty(width * height, dtype=wp.vec3, device=device)
        wp.launch(_box_filter_kernel, dim=(height, width), inputs=[wp.array(values, dtype=wp.vec3, device=device), factor,
                                                                  width, rss, out], device=device)
        ref = box_filter_f64(values, width, height, factor, root_sum_square=bool(rss))
        np.testing.assert_allclose(out.numpy().reshape(height, width, 3), ref, rtol=RTOL_FLOAT32, atol=1e-6)
    cov = wp.empty(width * height, dtype=wp.float32, device=device)
    wp.launch(_coverage_kernel, dim=(height, width), inputs=[wp.array(hit, dtype=wp.int32, device=device), factor, width, cov],
              device=device)
    ref = hit.reshape(height, factor, width, factor).mean(axis=(1, 3))
    np.testing.assert_allclose(cov.numpy().reshape(height, width), ref, rtol=0, atol=1e-7)


def test_pixel_centre_on_a_vertex_matches_the_per_vertex_references(device):
    """An odd image's centre ray is the camera's forward axis: aimed at a ground vertex it hits
    that vertex, so the pixel's reference is the vertex's (independent random streams)."""
    scene = _occluded_ground()
    camera = _camera()
    vertex = int(np.argmin(np.linalg.norm(scene.points_at(0.0), axis=1)))  # the ground vertex at the origin
    ref = reference_image(scene, 0.0, GGX, camera=camera, width=9, height=9, samples=1024, device=device, seed=3)
    centre = (4, 4)
    np.testing.assert_allclose(ref.hits.points[4 * 9 + 4], scene.points_at(0.0)[vertex], atol=HIT_ATOL)
    spec = shade_glossy(scene, 0.0, GGX, eye=camera.position, samples=1024, device=device, vertices=[vertex], seed=11)
    diff = shade(scene, 0.0, samples=1024, device=device, vertices=[vertex], seed=12)
    for part, vertex_result in (("specular", spec), ("diffuse", diff)):
        pixel = getattr(ref, part)[centre]
        sigma = np.hypot(getattr(ref, part + "_stderr")[centre], vertex_result.stderr[0])
        assert_within_stderr(pixel, vertex_result.radiance[0], sigma, floor=RTOL_FLOAT32 * pixel, what=f"{part} pixel vs vertex")
        assert pixel.min() > 0.0
    total = spec.radiance[0] + diff.radiance[0]
    sigma = np.sqrt(ref.stderr[centre] ** 2 + spec.stderr[0] ** 2 + diff.stderr[0] ** 2)
    assert_within_stderr(ref.radiance[centre], total, sigma, floor=RTOL_FLOAT32 * total, what="pixel vs vertex total")


def test_specular_part_is_shade_points_at_the_hits(device):
    """The same estimator, receivers, tint and seed: identical to shade_points at the hit points."""
    scene = _occluded_ground()
    camera = _camera()
    width, height = 12, 9
    ref = reference_image(scene, 0.0, GGX, camera=camera, width=width, height=height, samples=32, device=device, seed=5,
                          include=("specular",))
    shader = GlossyReferenceShader(scene, GGX, camera.position, samples=32, device=device, seed=5, vertices=[0])
    state = scene.evaluate(0.0, device=device)
    shader.update(state.points, state.normals)
    hit = np.nonzero(ref.hits.hit)[0]
    count = width * height
    out_r = wp.zeros(len(hit), dtype=wp.vec3, device=device)
    out_s = wp.zeros(len(hit), dtype=wp.vec3, device=device)
    shader.shade_points(wp.array(ref.hits.points, dtype=wp.vec3, device=device), wp.array(ref.hits.normals, dtype=wp.vec3, device=device),
                        wp.array(np.ones((count, 3), np.float32), dtype=wp.vec3, device=device),
                        wp.array(hit.astype(np.int32), dtype=wp.int32, device=device), out_r, out_s, seed=5)
    expected = np.zeros((count, 3), np.float32)
    expected[hit] = out_r.numpy()
    assert np.array_equal(ref.specular.reshape(count, 3), expected)
    assert np.array_equal(ref.radiance, ref.specular) and ref.diffuse is None
    assert ref.mask.sum() == len(hit)


def test_uniform_roughness_and_colour_arrays_reproduce_the_uniform_material(device):
    scene = _occluded_ground()
    kw = dict(camera=_camera(), width=10, height=8, samples=16, device=device, seed=2, include=("specular",))
    count = 80
    base = reference_image(scene, 0.0, GGX, **kw)
    same = reference_image(scene, 0.0, GGX, roughness=np.full(count, GGX.roughness), specular=np.ones((8, 10, 3)), **kw)
    assert np.array_equal(base.radiance, same.radiance) and np.array_equal(base.stderr, same.stderr)
    # the per-vertex parameters of the glossy shader: equal to the uniform ones, identical results
    uniform = shade_glossy(scene, 0.0, GGX, eye=(0.3, -2.0, 1.5), samples=16, color=(0.9, 0.8, 0.7), device=device)
    rows = shade_glossy(scene, 0.0, GGX, eye=(0.3, -2.0, 1.5), samples=16, color=np.tile([0.9, 0.8, 0.7], (scene.vertex_count, 1)),
                        roughness=np.full(scene.vertex_count, GGX.roughness), device=device)
    assert np.array_equal(uniform.radiance, rows.radiance) and np.array_equal(uniform.stderr, rows.stderr)


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
def test_two_valued_maps_equal_two_uniform_runs(device, distribution):
    """Left half alpha 0.15 and colour A, right half alpha 0.6 and colour B: each half is the run
    with that uniform BRDF (identical: same per-pixel streams), the colour a per-pixel factor."""
    scene = _occluded_ground()
    width, height = 12, 8
    kw = dict(camera=_camera(), width=width, height=height, samples=16, device=device, seed=4, include=("specular",))
    left = np.zeros((height, width), bool)
    left[:, : width // 2] = True
    alphas = (0.15, 0.6)
    colours = (np.array([1.0, 0.5, 0.25]), np.array([0.2, 0.9, 0.4]))
    rough = np.where(left, alphas[0], alphas[1])
    colour = np.where(left[..., None], colours[0], colours[1])
    mixed = reference_image(scene, 0.0, materials.Microfacet(0.3, distribution, 0.1), roughness=rough, **kw)
    tinted = reference_image(scene, 0.0, materials.Microfacet(0.3, distribution, 0.1), roughness=rough, specular=colour, **kw)
    for region, alpha, c in ((left, alphas[0], colours[0]), (~left, alphas[1], colours[1])):
        uniform = reference_image(scene, 0.0, materials.Microfacet(alpha, distribution, 0.1), **kw)
        assert np.array_equal(mixed.radiance[region], uniform.radiance[region])
        assert np.array_equal(mixed.stderr[region], uniform.stderr[region])
        np.testing.assert_allclose(tinted.radiance[region], uniform.radiance[region] * c, rtol=RTOL_FLOAT32, atol=1e-7)
    assert not np.allclose(mixed.radiance[left], reference_image(scene, 0.0, materials.Microfacet(alphas[1], distribution, 0.1),
                                                                 **kw).radiance[left])


@pytest.mark.parametrize("distribution", ["ggx", "beckmann"])
def test_glossy_plane_under_a_constant_sky_is_its_directional_albedo(device, distribution):
    """No occluder, constant radiance L: L_o(v) = L * integral b(v, s) cos ds per pixel (roughness
    map of two values); the diffuse part is albedo * L."""
    radiance = np.array([1.5, 1.0, 0.5])
    scene = _big_plane()
    width, height = 16, 12
    brdf = materials.Microfacet(0.3, distribution, f0=0.5, specular=0.8)
    rough = np.where(np.arange(width)[None, :] < width // 2, 0.2, 0.5) * np.ones((height, 1))
    ref = reference_image(scene, 0.0, brdf, camera=_camera((0.0, -3.0, 2.0)), width=width, height=height, samples=256,
                          lighting=[Environment.constant(radiance)], roughness=rough, device=device, seed=1)
    assert ref.mask.all()
    cos_view = np.einsum("ij,ij->i", ref.hits.normals, ref.eye - ref.hits.points)
    cos_view /= np.linalg.norm(ref.eye - ref.hits.points, axis=1)
    expected = np.empty(width * height)
    for alpha in (0.2, 0.5):
        sel = rough.reshape(-1) == alpha
        expected[sel] = _directional_albedo(materials.Microfacet(alpha, distribution, 0.5, 0.8), cos_view[sel])
    expected = (expected[:, None] * radiance).reshape(height, width, 3)
    assert_within_stderr(ref.specular, expected, ref.specular_stderr, floor=(QUADRATURE_RTOL + RTOL_FLOAT32) * expected,
                         what="specular pixels vs directional albedo")
    assert np.median(ref.specular_stderr / expected) < 0.05, "the check has power"
    diffuse = scene.albedo[0] * radiance
    assert_within_stderr(ref.diffuse, diffuse, ref.diffuse_stderr, floor=RTOL_FLOAT32 * diffuse, what="diffuse pixels")


def test_directional_albedo_quadrature_has_converged():
    brdf = materials.Microfacet(0.15, "ggx", 0.5)
    cos_view = np.array([0.2, 0.6, 0.95])
    coarse = _directional_albedo(brdf, cos_view)
    fine = _directional_albedo(brdf, cos_view, 320, 640)
    np.testing.assert_allclose(coarse, fine, rtol=QUADRATURE_RTOL)


def test_pixel_hits_expose_points_normals_uvs_and_barycentrics(device):
    scene = _occluded_ground(uvs=True)
    hits = pixel_hits(scene, 0.0, camera=_camera(), width=10, height=8, supersample=2, device=device)
    assert hits.ray_count == 320 and hits.hit.shape == (320,) and hits.points.shape == (320, 3)
    h = hits.hit
    corners = scene.faces[hits.triangles[h]]
    rebuilt = np.einsum("ik,ikj->ij", hits.barycentrics[h], scene.points_at(0.0)[corners])
    np.testing.assert_allclose(rebuilt, hits.points[h], atol=HIT_ATOL)
    np.testing.assert_allclose(np.linalg.norm(hits.normals[h], axis=1), 1.0, atol=1e-5)
    assert np.all(np.einsum("ij,ij->i", hits.normals[h], hits.directions[h]) <= 0.0), "normals face the camera"
    on_ground = h & (hits.triangles < scene.meshes[0].triangle_count)
    assert np.array_equal(hits.uv_valid, on_ground)
    np.testing.assert_allclose(hits.uvs[on_ground], hits.points[on_ground, :2] * 0.25 + 0.5, atol=HIT_ATOL)
    assert np.all(hits.triangles[~h] == -1)


def test_supersampled_image_is_bounded_and_saved(device, tmp_path):
    scene = _occluded_ground()
    ref = reference_image(scene, 0.0, GGX, camera=_camera(fov=70.0), width=8, height=6, samples=8, supersample=2,
                          device=device)
    assert ref.radiance.shape == (6, 8, 3) and ref.coverage.shape == (6, 8)
    assert 0 < ref.mask.sum() < 48 and np.all(ref.mask == (ref.coverage == 1.0))
    assert np.all(np.isfinite(ref.radiance)) and np.all(ref.radiance >= 0.0) and np.all(ref.radiance[ref.coverage == 0] == 0.0)
    paths = ref.save(tmp_path / "img")
    assert sorted(paths) == ["diffuse", "exr", "png", "specular"] and paths["png"].exists()
    np.testing.assert_array_equal(read_exr(paths["exr"]), ref.radiance)
    np.testing.assert_array_equal(read_exr(paths["specular"]), ref.specular)


@pytest.mark.parametrize("alpha", [1e-3, 2.0])
def test_extreme_roughness_is_bounded(device, alpha):
    """Near-mirror and very rough lobes under a constant sky: finite and at most L (f0 = 1,
    directional albedo <= 1), never NaN."""
    scene = _big_plane()
    brdf = materials.Microfacet(0.3, "ggx", f0=1.0)
    ref = reference_image(scene, 0.0, brdf, camera=_camera((0.0, -3.0, 2.0)), width=8, height=6, samples=64,
                          lighting=[Environment.constant((1.0, 1.0, 1.0))], roughness=np.full(48, alpha), include=("specular",),
                          device=device)
    assert np.all(np.isfinite(ref.radiance)) and np.all(np.isfinite(ref.stderr))
    assert np.all(ref.radiance >= 0.0) and np.all(ref.radiance <= 1.0 + STDERR_SIGMAS * ref.stderr + RTOL_FLOAT32)


def test_bad_input_names_the_parameter(device):
    scene = _occluded_ground()
    kw = dict(camera=_camera(), width=6, height=4, samples=4, device=device)
    with pytest.raises(ValueError, match=r"roughness must have shape \(24,\)"):
        reference_image(scene, 0.0, GGX, roughness=np.full(23, 0.3), **kw)
    with pytest.raises(ValueError, match="specular must have shape"):
        reference_image(scene, 0.0, GGX, specular=np.ones(24), **kw)
    with pytest.raises(ValueError, match="albedo must have shape"):
        reference_image(scene, 0.0, GGX, albedo=np.ones((4, 6, 2)), **kw)
    with pytest.raises(ValueError, match=r"roughness must have shape \(96,\)"):
        reference_image(scene, 0.0, GGX, roughness=np.full(24, 0.3), supersample=2, **kw)  # one value per ray
    with pytest.raises(ValueError, match=r"roughness must be finite and in \(0, 2\]"):
        reference_image(scene, 0.0, GGX, roughness=np.full(24, 2.5), **kw)
    with pytest.raises(ValueError, match="roughness must be finite and >= 0"):
        reference_image(scene, 0.0, GGX, roughness=np.full(24, np.nan), **kw)
    with pytest.raises(ValueError, match="specular must be finite and >= 0"):
        reference_image(scene, 0.0, GGX, specular=-np.ones((24, 3)), **kw)
    with pytest.raises(ValueError, match="roughness overrides a microfacet roughness.*'phong'"):
        reference_image(scene, 0.0, materials.Phong(20.0), roughness=np.full(24, 0.3), **kw)
    with pytest.raises(ValueError, match="include"):
        reference_image(scene, 0.0, GGX, include=("glossy",), **kw)
    with pytest.raises(ValueError, match="include"):
        reference_image(scene, 0.0, GGX, include=(), **kw)
    with pytest.raises(ValueError, match="supersample must be a positive integer"):
        reference_image(scene, 0.0, GGX, supersample=0, **kw)
    with pytest.raises(ValueError, match="method"):
        reference_image(scene, 0.0, GGX, method="cosine", **kw)
    with pytest.raises(ValueError, match="eye"):
        reference_image(scene, 0.0, GGX, eye=(0.0, np.inf, 1.0), **kw)
    with pytest.raises(ValueError, match="color must be 3 floats or have shape"):
        shade_glossy(scene, 0.0, GGX, eye=(0.0, -2.0, 1.0), color=np.ones((5, 3)), device=device)
    with pytest.raises(ValueError, match=r"roughness must have shape"):
        shade_glossy(scene, 0.0, GGX, eye=(0.0, -2.0, 1.0), roughness=np.full(5, 0.3), device=device)
    # values at rays that miss are ignored (textures are undefined there)
    hits = pixel_hits(scene, 0.0, camera=_camera(fov=80.0), width=6, height=4, device=device)
    assert not hits.hit.all()
    rough = np.where(hits.hit, 0.3, np.nan)
    ref = reference_image(scene, 0.0, GGX, roughness=rough, **{**kw, "camera": _camera(fov=80.0)})
    assert np.all(np.isfinite(ref.radiance))
