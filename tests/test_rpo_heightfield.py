"""Dynamic height fields with RPO shading (warpshade.methods.heightfield): the kernels against
their float64 oracles, analytic cases, the visibility against ray tracing, failure cases, and the
bundled graph end to end on a reduced-resolution copy of the water."""

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from warpshade.render import frame_camera
from scipy.spatial.transform import Rotation

from warpshade._wp import wp
from warpshade.basis import sh
from warpshade.graph import GraphSpec, StageSpec, load
from warpshade.io import _heightfield as hfio
from warpshade.io import bundled_asset_directory, load_scene
from warpshade.methods.heightfield import _kernels as hfk
from warpshade.methods.heightfield import _model as hf
from warpshade.methods.heightfield import _mirror as ref
from warpshade.graph import StageError
from warpshade.scene import Camera, Environment, LightingSource, Mesh, Scene

ROOT = Path(__file__).resolve().parent.parent

# float32 kernels against float64 (rotation, product: a few float32 ulps of O(1) coefficients)
ATOL_SH_ALGEBRA = 1e-5
# the wedge table against direct 2-D quadrature of the wedge's indicator (both float64)
ATOL_WEDGE_TABLE = 1e-12
# texel visibility (float32 table interpolation, 257 entries) against the exact float64 wedges at
# the kernel's own horizons; measured 3e-4 (largest coefficient about 3.5)
ATOL_TEXEL_VISIBILITY = 2e-3
# the flat plane: every wedge at z0 = 0 sums to the exact hemisphere / sphere (float32)
ATOL_FLAT = 2e-5
# horizon-based visibility (64 x 64 grid, 16 azimuths, order 4) against 4096 ray-traced rays
# per vertex (world frame, open below the tangent plane), relative RMS over the vertices:
# measured 3.1 % (the azimuthal wedges, the march's bias, the texel's tangent plane)
RTOL_VS_TRACED = 0.05
# the shading kernel against its float64 mirror, relative to the largest radiance; measured 2e-6
RTOL_SHADE = 1e-4
# heightfield_shade against rpo.shade over the same per-vertex visibility (different tangent
# frames and F evaluation: table in cos(theta_o) vs direct view factors), relative RMS; measured 0.4 %
RTOL_SHADE_VS_RPO = 0.02


def _ripples(resolution=64, times=(0.0, 0.5), **kw) -> Scene:
    spec = hfio.HeightFieldSpec(resolution, (4.0, 4.0), [(0.06, 1.3, 1.0, 0.3, 0.6, 0.0), (0.03, 0.6, -0.4, 1.0, 0.5, 1.0)],
                                [(0.02, 0.4, 0.3, -0.5, 0.3, 0.0, 0.5)], terrain=(0.01, 1.0, 2, 3), **kw)
    mesh = hfio.mesh_from_spec(spec, times, path="/Water")
    cam = Camera(np.array([-1.5, 4.0, 1.0]), np.array([0.0, -0.5, 0.0]), np.array([0.0, 0.0, 1.0]))
    return Scene.from_meshes([mesh], frames=range(len(times)), camera=cam)


def _grid_scene(heights, size=2.0, camera=True) -> Scene:
    h = np.asarray(heights, np.float64)
    g = h.shape[0]
    x, y = hfio.grid_xy(g, (size, size))
    mesh = Mesh("/Grid", np.stack([x, y, h.ravel()], 1), hfio.grid_faces(g))
    cam = Camera(np.array([0.0, -3.0, 1.5]), np.zeros(3), np.array([0.0, 0.0, 1.0])) if camera else None
    return Scene.from_meshes([mesh], camera=cam)


def _sky(scene):
    return LightingSource([Environment.sky()], scene.up_axis)


