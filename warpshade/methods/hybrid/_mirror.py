"""Float64 mirror of the hybrid tracer's kernels (NumPy): the tests' oracle, never ground truth.

Each function does the maths of one kernel of :mod:`._kernels` in float64, from the same inputs
(the per-vertex rotations and ray hits are given: :func:`warpshade.geometry._bvh.trace_occlusion_f64`
gives the hits of a tiny scene).
"""

from __future__ import annotations

import numpy as np

from ...basis import sh

__all__: list[str] = []

_RESET_NONE, _RESET_VARIANCE, _RESET_MOTION, _RESET_NONFINITE = 0, 1, 2, 3


def cycle_directions_f64(count: int, step: int, cycle: int) -> np.ndarray:
    """The ``count`` directions of frame ``step mod cycle`` of a cycle before the rotation
    (:func:`._kernels.cycle_direction`), (count, 3)."""
    j = step % cycle
    u, v = (0.5, 0.0) if j == 0 else ((0.5 + j * 0.7548776662466927) % 1.0, (j * 0.5698402909980532) % 1.0)
    k = np.arange(count, dtype=np.float64)
    z = 1.0 - 2.0 * (k + u) / count
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = 2.0 * np.pi * np.mod(k * 0.6180339887498949 + v, 1.0)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def residual_f64(normals, rotations, samples, occluded, order: int, control=None, frames=None, add_control: bool = False,
                 quantity: str = "transfer"):
    """The control-variate residual and the variance of that one-frame estimate per vertex.

    Args:
        normals: (V, 3) unit normals.
        rotations: (V, 3, 3) per-vertex rotations of the sample set.
        samples: (K, 3) unit sample directions (:func:`cycle_directions_f64`).
        occluded: (V, K) bool, True where the ray toward ``rotations[v] @ samples[k]`` hits something
            (only rays above the horizon are used).
        order: SH order; control: (V, C) control transfer or None; frames: (V, 3, 3) tangent
            frames (rows t, b, n) for local-frame coefficients, or None for the world frame.

    Returns:
        ``(residual (V, C), variance (V,))`` as :func:`._kernels.residual_kernel` defines them.
    """
    n = np.asarray(normals, np.float64)
    rot = np.asarray(rotations, np.float64)
    s = np.asarray(samples, np.float64)
    k = s.shape[0]
    c = order * order
    d = np.einsum("vij,kj->vki", rot, s)  # (V, K, 3) world directions
    ds = d if frames is None else np.einsum("vij,vkj->vki", np.asarray(frames, np.float64), d)
    y = sh.basis(ds, order)  # (V, K, C)
    cos = np.einsum("vki,vi->vk", d, n)
    if quantity == "transfer":
        f = np.where((cos > 0) & ~np.asarray(occluded, bool), cos, 0.0)
    else:
        f = np.where((cos > 0) & np.asarray(occluded, bool), 0.0, 1.0)
    f_hat = 0.0 if control is None else np.einsum("vkc,vc->vk", y, np.asarray(control, np.float64))
    e = f - f_hat
    w = 4.0 * np.pi / k
    r = w * np.einsum("vk,vkc->vc", e, y)
    second = c * w * np.sum(e * e, axis=1)
    var = np.maximum(second - np.sum(r * r, axis=1), 0.0) / (k - 1) if k > 1 else second
    if add_control and control is not None:
        r = r + np.asarray(control, np.float64)
    return r, var


def _edge_weights(offsets, neighbours, points, normals, scale, sigma_normal: float, sigma_distance: float, v: int):
    """The neighbours of ``v`` that count and their edge-aware weights (:func:`._kernels.edge_weight`)."""
    p, nrm = points, normals
    lv = np.linalg.norm(nrm[v])
    sd = sigma_distance * float(scale[v])
    out = []
    if lv <= 0 or sd <= 0:
        return out
    for u in neighbours[offsets[v]:offsets[v + 1]]:
        lu = np.linalg.norm(nrm[u])
        if lu <= 0:
            continue
        cosang = nrm[v] @ nrm[u] / (lv * lu)
        if cosang <= 0:
            continue
        dp = p[u] - p[v]
        w = np.exp(-(1.0 - cosang) / sigma_normal**2 - dp @ dp / (2.0 * sd * sd))
        if np.isfinite(w) and w > 0:
            out.append((int(u), float(w)))
    return out


