"""Warp kernels of per-frame ray tracing with a control variate, reuse over frames and over the mesh.

Per vertex ``v`` and frame, with ``K`` sample directions ``w_k`` and the control's transfer
``T_hat`` (zero without a control) and its
reconstruction ``f_hat(w) = sum_j T_hat_j y_j(w')`` (``w' = w`` in the world frame, ``F w`` in the
tangent frame ``F``):

Sample directions (:func:`cycle_direction`): ``step`` is a per-run frame counter held on the
device; frames go in cycles of ``M`` (``cycle``): frame ``j = step mod M`` of a cycle uses the
spherical Fibonacci set shifted in its (z, phi) parametrisation by the ``j``-th point of the R2
sequence (``z_k = 1 - 2 (k + u_j) / K``, ``phi_k = 2 pi frac(k / golden + v_j)``; ``j = 0`` is
:func:`warpshade.basis.quadrature.fibonacci`), so that the ``M`` frames of a cycle together are
a stratified set of ``K M`` directions; all of them rotated by one uniformly random rotation per
vertex and cycle, drawn from ``(seed + (step div M) * STEP_STRIDE, v)``. Every frame's set is a
fixed point set under a uniform random rotation, so every frame's estimate is unbiased.

* :func:`cycle_table_kernel` -- the step's directions ``d_k`` and their SH, once per frame for every
  vertex (:func:`residual_kernel` turns each vertex's rotation onto its control and its sum
  instead of evaluating SH per ray).
* :func:`residual_kernel` -- the control-variate residual and the variance of that one-frame
  estimate::

      e_k = V(w_k) max(0, n.w_k) - f_hat(w_k)
      r_i = (4 pi / K) sum_k e_k y_i(w_k')
      m2  = (4 pi)^2 mean_k e_k^2 |y(w_k')|^2 = 4 pi C mean_k e_k^2      (addition theorem)
      var = max(0, m2 - |r|^2) / (K - 1)    (K > 1; m2 for K = 1: an upper bound)

  ``var`` is the trace of the covariance of ``r`` (the sum over coefficients). For the SH
  visibility (``quantity`` 1, what ``rpo.shade`` reads) the integrand is ``V(w_k)`` above the
  horizon and 1 below it (open below the horizon: no ray), as ``rpo.visibility_traced``. With
  ``add_control`` the kernel writes ``T_hat + r`` (the full one-frame estimate) instead of ``r``. Only rays above the
  horizon are traced (``max(0, n.w)`` is zero below it); ``V`` is 1 for a ray that hits nothing.
* :func:`filter_kernel` -- one Jacobi pass of an edge-aware filter over the mesh neighbours:
  ``r'_v = (r_v + sum_u w_uv r_u) / (1 + sum_u w_uv)`` with
  ``w_uv = exp(-(1 - n_u.n_v) / sigma_n^2) exp(-|p_u - p_v|^2 / (2 (sigma_d s_v)^2))`` for
  ``n_u.n_v > 0`` (else 0), ``s_v`` the vertex's mean edge length at rest; it also writes the
  variance reduction of the pass for independent inputs, ``(1 + sum w)^2 / (1 + sum w^2)``.
* :func:`temporal_kernel` -- the exponential moving average of the residual per vertex, and the
  transfer ``T = T_hat + h``; when the control is the last estimate (``in_control``) the fresh
  input is the full estimate ``T_prev + r`` (filtered) and ``T = (1 - a) T_prev + a fresh``. With ``z = |r - h|^2 / (var_mean + var_h)`` (1 on average while the
  residual holds still) the weight of the fresh frame is ``max(alpha, 1 / (n + 1), s^2)``,
  ``s = clamp((z - fade) / (threshold - fade), 0, 1)``, so the history fades as the fresh rays drift
  from it, and is cut (weight 1) for ``z > threshold`` or when the vertex moved or turned fast.
  With ``soft`` (the ``reset = "soft"`` parameter) the fade is replaced by the weight that
  minimises the mean squared error of the blend for the history's estimated bias
  ``b^2 = max(0, d^2 - var_mean - var_h)``: ``a = (var_h + b^2) / (var_h + b^2 + var_mean)`` (for an
  unbiased history that is the running average's own ``var_h / (var_h + var_fresh)``); the cut
  above the threshold stays. One frame's excess ``d^2 - var_mean - var_h`` is as noisy as the fresh
  frame, so ``b^2`` is the positive part of its moving average (weight ``max(bias_weight,
  1 / (n + 1))``, restarted at every cut; ``bias_weight`` 1: this frame's alone): a weight drawn
  from one frame's noise would put that noise back into the history. With ``test_raw`` the test compares the unfiltered one-frame estimate (``raw``) instead, against
  the one-frame variance before the filter (``var_mean`` times the filter's gain): less sensitive
  by that gain, so it keeps more history (less noise) and follows a slowly drifting transfer later.
* :func:`warm_filter_kernel`, :func:`warm_blend_kernel` -- with ``warmup_frames`` ``N > 0``, after
  the moving average: the output is filtered more where the history is short (as real-time
  denoisers filter more where a pixel's history is short). ``P`` (``warmup_passes``) further
  passes of the edge-aware filter over the history ``h`` (the averaged residual, or the last
  estimate when it is the control) give ``B(h)``, each pass carrying the history's variance
  ``var_h`` as for independent inputs (``var' = (var_v + sum_u w_uv^2 var_u) / (1 + sum_u w_uv)^2``),
  and the output is ``h + w (B(h) - h)`` (plus the control), never fed back into the history. The
  history's variance falls as ``1 / n`` (``n`` its effective frames), so a history of ``n < N``
  frames lacks the factor ``n / N`` of the variance at ``N`` frames; modelling ``h`` as ``B(h)`` plus
  an independent rest, the blend's variance is ``var_B + (1 - w)^2 (var_h - var_B)``, and ``w`` is the
  least weight that brings it to ``var_h n / N``::

      w = 1 - sqrt(clamp((n / N - rho) / (1 - rho), 0, 1)),   rho = var_B / var_h

  (``w = 0`` for ``n >= N``, or where the passes do not reduce the variance, ``rho >= 1``; ``w = 1``
  where even the full ``B(h)`` does not reach the target). The filter adds bias where the residual
  varies over the surface, so it is applied only as far as the missing frames need, and with
  ``limit`` (``warmup_limit = "mse"``) no further than the weight of least mean squared error for
  the bias it adds: in the same model the blend's error is ``var_B + (1 - w)^2 (var_h - var_B) +
  w^2 b^2``, ``b^2 = max(0, |B(h) - h|^2 - (var_h - var_B))`` the estimated squared bias of
  ``B(h)``, least at ``w = (var_h - var_B) / (var_h - var_B + b^2)``. Here the variances are the
  tracked ones times ``noise_scale`` (``warmup_noise``): the tracked variance is the formula for
  independent rays, above the actual spread of stratified ray sets averaged over filter passes
  (``benchmarks/bench_hybrid_variance.py``), which would let the limit pass bias for noise that
  is not there.
* :func:`reproject_kernel` -- with ``reproject`` on, before the rays: the per-vertex history (the
  averaged residual, or the last estimate when it is the control) is carried by the rotation of
  the vertex's tangent frame since the last frame, ``R = F_now^T F_prev`` (``F`` rows t, b, n:
  world to local), so that a history kept in the world frame follows the surface's turn
  (``h(w) <- h(R^T w)``: what was seen along the local direction ``F_prev w`` is now seen along
  ``F_now^T F_prev w``); vertices without history, or whose frames are not finite, are left as they are.
* :func:`visibility_transfer_kernel` -- a visibility model as control (``hybrid.visibility_transfer``):
  local SH visibility ``v`` (open below the horizon, tangent frame ``F``) as world-frame diffuse
  transfer ``T = R(F^T) (v * c)``, ``c`` the SH of the clamped cosine ``max(0, s_z)`` and ``v * c``
  the order-n truncated SH product (as ``visibility.diffuse`` shades it).
* :func:`advance_kernel` -- the frame counter, incremented at the end of every frame.
"""

