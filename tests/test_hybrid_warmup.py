"""hybrid.trace's history-aware filter (``warmup_frames``, ``warmup_passes``): its kernels against
the float64 mirror, the blend's variance target, a pure-noise stream with a step, and the stage
(its recorded frame: tests/test_hybrid.py::test_recorded_frames_equal_launches_from_python)."""

import numpy as np
import pytest
import trimesh

from warpshade._wp import wp
from warpshade.graph import GraphSpec, StageError, StageSpec
from warpshade.methods.hybrid import (filter_f64, _kernels as kernels, surface_neighbours, temporal_f64, warm_blend_f64,
                                      warm_filter_f64, warm_weight_f64)
from warpshade.scene import Environment, Mesh, Scene

from tolerances import ATOL_FLOAT64, assert_close

ORDER = 3
#: One pass over O(1) values and variances: a sum of <= ~8 float32 products and one division.
ATOL_PASS = 1e-5
#: The blend weight: a ratio of float32 variances, a square root; its value enters the output as
#: w (B - h) with |B - h| <= ~3.
ATOL_WEIGHT = 2e-5
#: Kernels and mirror over a stream of frames (moving average + passes + blend in float32).
ATOL_STREAM = 5e-5
#: Pure noise, one frame's standard deviation s per coefficient, 2 passes: measured noise of the
#: blended output against its target s sqrt(1 / N) (history of n < N frames topped up to N): the
#: variance carried through the passes ignores that the first pass correlates neighbours, so the
#: second pass reduces less than it counts and the output stays above the target (measured
#: 1.26, 1.12, 1.07, 1.04, 1.02 times it at histories of 1..5 frames, with and without the
#: least-squares limit); never below it by more than the spread of the estimate over ~2300
#: vertices x 9 coefficients (~1 %).
NOISE_OVER_TARGET = (0.95, 1.4)


def _plane(size=0.12, extent=3.0):
    plane = trimesh.creation.box(extents=(extent, extent, 0.05))
    plane = trimesh.Trimesh(*trimesh.remesh.subdivide_to_size(plane.vertices, plane.faces, size))
    return plane


def _mesh_arrays(plane):
    pts = np.asarray(plane.vertices, np.float64)
    nrm = np.asarray(plane.vertex_normals, np.float64)
    nb = surface_neighbours(np.asarray(plane.faces, np.int32), pts)
    return pts, nrm, nb


class _Warm:
    """The temporal kernel and the history-aware filter on given fresh frames (kernel side)."""

    def __init__(self, device, pts, nrm, nb, warm_frames, passes, params, limit=0):
        self.dev = dev = wp.get_device(device)
        v, c = pts.shape[0], ORDER * ORDER
        f32 = dict(dtype=wp.float32, device=dev)
        self.v, self.c, self.nb = v, c, nb
        self.pts = wp.array(pts.astype(np.float32), dtype=wp.vec3, device=dev)
        self.nrm = wp.array(nrm.astype(np.float32), dtype=wp.vec3, device=dev)
        self.scale = wp.array(nb.scale, **f32)
        self.offsets = wp.array(nb.offsets, dtype=wp.int32, device=dev)
        self.neighbours = wp.array(nb.neighbours, dtype=wp.int32, device=dev)
        st = kernels.TemporalState()
        st.history = wp.zeros((v, c), **f32)
        st.frames, st.variance_mean, st.variance = wp.zeros(v, **f32), wp.zeros(v, **f32), wp.zeros(v, **f32)
        st.prev_points, st.prev_normals = wp.zeros(v, dtype=wp.vec3, device=dev), wp.zeros(v, dtype=wp.vec3, device=dev)
        st.reset, st.excess = wp.zeros(v, dtype=wp.int32, device=dev), wp.zeros(v, **f32)
        self.st = st
        tp = kernels.TemporalParams()
        for k, val in params.items():
            setattr(tp, k, val)
        self.tp = tp
        self.transfer = wp.zeros((v, c), **f32)
        self.out = wp.zeros((v, c), **f32)
        self.weight = wp.zeros(v, **f32)
        self.buf = [wp.zeros((v, c), **f32) for _ in range(2)]
        self.bvar = [wp.zeros(v, **f32) for _ in range(2)]
        self.warm_frames, self.passes, self.limit = warm_frames, passes, limit

    def step(self, fresh, variance):
        dev, v = self.dev, self.v
        f32 = dict(dtype=wp.float32, device=dev)
        fr = wp.array(fresh.astype(np.float32), **f32)
        wp.launch(kernels.temporal_kernel(ORDER), dim=v, device=dev,
                  inputs=[self.pts, self.nrm, self.scale, wp.zeros((v, self.c), **f32), 1, fr, fr,
                          wp.array(variance.astype(np.float32), **f32), wp.full(v, 1.0, **f32), self.st, self.tp,
                          self.transfer])
        src, svar = self.st.history, self.st.variance
        for i in range(self.passes):
            wp.launch(kernels.warm_filter_kernel(ORDER), dim=v, device=dev,
                      inputs=[self.offsets, self.neighbours, self.pts, self.nrm, self.scale, 0.3, 1.0, src, svar,
                              self.buf[i % 2], self.bvar[i % 2]])
            src, svar = self.buf[i % 2], self.bvar[i % 2]
        wp.launch(kernels.warm_blend_kernel(ORDER), dim=v, device=dev,
                  inputs=[self.st.frames, float(self.warm_frames), self.limit, 1.0, self.st.history, self.st.variance, src, svar,
                          self.transfer, self.out, self.weight])
        return self.out.numpy().copy(), self.weight.numpy().copy(), self.transfer.numpy().copy()