def _run(scene, vis_params=None, shade_params=None, frame=0.0, per_vertex=True, *, device):
    stages = [StageSpec("vis", "heightfield.visibility", {"order": 4, "resolution": 32, "per_vertex": per_vertex,
                                                              **(vis_params or {})})]
    if shade_params is not None:
        stages.append(StageSpec("shade", "heightfield.shade", {"order": 4, "rank": 8, "roughness": 0.3,
                                                                    **shade_params}))
    out = "shade.radiance" if shade_params is not None else ("vis.visibility" if per_vertex else "vis.texel_visibility")
    rt = GraphSpec(stages=stages, output=out, name="hf-test").compile(scene, device=device, cache_dir=None, progress=False,
                                                                       lighting=_sky(scene))
    rt.step(frame)
    return rt


# ---- SH algebra and tables ----------------------------------------------------------------------
@pytest.mark.parametrize("order", [3, 4])
def test_static_rotation_and_product_match_float64(order, rng, device):
    _, _, rot_k, pair_k = hfk.shade_kernels(order)
    f = rng.normal(size=(64, order * order))
    g = rng.normal(size=(64, order * order))
    r = Rotation.random(64, random_state=3).as_matrix()
    r[0] = np.eye(3)
    r[1] = np.diag([1.0, -1.0, -1.0])  # the poles of the Euler angles
    out = wp.zeros((64, order * order), dtype=wp.float32, device=device)
    fa = wp.array(f.astype(np.float32), dtype=wp.float32, device=device)
    wp.launch(rot_k, dim=64, inputs=[fa, wp.array(r.astype(np.float32), dtype=wp.mat33, device=device), out], device=device)
    assert np.abs(out.numpy() - sh.rotate(f, r)).max() < ATOL_SH_ALGEBRA * 10
    wp.launch(pair_k, dim=64, inputs=[fa, wp.array(g.astype(np.float32), dtype=wp.float32, device=device), out], device=device)
    assert np.abs(out.numpy() - sh.product(f, g)).max() < ATOL_SH_ALGEBRA * 10


@pytest.mark.parametrize("order,azimuths", [(3, 8), (4, 16), (6, 12)])
def test_wedge_table_matches_direct_quadrature(order, azimuths):
    table = hf.wedge_table(order, azimuths, 33)
    z0 = np.linspace(-1.0, 1.0, 33)
    for i in (0, 5, 16, 27, 32):
        want = ref.wedge_f64(order, 0.0, 2 * np.pi / azimuths, z0[i])
        assert np.abs(table[i] - want).max() < ATOL_WEDGE_TABLE * 1e3
    # placed by a z-rotation: the wedge about phi = 1.1
    rz = Rotation.from_euler("z", 1.1).as_matrix()
    assert np.abs(sh.rotate(table[12], rz) - ref.wedge_f64(order, 1.1, 2 * np.pi / azimuths, z0[12])).max() < 1e-9
    # all wedges at z0 = -1 tile the sphere: V = 1
    full = sum(sh.rotate(table[0], Rotation.from_euler("z", 2 * np.pi * k / azimuths).as_matrix()) for k in range(azimuths))
    assert abs(full[0] - math.sqrt(4 * math.pi)) < 1e-9 and np.abs(full[1:]).max() < 1e-9


# ---- horizons ----------------------------------------------------------------------------------
def test_step_gives_the_analytic_horizon(device):
    g, size, wall, height = 33, 2.0, 20, 0.3
    h = np.zeros((g, g))
    h[:, wall:] = height
    dx = size / (g - 1)
    cols = np.array([10.0, 14.0, 17.0, 18.0, 19.0])
    rows = np.full_like(cols, 16.0)
    analytic = height / ((wall - cols) * dx)
    bf = ref.horizon_f64(h, dx, dx, cols, rows, 4)
    assert np.allclose(bf[:, 0], analytic, rtol=1e-12)
    assert np.all(bf[:, 2] == 0.0)  # looking away from the wall: flat ground
    rt = _run(_grid_scene(h, size), {"resolution": g, "azimuths": 4, "samples_per_octave": 4, "footprint": 0.05}, device=device)
    kernel = rt.stages[0].horizons(np.stack([cols, rows], 1))
    # the finest level's cells hold one vertex each: a sample at distance d reads the vertex
    # nearest to it, so the wall (D vertices away) is seen from d >= D - 1/2 on
    dist = wall - cols
    assert np.isclose(kernel[dist == 1, 0], analytic[dist == 1], rtol=1e-5)
    assert np.all(kernel[:, 0] >= analytic * (1 - 1e-5))  # the max pyramid never lowers a horizon
    assert np.all(kernel[:, 0] <= analytic * dist / (dist - 0.5) * (1 + 1e-5))
    assert np.allclose(kernel[:, 2], 0.0, atol=1e-6)