from __future__ import annotations

import functools

from ..._wp import wp
from ...basis.sh_warp import SHTables, sh_kernels
from ...geometry._bvh import RAY_MAX_DISTANCE
from ...transfer._raytrace import random_rotation

wp.set_module_options({"enable_backward": False})

__all__ = ["ResidualSettings", "residual_settings", "QUANTITY_TRANSFER", "QUANTITY_VISIBILITY", "STEP_STRIDE", "RESET_NONE", "RESET_VARIANCE", "RESET_MOTION", "RESET_NONFINITE"]

#: Added to the seed per frame step: consecutive frames draw unrelated rotations.
STEP_STRIDE = 7919
#: What the rays estimate: the diffuse transfer, or the SH visibility open below the horizon.
QUANTITY_TRANSFER = wp.constant(0)
QUANTITY_VISIBILITY = wp.constant(1)
#: Per-vertex reset codes written by the temporal kernel (what the diagnostics count).
RESET_NONE = wp.constant(0)
RESET_VARIANCE = wp.constant(1)
RESET_MOTION = wp.constant(2)
RESET_NONFINITE = wp.constant(3)

_RAY_MAX = wp.constant(RAY_MAX_DISTANCE)


#: R2 sequence steps (1 / plastic number, its square) and 1 / golden ratio.
_R2_U = wp.constant(0.7548776662466927)
_R2_V = wp.constant(0.5698402909980532)
_INV_GOLDEN = wp.constant(0.6180339887498949)