def _mirror_step(state, pts, nrm, nb, fresh, variance, params, warm_frames, passes, limit=0):
    """The same frame in float64: moving average, passes, blend."""
    v = pts.shape[0]
    transfer, state = temporal_f64(state, pts, nrm, nb.scale, fresh, variance, np.ones(v), np.zeros_like(fresh), params)
    b, bvar = state["history"], state["variance"]
    for _ in range(passes):
        b, bvar = warm_filter_f64(nb.offsets, nb.neighbours, pts, nrm, nb.scale, 0.3, 1.0, b, bvar)
    out, w = warm_blend_f64(state["frames"], warm_frames, state["history"], state["variance"], b, bvar, transfer,
                            limit=bool(limit))
    return out, w, state


PARAMS = {"alpha": 0.1, "motion": 1.0, "normal_cos": float(np.cos(np.radians(20))), "threshold": 1e9, "in_control": 0,
          "fade": 1e9, "test_raw": 0, "soft": 0, "bias_weight": 1.0}


def test_warm_filter_kernel_matches_mirror_and_carries_variance(device, rng):
    plane = _plane(size=0.4)
    pts, nrm, nb = _mesh_arrays(plane)
    v, c = pts.shape[0], ORDER * ORDER
    values = rng.standard_normal((v, c))
    var = rng.uniform(0.5, 2.0, v)
    dev = wp.get_device(device)
    f32 = dict(dtype=wp.float32, device=dev)
    out, out_var = wp.zeros((v, c), **f32), wp.zeros(v, **f32)
    wp.launch(kernels.warm_filter_kernel(ORDER), dim=v, device=dev,
              inputs=[wp.array(nb.offsets, dtype=wp.int32, device=dev), wp.array(nb.neighbours, dtype=wp.int32, device=dev),
                      wp.array(pts.astype(np.float32), dtype=wp.vec3, device=dev),
                      wp.array(nrm.astype(np.float32), dtype=wp.vec3, device=dev), wp.array(nb.scale, **f32), 0.3, 1.0,
                      wp.array(values.astype(np.float32), **f32), wp.array(var.astype(np.float32), **f32), out, out_var])
    f64, v64 = warm_filter_f64(nb.offsets, nb.neighbours, pts, nrm, nb.scale, 0.3, 1.0, values, var)
    assert_close(out.numpy(), f64, atol=ATOL_PASS, what="filtered history")
    assert_close(out_var.numpy(), v64, rtol=ATOL_PASS, what="carried variance")
    # the values are the edge-aware filter's; a uniform variance falls by that filter's gain
    plain, gain = filter_f64(nb.offsets, nb.neighbours, pts, nrm, nb.scale, 0.3, 1.0, values)
    assert_close(f64, plain, atol=ATOL_FLOAT64, what="same weights as filter_kernel")
    _, uniform = warm_filter_f64(nb.offsets, nb.neighbours, pts, nrm, nb.scale, 0.3, 1.0, values, np.ones(v))
    assert_close(uniform, 1.0 / gain, atol=ATOL_FLOAT64, what="variance of independent inputs")


