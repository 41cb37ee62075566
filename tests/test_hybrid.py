"""hybrid.trace: kernels against the float64 mirror, unbiasedness of the control-variate
estimator, history cuts, and the failure cases (K = 1, isolated vertices, non-manifold edges)."""

import numpy as np
import pytest
import trimesh

from warpshade._wp import wp
from warpshade.basis import quadrature
from warpshade.basis.sh_warp import sh_kernels
from warpshade.geometry._bvh import Visibility, trace_occlusion_f64
from warpshade.geometry._normals import vertex_normals_f64
from warpshade.graph import GraphSpec, StageSpec
from warpshade.methods.hybrid import cycle_directions_f64, filter_f64, residual_f64, surface_neighbours, temporal_f64
from warpshade.methods.hybrid import _kernels as kernels
from warpshade.scene import Environment, Mesh, Scene

from tolerances import ATOL_FLOAT32, STDERR_SIGMAS, assert_close

#: float32 residual against float64: a sum of K <= 64 terms (4 pi / K) e y with |e| <= ~3 (the
#: control's reconstruction) and |y| <= 2.7 at order 4; float32 rounding of each ~1e-7 relative.
ATOL_RESIDUAL = 2e-4
#: The variance estimate is a difference of two float32 sums of that size.
RTOL_VARIANCE = 1e-3
#: Filter / moving average: a few float32 products and one division per coefficient.
ATOL_AVERAGE = 1e-5
ORDER = 4
#: Static scene, a 64-ray bake as control and 16 rays per frame over 4 frames against 1024 rays:
#: the bake's and the 1024-ray noise, order 3 (measured ~0.01).
REL_VISIBILITY_STATIC = 0.03


def _plane_box(frames=1, teleport_at=None):
    """A subdivided ground plane with a box above it (the box jumps sideways at ``teleport_at``)."""
    plane = trimesh.creation.box(extents=(3.0, 3.0, 0.05))
    plane = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(plane.vertices, plane.faces, 0.4))
    box = trimesh.creation.box(extents=(0.8, 0.8, 0.4))
    xf = np.repeat(np.eye(4)[None], frames, axis=0)
    xf[:, 3, 2] = 0.6
    if teleport_at is not None:
        xf[teleport_at:, 3, 0] = 2.5
    meshes = [Mesh("/plane", plane.vertices, plane.faces),
              Mesh("/box", box.vertices, box.faces, animation="rigid" if frames > 1 else "static", transforms=xf)]
    return Scene.from_meshes(meshes, frames=range(frames), lights=[Environment.sky(sun_radiance=(0.0, 0.0, 0.0))])


def _frame_arrays(scene, device):
    pts = scene.points_at(0.0)
    nrm = vertex_normals_f64(pts, scene.faces)
    bvh = Visibility.from_scene(scene, device=device)
    return pts, nrm, bvh


def _residual(device, pts, nrm, bvh, samples, control, seed=0, step=0, order=ORDER, cycle=1, quantity=0, frames=None):
    v = pts.shape[0]
    c = order * order
    dev = wp.get_device(device)
    args = dict(dtype=wp.vec3, device=dev)
    p, n = wp.array(pts.astype(np.float32), **args), wp.array(nrm.astype(np.float32), **args)
    ctl = wp.array((np.zeros((1, c)) if control is None else control).astype(np.float32), dtype=wp.float32, device=dev)
    stp = wp.array(np.array([step], np.int32), dtype=wp.int32, device=dev)
    res = wp.zeros((v, c), dtype=wp.float32, device=dev)
    var = wp.zeros(v, dtype=wp.float32, device=dev)
    rot = wp.zeros(v, dtype=wp.mat33, device=dev)
    directions = wp.zeros(samples, dtype=wp.vec3, device=dev)
    basis = wp.zeros((samples, c), dtype=wp.float32, device=dev)
    wp.launch(kernels.cycle_table_kernel(order), dim=samples, device=dev, inputs=[stp, samples, cycle, directions, basis])
    wp.launch(kernels.residual_kernel(order), dim=v, device=dev,
              inputs=[bvh.id, p, n, wp.empty(0, dtype=wp.mat33, device=dev) if frames is None else
                      wp.array(frames.astype(np.float32), dtype=wp.mat33, device=dev), ctl,
                      kernels.residual_settings(quantity=quantity, count=samples, cycle=cycle, seed=seed, offset=bvh.offset,
                                                use_control=control is not None, use_local=frames is not None),
                      stp, directions, basis,
                      sh_kernels(order).tables(dev), 0, res, var])
    wp.launch(kernels.rotations_kernel, dim=v, device=dev, inputs=[seed, stp, cycle, rot])
    return res.numpy(), var.numpy(), rot.numpy()