@wp.func
def frame_rotation(seed: int, step: int, cycle: int, vertex: int) -> wp.mat33:
    """The random rotation of a vertex's sample set at frame step ``step`` (one per cycle)."""
    return random_rotation(seed + (step / cycle) * STEP_STRIDE, vertex)


@wp.func
def cycle_direction(k: int, count: int, step: int, cycle: int) -> wp.vec3:
    """Direction ``k`` of ``count`` at frame ``step mod cycle`` of a cycle (before the rotation)."""
    j = step % cycle
    u = 0.5
    v = 0.0
    if j > 0:
        u = wp.mod(0.5 + float(j) * _R2_U, 1.0)
        v = wp.mod(float(j) * _R2_V, 1.0)
    z = 1.0 - 2.0 * (float(k) + u) / float(count)
    r = wp.sqrt(wp.max(0.0, 1.0 - z * z))
    phi = 2.0 * wp.pi * wp.mod(float(k) * _INV_GOLDEN + v, 1.0)
    return wp.vec3(r * wp.cos(phi), r * wp.sin(phi), z)


@wp.kernel
def rotations_kernel(seed: int, step: wp.array(dtype=wp.int32), cycle: int, rotations: wp.array(dtype=wp.mat33)):
    """The rotations :func:`residual_kernel` uses at the current step (for checks)."""
    v = wp.tid()
    rotations[v] = frame_rotation(seed, step[0], cycle, v)


@wp.kernel
def advance_kernel(step: wp.array(dtype=wp.int32)):
    step[0] = step[0] + 1


@wp.struct
class ResidualSettings:
    """Constants of one :func:`residual_kernel` launch (set from the stage's parameters)."""

    use_local: int  # 1: the SH are evaluated in the tangent frame ``frames[v]`` (else the world frame)
    use_control: int  # 1: ``control`` holds the control's transfer ``T_hat`` (else it is zero)
    add_control: int  # 1: write ``T_hat + r`` (the full one-frame estimate) instead of ``r``
    quantity: int  # QUANTITY_TRANSFER (cosine-weighted visibility) or QUANTITY_VISIBILITY
    count: int  # K, rays per vertex and frame
    cycle: int  # M, frames per cycle of shifted direction sets
    seed: int  # seed of the per-vertex, per-cycle random rotations
    offset: float  # ray origins' offset along the normal (scene units)


def residual_settings(*, quantity: int = 0, count: int, cycle: int = 1, seed: int = 0, offset: float,
                      use_local: bool = False, use_control: bool = False, add_control: bool = False) -> ResidualSettings:
    """A :class:`ResidualSettings` from Python values."""
    rs = ResidualSettings()
    rs.use_local = 1 if use_local else 0
    rs.use_control = 1 if use_control else 0
    rs.add_control = 1 if add_control else 0
    rs.quantity = int(quantity)
    rs.count = int(count)
    rs.cycle = int(cycle)
    rs.seed = int(seed)
    rs.offset = float(offset)
    return rs