def test_march_kernel_matches_its_float64_mirror_and_brute_force(device):
    scene = _ripples(64)
    rt = _run(scene, {"samples_per_octave": 2, "footprint": 0.5}, device=device)
    vis = rt.stages[0]
    h = scene.points_at(0.0)[:, 2].reshape(64, 64)
    lay = vis.layout
    uv = np.random.default_rng(0).uniform(0, 63, size=(200, 2))
    kernel = vis.horizons(uv)
    d, lev = vis.march
    mirror = ref.horizon_march_f64(h, lay.dx, lay.dy, uv[:, 0], uv[:, 1], 16, d, lev)
    both = np.isfinite(mirror)
    assert np.array_equal(both, kernel > -1e29)
    assert np.abs(kernel[both] - mirror[both]).max() < 1e-4
    bf = ref.horizon_f64(h, lay.dx, lay.dy, uv[:, 0], uv[:, 1], 16)
    err = np.degrees(np.arctan(mirror[both]) - np.arctan(bf[both]))
    assert abs(err.mean()) < 2.0 and np.abs(err).mean() < 3.0  # degrees of horizon elevation


# ---- visibility --------------------------------------------------------------------------------
@pytest.mark.parametrize("below", ["open", "blocked"])
def test_flat_plane_gives_full_visibility(below, device):
    scene = _grid_scene(np.full((17, 17), 0.25))
    rt = _run(scene, {"resolution": 9, "below": below}, device=device)
    v = rt.output.numpy()
    if below == "open":
        want = np.zeros(16)
        want[0] = math.sqrt(4 * math.pi)
        assert np.abs(v - want[None]).max() < ATOL_FLAT
    else:
        # the upper hemisphere, away from the edge (nothing blocks beyond it: texels on the edge
        # see below the plane outward)
        want = ref.wedge_exact(4, 1, 0.0)[0]
        r, c = np.divmod(np.arange(17 * 17), 17)
        inner = (r >= 2) & (r <= 14) & (c >= 2) & (c <= 14)
        assert np.abs(v[inner] - want[None]).max() < ATOL_FLAT
        assert np.all(v[~inner, 0] >= want[0] - ATOL_FLAT)


@pytest.mark.parametrize("below", ["open", "blocked"])
def test_texel_visibility_matches_exact_wedges(below, device):
    scene = _ripples(48)
    rt = _run(scene, {"resolution": 16, "below": below}, per_vertex=False, device=device)
    vis = rt.stages[0]
    texels = rt.output.numpy()
    h = scene.points_at(0.0)[:, 2].reshape(48, 48)
    u, v = ref.texel_coordinates(48, 16)
    slopes = vis.horizons(np.stack([u, v], 1)).astype(np.float64)
    slopes[slopes < -1e29] = -np.inf
    tangent = None
    if below == "open":
        lay = vis.layout
        hx = (ref.bilinear(h, u + 1, v) - ref.bilinear(h, u - 1, v)) / ((np.minimum(u + 1, 47) - np.maximum(u - 1, 0)) * lay.dx)
        hy = (ref.bilinear(h, u, v + 1) - ref.bilinear(h, u, v - 1)) / ((np.minimum(v + 1, 47) - np.maximum(v - 1, 0)) * lay.dy)
        phi = 2 * np.pi * np.arange(16) / 16
        tangent = hx[:, None] * np.cos(phi)[None] + hy[:, None] * np.sin(phi)[None]
    want = ref.visibility_f64(slopes, 4, tangent)
    assert np.abs(texels - want).max() < ATOL_TEXEL_VISIBILITY