@pytest.mark.parametrize("limit,noise_scale", [(0, 1.0), (1, 1.0), (1, 0.25)])
def test_warm_blend_kernel_matches_mirror_and_meets_its_variance_target(device, rng, limit, noise_scale):
    """Per vertex: w = 0 once n >= N; w = 1 where even the filtered history is above the target;
    in between the blend's modelled variance var_B + (1 - w)^2 (var_h - var_B) is exactly var_h n / N.
    With ``limit`` the weight is capped by the least-squares weight for the estimated bias of the
    filtered history, r / (r + b^2) with r = noise_scale (var_h - var_B) and b^2 = max(0, |B - h|^2 - r)
    (the limit binds more as the noise it would remove is scaled down). A non-finite filtered value
    or a zero variance gives w = 0 (the history as it is)."""
    v, c, warm_frames = 96, ORDER * ORDER, 8.0
    frames = np.concatenate([[0.0, 1.0, 2.0, 8.0, 8.5, 20.0, 3.0, 3.0], rng.uniform(0.5, 12.0, v - 8)])
    var_h = rng.uniform(0.5, 2.0, v)
    var_b = var_h * rng.uniform(0.05, 1.2, v)
    var_b[1] = 0.5 * var_h[1]  # n / N = 1/8 < rho: the full filter
    var_b[7] = 0.1 * var_h[7]
    history = rng.standard_normal((v, c))
    # filtered history: |B - h|^2 from pure noise (var_h - var_B) to a bias of 4 times that
    scale = (np.sqrt(np.maximum(var_h - var_b, 0.05) / c) * rng.uniform(0.5, 3.0, v))[:, None]
    filtered = history + scale * rng.standard_normal((v, c))
    current = rng.standard_normal((v, c))
    filtered[7, 2] = np.nan
    var_h[8] = 0.0
    dev = wp.get_device(device)
    f32 = dict(dtype=wp.float32, device=dev)
    out, weight = wp.zeros((v, c), **f32), wp.zeros(v, **f32)

    def arr(x):
        return wp.array(np.asarray(x, np.float32), **f32)

    wp.launch(kernels.warm_blend_kernel(ORDER), dim=v, device=dev,
              inputs=[arr(frames), warm_frames, limit, noise_scale, arr(history), arr(var_h), arr(filtered), arr(var_b),
                      arr(current), out, weight])
    o64, w64 = warm_blend_f64(frames, warm_frames, history, var_h, filtered, var_b, current, limit=bool(limit),
                              noise_scale=noise_scale)
    assert_close(weight.numpy(), w64, atol=ATOL_WEIGHT, what="blend weight")
    assert_close(out.numpy(), o64, atol=10 * ATOL_WEIGHT, what="blended output")
    assert np.all(np.isfinite(out.numpy()))
    assert w64[0] == 0 and w64[3] == 0 and w64[4] == 0 and w64[5] == 0 and w64[7] == 0 and w64[8] == 0
    target = warm_weight_f64(frames, warm_frames, var_h, var_b)  # no limit, no finiteness check
    assert target[7] > 0  # dropped for the non-finite filtered value only
    assert target[1] == 1.0
    modelled = var_b + (1 - target) ** 2 * (var_h - var_b)
    inner = (target > 0) & (target < 1)
    assert inner.sum() > 10
    assert_close(modelled[inner], (var_h * frames / warm_frames)[inner], rtol=1e-12, what="blend variance = target")
    assert np.all(target[var_b >= var_h] == 0)
    with np.errstate(invalid="ignore"):
        d2 = np.sum((filtered - history) ** 2, axis=1)
    removed = noise_scale * (var_h - var_b)
    finite = np.isfinite(d2) & (var_h > 0)
    if limit:
        mse = np.where(removed > 0, removed / (removed + np.maximum(d2 - removed, 0.0)), 0.0)
        assert_close(w64[finite], np.minimum(target, mse)[finite], atol=ATOL_FLOAT64, what="capped weight")
        assert np.count_nonzero(w64[finite] < target[finite] - 1e-6) > 10  # the cap binds somewhere
        if noise_scale < 1.0:  # less noise to remove: never a larger weight, somewhere a smaller one
            unscaled = warm_blend_f64(frames, warm_frames, history, var_h, filtered, var_b, current, limit=True)[1]
            assert np.all(w64 <= unscaled + ATOL_FLOAT64) and np.any(w64 < unscaled - 1e-6)
    else:
        assert_close(np.delete(target, 7), np.delete(w64, 7), atol=0.0, what="weight")