@functools.lru_cache(maxsize=None)
def cycle_table_kernel(order: int):
    """The step's sample set, shared by every vertex (cached per order): ``kernel(step, count,
    cycle, directions, basis)`` over ``dim = count`` writes :func:`cycle_direction` ``k`` of the
    current step into ``directions[k]`` and its real SH (order ``order``) into ``basis[k]``, for
    :func:`residual_kernel` (launched before it in the same frame)."""
    sh = sh_kernels(order)
    sh_eval, sh_store = sh.eval, sh.store

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(step: wp.array(dtype=wp.int32), count: int, cycle: int, directions: wp.array(dtype=wp.vec3),
               basis: wp.array2d(dtype=wp.float32)):
        k = wp.tid()
        d = cycle_direction(k, count, step[0], cycle)
        directions[k] = d
        sh_store(basis, k, sh_eval(d))

    return kernel


@functools.lru_cache(maxsize=None)
def residual_kernel(order: int):
    """The per-vertex residual kernel at an SH order (cached): inputs ``mesh_id, points, normals,
    frames, control, settings (ResidualSettings), step, directions, basis, tables, start, residual,
    variance`` (``directions``, ``basis``: the step's set from :func:`cycle_table_kernel`; ``tables``:
    the order's :class:`~warpshade.basis.sh_warp.SHTables`).

    A vertex's directions are ``w_k = R d_k`` (``R`` its rotation, ``d_k`` the step's set), seen in
    its SH frame as ``M d_k`` (``M = R``, or ``F R`` in the tangent frame). SH rotation commutes with
    evaluation, ``y(M d) = D(M) y(d)``, so the per-sample SH are the shared table ``y(d_k)``: the
    control is turned into the set's frame once (``D(M)^T T_hat``, the same dot products), the sum
    ``sum_k e_k y(d_k)`` is turned back once, and a sample with ``e_k = 0`` (shadowed or below the
    horizon without a control) adds nothing."""
    sh = sh_kernels(order)
    C = sh.coeff_count
    vec_t = sh.vec
    sh_rotate, sh_load = sh.rotate, sh.load

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(
        mesh_id: wp.uint64,
        points: wp.array(dtype=wp.vec3),
        normals: wp.array(dtype=wp.vec3),
        frames: wp.array(dtype=wp.mat33),
        control: wp.array2d(dtype=wp.float32),
        settings: ResidualSettings,
        step: wp.array(dtype=wp.int32),
        directions: wp.array(dtype=wp.vec3),
        basis: wp.array2d(dtype=wp.float32),
        tables: SHTables,
        start: int,
        residual: wp.array2d(dtype=wp.float32),
        variance: wp.array(dtype=wp.float32),
    ):
        v = start + wp.tid()
        n = normals[v]
        origin = points[v] + settings.offset * n
        rot = frame_rotation(settings.seed, step[0], settings.cycle, v)
        to_set = rot  # the SH frame's turn of the shared set: y(to_set d_k)
        if settings.use_local != 0:
            to_set = frames[v] * rot
        t_hat = vec_t()
        t_set = vec_t()  # the control in the set's frame: t_hat . y(to_set d) = t_set . y(d)
        if settings.use_control != 0:
            t_hat = sh_load(control, v)
            t_set = sh_rotate(t_hat, wp.transpose(to_set), tables)
        acc = vec_t()
        m2 = float(0.0)
        for s in range(settings.count):
            d = rot * directions[s]
            f = float(0.0)
            c = wp.dot(n, d)
            if settings.quantity == QUANTITY_TRANSFER:
                if c > 0.0:
                    if not wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX):
                        f = c
            else:  # visibility, open below the horizon (no ray there)
                f = 1.0
                if c > 0.0:
                    if wp.mesh_query_ray_anyhit(mesh_id, origin, d, _RAY_MAX):
                        f = 0.0
            if settings.use_control != 0:
                y = sh_load(basis, s)
                e = f - wp.dot(t_set, y)
                acc += e * y
                m2 += e * e
            elif f != 0.0:
                acc += f * sh_load(basis, s)
                m2 += f * f
        acc = sh_rotate(acc, to_set, tables)
        k = settings.count
        weight = 4.0 * wp.pi / float(k)
        norm2 = float(0.0)
        for i in range(C):
            r = acc[i] * weight
            norm2 += r * r
            if settings.add_control != 0:
                r += t_hat[i]
            residual[v, i] = r
        second = float(C) * weight * m2
        var = second
        if k > 1:
            var = wp.max(second - norm2, 0.0) / float(k - 1)
        variance[v] = var

    return kernel


