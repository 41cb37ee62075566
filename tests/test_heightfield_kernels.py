"""The height field's restructured kernels against their float64 oracles: the lighting products
as per-frame product matrices, the texel march that stops once no later sample can matter, and
the shading by runs of vertices along a grid row (cells crossed, vertices skipped below their
tangent plane, a run cut by the grid's edge)."""

import math

import numpy as np
import pytest

from warpshade._wp import wp
from warpshade.basis import sh
from warpshade.basis.sh_warp import sh_kernels
from warpshade.graph import GraphSpec, StageSpec
from warpshade.io import _heightfield as hfio
from warpshade.methods.heightfield import _kernels as hfk
from warpshade.methods.heightfield import _mirror as ref
from warpshade.scene import Camera, Environment, LightingSource, Mesh, Scene

# the product matrices against the float64 SH product, relative to the largest coefficient
# (float32 sums of up to n^2 terms; measured ~2e-7)
RTOL_PRODUCT = 1e-5
# texel visibility against the exact float64 wedges at the full march's horizons (float32 table
# interpolation, 257 entries; the same bound as the texel test of test_rpo_heightfield.py)
ATOL_TEXEL_VISIBILITY = 2e-3
# the shading kernel against its float64 mirror, relative to the largest radiance (measured ~1e-6)
RTOL_SHADE = 1e-4


