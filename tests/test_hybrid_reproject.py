"""hybrid.trace with ``reproject``: the history carried by each vertex's tangent-frame turn, against
the float64 mirror, an exact rotation of a projected lobe, and a spinning box in a graph."""

import numpy as np
import pytest
import trimesh

from warpshade._wp import wp
from warpshade.basis import quadrature, sh
from warpshade.basis.sh_warp import sh_kernels
from warpshade.graph import GraphSpec, StageSpec
from warpshade.methods.hybrid import _kernels as kernels, reproject_f64
from warpshade.scene import Environment, Mesh, Scene

from tolerances import assert_close

ORDER = 4
#: float32 SH rotation (ZYZ Euler factorisation) against the float64 Ivanic-Ruedenberg blocks,
#: coefficients of size <= ~1: a few float32 roundings per band product.
ATOL_ROTATION = 2e-5
#: A spinning convex box, 16 rays per frame over 10 frames (the last estimate as control, no
#: history cuts), against the exact clamped-cosine projection: the reprojected history leaves only
#: the rays' noise (measured 0.030); without reprojection the history lags the 25-degree turn per
#: frame (measured 0.67).
REL_SPIN_REPROJECTED = 0.06
REL_SPIN_STALE = 0.3


def _random_rotations(rng, count):
    q = rng.standard_normal((count, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], 1)


def _reproject(device, target, frames, prev, count):
    dev = wp.get_device(device)
    t = wp.array(target.astype(np.float32), dtype=wp.float32, device=dev)
    pf = wp.array(prev.astype(np.float32), dtype=wp.mat33, device=dev)
    wp.launch(kernels.reproject_kernel(ORDER), dim=target.shape[0], device=dev,
              inputs=[wp.array(frames.astype(np.float32), dtype=wp.mat33, device=dev), pf,
                      wp.array(count.astype(np.float32), dtype=wp.float32, device=dev),
                      sh_kernels(ORDER).tables(dev), t])
    return t.numpy(), pf.numpy()


def test_reproject_kernel_matches_mirror_and_skips_vertices_without_history(device, rng):
    v, c = 12, ORDER * ORDER
    target = rng.standard_normal((v, c))
    frames, prev = _random_rotations(rng, v), _random_rotations(rng, v)
    count = np.full(v, 3.0)
    count[0] = 0.0  # no history yet: left as it is
    frames[1, 0, 0] = np.nan  # a degenerate vertex's frame: left as it is, never NaN
    out, stored = _reproject(device, target, frames, prev, count)
    expected = reproject_f64(target, frames, prev, count)
    assert_close(out, expected, atol=ATOL_ROTATION, what="reprojected history")
    assert_close(out[:2], target[:2], atol=1e-6, what="vertices without history or a finite frame")
    assert np.all(np.isfinite(out))
    assert_close(stored[2:], frames[2:], atol=1e-7, what="frames kept for the next step")


def test_reprojection_carries_a_lobe_seen_in_the_tangent_frame(device, rng):
    """A function fixed in each vertex's tangent frame, projected in the world at the last frame and
    reprojected, equals its projection in the world at the new frame."""
    v = 6
    local = rng.standard_normal((v, ORDER * ORDER))
    prev, frames = _random_rotations(rng, v), _random_rotations(rng, v)
    world_prev = sh.rotate(local, np.swapaxes(prev, 1, 2))  # f_world(w) = f_local(F w)
    world_now = sh.rotate(local, np.swapaxes(frames, 1, 2))
    out, _ = _reproject(device, world_prev, frames, prev, np.ones(v))
    assert_close(out, world_now, atol=ATOL_ROTATION, what="lobe carried by the frame's turn")