@wp.func
def edge_weight(nv: wp.vec3, lv: float, pv: wp.vec3, nu: wp.vec3, pu: wp.vec3, sigma_normal: float, sd: float):
    """The edge-aware weight of neighbour ``u`` for vertex ``v`` (0 where it does not count):
    ``exp(-(1 - n_u.n_v) / sigma_n^2 - |p_u - p_v|^2 / (2 sd^2))`` for ``n_u.n_v > 0``."""
    w = float(0.0)
    lu = wp.length(nu)
    if lu > 0.0:
        cosang = wp.dot(nv, nu) / (lv * lu)
        if cosang > 0.0:
            dp = pu - pv
            w = wp.exp(-(1.0 - cosang) / (sigma_normal * sigma_normal) - wp.dot(dp, dp) / (2.0 * sd * sd))
            if not (wp.isfinite(w) and w > 0.0):
                w = 0.0
    return w


@functools.lru_cache(maxsize=None)
def filter_kernel(order: int):
    """One pass of the edge-aware filter over mesh neighbours at an SH order (cached)."""
    C = order * order

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(
        offsets: wp.array(dtype=wp.int32),
        neighbours: wp.array(dtype=wp.int32),
        points: wp.array(dtype=wp.vec3),
        normals: wp.array(dtype=wp.vec3),
        scale: wp.array(dtype=wp.float32),
        sigma_normal: float,
        sigma_distance: float,
        src: wp.array2d(dtype=wp.float32),
        dst: wp.array2d(dtype=wp.float32),
        gain: wp.array(dtype=wp.float32),
    ):
        v = wp.tid()
        nv = normals[v]
        lv = wp.length(nv)
        pv = points[v]
        sd = sigma_distance * scale[v]
        for i in range(C):
            dst[v, i] = src[v, i]
        wsum = float(1.0)
        w2 = float(1.0)
        if lv > 0.0 and sd > 0.0:
            for e in range(offsets[v], offsets[v + 1]):
                u = neighbours[e]
                w = edge_weight(nv, lv, pv, normals[u], points[u], sigma_normal, sd)
                if w > 0.0:
                    for i in range(C):
                        dst[v, i] = dst[v, i] + w * src[u, i]
                    wsum += w
                    w2 += w * w
        inv = 1.0 / wsum
        for i in range(C):
            dst[v, i] = dst[v, i] * inv
        gain[v] = wsum * wsum / w2

    return kernel


@functools.lru_cache(maxsize=None)
def reproject_kernel(order: int):
    """Rotate each vertex's history by its tangent frame's turn since the last frame (cached)."""
    sh = sh_kernels(order)
    sh_rotate, sh_load, sh_store = sh.rotate, sh.load, sh.store

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(
        frames: wp.array(dtype=wp.mat33),
        prev_frames: wp.array(dtype=wp.mat33),
        count: wp.array(dtype=wp.float32),
        tables: SHTables,
        target: wp.array2d(dtype=wp.float32),
    ):
        v = wp.tid()
        f = frames[v]
        r = wp.transpose(f) * prev_frames[v]
        ok = count[v] > 0.0
        for i in range(3):
            for j in range(3):
                if not wp.isfinite(r[i, j]):
                    ok = False
        if ok:
            sh_store(target, v, sh_rotate(sh_load(target, v), r, tables))
        prev_frames[v] = f

    return kernel