def _hits(scene, pts, nrm, rot, samples, offset, step=0, cycle=1):
    dirs = np.einsum("vij,kj->vki", rot.astype(np.float64), cycle_directions_f64(samples, step, cycle))
    origins = np.repeat((pts + offset * nrm)[:, None, :], samples, axis=1)
    return trace_occlusion_f64(scene.points_at(0.0), scene.faces, origins.reshape(-1, 3),
                               dirs.reshape(-1, 3)).reshape(len(pts), samples)


def _tangent_frames(nrm):
    """Rows t, b, n per vertex: an orthonormal frame about each normal."""
    helper = np.where(np.abs(nrm[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t = np.cross(helper, nrm)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return np.stack([t, np.cross(nrm, t), nrm], axis=1)


@pytest.mark.parametrize("samples,cycle,quantity,control,local", [
    (1, 1, "transfer", True, False), (16, 1, "transfer", True, False), (16, 4, "transfer", True, False),
    (16, 1, "visibility", True, False), (16, 1, "transfer", False, False), (16, 2, "transfer", True, True),
    (16, 1, "visibility", False, True)])
def test_residual_kernel_matches_mirror(device, samples, cycle, quantity, control, local, rng):
    """The kernel (the step's SH table turned per vertex) against the float64 mirror (SH of every
    ray's direction in the vertex's frame), with and without a control, world and tangent frames."""
    scene = _plane_box()
    pts, nrm, bvh = _frame_arrays(scene, device)
    control = 0.3 * rng.standard_normal((pts.shape[0], ORDER * ORDER)) if control else None
    frames = _tangent_frames(nrm) if local else None
    code = kernels.QUANTITY_VISIBILITY if quantity == "visibility" else kernels.QUANTITY_TRANSFER
    res, var, rot = _residual(device, pts, nrm, bvh, samples, control, seed=5, step=3, cycle=cycle, quantity=code,
                              frames=frames)
    occluded = _hits(scene, pts, nrm, rot, samples, bvh.offset, step=3, cycle=cycle)
    r64, v64 = residual_f64(nrm, rot, cycle_directions_f64(samples, 3, cycle), occluded, ORDER, control,
                            frames=frames, quantity=quantity)
    assert_close(res, r64, atol=ATOL_RESIDUAL, what="residual")
    assert_close(var, v64, rtol=RTOL_VARIANCE, atol=ATOL_RESIDUAL, what="one-frame variance")
    assert np.all(np.isfinite(res)) and np.all(var >= 0)


def test_cycle_directions_are_the_fibonacci_set_and_stratify_together():
    assert_close(cycle_directions_f64(64, 0, 1), quadrature.fibonacci(64).directions, atol=1e-12, what="frame 0")
    union = np.concatenate([cycle_directions_f64(16, j, 8) for j in range(8)])
    z = np.sort(union[:, 2])
    # 128 directions, 8 per z-stratum of the 16-point set: the union is stratified in z
    assert np.all(np.histogram(z, bins=16, range=(-1, 1))[0] == 8)


def test_rotations_change_per_frame_step(device):
    scene = _plane_box()
    pts, nrm, bvh = _frame_arrays(scene, device)
    _, _, r0 = _residual(device, pts, nrm, bvh, 4, None, step=0)
    _, _, r1 = _residual(device, pts, nrm, bvh, 4, None, step=1)
    assert np.abs(r0 - r1).max() > 0.1
    c1 = _residual(device, pts, nrm, bvh, 4, None, step=1, cycle=4)[2]
    c3 = _residual(device, pts, nrm, bvh, 4, None, step=3, cycle=4)[2]
    c4 = _residual(device, pts, nrm, bvh, 4, None, step=4, cycle=4)[2]
    assert np.array_equal(c1, c3) and np.abs(c3 - c4).max() > 0.1  # one rotation per cycle of 4 frames
    assert_close(np.einsum("vij,vkj->vik", r0, r0), np.eye(3)[None], atol=ATOL_FLOAT32 * 10, what="orthonormal rotations")


def test_filter_kernel_matches_mirror(device, rng):
    scene = _plane_box()
    pts, nrm, _ = _frame_arrays(scene, device)
    nb = surface_neighbours(scene.faces, pts)
    v, c = pts.shape[0], ORDER * ORDER
    values = rng.standard_normal((v, c))
    dev = wp.get_device(device)
    out = wp.zeros((v, c), dtype=wp.float32, device=dev)
    gain = wp.zeros(v, dtype=wp.float32, device=dev)
    wp.launch(kernels.filter_kernel(ORDER), dim=v, device=dev,
              inputs=[wp.array(nb.offsets, dtype=wp.int32, device=dev), wp.array(nb.neighbours, dtype=wp.int32, device=dev),
                      wp.array(pts.astype(np.float32), dtype=wp.vec3, device=dev),
                      wp.array(nrm.astype(np.float32), dtype=wp.vec3, device=dev),
                      wp.array(nb.scale, dtype=wp.float32, device=dev), 0.3, 1.0,
                      wp.array(values.astype(np.float32), dtype=wp.float32, device=dev), out, gain])
    f64, g64 = filter_f64(nb.offsets, nb.neighbours, pts, nrm, nb.scale, 0.3, 1.0, values)
    assert_close(out.numpy(), f64, atol=ATOL_AVERAGE * 10, what="filtered residual")
    assert_close(gain.numpy(), g64, rtol=ATOL_AVERAGE * 10, what="filter gain")
    assert np.all(g64 >= 1.0)


def _temporal_run(device, frames_in, params, gain=2.0):
    """Run the temporal kernel over a list of (points, normals, fresh, variance, control[, raw]) frames
    (raw: the unfiltered estimate, ``fresh`` when left out); returns per frame (transfer, reset) of the kernel and of the mirror."""
    pts0 = frames_in[0][0]
    v, c = frames_in[0][2].shape
    dev = wp.get_device(device)
    st = kernels.TemporalState()
    st.history = wp.zeros((v, c), dtype=wp.float32, device=dev)
    st.frames = wp.zeros(v, dtype=wp.float32, device=dev)
    st.variance_mean = wp.zeros(v, dtype=wp.float32, device=dev)
    st.variance = wp.zeros(v, dtype=wp.float32, device=dev)
    st.prev_points = wp.zeros(v, dtype=wp.vec3, device=dev)
    st.prev_normals = wp.zeros(v, dtype=wp.vec3, device=dev)
    st.reset = wp.zeros(v, dtype=wp.int32, device=dev)
    st.excess = wp.zeros(v, dtype=wp.float32, device=dev)
    tp = kernels.TemporalParams()
    tp.bias_weight = 1.0
    for k, val in params.items():
        setattr(tp, k, val)
    scale = np.full(v, 0.1, np.float32)
    gain = np.full(v, gain, np.float32)
    mstate = {"history": np.zeros((v, c)), "frames": np.zeros(v), "variance_mean": np.zeros(v), "variance": np.zeros(v),
              "prev_points": np.zeros((v, 3)), "prev_normals": np.zeros((v, 3))}
    out = []
    transfer = wp.zeros((v, c), dtype=wp.float32, device=dev)
    for pts, nrm, fresh, var, ctl, *rest in frames_in:
        raw = rest[0] if rest else fresh
        f32 = dict(dtype=wp.float32, device=dev)
        wp.launch(kernels.temporal_kernel(ORDER), dim=v, device=dev,
                  inputs=[wp.array(pts.astype(np.float32), dtype=wp.vec3, device=dev),
                          wp.array(nrm.astype(np.float32), dtype=wp.vec3, device=dev), wp.array(scale, **f32),
                          wp.array(ctl.astype(np.float32), **f32), 1, wp.array(fresh.astype(np.float32), **f32), wp.array(raw.astype(np.float32), **f32),
                          wp.array(var.astype(np.float32), **f32), wp.array(gain, **f32), st, tp, transfer])
        t64, mstate = temporal_f64(mstate, pts, nrm, scale, fresh, var, gain, ctl, params, raw=raw)
        out.append((transfer.numpy().copy(), st.reset.numpy().copy(), st.frames.numpy().copy(), t64, mstate["reset"].copy(),
                    mstate["frames"].copy()))
    return out


PARAMS = {"alpha": 0.1, "motion": 1.0, "normal_cos": float(np.cos(np.radians(20))), "threshold": 4.0, "in_control": 0,
          "fade": 1.0, "test_raw": 0}


@pytest.mark.parametrize("in_control", [0, 1])
def test_temporal_kernel_matches_mirror_and_teleport_cuts_at_once(device, rng, in_control):
    v, c = 40, ORDER * ORDER
    pts = rng.uniform(-1, 1, (v, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (v, 1))
    truth = 0.2 * rng.standard_normal((v, c))
    ctl = 0.1 * rng.standard_normal((v, c))
    frames_in = []
    for t in range(8):
        p = pts + (np.array([30.0, 0.0, 0.0]) if t >= 5 else 0.0)  # teleport at frame 5
        fresh = truth - ctl + 0.01 * rng.standard_normal((v, c))
        frames_in.append((p, nrm, fresh, np.full(v, 2 * 0.01**2 * c), ctl))  # gain 2 in _temporal_run
    params = dict(PARAMS, in_control=in_control)
    runs = _temporal_run(device, frames_in, params)
    for t, (tr, reset, fr, t64, reset64, fr64) in enumerate(runs):
        assert_close(tr, t64, atol=ATOL_AVERAGE, what=f"transfer at step {t}")
        np.testing.assert_array_equal(reset, reset64)
        assert_close(fr, fr64, rtol=ATOL_AVERAGE, what="effective frames")
    assert np.all(runs[5][1] == kernels.RESET_MOTION)
    assert np.all(runs[5][2] == 1.0)  # cut at once, at the teleport frame
    if not in_control:  # (with in_control the fixed control given here is not the last estimate)
        assert runs[4][2].min() > 4.0  # history grew
        assert np.all(runs[6][1] == 0)


def test_variance_test_cuts_when_fresh_rays_disagree(device, rng):
    v, c = 30, ORDER * ORDER
    pts = rng.uniform(-1, 1, (v, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (v, 1))
    ctl = np.zeros((v, c))
    frames_in = []
    for t in range(6):
        level = 0.0 if t < 4 else 1.0  # the shadow changes at frame 4 without the vertex moving
        fresh = level + 0.01 * rng.standard_normal((v, c))
        frames_in.append((pts, nrm, fresh, np.full(v, 2 * 0.01**2 * c), ctl))
    runs = _temporal_run(device, frames_in, PARAMS)
    assert np.all(runs[4][1] == 1)  # RESET_VARIANCE
    assert_close(runs[4][0], frames_in[4][2], atol=ATOL_AVERAGE, what="fresh estimate taken at the cut")
    assert np.count_nonzero(runs[3][1]) == 0


@pytest.mark.parametrize("in_control", [0, 1])
def test_variance_test_on_the_raw_estimate(device, rng, in_control):
    """``test_raw``: the unfiltered estimate against the variance of one frame before the filter.
    With a filter gain of 8, a change of one raw standard deviation per coefficient (z ~ 7 after
    the filter, ~ 2 before it) is cut when tested after the filter and kept when tested before it;
    a shadow that flips (1.0, 100 raw standard deviations) is cut either way. Kernel and mirror
    agree, with raw and filtered estimates that differ."""
    v, c = 30, ORDER * ORDER
    pts = rng.uniform(-1, 1, (v, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (v, 1))
    sd, gain = 0.01, 8.0  # per coefficient, one frame, before the filter; after it sd / sqrt(gain)
    cuts = {}
    for test_raw in (0, 1):
        frames_in = []
        for t in range(8):
            level = 0.0 if t < 4 else (sd if t < 7 else 1.0)
            raw = level + sd * rng.standard_normal((v, c))
            fresh = level + sd / np.sqrt(gain) * rng.standard_normal((v, c))
            frames_in.append([pts, nrm, fresh, np.full(v, sd**2 * c), np.zeros((v, c)), raw])
        params = dict(PARAMS, in_control=in_control, test_raw=test_raw, threshold=4.0)
        runs = []
        for t in range(8):  # with in_control the control is the last transfer
            if in_control and runs:
                frames_in[t][4] = runs[-1][0]
            runs = _temporal_run(device, frames_in[: t + 1], params, gain=gain)
        for tr, reset, fr, t64, reset64, fr64 in runs:
            assert_close(tr, t64, atol=ATOL_AVERAGE, what="transfer")
            np.testing.assert_array_equal(reset, reset64)
        cuts[test_raw] = [int(np.count_nonzero(r[1] == kernels.RESET_VARIANCE)) for r in runs]
        assert np.all(runs[7][1] == kernels.RESET_VARIANCE), f"test_raw {test_raw}: the flipped shadow is not cut"
    assert cuts[0][4] >= 0.8 * v and cuts[1][4] <= 0.1 * v, cuts


def test_fade_starts_at_its_z(device):
    """After 9 frames that agree, a fresh frame at z = 3 (threshold 4): with ``fade`` 1 its weight
    is ((3 - 1) / (4 - 1))^2 = 4/9; with ``fade`` 3 the history holds (weight alpha = 0.1)."""
    v, c = 6, ORDER * ORDER
    pts = np.zeros((v, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (v, 1))
    var, gain = 1e-4 * c, 2.0  # one frame, before the filter: vf = var / gain after it
    vf = var / gain
    n = 9.0
    x = np.sqrt(3.0 * vf * (1.0 + 1.0 / n) / c)  # z = C x^2 / (vf + vf / n) = 3
    frames_in = [(pts, nrm, np.zeros((v, c)), np.full(v, var), np.zeros((v, c))) for _ in range(9)]
    frames_in.append((pts, nrm, np.full((v, c), x), np.full(v, var), np.zeros((v, c))))
    for fade, weight in ((1.0, 4.0 / 9.0), (3.0, 0.1)):
        runs = _temporal_run(device, frames_in, dict(PARAMS, fade=fade, threshold=4.0), gain=gain)
        for tr, reset, fr, t64, reset64, fr64 in runs:
            assert_close(tr, t64, atol=ATOL_AVERAGE, what="transfer")
            assert_close(fr, fr64, rtol=ATOL_AVERAGE, what="effective frames")
            assert np.all(reset == 0)
        assert_close(runs[-1][0], np.full((v, c), weight * x), rtol=1e-4, what=f"fresh weight at fade {fade}")


def test_soft_reset_weight_is_least_squares_for_the_estimated_bias(device):
    """After 9 agreeing frames (history variance vf / 9), a fresh frame at z = 3: the estimated
    bias is b^2 = d^2 - vf - vf / 9 = 20 vf / 9 and the fresh weight (vf / 9 + b^2) / (vf / 9 + b^2 + vf)
    = 0.7; at z = 1 no bias is seen and the weight is the running average's 1 / (n + 1) = 0.1."""
    v, c = 6, ORDER * ORDER
    pts = np.zeros((v, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (v, 1))
    var, gain = 1e-4 * c, 2.0
    vf = var / gain
    for z, weight in ((3.0, 0.7), (1.0, 0.1)):
        x = np.sqrt(z * vf * (1.0 + 1.0 / 9.0) / c)
        frames_in = [(pts, nrm, np.zeros((v, c)), np.full(v, var), np.zeros((v, c))) for _ in range(9)]
        frames_in.append((pts, nrm, np.full((v, c), x), np.full(v, var), np.zeros((v, c))))
        runs = _temporal_run(device, frames_in, dict(PARAMS, soft=1, threshold=4.0), gain=gain)
        for tr, reset, fr, t64, reset64, fr64 in runs:
            assert_close(tr, t64, atol=ATOL_AVERAGE, what="transfer")
            assert_close(fr, fr64, rtol=ATOL_AVERAGE, what="effective frames")
            assert np.all(reset == 0)
        assert_close(runs[-1][0], np.full((v, c), weight * x), rtol=1e-4, what=f"fresh weight at z {z}")


def test_soft_reset_bias_averaged_over_frames_keeps_noise_out_and_follows_a_step(device, rng):
    """Pure noise (one-frame std s per coefficient, unbiased), soft reset, no cut: with the bias
    estimated from one frame the transfer's noise after 30 frames is 0.44 s (measured with the
    mirror; the moving average alone would give sqrt(alpha / (2 - alpha)) s = 0.23 s), averaged over
    8 frames 0.26 s; a step of 6 s per coefficient is still followed within 2 frames."""
    v, c = 200, ORDER * ORDER
    pts = np.zeros((v, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (v, 1))
    vf = 1e-3
    s = np.sqrt(vf / c)
    stream = [s * rng.standard_normal((v, c)) + (0.0 if t < 30 else 6.0 * s) for t in range(33)]
    frames_in = [(pts, nrm, x, np.full(v, vf), np.zeros((v, c))) for x in stream]
    noise = {}
    for bias_weight in (1.0, 0.125):
        runs = _temporal_run(device, frames_in, dict(PARAMS, soft=1, threshold=1e9, bias_weight=bias_weight), gain=1.0)
        for tr, reset, fr, t64, reset64, fr64 in runs:
            assert_close(tr, t64, atol=ATOL_AVERAGE, what=f"transfer, bias weight {bias_weight}")
        noise[bias_weight] = float(np.sqrt(np.mean(runs[29][0] ** 2))) / s
        assert np.mean(runs[31][0]) > 0.9 * 6.0 * s, bias_weight  # the step, two frames on
    assert noise[0.125] < 0.75 * noise[1.0], noise
    assert noise[0.125] > np.sqrt(0.1 / 1.9) * 0.9, noise  # not below what the moving average allows


def test_history_is_the_running_average_up_to_one_over_alpha(device, rng):
    """While the fresh frames agree with the history, frame t's weight is max(alpha, 1 / (t + 1)):
    the transfer is the plain mean of the first 1 / alpha = 10 fresh frames, and the effective
    frames count 1, 2, ..., 10; after that an exponential average with weight alpha."""
    v, c = 20, ORDER * ORDER
    pts = rng.uniform(-1, 1, (v, 3))
    nrm = np.tile([0.0, 0.0, 1.0], (v, 1))
    sd = 0.01
    fresh = [0.3 + sd * rng.standard_normal((v, c)) for _ in range(14)]
    frames_in = [(pts, nrm, f, np.full(v, 2 * sd**2 * c), np.zeros((v, c))) for f in fresh]  # gain 2
    runs = _temporal_run(device, frames_in, dict(PARAMS, threshold=1e9, fade=1e9))
    expect = None
    for t, (tr, reset, fr, *_rest) in enumerate(runs):
        expect = np.mean(fresh[: t + 1], axis=0) if t < 10 else 0.9 * expect + 0.1 * fresh[t]
        assert_close(tr, expect, atol=ATOL_AVERAGE, what=f"transfer at frame {t}")
        assert np.all(reset == 0)
        if t < 10:
            assert_close(fr, np.full(v, t + 1.0), rtol=ATOL_AVERAGE, what=f"effective frames at frame {t}")


def _exact_projection(scene, pts, nrm, order, offset, rays=1024):
    rot = np.repeat(np.eye(3)[None], len(pts), axis=0)
    occ = _hits(scene, pts, nrm, rot, rays, offset)
    r, _ = residual_f64(nrm, rot, cycle_directions_f64(rays, 0, 1), occ, order)
    return r


def test_control_variate_is_unbiased_and_a_wrong_control_only_adds_variance(device, rng):
    """Mean over frames (cycles of 4 shifted sets, a random rotation per cycle) of T_hat + r
    approaches the exact projection for a good control and a wrong one; the wrong one's spread
    is larger."""
    order = ORDER
    scene = _plane_box()
    pts, nrm, bvh = _frame_arrays(scene, device)
    pick = np.flatnonzero(np.abs(pts[:, 2] + 0.025) < 1e-3)[::7][:12]  # plane top vertices
    exact = _exact_projection(scene, pts[pick], nrm[pick], order, bvh.offset)
    good = np.zeros((pts.shape[0], order * order))
    good[pick] = exact + 0.02 * rng.standard_normal(exact.shape)
    wrong = 1.5 * rng.standard_normal((pts.shape[0], order * order))
    steps = 96
    for control, name in ((good, "good"), (wrong, "wrong")):
        est = np.stack([(control + _residual(device, pts, nrm, bvh, 4, control, seed=11, step=s, order=order,
                                             cycle=4)[0])[pick] for s in range(steps)])
        mean, se = est.mean(axis=0), est.std(axis=0, ddof=1) / np.sqrt(steps)
        # the exact projection's own quadrature error (1024 Fibonacci rays) is well under 2e-3
        assert np.all(np.abs(mean - exact) <= STDERR_SIGMAS * se + 2e-3), f"{name} control: biased"
        if name == "good":
            spread_good = est.std(axis=0).mean()
        else:
            assert est.std(axis=0).mean() > 3 * spread_good


def _graph(samples=4, control="none", **trace):
    return GraphSpec([StageSpec("trace", "hybrid.trace", {"order": ORDER, "samples": samples, "control": control, **trace}),
                      StageSpec("shade", "prt.shade", {"order": ORDER}, {"transfer": "trace.transfer"})],
                     "shade.radiance", name="hybrid-test")


@pytest.mark.parametrize("control", ["none", "previous"])
def test_one_ray_per_vertex_is_bounded_and_reported(device, control):
    scene = _plane_box(frames=4)
    rt = _graph(samples=1, control=control).compile(scene, device=device, cache_dir=None, progress=False)
    rt.run(list(scene.frames), warmup=False)
    d = rt.frame_stages[0].diagnostics()
    for f in scene.frames:
        out = rt.results[float(f)]
        assert np.all(np.isfinite(out))
    assert np.isfinite(d["variance_rel"]) and d["effective_samples_min"] >= 1.0
    assert d["steps"] == 4


def test_teleporting_blocker_cuts_history_in_the_graph(device):
    scene = _plane_box(frames=6, teleport_at=4)
    rt = _graph(samples=4).compile(scene, device=device, cache_dir=None, progress=False)
    stage = rt.frame_stages[0]
    box = scene.meshes[1]
    for f in scene.frames[:4]:
        rt.step(f)
    assert stage.diagnostics()["resets_motion"] == 0
    rt.step(scene.frames[4])
    d = stage.diagnostics()
    assert d["resets_motion"] == box.vertex_count


def test_isolated_and_non_manifold_vertices_are_bounded_and_reported(device):
    """A fin shared by three triangles along one edge, a degenerate triangle and a vertex in no
    triangle: the adjacency reports them and the output stays finite."""
    pts = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1], [3, 3, 3], [2, 2, 0]], np.float64)
    faces = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [6, 6, 2]], np.int32)
    nb = surface_neighbours(faces, pts)
    assert nb.report["non_manifold_edges"] == 1 and nb.report["isolated_vertices"] == 1
    assert nb.report["degenerate_triangles"] == 1
    assert np.all(np.isfinite(nb.scale)) and np.all(nb.scale > 0)
    scene = Scene.from_meshes([Mesh("/fin", pts, faces)], frames=range(3),
                              lights=[Environment.sky(sun_radiance=(0.0, 0.0, 0.0))])
    rt = _graph(samples=8, filter_iterations=2).compile(scene, device=device, cache_dir=None, progress=False)
    rt.run(list(scene.frames), warmup=False)
    d = rt.frame_stages[0].diagnostics()
    assert d["surface_isolated_vertices"] == 1 and d["surface_non_manifold_edges"] == 1
    for f in scene.frames:
        assert np.all(np.isfinite(rt.results[float(f)]))


def test_noise_and_lag_metrics(device):
    """Noise over seeds: zero (one run) for a method without a seed, positive for few rays; lag is
    finite on a moving scene and None when no geometry moves."""
    from warpshade.measure import ground_truth, lag, noise
    from warpshade.scene import LightingSource

    scene = _plane_box(frames=5, teleport_at=3)
    lighting = LightingSource(scene.lights, scene.up_axis, 0.0, 0.0)
    hybrid = tuple((s.name, s.type, s.params, s.inputs) for s in _graph(samples=4).stages)
    plain = (("shade", "prt.unshadowed", {"order": 2}, {}),)
    n_plain = noise(scene, lighting, plain, frame=2.0, seeds=3, device=device, cache_dir=None)
    assert n_plain["deterministic"] and n_plain["noise_rel"] == 0.0
    n_hybrid = noise(scene, lighting, hybrid, frame=2.0, seeds=3, device=device, cache_dir=None)
    assert n_hybrid["noise_seeds"] == 3 and 0.0 < n_hybrid["noise_rel"] < 1.0

    def truth_for(frames):
        return ground_truth(scene, lighting, frames, 16, device, cache_dir=None)

    lg = lag(scene, lighting, hybrid, truth_for, fast=1, spread=2, device=device, cache_dir=None)
    assert lg["lag_fast_frames"] == [3.0] and np.isfinite(lg["lag"]) and lg["lag"] > 0
    still = _plane_box(frames=3)
    assert lag(still, lighting, hybrid, truth_for, device=device, cache_dir=None)["lag"] is None


def test_visibility_for_rpo_is_bounded_and_close_to_traced(device):
    """The same estimator on the SH visibility (open below the horizon, tangent frames) with the
    static bake as control feeds rpo.shade; on a static scene it stays within the few-ray noise of
    rpo.visibility_traced."""
    from warpshade.methods.hybrid import glossy_stages_for

    scene = _plane_box(frames=4)
    stages = glossy_stages_for(16, order=3, bake_samples=64, shade={"eye": (0.0, -4.0, 2.0)})
    spec = GraphSpec([StageSpec(n, t, p, i) for n, t, p, i in stages], "trace.visibility", name="hybrid-rpo")
    rt = spec.compile(scene, device=device, cache_dir=None, progress=False)
    for f in scene.frames:
        vis = rt.step(f).numpy()
    traced = GraphSpec([StageSpec("vis", "rpo.visibility_traced", {"order": 3, "samples": 1024})], "vis.visibility",
                       name="rpo-traced").compile(scene, device=device, cache_dir=None, progress=False)
    ref = traced.step(scene.frames[-1]).numpy()
    assert np.all(np.isfinite(vis))
    rel = np.sqrt(np.mean((vis - ref) ** 2)) / np.sqrt(np.mean(ref**2))
    assert rel < REL_VISIBILITY_STATIC, rel
    spec = GraphSpec([StageSpec(n, t, p, i) for n, t, p, i in stages], "shade.radiance", name="hybrid-rpo-shade")
    out = spec.compile(scene, device=device, cache_dir=None, progress=False).step(scene.frames[0]).numpy()
    assert np.all(np.isfinite(out))


@pytest.mark.parametrize("trace", [{}, {"warmup_frames": 6.0, "warmup_passes": 3, "warmup_noise": 0.5}],
                         ids=["plain", "warmup"])
@pytest.mark.parametrize("control", ["none", "previous"])
def test_recorded_frames_equal_launches_from_python(device, monkeypatch, control, trace):
    """The frame counter, the rays, the filter, the history and the history-aware filter all live in
    the recorded frame: replaying it gives what launching every kernel from Python gives, with no
    launch from Python."""
    import warp

    from warpshade.scene._state import CPU_REFIT_NOTE

    from tolerances import REPLAY_RTOL

    monkeypatch.setenv("WARPSHADE_THREADS", "1")  # no chunked CPU launches: the frame is one replay
    scene = _plane_box(frames=6, teleport_at=4)
    runs = {}
    for capture in (False, True):
        rt = _graph(samples=4, control=control, filter_iterations=2, **trace).compile(
            scene, device=device, cache_dir=None, progress=False, capture=capture)
        rt.step(0.0)
        rt.step(0.0)
        if capture:
            assert rt.program is not None
            assert rt.program.uncaptured == ([CPU_REFIT_NOTE] if wp.get_device(device).is_cpu else [])
            launches = []
            original = warp.launch
            monkeypatch.setattr(warp, "launch", lambda *a, **k: launches.append(1) or original(*a, **k))
        runs[capture] = [rt.step(f).numpy().copy() for f in (1.0, 2.0, 5.0, 3.0)]
        if capture:
            assert not launches, "a replayed frame makes no kernel launches from Python"
    size = max(np.abs(a).max() for a in runs[False])
    for a, b in zip(runs[True], runs[False]):
        np.testing.assert_allclose(a, b, rtol=0, atol=REPLAY_RTOL * size)
    assert not np.allclose(runs[False][0], runs[False][1]), "new rays every frame"