def _noise_and_step(device, limit, warm_frames, passes, step_at, frames, check_mirror):
    """The pure-noise stream with a step (see the test below), kernels (and mirror at some frames)."""
    rng = np.random.default_rng(1234)
    plane = _plane()
    pts, nrm, nb = _mesh_arrays(plane)
    v, c = pts.shape[0], ORDER * ORDER
    s = 0.01
    vf = s * s * c
    shadow = (pts[:, 0] < 0.0).astype(np.float64)
    params = dict(PARAMS, threshold=8.0)
    warm = _Warm(device, pts, nrm, nb, warm_frames, passes, params, limit=limit)
    mstate = {"history": np.zeros((v, c)), "frames": np.zeros(v), "variance_mean": np.zeros(v), "variance": np.zeros(v),
              "prev_points": np.zeros((v, 3)), "prev_normals": np.zeros((v, 3))}
    outs, plains, weights = [], [], []
    for t in range(frames):
        x = s * rng.standard_normal((v, c)) + (20 * s * shadow[:, None] if t >= step_at else 0.0)
        out, w, plain = warm.step(x, np.full(v, vf))
        if check_mirror and (t < 3 or t == step_at):
            o64, w64, mstate = _mirror_step(mstate, pts, nrm, nb, x, np.full(v, vf), params, warm_frames, passes, limit)
            assert_close(out, o64, atol=ATOL_STREAM, what=f"output at frame {t}, limit {limit}")
            assert_close(w, w64, atol=ATOL_STREAM * 10, what=f"weight at frame {t}, limit {limit}")
        elif check_mirror and t < step_at + 1:
            _, _, mstate = _mirror_step(mstate, pts, nrm, nb, x, np.full(v, vf), params, warm_frames, passes, limit)
        outs.append(out)
        plains.append(plain)
        weights.append(w)
    return pts, nb, s, shadow, outs, plains, weights


def test_pure_noise_falls_at_short_history_and_a_step_is_followed(device):
    """A flat plane, pure noise (one frame's std s per coefficient, unbiased) for 12 frames, then a
    step of 20 s on one half (a shadow moving in: the variance test cuts there). With N = 6 and 2
    passes the output's noise over the first frames falls towards s / sqrt(N) (never below it, by
    more than the estimate's spread) and equals the plain moving average's from frame N on; at the
    step the cut vertices away from the edge take the new level at once, and N frames later the
    output is again exactly the moving average's (the history itself is never filtered). With the
    least-squares limit the noise falls as much (pure noise: no bias seen) while the vertices at the
    step's edge, where the filter would mix the two levels, keep their own estimate."""
    warm_frames, passes, step_at, frames = 6.0, 2, 12, 18
    edge_error = {}
    for limit in (0, 1):
        pts, nb, s, shadow, outs, plains, weights = _noise_and_step(device, limit, warm_frames, passes, step_at,
                                                                     frames, check_mirror=True)
        top = np.flatnonzero(pts[:, 2] > 0.02)
        target = s / np.sqrt(warm_frames)
        for t in range(int(warm_frames) - 1):  # n = t + 1 < N
            noise_warm = float(np.sqrt(np.mean(outs[t][top] ** 2)))
            noise_plain = float(np.sqrt(np.mean(plains[t][top] ** 2)))
            assert noise_warm < noise_plain, (limit, t, noise_warm, noise_plain)
            ratio = noise_warm / target
            assert NOISE_OVER_TARGET[0] <= ratio <= NOISE_OVER_TARGET[1], (limit, t, ratio)
        for t in range(int(warm_frames) - 1, step_at):  # n >= N: the plain moving average, exactly
            assert np.all(weights[t] == 0.0)
            np.testing.assert_array_equal(outs[t], plains[t])
        # the step: cut where the shadow came in; away from its edge the new level at once
        edge = np.abs(pts[:, 0]) < 4 * float(np.mean(nb.scale))
        inside = np.intersect1d(top, np.flatnonzero((shadow > 0) & ~edge))
        outside = np.intersect1d(top, np.flatnonzero((shadow == 0) & ~edge))
        level = 20 * s
        assert np.mean(weights[step_at][inside] > 0) > 0.9  # short history there: filtered more
        assert abs(float(np.mean(outs[step_at][inside])) - level) < 0.05 * level
        assert abs(float(np.mean(outs[step_at][outside]))) < 0.05 * level
        rms = {k: float(np.sqrt(np.mean((x[step_at][inside] - level) ** 2))) for k, x in (("warm", outs), ("plain", plains))}
        assert rms["warm"] < rms["plain"], rms
        after = step_at + int(warm_frames) - 1
        np.testing.assert_array_equal(outs[after], plains[after])
        near = np.intersect1d(top, np.flatnonzero(edge))
        truth = level * shadow[near][:, None]
        edge_error[limit] = (float(np.sqrt(np.mean((outs[step_at][near] - truth) ** 2))) / s,
                             float(np.sqrt(np.mean((plains[step_at][near] - truth) ** 2))) / s)
    # at the edge: unlimited, the two levels mix (measured 1.45 s against the plain average's
    # 0.70 s); limited, below the plain average's (measured 0.54 s)
    assert edge_error[0][0] > edge_error[0][1], edge_error
    assert edge_error[1][0] < edge_error[1][1], edge_error