@wp.struct
class TemporalState:
    """Per-vertex history of the moving average (device arrays, fixed for a run).

    Attributes:
        history: averaged residual h, (V, C) float32.
        frames: effective frames n in the average (0: none yet), (V,) float32.
        variance_mean: moving average of the one-frame variance, (V,) float32.
        variance: variance of the average (trace of its covariance), (V,) float32.
        prev_points, prev_normals: the vertex at the last frame, (V,) vec3.
        reset: why the history was cut this frame (RESET_* codes), (V,) int32.
        excess: moving average of the squared difference's excess over its variance (the soft
            reset's estimate of the history's squared bias), (V,) float32.
    """

    history: wp.array2d(dtype=wp.float32)
    frames: wp.array(dtype=wp.float32)
    variance_mean: wp.array(dtype=wp.float32)
    variance: wp.array(dtype=wp.float32)
    prev_points: wp.array(dtype=wp.vec3)
    prev_normals: wp.array(dtype=wp.vec3)
    reset: wp.array(dtype=wp.int32)
    excess: wp.array(dtype=wp.float32)


@wp.struct
class TemporalParams:
    """Constants of the moving average (set from the stage's parameters)."""

    alpha: float  # smallest weight of a new frame (EMA weight once enough frames are in)
    motion: float  # displacement per frame, in mean edge lengths, that cuts the history
    normal_cos: float  # cosine of the normal's turn per frame that cuts the history
    threshold: float  # variance test: cut when z = |r - h|^2 / (var_mean + var) > threshold
    in_control: int  # 1: the control is the last estimate (the history lives in it; fresh = T_prev + r)
    fade: float  # z above which the history fades (the fresh frame's weight s^2 reaches 1 at the threshold)
    test_raw: int  # 1: the variance test compares the unfiltered one-frame estimate with the history
    soft: int  # 1: below the threshold the fresh frame's weight is the MSE-optimal one for the estimated bias (no fade)
    bias_weight: float  # soft: smallest weight of a new frame in the moving average of the excess (1: this frame's alone)


@functools.lru_cache(maxsize=None)
def temporal_kernel(order: int):
    """The temporal accumulation at an SH order (cached)."""
    C = order * order

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(
        points: wp.array(dtype=wp.vec3),
        normals: wp.array(dtype=wp.vec3),
        scale: wp.array(dtype=wp.float32),
        control: wp.array2d(dtype=wp.float32),
        use_control: int,
        fresh: wp.array2d(dtype=wp.float32),
        raw: wp.array2d(dtype=wp.float32),
        fresh_variance: wp.array(dtype=wp.float32),
        gain: wp.array(dtype=wp.float32),
        state: TemporalState,
        params: TemporalParams,
        transfer: wp.array2d(dtype=wp.float32),
    ):
        v = wp.tid()
        p = points[v]
        n = normals[v]
        g = wp.max(gain[v], 1.0)
        vf = fresh_variance[v] / g
        count = state.frames[v]
        code = int(RESET_NONE)
        drift = float(0.0)
        # distance of the fresh estimate from the history (the last transfer when it lives in the control)
        d2 = float(0.0)
        for i in range(C):
            h = state.history[v, i]
            if params.in_control != 0:
                h = control[v, i]
            x = fresh[v, i]
            if params.test_raw != 0:
                x = raw[v, i]
            diff = x - h
            d2 += diff * diff
        if count > 0.0:
            moved = wp.length(p - state.prev_points[v])
            ln = wp.length(n) * wp.length(state.prev_normals[v])
            turned = float(1.0)
            if ln > 0.0:
                turned = wp.dot(n, state.prev_normals[v]) / ln
            if moved > params.motion * scale[v] or turned < params.normal_cos:
                code = RESET_MOTION
            else:
                vm = (1.0 - params.alpha) * state.variance_mean[v] + params.alpha * vf
                if params.test_raw != 0:
                    vm = vm * g  # the one-frame variance before the filter
                z = d2 / (vm + state.variance[v] + 1.0e-12)
                if z > params.threshold:
                    code = RESET_VARIANCE
                elif params.soft != 0:
                    vh = state.variance[v]
                    beta = wp.max(params.bias_weight, 1.0 / (count + 1.0))
                    excess = (1.0 - beta) * state.excess[v] + beta * (d2 - vm - vh)
                    state.excess[v] = excess
                    b2 = wp.max(excess, 0.0)
                    drift = (vh + b2) / (vh + b2 + vm + 1.0e-12)
                elif params.threshold > params.fade:
                    s = wp.clamp((z - params.fade) / (params.threshold - params.fade), 0.0, 1.0)
                    drift = s * s
        if not (wp.isfinite(d2) and wp.isfinite(vf)):
            code = RESET_NONFINITE
        if code != RESET_NONE or count <= 0.0:
            state.excess[v] = 0.0
        a = float(1.0)
        if count > 0.0 and code == RESET_NONE:
            a = wp.max(wp.max(params.alpha, 1.0 / (count + 1.0)), drift)
        if code == RESET_NONFINITE:
            for i in range(C):
                state.history[v, i] = 0.0
                transfer[v, i] = 0.0
                if use_control != 0:
                    c = control[v, i]
                    if wp.isfinite(c):
                        transfer[v, i] = c
            state.frames[v] = 0.0
            state.variance[v] = 0.0
            state.variance_mean[v] = 0.0
        else:
            for i in range(C):
                h = state.history[v, i]
                base = float(0.0)
                if params.in_control != 0:
                    h = control[v, i]
                elif use_control != 0:
                    base = control[v, i]
                h = (1.0 - a) * h + a * fresh[v, i]
                state.history[v, i] = h
                transfer[v, i] = base + h
            if a >= 1.0:
                state.frames[v] = 1.0
                state.variance[v] = vf
                state.variance_mean[v] = vf
            else:
                b = 1.0 - a
                state.frames[v] = 1.0 / (b * b / count + a * a)
                state.variance[v] = b * b * state.variance[v] + a * a * vf
                state.variance_mean[v] = b * state.variance_mean[v] + a * vf
        state.reset[v] = code
        state.prev_points[v] = p
        state.prev_normals[v] = n

    return kernel