def test_horizon_visibility_against_ray_traced(device):
    from warpshade.transfer import compute

    scene = _ripples(64)
    rt = _run(scene, {"resolution": 64, "samples_per_octave": 2}, device=device)
    vis = rt.output.numpy()
    idx = np.random.default_rng(1).choice(scene.vertex_count, 300, replace=False)
    traced = compute(scene, 0.0, 4, 4096, space="world", device=device, vertices=idx, below_horizon="visible").visibility
    err = np.sqrt(np.mean(np.sum((vis[idx] - traced) ** 2, 1)) / np.mean(np.sum(traced**2, 1)))
    assert err < RTOL_VS_TRACED


# ---- shading -----------------------------------------------------------------------------------
def test_shade_kernel_matches_float64_mirror(device):
    scene = _ripples(48)
    rt = _run(scene, {"resolution": 16, "per_vertex": False}, {"specular": (0.9, 0.7, 0.5)}, device=device)
    shade = rt.stages[1]
    out = rt.output.numpy()
    texels = rt.stages[0]._texels.numpy().astype(np.float64)
    light = shade._lighting.light.numpy().astype(np.float64)
    g_texel = np.stack([sh.product(np.broadcast_to(light[c], texels.shape), texels) for c in range(3)], 1)
    # bilinear from the 16 x 16 texels to the 48 x 48 vertices
    r, c = np.divmod(np.arange(48 * 48), 48)
    fu, fv = c * 15 / 47, r * 15 / 47
    c0, r0 = np.minimum(fu.astype(int), 14), np.minimum(fv.astype(int), 14)
    tu, tv = (fu - c0)[:, None, None], (fv - r0)[:, None, None]
    t00 = r0 * 16 + c0
    g = (1 - tu) * (1 - tv) * g_texel[t00] + tu * (1 - tv) * g_texel[t00 + 1] + (1 - tu) * tv * g_texel[t00 + 16] + \
        tu * tv * g_texel[t00 + 17]
    st = rt.state
    want = ref.shade_f64(st.points.numpy(), st.normals.numpy(), st.eye.numpy()[0], g, shade.table, (0.9, 0.7, 0.5))
    assert np.abs(out - want).max() < RTOL_SHADE * want.max()
    assert out.max() > 0.0


def test_heightfield_shade_agrees_with_rpo_shade(device):
    import warpshade.methods.rpo._stages  # noqa: F401  (rpo.shade)
    import warpshade.methods.ldprt._stages  # noqa: F401  (ldprt.tangents)

    scene = _ripples(48)
    common = {"order": 4, "rank": 8, "roughness": 0.3}
    stages = [StageSpec("vis", "heightfield.visibility", {"order": 4, "resolution": 48}),
              StageSpec("tangents", "ldprt.tangents"),
              StageSpec("rpo", "rpo.shade", {**common, "visibility_space": "world"}, {"visibility": "vis.visibility"}),
              StageSpec("shade", "heightfield.shade", common, {"texel_visibility": "vis.texel_visibility"})]
    rt = GraphSpec(stages=stages, output="shade.radiance").compile(scene, device=device, cache_dir=None, progress=False,
                                                                   lighting=_sky(scene))
    rt.step(0.0)
    a = rt.output.numpy()
    b = rt.stages[[s.name for s in rt.stages].index("rpo")]._radiance.numpy()
    err = np.sqrt(np.mean((a - b) ** 2) / np.mean(b**2))
    assert err < RTOL_SHADE_VS_RPO