def filter_f64(offsets, neighbours, points, normals, scale, sigma_normal: float, sigma_distance: float, values):
    """One pass of the edge-aware filter over mesh neighbours (:func:`._kernels.filter_kernel`).

    Returns:
        ``(filtered (V, C), gain (V,))``: the gain is ``(1 + sum w)^2 / (1 + sum w^2)``.
    """
    p = np.asarray(points, np.float64)
    nrm = np.asarray(normals, np.float64)
    src = np.asarray(values, np.float64)
    out = src.copy()
    gain = np.ones(p.shape[0])
    for v in range(p.shape[0]):
        acc, wsum, w2 = src[v].copy(), 1.0, 1.0
        for u, w in _edge_weights(offsets, neighbours, p, nrm, scale, sigma_normal, sigma_distance, v):
            acc += w * src[u]
            wsum += w
            w2 += w * w
        out[v] = acc / wsum
        gain[v] = wsum * wsum / w2
    return out, gain


def warm_filter_f64(offsets, neighbours, points, normals, scale, sigma_normal: float, sigma_distance: float, values,
                    variance):
    """One pass of the history-aware filter (:func:`._kernels.warm_filter_kernel`): the edge-aware
    filter's weights, and the per-vertex variance carried as for independent inputs,
    ``(var_v + sum_u w^2 var_u) / (1 + sum_u w)^2``.

    Returns:
        ``(filtered (V, C), variance (V,))``.
    """
    p = np.asarray(points, np.float64)
    nrm = np.asarray(normals, np.float64)
    src = np.asarray(values, np.float64)
    var = np.asarray(variance, np.float64)
    out = src.copy()
    out_var = var.copy()
    for v in range(p.shape[0]):
        acc, wsum, vsum = src[v].copy(), 1.0, var[v]
        for u, w in _edge_weights(offsets, neighbours, p, nrm, scale, sigma_normal, sigma_distance, v):
            acc += w * src[u]
            wsum += w
            vsum += w * w * var[u]
        out[v] = acc / wsum
        out_var[v] = vsum / (wsum * wsum)
    return out, out_var


def warm_weight_f64(frames, warm_frames: float, variance, filtered_variance, distance2=None,
                    noise_scale: float = 1.0) -> np.ndarray:
    """The per-vertex weight of the filtered history (:func:`._kernels.warm_weight`):
    ``1 - sqrt(clamp((n / N - rho) / (1 - rho), 0, 1))`` with ``rho = var_B / var_h``, for
    ``0 < n < N``, ``var_h > 0`` and ``rho < 1``; else 0. With ``distance2`` (``|B(h) - h|^2`` per
    vertex) at most ``r / (r + b^2)``, ``r = noise_scale (var_h - var_B)``, ``b^2 = max(0, distance2 - r)``."""
    n = np.asarray(frames, np.float64)
    vh = np.asarray(variance, np.float64)
    vb = np.asarray(filtered_variance, np.float64)
    w = np.zeros(n.shape)
    for v in range(n.size):
        if 0 < n[v] < warm_frames and vh[v] > 0:
            rho = vb[v] / vh[v]
            if rho < 1:
                w[v] = 1.0 - np.sqrt(min(max((n[v] / warm_frames - rho) / (1.0 - rho), 0.0), 1.0))
                if distance2 is not None:
                    removed = noise_scale * (vh[v] - vb[v])
                    w[v] = min(w[v], removed / (removed + max(float(distance2[v]) - removed, 0.0)))
    return w


