"""Float64 oracles of the height-field kernels (:mod:`._kernels`).

* :func:`horizon_f64` -- horizon slopes by brute force: every half vertex spacing along
  each azimuth, bilinear heights of the full-resolution grid, to the grid's edge;
* :func:`wedge_f64` -- the SH of one azimuthal wedge open above an elevation, by direct
  quadrature of its indicator over the region (2-D Gauss-Legendre in phi and z, SH evaluated
  at the directions: independent of the separable, closed-form-in-phi table of
  :func:`._model.wedge_table`);
* :func:`visibility_f64` -- eq. 4-5 in float64 from given horizon slopes: the sum of exact
  wedges (no table interpolation) turned by exact z-rotations;
* :func:`pyramid_f64`, :func:`horizon_march_f64` -- the max pyramid and the
  kernel's march (same samples and levels) in float64: what the kernel computes;
* :func:`shade_f64` -- the shading of :class:`._stages.HeightFieldShadeStage` in
  float64 (frame about the normal with the view in its x-z plane, the F table, full SH rotation
  and product of :mod:`warpshade.basis.sh`).
"""

from __future__ import annotations

import math

import numpy as np

from ...basis import sh

__all__ = [
    "bilinear",
    "horizon_march_f64",
    "horizon_f64",
    "pyramid_f64",
    "texel_coordinates",
    "wedge_f64",
    "wedge_exact",
]


def texel_coordinates(size: int, res: int) -> tuple[np.ndarray, np.ndarray]:
    """Column and row (vertex units) of the R x R visibility texels, row-major, (R*R,) each."""
    scale = (size - 1) / (res - 1)
    a, b = np.divmod(np.arange(res * res), res)
    return b * scale, a * scale


def bilinear(h: np.ndarray, u, v) -> np.ndarray:
    """Bilinear heights of a (G, G) grid (rows y, columns x) at column u, row v (clamped)."""
    g = h.shape[0]
    fu = np.clip(np.asarray(u, np.float64), 0.0, g - 1)
    fv = np.clip(np.asarray(v, np.float64), 0.0, g - 1)
    c0 = np.minimum(fu.astype(np.int64), g - 2)
    r0 = np.minimum(fv.astype(np.int64), g - 2)
    tu, tv = fu - c0, fv - r0
    return (1 - tv) * ((1 - tu) * h[r0, c0] + tu * h[r0, c0 + 1]) + tv * ((1 - tu) * h[r0 + 1, c0] + tu * h[r0 + 1, c0 + 1])


def horizon_f64(h, dx: float, dy: float, u, v, azimuths: int, step: float = 0.5) -> np.ndarray:
    """Largest slope ``(h(p + d a) - h(p)) / d`` along each azimuth ``phi_i = 2 pi i / A`` from
    points (u, v) (vertex units), every ``step`` of the smaller spacing, to the grid's edge:
    (P, A) float64, ``-inf`` where no sample is inside."""
    h = np.asarray(h, np.float64)
    g = h.shape[0]
    u = np.asarray(u, np.float64)
    v = np.asarray(v, np.float64)
    h0 = bilinear(h, u, v)
    s = min(dx, dy)
    dmax = math.hypot(dx, dy) * (g - 1)
    d = np.arange(1, int(dmax / (step * s)) + 2) * step * s
    out = np.full((u.size, azimuths), -np.inf)
    for i in range(azimuths):
        phi = 2 * np.pi * i / azimuths
        pu = u[:, None] + d[None] * math.cos(phi) / dx
        pv = v[:, None] + d[None] * math.sin(phi) / dy
        inside = (pu >= 0) & (pu <= g - 1) & (pv >= 0) & (pv <= g - 1)
        slope = (bilinear(h, pu, pv) - h0[:, None]) / d[None]
        out[:, i] = np.max(np.where(inside, slope, -np.inf), axis=1)
    return out


def pyramid_f64(h) -> list[np.ndarray]:
    """The max pyramid of a (G, G) grid: level k is the maximum over 2^k x 2^k vertices."""
    levels = [np.asarray(h, np.float64)]
    while levels[-1].shape[0] > 1:
        a = levels[-1]
        n = a.shape[0]
        m = (n + 1) // 2
        idx = np.minimum(np.arange(2 * m), n - 1)
        b = a[np.ix_(idx, idx)].reshape(m, 2, m, 2)
        levels.append(b.max(axis=(1, 3)))
    return levels


def horizon_march_f64(h, dx, dy, u, v, azimuths: int, distances, levels) -> np.ndarray:
    """The kernel's horizon march in float64: sample j at distance ``distances[j]`` reads the
    maximum of pyramid level ``levels[j]`` in the cell holding the sample; (P, A) slopes."""
    pyr = pyramid_f64(h)
    u = np.asarray(u, np.float64)
    v = np.asarray(v, np.float64)
    h0 = bilinear(pyr[0], u, v)
    out = np.full((u.size, azimuths), -np.inf)
    for i in range(azimuths):
        phi = 2 * np.pi * i / azimuths
        alive = np.ones(u.size, bool)
        for d, k in zip(distances, levels):
            lev = pyr[int(k)]
            n = lev.shape[0]
            ci = np.floor((u + 0.5 + d * math.cos(phi) / dx) / 2.0**k).astype(np.int64)
            ri = np.floor((v + 0.5 + d * math.sin(phi) / dy) / 2.0**k).astype(np.int64)
            alive &= (ci >= 0) & (ri >= 0) & (ci < n) & (ri < n)
            val = (lev[np.clip(ri, 0, n - 1), np.clip(ci, 0, n - 1)] - h0) / d
            out[:, i] = np.where(alive, np.maximum(out[:, i], val), out[:, i])
    return out


