"""Tabulated anisotropic BRDFs (:mod:`warpshade.scene._tabulated_aniso`) on the Warp device: the
look-up, the sampling mixture and its pdf, for the ray-traced references
(:mod:`warpshade.scene._materials_warp` dispatches model code :data:`ANISO_TABLE_MODEL` here).

Evaluation (:func:`aniso_table_eval`) works in the tangent frame ``(t, n x t, n)`` of a tangent
direction (world; projected on the tangent plane of ``n``, an orthonormal-basis tangent where it is
parallel to ``n``, as :func:`warpshade.scene._materials_warp.tangent_frame`): the local ``v`` and
``s`` give the half/difference angles exactly as the float64 mirror does
(:func:`warpshade.scene._tabulated._half_diff`), looked up "nearest" or "linear"
(:func:`warpshade.scene._tabulated_aniso.table_lookup`, here in float32).

Sampling (:func:`aniso_table_sample`): a mixture, with probability ``weight`` a half vector from an
anisotropic Beckmann slope distribution fitted to the table's specular peak (:func:`table_lobe_aniso`;
``phi_h = atan2(a_y sin 2 pi u2, a_x cos 2 pi u2)``, ``tan^2 theta_h = -ln(1 - u1) / (cos^2 phi_h /
a_x^2 + sin^2 phi_h / a_y^2)``, density ``D_B(h) cos theta_h`` per steradian of h) reflected about
it, else the cosine lobe about ``n``; :func:`aniso_table_pdf` is the exact mixture pdf
``weight D_B(h) cos theta_h / (4 |v.h|) + (1 - weight) (n.s) / pi``, positive over the whole upper
hemisphere, so every estimator stays unbiased whatever the fit.

:func:`warpshade.scene._materials_warp.upload_brdf_passes` makes the ``BRDFParams`` of an
:class:`~warpshade.scene._tabulated_aniso.AnisotropicTable`: ``model`` :data:`ANISO_TABLE_MODEL`,
``table`` the address of the float32 table (the channel the table's ``channel`` names), ``table_dims``
``(n_theta_h, n_phi_h, n_theta_d, n_phi_d)``, ``exponent`` 1 for "linear" (0 "nearest"),
``roughness``/``roughness_y`` the fitted lobe's ``a_x``/``a_y`` and ``f0`` its ``weight``.
"""

from __future__ import annotations

import numpy as np

from .._wp import wp

wp.set_module_options({"enable_backward": False})

__all__ = ["ANISO_LOBE_WEIGHT", "ANISO_TABLE_MODEL", "aniso_table_eval", "aniso_table_pdf", "aniso_table_sample",
           "clamped_axis", "table_lobe_aniso", "tangent_frame_from"]

#: Model code of a tabulated anisotropic BRDF in :class:`~warpshade.scene._materials_warp.BRDFParams`
#: (the next free code after ``tabulated``, 8).
ANISO_TABLE_MODEL = 9
#: Probability of the fitted lobe in the sampling mixture (the rest is the cosine lobe).
ANISO_LOBE_WEIGHT = 0.85
#: Range of the fitted lobe's slope parameters.
ANISO_LOBE_ALPHA = (0.01, 1.0)
#: theta_d below which the table's cells are taken as the specular peak's profile (radians).
ANISO_FIT_THETA_D = np.radians(10.0)

_PI = 3.141592653589793


def table_lobe_aniso(table: np.ndarray) -> tuple[float, float]:
    """``(a_x, a_y)`` of the sampling lobe of a one-channel table (n_theta_h, n_phi_h, n_theta_d,
    n_phi_d), float64, invalid cells negative.

    Near the specular configuration (``theta_d`` under :data:`ANISO_FIT_THETA_D`) a microfacet BRDF
    is ``D(h) F G / (4 cos^2 theta_h)``; the anisotropic Beckmann ``log D = c - tan^2 theta_h
    (cos^2 phi_h / a_x^2 + sin^2 phi_h / a_y^2)`` is fitted to ``log(f cos^2 theta_h)`` of those
    cells (mean over valid theta_d, phi_d; weighted least squares, cells above 1e-3 of the peak and
    under 44 degrees, weights the values). Only the estimator's variance depends on it.
    """
    from ._tabulated_aniso import aniso_cell_centres

    table = np.asarray(table, np.float64)
    th, ph, td, _ = aniso_cell_centres(table.shape)
    rows = np.nonzero(td < ANISO_FIT_THETA_D)[0]
    rows = rows if rows.size else np.array([0])
    cells = table[:, :, rows, :]
    valid = cells >= 0.0
    count = valid.sum(axis=(2, 3))
    prof = np.where(count > 0, np.where(valid, cells, 0.0).sum(axis=(2, 3)) / np.maximum(count, 1), 0.0)
    tt, pp = np.meshgrid(th, ph, indexing="ij")
    ndf = np.maximum(prof - prof.min(), 0.0) * np.cos(tt) ** 2
    keep = (tt < np.radians(44.0)) & (ndf > 1e-3 * max(ndf.max(), 1e-300)) & (count > 0)
    lo, hi = ANISO_LOBE_ALPHA
    if keep.sum() < 3:
        return 0.5, 0.5
    tan2 = np.tan(tt[keep]) ** 2
    a = np.stack([np.ones(keep.sum()), -tan2 * np.cos(pp[keep]) ** 2, -tan2 * np.sin(pp[keep]) ** 2], -1)
    w = np.sqrt(ndf[keep])
    coef = np.linalg.lstsq(a * w[:, None], np.log(ndf[keep]) * w, rcond=None)[0]
    ax = 1.0 / np.sqrt(coef[1]) if coef[1] > 0.0 else hi
    ay = 1.0 / np.sqrt(coef[2]) if coef[2] > 0.0 else hi
    return float(np.clip(ax, lo, hi)), float(np.clip(ay, lo, hi))