def _grid_scene(heights, size=2.0, eye=(0.0, -3.0, 1.5)) -> Scene:
    h = np.asarray(heights, np.float64)
    g = h.shape[0]
    x, y = hfio.grid_xy(g, (size, size))
    mesh = Mesh("/Grid", np.stack([x, y, h.ravel()], 1), hfio.grid_faces(g))
    cam = Camera(np.asarray(eye, np.float64), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    return Scene.from_meshes([mesh], camera=cam)


def _bumps(g: int, amplitude: float) -> np.ndarray:
    t = np.linspace(0.0, 1.0, g)
    x, y = np.meshgrid(t, t)
    return amplitude * (np.sin(9.0 * x + 1.0) * np.cos(7.0 * y) + 0.5 * np.sin(23.0 * (x + y)))


def _compile(scene, vis, shade=None, *, device):
    stages = [StageSpec("vis", "heightfield.visibility", {"order": 4, "per_vertex": False, **vis})]
    if shade is not None:
        stages.append(StageSpec("shade", "heightfield.shade", {"order": 4, "rank": 8, "roughness": 0.3, **shade}))
    out = "shade.radiance" if shade is not None else "vis.texel_visibility"
    rt = GraphSpec(stages=stages, output=out, name="hf-kernels").compile(
        scene, device=device, cache_dir=None, progress=False, lighting=LightingSource([Environment.sky()], scene.up_axis))
    rt.step(0.0)
    return rt


@pytest.mark.parametrize("order", [3, 4])
def test_product_matrices_match_the_float64_product(order, rng, device):
    n2 = order * order
    light = rng.normal(size=(3, n2))
    vis = rng.normal(size=(50, n2))
    vec_t = sh_kernels(order).vec
    cols = wp.zeros(3 * n2, dtype=vec_t, device=device)
    g = wp.zeros(3 * 50, dtype=vec_t, device=device)
    wp.launch(hfk.light_columns_kernel(order), dim=3, inputs=[wp.array(light.astype(np.float32), dtype=wp.float32,
                                                                        device=device), cols], device=device)
    product = hfk.shade_kernels(order)[0]
    wp.launch(product, dim=50, inputs=[wp.array(vis.astype(np.float32), dtype=wp.float32, device=device), cols, 0, g],
              device=device)
    got = g.numpy().reshape(50, 3, n2)
    want = np.stack([sh.product(np.broadcast_to(light[c], vis.shape), vis) for c in range(3)], 1)
    assert np.abs(got - want).max() < RTOL_PRODUCT * np.abs(want).max()


@pytest.mark.parametrize("below,azimuths", [("open", 16), ("blocked", 16), ("open", 7), ("blocked", 5)])
def test_texel_march_that_stops_early_matches_the_full_march(below, azimuths, device):
    # steep bumps: uphill the march's bound (top - h0) / d falls under the slope found or under
    # the tangent plane within a few samples, so most marches stop before the grid's edge; the
    # kernel marches four azimuths at a time (7: four, then three; 5: four, then one)
    g, res = 40, 14
    h = _bumps(g, 0.25)
    scene = _grid_scene(h)
    rt = _compile(scene, {"resolution": res, "below": below, "azimuths": azimuths}, device=device)
    vis = rt.stages[0]
    texels = rt.output.numpy()
    u, v = ref.texel_coordinates(g, res)
    slopes = vis.horizons(np.stack([u, v], 1)).astype(np.float64)  # the full march (no early end)
    assert np.mean(slopes > 0.5) > 0.1  # the case the early end is for
    slopes[slopes < -1e29] = -np.inf
    tangent = None
    if below == "open":
        lay = vis.layout
        hx = (ref.bilinear(h, u + 1, v) - ref.bilinear(h, u - 1, v)) / ((np.minimum(u + 1, g - 1) - np.maximum(u - 1, 0)) * lay.dx)
        hy = (ref.bilinear(h, u, v + 1) - ref.bilinear(h, u, v - 1)) / ((np.minimum(v + 1, g - 1) - np.maximum(v - 1, 0)) * lay.dy)
        phi = 2 * np.pi * np.arange(azimuths) / azimuths
        tangent = hx[:, None] * np.cos(phi)[None] + hy[:, None] * np.sin(phi)[None]
    want = ref.visibility_f64(slopes, 4, tangent)
    assert np.abs(texels - want).max() < ATOL_TEXEL_VISIBILITY


@pytest.mark.parametrize("size,res", [(70, 9), (33, 33)])
def test_shading_runs_match_the_float64_mirror(size, res, device):
    # 70 vertices a row: runs of 32, 32 and 6; a low eye puts some vertices' views below their
    # tangent planes (skipped inside a run); 33 x 33 texels: one cell per vertex step
    h = _bumps(size, 0.12)
    scene = _grid_scene(h, eye=(0.3, -1.6, 0.08))
    rt = _compile(scene, {"resolution": res}, {"specular": (0.9, 0.7, 0.5)}, device=device)
    shade = rt.stages[1]
    out = rt.output.numpy()
    flags = shade._flags.numpy()
    assert np.count_nonzero(flags & hfk.FLAG_BELOW_HORIZON) > 0
    assert np.count_nonzero(flags & hfk.FLAG_BELOW_HORIZON) < size * size // 2
    texels = rt.stages[0]._texels.numpy().astype(np.float64)
    light = shade._lighting.light.numpy().astype(np.float64)
    g_texel = np.stack([sh.product(np.broadcast_to(light[c], texels.shape), texels) for c in range(3)], 1)
    r, c = np.divmod(np.arange(size * size), size)
    scale = (res - 1) / (size - 1)
    fu, fv = c * scale, r * scale
    c0, r0 = np.minimum(fu.astype(int), res - 2), np.minimum(fv.astype(int), res - 2)
    tu, tv = (fu - c0)[:, None, None], (fv - r0)[:, None, None]
    t00 = r0 * res + c0
    g = (1 - tu) * (1 - tv) * g_texel[t00] + tu * (1 - tv) * g_texel[t00 + 1] + (1 - tu) * tv * g_texel[t00 + res] + \
        tu * tv * g_texel[t00 + res + 1]
    st = rt.state
    want = ref.shade_f64(st.points.numpy(), st.normals.numpy(), st.eye.numpy()[0], g, shade.table, (0.9, 0.7, 0.5))
    assert want.max() > 0.0
    assert np.abs(out - want).max() < RTOL_SHADE * want.max()
    assert np.all(out[(flags & hfk.FLAG_BELOW_HORIZON) != 0] == 0.0)
    assert math.isfinite(float(out.sum()))