def wedge_f64(order: int, center: float, width: float, z0: float, nodes: int = 64) -> np.ndarray:
    """SH of the indicator ``{|phi - center| <= width / 2, z > z0}`` by direct quadrature over
    the region: Gauss-Legendre in phi over the wedge times Gauss-Legendre in z over ``[z0, 1]``,
    the SH evaluated at the 3-D directions (no separation, no symmetry assumed), (n*n,) float64."""
    x, w = np.polynomial.legendre.leggauss(int(nodes))
    phi = center + 0.5 * width * x
    wphi = 0.5 * width * w
    z = z0 + (1.0 - z0) * 0.5 * (x + 1.0)
    wz = 0.5 * (1.0 - z0) * w
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    rho = np.sqrt(np.maximum(1.0 - zz * zz, 0.0))
    d = np.stack([rho * np.cos(pp), rho * np.sin(pp), zz], -1).reshape(-1, 3)
    return sh.basis(d, order).T @ np.outer(wz, wphi).ravel()


def wedge_exact(order: int, azimuths: int, z0, nodes: int = 96) -> np.ndarray:
    """The canonical wedge ``|phi| <= pi / A``, ``z > z0`` in SH at any z0 (..., n*n): the
    separable integral of :func:`._model.wedge_table` with no table interpolation."""
    z0 = np.atleast_1d(np.asarray(z0, np.float64))
    n = int(order)
    half = math.pi / azimuths
    x, w = np.polynomial.legendre.leggauss(nodes)
    z = z0[:, None] + (1.0 - z0[:, None]) * 0.5 * (x[None] + 1.0)
    wz = 0.5 * (1.0 - z0[:, None]) * w[None]
    dirs = np.stack([np.sqrt(np.maximum(1.0 - z * z, 0.0)), np.zeros_like(z), z], -1)
    y = sh.basis(dirs.reshape(-1, 3), n).reshape(z.shape + (n * n,))
    phi_int = np.zeros(n * n)
    for l in range(n):
        phi_int[l * l + l] = 2.0 * half
        for m in range(1, l + 1):
            phi_int[l * l + l + m] = 2.0 * math.sin(m * half) / m
    return np.einsum("eq,eqi->ei", wz, y) * phi_int[None]


def _rotate_z(f: np.ndarray, angle: float) -> np.ndarray:
    r = np.array([[math.cos(angle), -math.sin(angle), 0.0], [math.sin(angle), math.cos(angle), 0.0], [0.0, 0.0, 1.0]])
    return sh.rotate(f, r)


def visibility_f64(slopes, order: int, tangent_slopes=None) -> np.ndarray:
    """Eq. 4-5 in float64: ``sum_i Rz(phi_i) W(z_i)`` with ``z_i`` the sine of the horizon
    elevation (``-1`` for ``-inf``); with ``tangent_slopes`` (P, A) the region under the tangent
    plane is open (``below = "open"``). (P, n*n)."""
    s = np.asarray(slopes, np.float64)
    p, a = s.shape
    zh = np.where(np.isfinite(s), s / np.sqrt(1.0 + np.where(np.isfinite(s), s, 0.0) ** 2), -1.0)
    out = np.zeros((p, order * order))
    full = wedge_exact(order, a, -1.0)[0]
    for i in range(a):
        w = wedge_exact(order, a, zh[:, i])
        if tangent_slopes is not None:
            t = np.asarray(tangent_slopes, np.float64)[:, i]
            zt = np.minimum(t / np.sqrt(1.0 + t * t), zh[:, i])
            w = w + full[None] - wedge_exact(order, a, zt)
        out += _rotate_z(w, 2 * np.pi * i / a)
    return out


def shade_f64(points, normals, eye, g_vertex, table, specular=(1.0, 1.0, 1.0)) -> np.ndarray:
    """The height-field shading in float64: ``specular_c max(0, F_w(wo) . g_c)`` per vertex.

    Args:
        points, normals: (V, 3) world; eye: (3,).
        g_vertex: (V, 3, n*n) the lighting products ``l_c * v`` at the vertices (world).
        table: (E, n*n) F over ``cos t`` on ``linspace(0, 1, E)`` (views ``(sin t, 0, cos t)``).

    Returns:
        (V, 3); 0 where the view is at or below the tangent plane.
    """
    p = np.asarray(points, np.float64)
    n = np.asarray(normals, np.float64)
    d = np.asarray(eye, np.float64)[None] - p
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    mu = np.einsum("vi,vi->v", n, d)
    x = d - mu[:, None] * n
    xl = np.linalg.norm(x, axis=1, keepdims=True)
    x = np.where(xl > 1e-6, x / np.maximum(xl, 1e-300), np.cross(n, [0.0, 1.0, 0.0]))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(n, x)
    frames = np.stack([x, y, n], 1)  # rows (x, y, n): local = F world
    e = table.shape[0]
    tt = np.clip(mu, 0.0, 1.0) * (e - 1)
    i0 = np.minimum(tt.astype(np.int64), e - 2)
    fr = (tt - i0)[:, None]
    f = (1 - fr) * table[i0] + fr * table[i0 + 1]
    fw = sh.rotate(f, np.transpose(frames, (0, 2, 1)))
    r = np.einsum("vi,vci->vc", fw, np.asarray(g_vertex, np.float64))
    r[mu <= 0.0] = 0.0
    return np.maximum(r, 0.0) * np.asarray(specular, np.float64)
