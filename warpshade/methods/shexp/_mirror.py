"""float64 NumPy reference of the SHEXP per-receiver pipeline (the oracle of :mod:`._kernels`).

Same algorithm as :func:`._kernels.receiver_kernel`, written independently with the float64 SH
algebra of :mod:`warpshade.basis.sh`: self-shadowing replacement (:func:`effective_spheres`),
log accumulation with the blocking-cap log table (:func:`log_visibility`) or the product
baseline (:func:`product_visibility`), exponentiation (:func:`warpshade.basis.sh.exp`) and
diffuse shading (:func:`shade`). Vectorised over receivers and spheres; meant for tests and
small checks, not for frames.
"""

from __future__ import annotations

import numpy as np

from ...basis import sh

__all__ = [
    "effective_spheres",
    "sphere_directions",
    "plane_caps",
    "log_visibility",
    "product_visibility",
    "visibility",
    "shade",
]

RULES = ("none", "paper", "continuous")


def _rule_id(rule) -> int:
    if isinstance(rule, str):
        if rule not in RULES:
            raise ValueError(f"self-shadow rule must be one of {RULES}, got {rule!r}")
        return RULES.index(rule)
    return int(rule)


def effective_spheres(points, normals, centres, radii, rule="continuous"):
    """Replacement spheres of sec. 6.2 (see :func:`._kernels.effective_sphere` for the rules).

    Args:
        points: receivers, (..., 3); normals: unit normals, (..., 3).
        centres: sphere centres, (..., 3); radii: (...,). All broadcast together.
        rule: "none", "paper" or "continuous".

    Returns:
        ``(centres', radii')`` with the broadcast shapes; ``radii' <= 0`` marks dropped spheres.
    """
    rule = _rule_id(rule)
    p = np.asarray(points, np.float64)
    n = np.asarray(normals, np.float64)
    c = np.asarray(centres, np.float64)
    r = np.asarray(radii, np.float64)
    shape = np.broadcast_shapes(p.shape[:-1], n.shape[:-1], c.shape[:-1], r.shape)
    p, n, c = (np.broadcast_to(a, shape + (3,)) for a in (p, n, c))
    r = np.broadcast_to(r, shape)
    out_c = np.array(c, dtype=np.float64)
    out_r = np.full(shape, -1.0)
    valid = np.isfinite(r) & (r > 0.0) & np.all(np.isfinite(c), axis=-1)
    offset = c - p
    dist = np.linalg.norm(offset, axis=-1)
    if rule == 0:
        keep = valid & (dist > r)
        out_r[keep] = r[keep]
        return out_c, out_r
    hc = np.einsum("...i,...i->...", offset, n)
    alive = valid & (hc > -r)
    inside = alive & (dist < r)
    shrink = inside & (hc > 0.0)
    out_r[shrink] = hc[shrink]
    outside = alive & ~inside
    front = outside & (hc >= r)
    out_r[front] = r[front]
    strad = outside & ~front
    h = hc + r
    q1 = c - hc[..., None] * n
    d = np.sqrt(np.maximum(r * r - hc * hc, 0.0))
    along = np.linalg.norm(p - q1, axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (along - d) / d
    degenerate = d <= 1e-7 * r
    if rule == 1:
        r_new = np.minimum(np.maximum(1.0, t) * 0.5 * h, r)
    else:
        r_in = np.maximum(hc, 0.0)
        r_new = np.where(t < 1.0, r_in + np.maximum(t, 0.0) * (0.5 * h - r_in), np.minimum(t * 0.5 * h, r))
    r_new = np.where(degenerate, r, r_new)
    out_r[strad] = r_new[strad]
    out_c[strad] = (q1 + r_new[..., None] * n)[strad]
    return out_c, out_r


#: As :data:`._kernels.PLANE_ON_SURFACE`.
PLANE_ON_SURFACE = 1.0e-3


def plane_caps(points, planes):
    """Blocking caps of planar blockers (rows centre, normal, radius; (P, 7)) seen from points.

    Returns:
        ``(axes (R, P, 3), theta (R, P))``; theta <= 0 where the receiver lies on the plane.
    """
    p = np.asarray(points, np.float64)[:, None, :]
    planes = np.asarray(planes, np.float64).reshape(-1, 7)
    c, n, r = planes[:, :3], planes[:, 3:6], planes[:, 6]
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    h = np.einsum("rpi,pi->rp", p - c, n)
    axes = np.where((h < 0.0)[..., None], n, -n)
    on = ~(r > 0.0) | (np.abs(h) < PLANE_ON_SURFACE * r)
    with np.errstate(divide="ignore"):
        theta = np.where(on, -1.0, np.arctan(r / np.abs(np.where(on, 1.0, h))))
    return axes, theta


def sphere_directions(points, centres, radii):
    """Unit directions to sphere centres and angular radii ``asin(r/|P - p|)`` (clamped)."""
    offset = np.asarray(centres, np.float64) - np.asarray(points, np.float64)
    dist = np.linalg.norm(offset, axis=-1)
    s = offset / np.maximum(dist, 1e-300)[..., None]
    theta = np.arcsin(np.clip(np.asarray(radii) / np.maximum(dist, 1e-300), 0.0, 1.0))
    return s, theta


def log_visibility(points, normals, centres, radii, order: int, rule="continuous", weights=None, skip=None, planes=None,
                   baked=None):
    """Accumulated log visibility ``f = sum_i W_i F(theta_i) y(s_i)`` per receiver (eqs. 34, 38).

    Args:
        points, normals: receivers, (R, 3).
        centres, radii: spheres, (S, 3) and (S,) shared by all receivers, or (R, S, 3), (R, S).
        order: SH order n.
        rule: self-shadowing rule.
        weights: per-band ratio vectors, (S, n) or (R, S, n), or None.
        skip: boolean mask of spheres not to accumulate, (S,) or (R, S), or None.

    Returns:
        (R, n*n) float64.
    """
    p = np.asarray(points, np.float64)[:, None, :]
    n = np.asarray(normals, np.float64)[:, None, :]
    ec, er = effective_spheres(p, n, centres, radii, rule)
    s, theta = sphere_directions(p, ec, np.maximum(er, 0.0))
    zh = sh.log_cap_table(order).lookup(theta)  # (R, S, n)
    if weights is not None:
        zh = zh * np.asarray(weights, np.float64)
    use = er > 0.0
    if skip is not None:
        use &= ~np.broadcast_to(np.asarray(skip, bool), use.shape)
    safe_s = np.where(use[..., None], s, np.array([0.0, 0.0, 1.0]))
    terms = sh.zh_to_sh(safe_s, zh) * use[..., None]
    f = terms.sum(axis=1)
    if planes is not None and len(planes):
        axes, theta = plane_caps(points, planes)
        use_p = theta > 0.0
        if baked is not None:
            use_p &= ~np.asarray(baked, bool)[:, None]
        f += (sh.zh_to_sh(axes, sh.log_cap_table(order).lookup(np.maximum(theta, 0.0))) * use_p[..., None]).sum(axis=1)
    return f


def product_visibility(points, normals, centres, radii, order: int, rule="continuous", skip=None, return_dc_log=False,
                       planes=None, baked=None):
    """Visibility by repeated order-n products of blocker visibilities (Zhou et al. 2005 path).

    ``g = (((1 * G_1) * G_2) * ...)`` in sphere order with ``G_i = G(theta_i) y(s_i)`` the
    rotated blocking-cap visibility (:func:`sh.cap_zh` with ``blocked=True``). (R, n*n); with
    ``return_dc_log`` also the sum of ``log(G_i,0 / sqrt(4 pi))`` per receiver.
    """
    p = np.asarray(points, np.float64)[:, None, :]
    n = np.asarray(normals, np.float64)[:, None, :]
    ec, er = effective_spheres(p, n, centres, radii, rule)
    s, theta = sphere_directions(p, ec, np.maximum(er, 0.0))
    use = er > 0.0
    if skip is not None:
        use &= ~np.broadcast_to(np.asarray(skip, bool), use.shape)
    safe_s = np.where(use[..., None], s, np.array([0.0, 0.0, 1.0]))
    vis = sh.zh_to_sh(safe_s, sh.cap_zh(theta, order, blocked=True))  # (R, S, n*n)
    if planes is not None and len(planes):
        axes, theta_p = plane_caps(points, planes)
        use_p = theta_p > 0.0
        if baked is not None:
            use_p &= ~np.asarray(baked, bool)[:, None]
        vis = np.concatenate([vis, sh.zh_to_sh(axes, sh.cap_zh(np.maximum(theta_p, 0.0), order, blocked=True))], axis=1)
        use = np.concatenate([use, use_p], axis=1)
    one = np.zeros(order * order)
    one[0] = np.sqrt(4.0 * np.pi)
    g = np.broadcast_to(one, (p.shape[0], order * order)).copy()
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(vis.shape[1]):
            rows = use[:, k] & np.all(np.isfinite(g), axis=1)
            if np.any(rows):
                g[rows] = sh.product(g[rows], vis[rows, k])
    if not return_dc_log:
        return g
    dc_log = (np.log(np.maximum(vis[..., 0] / np.sqrt(4.0 * np.pi), 1e-30)) * use).sum(axis=1)
    return g, dc_log


#: Norm bound of a visibility vector (as :data:`._kernels.VISIBILITY_NORM_LIMIT`).
VISIBILITY_NORM_LIMIT = 1.5 * np.sqrt(4.0 * np.pi)


def visibility(points, normals, centres, radii, order: int, method="hyb", degree=None, rule="continuous",
               window=None, weights=None, skip=None, accumulate="log", planes=None, baked=None):
    """The (windowed) total blocker visibility vector g per receiver, (R, n*n) float64.

    Rows whose g exceeds :data:`VISIBILITY_NORM_LIMIT` fall back to ``exp(mean log) * 1`` as in
    the kernel (log path: ``f_0 / sqrt(4 pi)``; product path: the sum of the blockers'
    ``log(G_0 / sqrt(4 pi))``).
    """
    if accumulate == "log":
        f = log_visibility(points, normals, centres, radii, order, rule, weights, skip, planes, baked)
        g = sh.exp(f, method, degree)
        dc_log = f[:, 0] / np.sqrt(4.0 * np.pi)
    else:
        g, dc_log = product_visibility(points, normals, centres, radii, order, rule, skip, return_dc_log=True,
                                       planes=planes, baked=baked)
    bad = ~(np.linalg.norm(g, axis=1) <= VISIBILITY_NORM_LIMIT)
    if np.any(bad):
        g[bad] = 0.0
        g[bad, 0] = np.sqrt(4.0 * np.pi) * np.exp(np.minimum(dc_log[bad], 0.0))
    if window is not None:
        g = g * np.asarray(window, np.float64)[sh.band_of(order)]
    return g


def shade(g, normals, light, albedo, transfer=None, sphere_lights=(), points=None):
    """Diffuse radiance ``albedo / pi * max(0, (L_c, g, X))``, (R, 3) float64.

    ``X = H(N)`` (clamped cosine about N, no 1/pi) or the given per-receiver ``transfer``;
    the triple integral is computed as ``dot(L_c, g * X)``. Sphere lights (objects with
    ``position``, ``radius``, ``radiance``) add ``radiance_c (L_s, g, X)`` with ``L_s`` the cap
    they subtend from ``points``.
    """
    g = np.asarray(g, np.float64)
    order = int(round(np.sqrt(g.shape[-1])))
    n = np.asarray(normals, np.float64)
    if transfer is None:
        x = sh.zh_to_sh(n, sh.clamped_cosine_zh(order, "zh"))
    else:
        x = np.asarray(transfer, np.float64)
    t = sh.product(g, x)
    rgb = t @ np.asarray(light, np.float64).T
    for light_s in sphere_lights:
        offset = np.asarray(light_s.position, np.float64) - np.asarray(points, np.float64)
        dist = np.linalg.norm(offset, axis=-1)
        inside = dist <= light_s.radius
        theta = np.where(inside, np.pi, np.arcsin(np.clip(light_s.radius / np.maximum(dist, 1e-300), 0.0, 1.0)))
        d = offset / np.maximum(dist, 1e-300)[:, None]
        cap = sh.zh_to_sh(np.where(inside[:, None], np.array([0.0, 0.0, 1.0]), d), sh.cap_zh(theta, order))
        rgb += np.einsum("ri,ri->r", cap, t)[:, None] * np.asarray(light_s.radiance, np.float64)[None, :]
    return np.asarray(albedo, np.float64) / np.pi * np.maximum(rgb, 0.0)