@functools.lru_cache(maxsize=None)
def warm_filter_kernel(order: int):
    """One pass of the edge-aware filter (the weights of :func:`filter_kernel`) over the history,
    carrying its per-vertex variance as for independent inputs (cached)."""
    C = order * order

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(
        offsets: wp.array(dtype=wp.int32),
        neighbours: wp.array(dtype=wp.int32),
        points: wp.array(dtype=wp.vec3),
        normals: wp.array(dtype=wp.vec3),
        scale: wp.array(dtype=wp.float32),
        sigma_normal: float,
        sigma_distance: float,
        src: wp.array2d(dtype=wp.float32),
        src_variance: wp.array(dtype=wp.float32),
        dst: wp.array2d(dtype=wp.float32),
        dst_variance: wp.array(dtype=wp.float32),
    ):
        v = wp.tid()
        nv = normals[v]
        lv = wp.length(nv)
        pv = points[v]
        sd = sigma_distance * scale[v]
        for i in range(C):
            dst[v, i] = src[v, i]
        wsum = float(1.0)
        var = src_variance[v]
        if lv > 0.0 and sd > 0.0:
            for e in range(offsets[v], offsets[v + 1]):
                u = neighbours[e]
                w = edge_weight(nv, lv, pv, normals[u], points[u], sigma_normal, sd)
                if w > 0.0:
                    for i in range(C):
                        dst[v, i] = dst[v, i] + w * src[u, i]
                    wsum += w
                    var += w * w * src_variance[u]
        inv = 1.0 / wsum
        for i in range(C):
            dst[v, i] = dst[v, i] * inv
        dst_variance[v] = var * inv * inv

    return kernel


@wp.func
def warm_weight(frames: float, warm_frames: float, variance: float, filtered_variance: float, distance2: float,
                limit: int, noise_scale: float):
    """The blend weight of the filtered history (see :func:`warm_blend_kernel`)."""
    w = float(0.0)
    if frames > 0.0 and frames < warm_frames and variance > 0.0:
        ratio = filtered_variance / variance
        if ratio < 1.0:
            u = wp.clamp((frames / warm_frames - ratio) / (1.0 - ratio), 0.0, 1.0)
            w = 1.0 - wp.sqrt(u)
            if limit != 0:  # no further than the least mean squared error for the filter's estimated bias
                removed = noise_scale * (variance - filtered_variance)
                bias2 = wp.max(distance2 - removed, 0.0)
                w = wp.min(w, removed / (removed + bias2))
    return w