@wp.func
def tangent_frame_from(tangent: wp.vec3, n: wp.vec3) -> wp.mat33:
    """Rows (t, n x t, n): ``tangent`` projected on the tangent plane of ``n``, normalised (an
    orthonormal-basis tangent where it is parallel to ``n``)."""
    t = tangent - wp.dot(tangent, n) * n
    tl = wp.length(t)
    if tl > 1.0e-6:
        t = t / tl
    else:
        sign = wp.where(n[2] >= 0.0, 1.0, -1.0)
        a = -1.0 / (sign + n[2])
        t = wp.vec3(1.0 + sign * n[0] * n[0] * a, sign * n[0] * n[1] * a, -sign * n[0])
    bt = wp.cross(n, t)
    return wp.mat33(t[0], t[1], t[2], bt[0], bt[1], bt[2], n[0], n[1], n[2])


@wp.func
def _cell(table: wp.uint64, dims: wp.vec4i, i: int, j: int, k: int, l: int) -> float:
    values = wp.array(ptr=table, shape=(dims[0] * dims[1] * dims[2] * dims[3],), dtype=float)
    return values[((i * dims[1] + j) * dims[2] + k) * dims[3] + l]


@wp.func
def clamped_axis(u: float, n: int) -> wp.vec3:
    """Clamped linear interpolation along one cell-index axis: (i0, i1, t) (indices as floats)."""
    uc = wp.clamp(u, 0.0, float(n) - 1.0)
    i0 = wp.min(int(wp.floor(uc)), wp.max(n - 2, 0))
    i1 = wp.min(i0 + 1, n - 1)
    return wp.vec3(float(i0), float(i1), wp.clamp(uc - float(i0), 0.0, 1.0))


@wp.func
def _periodic(u: float, n: int) -> wp.vec3:
    """Periodic linear interpolation along one cell-index axis (period n cells)."""
    f = wp.floor(u)
    i0 = int(f) % n
    if i0 < 0:
        i0 += n
    return wp.vec3(float(i0), float((i0 + 1) % n), u - f)


@wp.func
def _fold(phi: float) -> float:
    """An angle in (-pi, pi] folded into [0, pi)."""
    out = phi
    if out < 0.0:
        out += _PI
    if out >= _PI:
        out -= _PI
    return out