# ---- failures ----------------------------------------------------------------------------------
def test_grid_checks_and_bad_parameters_are_clear_errors(device):
    flat = np.zeros((9, 9))
    x, y = hfio.grid_xy(9, (2.0, 2.0))
    not_square = Scene.from_meshes([Mesh("/m", np.stack([x, y, 0 * x], 1)[:72], hfio.grid_faces(9)[:112])])
    with pytest.raises(StageError, match="heightfield.visibility.*square"):
        _run(not_square, device=device)
    pts = np.stack([x, y, 0 * x], 1)[np.random.default_rng(0).permutation(81)]
    with pytest.raises(StageError, match="heightfield.visibility.*(regular 9 x 9 grid|row-major)"):
        _run(Scene.from_meshes([Mesh("/m", pts, hfio.grid_faces(9))]), device=device)
    samples = np.stack([np.stack([x, y, 0 * x], 1)] * 2).astype(np.float32)
    samples[1, :, 0] += 0.05
    sideways = Scene.from_meshes([Mesh("/m", samples[0], hfio.grid_faces(9), animation="deforming", point_samples=samples)],
                                 frames=[0, 1])
    with pytest.raises(StageError, match="sideways"):
        _run(sideways, device=device)
    with pytest.raises(StageError, match="resolution 32 exceeds"):
        _run(_grid_scene(flat), device=device)
    with pytest.raises(StageError, match="azimuths"):
        _run(_grid_scene(flat), {"resolution": 9, "azimuths": 2}, device=device)
    with pytest.raises(StageError, match="below"):
        _run(_grid_scene(flat), {"resolution": 9, "below": "maybe"}, device=device)
    # no camera and no eye: the framing camera of the scene's bounds is the viewer (methods/viewer.py)
    rt = _run(_grid_scene(flat, camera=False), {"resolution": 9}, {}, device=device)
    np.testing.assert_allclose(rt.state.eye.numpy()[0], frame_camera(*rt.scene.bounds_over_frames(), rt.scene.up_axis).position,
                               rtol=1e-6)
    with pytest.raises(ValueError, match="resolution must be >= 2"):
        hfio.mesh_from_spec(hfio.HeightFieldSpec(1), [0.0])
    with pytest.raises(ValueError, match="MAX_SAMPLE_BYTES"):
        hfio.mesh_from_spec(hfio.HeightFieldSpec(8192), np.arange(48.0))


def test_spiky_heights_stay_finite_and_bounded(device):
    h = np.random.default_rng(5).normal(size=(33, 33)) * 50.0
    h[10, 10] = 1e4
    h[20, 5:25] = -1e4
    rt = _run(_grid_scene(h), {"resolution": 17}, {}, device=device)
    out = rt.output.numpy()
    assert np.all(np.isfinite(out)) and out.min() >= 0.0 and out.max() < 1e3
    vis = rt.stages[0]._vertex.numpy()
    assert np.all(np.isfinite(vis)) and np.abs(vis).max() <= math.sqrt(4 * math.pi) * 2


# ---- the asset and the graph -------------------------------------------------------------------
def test_loader_expands_the_height_field(tmp_path, device):
    from warpshade.usd_assets.generator.ripples import make_ripples

    path = make_ripples(str(tmp_path), resolution=64, frame_count=4, file_name="ripples64.usda")
    shutil.copy(Path(bundled_asset_directory()) / "sky.hdr", tmp_path / "sky.hdr")
    scene = load_scene(path)
    mesh = scene.meshes[0]
    assert scene.vertex_count == 64 * 64 and mesh.animation == "deforming" and mesh.point_samples.shape == (4, 4096, 3)
    assert mesh.triangle_count == 2 * 63 * 63 and scene.camera is not None and scene.lights
    n = scene.normals_at(0.0)
    assert n[:, 2].min() > 0.5  # counter-clockwise from +z
    from pxr import Usd

    stage = Usd.Stage.Open(path)
    spec = hfio.read_spec(stage.GetPrimAtPath("/World/Water"))
    want = hfio.heights(spec, [2 / 24.0])[0]
    assert np.allclose(mesh.point_samples[2, :, 2], want, atol=1e-6)
    # the bundled graph end to end on this copy
    graph = load(ROOT / "stages" / "ripples_height_rpo.toml")
    graph.validate_spec = {"frames": [0]}
    for st in graph.stages:  # the 128 x 128 texels of the graph as written exceed this 64 x 64 copy
        if st.type == "heightfield.visibility":
            st.params["resolution"] = 32
    rt = graph.compile(scene, device=device, cache_dir=None, progress=False)
    rt.run([0.0, 1.0], warmup=False)
    for f in (0.0, 1.0):
        out = rt.results[f]
        assert out.shape == (4096, 3) and np.all(np.isfinite(out)) and out.min() >= 0.0 and out.max() > 0.0