@functools.lru_cache(maxsize=None)
def warm_blend_kernel(order: int):
    """The output where the history is short: ``out = cur + w (B(h) - h)`` (cached)."""
    C = order * order

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(
        frames: wp.array(dtype=wp.float32),
        warm_frames: float,
        limit: int,
        noise_scale: float,
        history: wp.array2d(dtype=wp.float32),
        variance: wp.array(dtype=wp.float32),
        filtered: wp.array2d(dtype=wp.float32),
        filtered_variance: wp.array(dtype=wp.float32),
        current: wp.array2d(dtype=wp.float32),
        out: wp.array2d(dtype=wp.float32),
        weight: wp.array(dtype=wp.float32),
    ):
        v = wp.tid()
        d2 = float(0.0)
        for i in range(C):
            d = filtered[v, i] - history[v, i]
            d2 += d * d
        ok = wp.isfinite(d2)
        w = float(0.0)
        if ok:
            w = warm_weight(frames[v], warm_frames, variance[v], filtered_variance[v], d2, limit, noise_scale)
        if not wp.isfinite(w):
            w = 0.0
        for i in range(C):
            x = current[v, i]
            if w > 0.0:
                x = x + w * (filtered[v, i] - history[v, i])
            out[v, i] = x
        weight[v] = w

    return kernel


@functools.lru_cache(maxsize=None)
def visibility_transfer_kernel(order: int):
    """``kernel(visibility, frames, cos_sh, tables, start, transfer)``: ``R(F^T)(v * cos)`` per vertex."""
    shk = sh_kernels(order)
    n2 = order * order
    vec_t = shk.vec
    sh_rotate, sh_product, sh_load, sh_store = shk.rotate, shk.product, shk.load, shk.store

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(visibility: wp.array2d(dtype=wp.float32), frames: wp.array(dtype=wp.mat33),
               cos_sh: wp.array(dtype=wp.float32), tables: SHTables, start: int,
               transfer: wp.array2d(dtype=wp.float32)):
        v = wp.tid() + start
        c = vec_t()
        for i in range(n2):
            c[i] = cos_sh[i]
        t = sh_product(sh_load(visibility, v), c, tables)
        sh_store(transfer, v, sh_rotate(t, wp.transpose(frames[v]), tables))

    return kernel


@functools.lru_cache(maxsize=None)
def world_visibility_transfer_kernel(order: int, visibility_order: int):
    """``kernel(visibility, normals, cos_zh, tables, start, transfer)``: ``v * cos_n`` per vertex,
    the world-frame SH visibility ``v`` (order ``visibility_order`` <= ``order``, zero above it)
    times the clamped cosine about the vertex normal ``n``, projected to ``order`` (a vertex with
    a zero normal gets zero)."""
    if not 1 <= visibility_order <= order:
        raise ValueError(f"world_visibility_transfer_kernel: visibility order {visibility_order} not in 1..{order}")
    shk = sh_kernels(order)
    nv2 = visibility_order * visibility_order
    vec_t, bands_t = shk.vec, shk.bands
    sh_product, sh_zh_to_sh, sh_store = shk.product, shk.zh_to_sh, shk.store

    @wp.kernel(enable_backward=False, module="unique")
    def kernel(visibility: wp.array2d(dtype=wp.float32), normals: wp.array(dtype=wp.vec3),
               cos_zh: wp.array(dtype=wp.float32), tables: SHTables, start: int,
               transfer: wp.array2d(dtype=wp.float32)):
        v = wp.tid() + start
        g = bands_t()
        for l in range(order):
            g[l] = cos_zh[l]
        vis = vec_t()
        for i in range(nv2):
            vis[i] = visibility[v, i]
        n = normals[v]
        length = wp.length(n)
        if length > 0.0:  # a vertex without a normal gets no control (zero: the plain estimate)
            sh_store(transfer, v, sh_product(vis, sh_zh_to_sh(n / length, g), tables))
        else:
            sh_store(transfer, v, vec_t())

    return kernel