def warm_blend_f64(frames, warm_frames: float, history, variance, filtered, filtered_variance, current,
                   limit: bool = False, noise_scale: float = 1.0):
    """The output of the history-aware filter (:func:`._kernels.warm_blend_kernel`):
    ``current + w (filtered - history)`` per vertex, ``w`` from :func:`warm_weight_f64` (with
    ``limit``: capped by the least-squares weight for the estimated bias; 0 where the difference is
    not finite).

    Returns:
        ``(output (V, C), weight (V,))``.
    """
    h = np.asarray(history, np.float64)
    b = np.asarray(filtered, np.float64)
    with np.errstate(invalid="ignore"):
        d = b - h
        d2 = np.sum(d * d, axis=1)
    w = warm_weight_f64(frames, warm_frames, variance, filtered_variance, np.where(np.isfinite(d2), d2, 0.0) if limit else None,
                        noise_scale)
    w = np.where(np.isfinite(d2), w, 0.0)
    out = np.array(current, np.float64) + w[:, None] * np.where(w[:, None] > 0, d, 0.0)
    return out, w


def temporal_f64(state: dict, points, normals, scale, fresh, fresh_variance, gain, control, params: dict, raw=None):
    """One frame of the moving average (:func:`._kernels.temporal_kernel`), on a copy of ``state``.

    Args:
        state: ``history`` (V, C), ``frames`` (V,), ``variance_mean`` (V,), ``variance`` (V,),
            ``prev_points`` (V, 3), ``prev_normals`` (V, 3).
        control: (V, C) or None; params: ``alpha``, ``motion``, ``normal_cos``, ``threshold``,
            ``in_control``, ``fade`` (optional, default 1), ``soft`` (optional, default 0: the
            MSE-optimal weight for the estimated bias instead of the fade), ``bias_weight`` (optional,
            default 1: the smallest weight of a new frame in the moving average of the excess), ``test_raw`` (optional, 0: the variance test on ``fresh``; 1: on ``raw``,
            the unfiltered one-frame estimate, against the variance before the filter).
        raw: (V, C) the unfiltered one-frame estimate (``fresh`` when None).

    Returns:
        ``(transfer (V, C), new_state)`` with ``new_state["reset"]`` the per-vertex codes.
    """
    st = {k: np.array(v, np.float64) for k, v in state.items()}
    st.setdefault("excess", np.zeros(np.shape(fresh)[0]))
    p = np.asarray(points, np.float64)
    n = np.asarray(normals, np.float64)
    fr = np.asarray(fresh, np.float64)
    ctl = np.zeros_like(fr) if control is None else np.asarray(control, np.float64)
    vcount, c = fr.shape
    out = np.zeros_like(fr)
    reset = np.zeros(vcount, np.int32)
    alpha = params["alpha"]
    test_raw = bool(params.get("test_raw", 0))
    fade = float(params.get("fade", 1.0))
    rw = fr if raw is None else np.asarray(raw, np.float64)
    for v in range(vcount):
        g = max(gain[v], 1.0)
        vf = fresh_variance[v] / g
        count = st["frames"][v]
        h_prev = ctl[v] if params["in_control"] else st["history"][v]
        d2 = float(np.sum(((rw[v] if test_raw else fr[v]) - h_prev) ** 2))
        code = _RESET_NONE
        drift = 0.0
        if count > 0:
            moved = np.linalg.norm(p[v] - st["prev_points"][v])
            ln = np.linalg.norm(n[v]) * np.linalg.norm(st["prev_normals"][v])
            turned = n[v] @ st["prev_normals"][v] / ln if ln > 0 else 1.0
            if moved > params["motion"] * scale[v] or turned < params["normal_cos"]:
                code = _RESET_MOTION
            else:
                vm = (1 - alpha) * st["variance_mean"][v] + alpha * vf
                if test_raw:
                    vm *= g
                z = d2 / (vm + st["variance"][v] + 1e-12)
                if z > params["threshold"]:
                    code = _RESET_VARIANCE
                elif params.get("soft", 0):
                    vh = st["variance"][v]
                    beta = max(float(params.get("bias_weight", 1.0)), 1.0 / (count + 1.0))
                    st["excess"][v] = (1 - beta) * st["excess"][v] + beta * (d2 - vm - vh)
                    b2 = max(st["excess"][v], 0.0)
                    drift = (vh + b2) / (vh + b2 + vm + 1e-12)
                elif params["threshold"] > fade:
                    drift = min(max((z - fade) / (params["threshold"] - fade), 0.0), 1.0) ** 2
        if not (np.isfinite(d2) and np.isfinite(vf)):
            code = _RESET_NONFINITE
        if code != _RESET_NONE or count <= 0:
            st["excess"][v] = 0.0
        if code == _RESET_NONFINITE:
            st["history"][v] = 0.0
            out[v] = np.where(np.isfinite(ctl[v]), ctl[v], 0.0) if control is not None else 0.0
            st["frames"][v] = st["variance"][v] = st["variance_mean"][v] = 0.0
        else:
            a = max(alpha, 1.0 / (count + 1.0), drift) if count > 0 and code == _RESET_NONE else 1.0
            h = (1 - a) * h_prev + a * fr[v]
            st["history"][v] = h
            out[v] = h if params["in_control"] else ctl[v] + h
            if a >= 1.0:
                st["frames"][v], st["variance"][v], st["variance_mean"][v] = 1.0, vf, vf
            else:
                b = 1 - a
                st["frames"][v] = 1.0 / (b * b / count + a * a)
                st["variance"][v] = b * b * st["variance"][v] + a * a * vf
                st["variance_mean"][v] = b * st["variance_mean"][v] + a * vf
        reset[v] = code
        st["prev_points"][v] = p[v]
        st["prev_normals"][v] = n[v]
    st["reset"] = reset
    return out, st