def _spinning_box(frames, degrees, teleport_at=None):
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.4))
    xf = np.repeat(np.eye(4)[None], frames, axis=0)
    for t in range(frames):
        a = np.radians(degrees * t)
        xf[t, :3, :3] = [[np.cos(a), np.sin(a), 0.0], [-np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]]
    if teleport_at is not None:
        xf[teleport_at:, 3, 0] = 30.0
    mesh = Mesh("/box", box.vertices, box.faces, animation="rigid", transforms=xf)
    return Scene.from_meshes([mesh], frames=range(frames), lights=[Environment.sky(sun_radiance=(0.0, 0.0, 0.0))])


def _graph(**trace):
    params = {"order": ORDER, "samples": 16, "control": "previous", "normal_turn": 180.0, "motion": 1000.0,
              "threshold": 1e6, "fade": 1e6, "filter_iterations": 0, **trace}
    wires = {"tangents": "tangents.tangents"} if params.get("reproject") else {}
    pre = [StageSpec("tangents", "ldprt.tangents", {})] if wires else []
    return GraphSpec([*pre, StageSpec("trace", "hybrid.trace", params, wires),
                      StageSpec("shade", "prt.shade", {"order": ORDER}, {"transfer": "trace.transfer"})],
                     "shade.radiance", name="hybrid-reproject-test")


def _clamped_cosine(normals):
    q = quadrature.fibonacci(20000)
    y = sh.basis(q.directions, ORDER)
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    f = np.maximum(0.0, n @ q.directions.T)
    return f @ (y * q.weights[:, None])


def _trace_stage(rt):
    return next(s for s in rt.frame_stages if s.type_name == "hybrid.trace")


@pytest.mark.parametrize("reproject", [True, False])
def test_spinning_convex_box_keeps_its_history_only_when_reprojected(device, reproject):
    scene = _spinning_box(10, 25.0)
    rt = _graph(reproject=reproject).compile(scene, device=device, cache_dir=None, progress=False)
    for f in scene.frames:
        rt.step(f)
    stage = _trace_stage(rt)
    t = stage._transfer.numpy().astype(np.float64)
    from warpshade.geometry._normals import vertex_normals_f64

    last = float(scene.frames[-1])
    exact = _clamped_cosine(vertex_normals_f64(scene.points_at(last), scene.faces))
    rel = np.sqrt(np.mean(np.sum((t - exact) ** 2, axis=1)) / np.mean(np.sum(exact**2, axis=1)))
    d = stage.diagnostics()
    assert d["resets_motion"] == 0 and d["resets_variance"] == 0 and np.all(np.isfinite(t))
    if reproject:
        assert rel < REL_SPIN_REPROJECTED, rel
    else:
        assert rel > REL_SPIN_STALE, rel


def test_teleport_still_cuts_the_reprojected_history(device):
    scene = _spinning_box(6, 5.0, teleport_at=4)
    rt = _graph(reproject=True, motion=1.0).compile(scene, device=device, cache_dir=None, progress=False)
    stage = _trace_stage(rt)
    for f in scene.frames[:4]:
        rt.step(f)
    assert stage.diagnostics()["resets_motion"] == 0
    out = rt.step(scene.frames[4]).numpy()
    d = stage.diagnostics()
    assert d["resets_motion"] == scene.vertex_count
    assert np.all(np.isfinite(out))


def test_reproject_in_the_tangent_frames_is_refused(device):
    scene = _spinning_box(2, 5.0)
    spec = GraphSpec([StageSpec("tangents", "ldprt.tangents", {}),
                      StageSpec("trace", "hybrid.trace", {"order": ORDER, "samples": 4, "control": "none", "space": "local",
                                                          "reproject": True}, {"tangents": "tangents.tangents"}),
                      StageSpec("shade", "ldprt.shade_rotated", {"order": ORDER},
                                {"transfer": "trace.transfer", "tangents": "tangents.tangents"})], "shade.radiance")
    with pytest.raises(Exception, match="parameter .reproject. applies to the world frame"):
        spec.compile(scene, device=device, cache_dir=None, progress=False)