def test_shade_diagnostics_count_every_vertex_of_a_chunked_launch(device):
    # 96^2 vertices: more than two CPU chunks, so several threads shade at once; the counts are
    # per-vertex flags summed on the host, never a counter the threads share
    from warpshade.methods.heightfield._stages import CPU_CHUNK_MIN

    scene = _ripples(96)
    assert scene.vertex_count > 2 * CPU_CHUNK_MIN
    rt = _run(scene, {"resolution": 32, "per_vertex": False}, {}, device=device)
    st = rt.state
    p, n = st.points.numpy().astype(np.float64), st.normals.numpy().astype(np.float64)
    facing = np.einsum("ij,ij->i", n, st.eye.numpy()[0].astype(np.float64) - p)
    below = int(np.count_nonzero(facing <= 0.0))
    assert 0 < below < scene.vertex_count  # the view grazes the waves: some vertices face away
    diag = rt.stages[1].diagnostics()
    assert diag["below_horizon"] == below
    out = rt.output.numpy()
    assert np.all(out[facing <= 0.0] == 0.0)
    assert diag["negative_clamped"] == 0


@pytest.mark.parametrize("order", [3, 4, 6])
def test_even_rotation_is_the_rotation_of_a_cosine_only_function(order, rng, device):
    # an f without sine terms (the view factors of an isotropic lobe): the half first z-rotation
    # gives what the full rotation gives, and the float64 rotation
    rot = hfk.even_frame_rotation(order)
    from warpshade.basis.sh_warp import sh_kernels

    vec_t = sh_kernels(order).vec
    n2 = order * order

    @wp.kernel(enable_backward=False, module="unique")
    def rotate_even(f: wp.array2d(dtype=wp.float32), r: wp.array(dtype=wp.mat33), out: wp.array2d(dtype=wp.float32)):
        i = wp.tid()
        v = vec_t()
        for k in range(n2):
            v[k] = f[i, k]
        o = rot(v, r[i])
        for k in range(n2):
            out[i, k] = o[k]

    sine = [l * l + l + m for l in range(order) for m in range(-l, 0)]
    f = rng.normal(size=(64, n2))
    f[:, sine] = 0.0
    r = Rotation.random(64, random_state=5).as_matrix()
    r[0] = np.eye(3)
    r[1] = np.diag([1.0, -1.0, -1.0])
    fa = wp.array(f.astype(np.float32), dtype=wp.float32, device=device)
    ra = wp.array(r.astype(np.float32), dtype=wp.mat33, device=device)
    even = wp.zeros((64, n2), dtype=wp.float32, device=device)
    full = wp.zeros((64, n2), dtype=wp.float32, device=device)
    wp.launch(rotate_even, dim=64, inputs=[fa, ra, even], device=device)
    wp.launch(hfk.shade_kernels(order)[2], dim=64, inputs=[fa, ra, full], device=device)
    assert np.array_equal(even.numpy(), full.numpy())
    assert np.abs(even.numpy() - sh.rotate(f, r)).max() < ATOL_SH_ALGEBRA * 10


def test_view_tables_of_isotropic_brdfs_are_even_and_a_sine_term_is_seen():
    scene = _ripples(48)
    rt = _run(scene, {"resolution": 16, "per_vertex": False}, {}, device="cpu")
    table = rt.stages[1].table
    assert hfk.table_is_even(table) and rt.stages[1]._even  # the stage shades with the even kernel
    odd = table.copy()
    odd[:, 1] = 1e-6 * np.abs(table).max()  # (l, m) = (1, -1)
    assert not hfk.table_is_even(odd)