@wp.func
def aniso_table_eval(b_table: wp.uint64, dims: wp.vec4i, linear: float, tangent: wp.vec3, n: wp.vec3, v: wp.vec3,
                     s: wp.vec3) -> float:
    """The table at world ``v``, ``s`` (above the horizon of ``n``) in the frame of ``tangent``."""
    frame = tangent_frame_from(tangent, n)
    vl = frame * v
    sl = frame * s
    h = vl + sl
    hl = wp.length(h)
    if hl > 1.0e-12:
        h = h / hl
    else:
        h = wp.vec3(0.0, 0.0, 1.0)
    theta_h = wp.atan2(wp.sqrt(h[0] * h[0] + h[1] * h[1]), h[2])
    phi_h = wp.atan2(h[1], h[0])
    cp = wp.cos(phi_h)
    sp = wp.sin(phi_h)
    tx = sl[0] * cp + sl[1] * sp
    ty = -sl[0] * sp + sl[1] * cp
    ct = wp.cos(theta_h)
    st = wp.sin(theta_h)
    dx = tx * ct - sl[2] * st
    dz = tx * st + sl[2] * ct
    theta_d = wp.atan2(wp.sqrt(dx * dx + ty * ty), dz)
    phi_d = wp.atan2(ty, dx)
    half_pi = 0.5 * _PI
    u0 = wp.sqrt(wp.max(theta_h, 0.0) / half_pi) * float(dims[0])
    u1 = _fold(phi_h) / _PI * float(dims[1])
    u2 = theta_d / half_pi * float(dims[2])
    u3 = _fold(phi_d) / _PI * float(dims[3])
    if linear == 0.0:
        i = wp.clamp(int(wp.floor(u0)), 0, dims[0] - 1)
        j = wp.clamp(int(wp.floor(u1)), 0, dims[1] - 1)
        k = wp.clamp(int(wp.floor(u2)), 0, dims[2] - 1)
        l = wp.clamp(int(wp.floor(u3)), 0, dims[3] - 1)
        return wp.max(_cell(b_table, dims, i, j, k, l), 0.0)
    a0 = clamped_axis(u0 - 0.5, dims[0])
    a1 = _periodic(u1 - 0.5, dims[1])
    a2 = clamped_axis(u2 - 0.5, dims[2])
    a3 = _periodic(u3 - 0.5, dims[3])
    num = float(0.0)
    den = float(0.0)
    for corner in range(16):
        c0 = corner & 1
        c1 = (corner >> 1) & 1
        c2 = (corner >> 2) & 1
        c3 = (corner >> 3) & 1
        w = wp.where(c0 == 1, a0[2], 1.0 - a0[2]) * wp.where(c1 == 1, a1[2], 1.0 - a1[2])
        w = w * wp.where(c2 == 1, a2[2], 1.0 - a2[2]) * wp.where(c3 == 1, a3[2], 1.0 - a3[2])
        val = _cell(b_table, dims, int(a0[c0]), int(a1[c1]), int(a2[c2]), int(a3[c3]))
        if val >= 0.0:  # invalid cells are left out of the blend
            num += w * val
            den += w
    if den > 0.0:
        return num / den
    return 0.0


@wp.func
def _lobe_d(hl: wp.vec3, ax: float, ay: float) -> float:
    """Anisotropic Beckmann ``D_B`` at a local half vector."""
    z = hl[2]
    if z <= 1.0e-6:
        return 0.0
    z2 = z * z
    q = (hl[0] * hl[0] / (ax * ax) + hl[1] * hl[1] / (ay * ay)) / z2
    return wp.exp(-q) / (_PI * ax * ay * z2 * z2)


@wp.func
def aniso_table_sample(ax: float, ay: float, weight: float, tangent: wp.vec3, n: wp.vec3, v: wp.vec3, u1: float,
                       u2: float) -> wp.vec3:
    """A direction from the mixture (module docstring); u1, u2 uniform in [0, 1)."""
    frame = tangent_frame_from(tangent, n)
    if u1 < weight:
        u = u1 / weight
        ang = 2.0 * _PI * u2
        phi = wp.atan2(ay * wp.sin(ang), ax * wp.cos(ang))
        cp = wp.cos(phi)
        sp = wp.sin(phi)
        tan2 = -wp.log(wp.max(1.0 - u, 1.0e-30)) / (cp * cp / (ax * ax) + sp * sp / (ay * ay))
        cos_t = 1.0 / wp.sqrt(1.0 + tan2)
        sin_t = wp.sqrt(wp.max(0.0, 1.0 - cos_t * cos_t))
        h = wp.normalize(wp.transpose(frame) * wp.vec3(sin_t * cp, sin_t * sp, cos_t))
        return wp.normalize(2.0 * wp.dot(v, h) * h - v)
    u = (u1 - weight) / (1.0 - weight)
    r = wp.sqrt(wp.clamp(u, 0.0, 1.0))
    phi = 2.0 * _PI * u2
    local = wp.vec3(r * wp.cos(phi), r * wp.sin(phi), wp.sqrt(wp.clamp(1.0 - u, 0.0, 1.0)))
    return wp.normalize(wp.transpose(frame) * local)


@wp.func
def aniso_table_pdf(ax: float, ay: float, weight: float, tangent: wp.vec3, n: wp.vec3, v: wp.vec3,
                    s: wp.vec3) -> float:
    """Solid-angle pdf of :func:`aniso_table_sample` at ``s``."""
    pdf = (1.0 - weight) * wp.max(wp.dot(n, s), 0.0) / _PI
    h = v + s
    hl = wp.length(h)
    if hl > 1.0e-12:
        h = h / hl
        vh = wp.abs(wp.dot(v, h))
        if vh > 1.0e-12:
            hloc = tangent_frame_from(tangent, n) * h
            pdf += weight * _lobe_d(hloc, ax, ay) * wp.max(hloc[2], 0.0) / (4.0 * vh)
    return pdf