def _plane_box(frames, teleport_at=None):
    plane = _plane(size=0.4)
    box = trimesh.creation.box(extents=(0.8, 0.8, 0.4))
    xf = np.repeat(np.eye(4)[None], frames, axis=0)
    xf[:, 3, 2] = 0.6
    if teleport_at is not None:
        xf[teleport_at:, 3, 0] = 2.5
    meshes = [Mesh("/plane", plane.vertices, plane.faces),
              Mesh("/box", box.vertices, box.faces, animation="rigid", transforms=xf)]
    return Scene.from_meshes(meshes, frames=range(frames), lights=[Environment.sky(sun_radiance=(0.0, 0.0, 0.0))])


def _graph(control, **trace):
    params = {"order": ORDER, "samples": 8, "control": control, "threshold": 1e6, "fade": 1e6, **trace}
    return GraphSpec([StageSpec("trace", "hybrid.trace", params),
                      StageSpec("shade", "prt.shade", {"order": ORDER}, {"transfer": "trace.transfer"})],
                     "trace.transfer", name="hybrid-warmup-test")


@pytest.mark.parametrize("control", ["none", "previous"])
def test_stage_filters_only_while_the_history_is_short(device, control):
    """Same seed, warm-up on and off: the outputs differ while histories are shorter than N and are
    equal (bit for bit) once every vertex has N frames -- the history is never filtered, also when
    the last estimate is the control; the shaded radiance stays finite."""
    scene = _plane_box(9)
    runs, diags = {}, {}
    for warm in (0.0, 4.0):
        rt = _graph(control, warmup_frames=warm).compile(scene, device=device, cache_dir=None, progress=False)
        stage = rt.frame_stages[0]
        runs[warm], diags[warm] = [], []
        for f in scene.frames:
            runs[warm].append(rt.step(f).numpy().copy())
            diags[warm].append(stage.diagnostics())
    assert "warmup_weight_mean" not in diags[0.0][0]
    assert diags[4.0][0]["warmup_vertices"] > 0 and not np.allclose(runs[0.0][0], runs[4.0][0])
    late = [t for t, d in enumerate(diags[4.0]) if d["effective_samples_min"] >= 8 * 4.0]
    assert late and late[0] <= 5, [d["effective_samples_min"] for d in diags[4.0]]
    for t in late:
        assert diags[4.0][t]["warmup_vertices"] == 0
        np.testing.assert_array_equal(runs[4.0][t], runs[0.0][t])
    assert all(np.all(np.isfinite(r)) for r in runs[4.0])


def test_teleport_filters_the_cut_vertices(device):
    scene = _plane_box(8, teleport_at=6)
    rt = _graph("none", warmup_frames=4.0).compile(scene, device=device, cache_dir=None, progress=False)
    stage = rt.frame_stages[0]
    for f in scene.frames[:6]:
        rt.step(f)
    assert stage.diagnostics()["warmup_vertices"] == 0
    out = rt.step(scene.frames[6]).numpy()
    d = stage.diagnostics()
    box = scene.meshes[1].vertex_count
    assert d["resets_motion"] == box
    assert 0 < d["warmup_vertices"] <= box  # the cut vertices, and only those
    assert np.all(np.isfinite(out))


@pytest.mark.parametrize("value", [-1.0, 1e4])
def test_warmup_frames_out_of_range_is_reported(device, value):
    scene = _plane_box(2)
    with pytest.raises(StageError, match="warmup_frames"):
        _graph("none", warmup_frames=value).compile(scene, device=device, cache_dir=None, progress=False)