def reproject_f64(target, frames, prev_frames, count):
    """The history carried by each vertex's tangent-frame turn (:func:`._kernels.reproject_kernel`):
    ``sh.rotate(h, F^T F_prev)`` where ``count > 0`` and both frames are finite, else ``h`` as it is.

    Args:
        target: (V, C) per-vertex SH history (world frame); frames, prev_frames: (V, 3, 3) tangent
            frames (rows t, b, n) now and at the last frame; count: (V,) effective frames of history.

    Returns:
        (V, C) float64.
    """
    out = np.array(target, np.float64)
    f = np.asarray(frames, np.float64)
    fp = np.asarray(prev_frames, np.float64)
    with np.errstate(invalid="ignore"):
        r = np.einsum("vji,vjk->vik", f, fp)  # F^T F_prev
    ok = (np.asarray(count) > 0) & np.all(np.isfinite(r), axis=(1, 2))
    if np.any(ok):
        out[ok] = sh.rotate(out[ok], r[ok])
    return out


def estimate_f64(normals, rotations, samples, occluded, order: int, control=None):
    """One frame without reuse: ``T = T_hat + r`` (the unbiased control-variate estimate)."""
    r, _ = residual_f64(normals, rotations, samples, occluded, order, control)
    return r if control is None else np.asarray(control, np.float64) + r


def visibility_transfer_f64(visibility, frames, order: int) -> np.ndarray:
    """Float64 mirror of :func:`visibility_transfer_kernel`: (V, C) world-frame transfer from
    (V, C) local visibility and (V, 3, 3) tangent frames (rows t, b, n)."""
    local = sh.product(np.asarray(visibility, np.float64), np.broadcast_to(sh.clamped_cosine_sh(order), np.shape(visibility)))
    return sh.rotate(local, np.swapaxes(np.asarray(frames, np.float64), 1, 2))


def world_visibility_transfer_f64(visibility, normals, order: int) -> np.ndarray:
    """Float64 mirror of :func:`world_visibility_transfer_kernel`: (V, order^2) world-frame transfer
    from (V, Cv) world-frame visibility (zero-padded to ``order``) and (V, 3) vertex normals (a zero
    normal gives zero)."""
    vis = np.asarray(visibility, np.float64)
    v = np.zeros((vis.shape[0], order * order))
    v[:, : vis.shape[1]] = vis
    nrm = np.asarray(normals, np.float64)
    length = np.linalg.norm(nrm, axis=1)
    ok = length > 0.0
    axis = np.where(ok[:, None], nrm / np.where(ok, length, 1.0)[:, None], [0.0, 0.0, 1.0])
    zh = sh.clamped_cosine_zh(order, "zh")
    band = np.concatenate([np.full(2 * l + 1, np.sqrt(4.0 * np.pi / (2 * l + 1)) * zh[l]) for l in range(order)])
    cos_n = sh.basis(axis, order) * band
    return np.where(ok[:, None], sh.product(v, cos_n), 0.0)
