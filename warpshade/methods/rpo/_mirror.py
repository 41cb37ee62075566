"""Float64 mirrors of the RPO kernels, and the exact-BRDF oracle they are measured against.

* :func:`shade_f64` -- what :func:`._kernels.shade_kernel` computes, in float64 with the
  float64 SH algebra (:mod:`warpshade.basis.sh`): the tests' oracle of the kernel.
* :func:`shade_exact_brdf` -- the same integral with the BRDF itself in place of its factors,
  ``integral f(wo, s) max(0, s_z) v(s) l(s) ds`` over the sphere by quadrature, with the order-n
  visibility ``v`` and lighting ``l``: what the operators approximate. Its gap to the operators is
  the factorisation error alone (SVD rank, view-factor fit, light-factor truncation).
"""

from __future__ import annotations

import numpy as np

from ...basis import quadrature, sh

__all__ = [
    "local_views",
]


def local_views(frames, points, eye) -> np.ndarray:
    """Unit view directions in the tangent frames (rows t, b, n), (V, 3) float64."""
    d = np.asarray(eye, np.float64).reshape(1, 3) - np.asarray(points, np.float64)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    return np.einsum("vij,vj->vi", np.asarray(frames, np.float64), d)


def _local_visibility(frames, visibility, visibility_space: str) -> np.ndarray:
    v = np.asarray(visibility, np.float64)
    return sh.rotate(v, np.asarray(frames, np.float64)) if visibility_space == "world" else v


def shade_f64(frames, points, eye, visibility, operators, material, light, specular=(1.0, 1.0, 1.0),
              zh=None, visibility_space: str = "local", evaluation: str = "gaunt", channels=None) -> tuple[np.ndarray, dict]:
    """Eq. 11 per receiver, float64.

    Args:
        frames: (V, 3, 3) tangent frames (rows t, b, n); points (V, 3); eye (3,).
        visibility: (V, n*n) SH visibility, local or world frame (``visibility_space``).
        operators: list of :class:`._model.ReflectanceOperator`, one per material slot.
        material: (V,) slot index per receiver.
        channels: per slot, 1 (its operator shades all three channels) or 3 (slots s, s+1, s+2
            shade red, green and blue); None: 1 everywhere.
        light: (3, n*n) world-frame SH lighting (used when ``zh`` is None).
        specular: RGB factor.
        zh: a :class:`._lighting.ZHLighting` to shade with its lobes instead of the full rotation.
        evaluation: "gaunt" (``F(wo) * v``) or "matrices" (``sum_b u_b M_b v``).

    Returns:
        ``(radiance (V, 3), {"negative": count, "below_horizon": count})``.
    """
    frames = np.asarray(frames, np.float64)
    views = local_views(frames, points, eye)
    vis = _local_visibility(frames, visibility, visibility_space)
    material = np.asarray(material, np.int64)
    n2 = vis.shape[1]
    if zh is None:
        lo = sh.rotate(np.asarray(light, np.float64)[:, :n2][None], frames[:, None])  # (V, 3, n*n) local lighting
    else:
        lo = zh.local(frames)
    nch = np.ones(len(operators), np.int64) if channels is None else np.asarray(channels, np.int64)
    r = np.zeros((vis.shape[0], 3))
    for s in range(len(operators)):
        m = material == s
        if not np.any(m):
            continue
        for ch in range(int(nch[s])):
            op = operators[s + ch]
            pv = op.prepare_visibility(vis[m])
            if evaluation == "matrices":
                t = np.einsum("vb,bij,vj->vi", op.view_weights(views[m]), op.matrices(), pv)
            else:
                t = op.local_transfer(views[m], pv)
            rc = np.einsum("vi,vci->vc", t, lo[m])
            if nch[s] == 1:
                r[m] = rc
            else:
                r[m, ch] = rc[:, ch]
    below = views[:, 2] <= 0.0
    r[below] = 0.0
    neg = np.any(r < 0.0, axis=1)
    out = np.maximum(r, 0.0) * np.asarray(specular, np.float64)
    return out, {"negative": int(np.sum(neg & ~below)), "below_horizon": int(np.sum(below))}


def shade_exact_brdf(frames, points, eye, visibility, light, brdf, specular=(1.0, 1.0, 1.0),
                     visibility_space: str = "local", degree: int = 40) -> np.ndarray:
    """``specular_c * integral f(wo, s) max(0, s_z) v(s) l_c(s) ds`` with the BRDF itself (float64).

    The order-n visibility and lighting are evaluated as SH functions on a Gauss-Legendre rule of
    ``degree`` over the sphere (local frame), so this differs from the operators only by the
    BRDF's factorisation. Views at or below the horizon give 0. Returns (V, 3).
    """
    frames = np.asarray(frames, np.float64)
    views = local_views(frames, points, eye)
    vis = _local_visibility(frames, visibility, visibility_space)
    n = int(round(np.sqrt(vis.shape[1])))
    rule = quadrature.gauss_legendre(int(degree))
    dirs, w = rule.directions, rule.weights
    up = dirs[:, 2] > 0.0
    dirs, w = dirs[up], w[up]
    y = sh.basis(dirs, n)  # (Q, n*n)
    lo = sh.rotate(np.asarray(light, np.float64)[:, : n * n][None], frames[:, None])  # (V, 3, n*n)
    out = np.zeros((views.shape[0], 3))
    step = max(1, 2_000_000 // max(1, dirs.shape[0]))
    for a in range(0, views.shape[0], step):
        b = slice(a, a + step)
        vals = brdf.evaluate(np.broadcast_to(views[b, None, :], (views[b].shape[0], dirs.shape[0], 3)),
                             np.broadcast_to(dirs[None], (views[b].shape[0],) + dirs.shape)) if np.all(views[b, 2] > 0) \
            else _evaluate_masked(brdf, views[b], dirs)
        vv = vis[b] @ y.T  # (B, Q) visibility values
        ll = np.einsum("vci,qi->vcq", lo[b], y)  # (B, 3, Q)
        out[b] = np.einsum("vq,vcq->vc", vals * vv * (w * dirs[:, 2]), ll)
    out[views[:, 2] <= 0.0] = 0.0
    return out * np.asarray(specular, np.float64)


def _evaluate_masked(brdf, views, dirs) -> np.ndarray:
    vals = np.zeros((views.shape[0], dirs.shape[0]))
    ok = views[:, 2] > 0.0
    if np.any(ok):
        vals[ok] = brdf.evaluate(views[ok, None, :], dirs[None])
    return vals
