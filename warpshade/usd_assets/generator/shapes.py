"""Mesh builders of the scene generator (NumPy only, nothing written).

Each builder returns ``(points, counts, indices)``: points (N, 3) float64 in metres, per-face
vertex counts and the flat face-vertex indices of a USD Mesh, faces counter-clockwise around
their outward normal (some also return per-point extras, as their docstrings say). Also the
:func:`smoothstep` blend that skinning weights and motions use.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator


def smoothstep(x):
    """0 below 0, 1 above 1, 3x^2 - 2x^3 between."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def grid(resolution: int, size: float, z: float = 0.0):
    """A square quad grid in the XY plane, (points, counts, indices), normal +Z."""
    s = np.linspace(-size / 2, size / 2, resolution)
    x, y = np.meshgrid(s, s, indexing="ij")
    pts = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], 1)
    i, j = np.meshgrid(np.arange(resolution - 1), np.arange(resolution - 1), indexing="ij")
    v00 = (i * resolution + j).ravel()
    quads = np.stack([v00, v00 + resolution, v00 + resolution + 1, v00 + 1], 1)  # +x then +y: CCW from +Z
    return pts, np.full(len(quads), 4), quads.ravel()


def revolution(profile, around: int, cap_polygons: bool = False):
    """Surface of revolution about +Z.

    Args:
        profile: (z, r) pairs from bottom to top; r == 0 at an end makes a pole (triangle fan).
        around: segments around the axis.
        cap_polygons: close open ends with one n-gon each instead of poles.

    Returns:
        points (N, 3), counts, indices, and each point's ring index.
    """
    ang = 2 * np.pi * np.arange(around) / around
    pts, ring_of, ring_start = [], [], []
    for k, (z, r) in enumerate(profile):
        ring_start.append(len(pts))
        if r == 0.0:
            pts.append([0.0, 0.0, z])
            ring_of.append(k)
        else:
            for a in ang:
                pts.append([r * np.cos(a), r * np.sin(a), z])
                ring_of.append(k)
    counts, idx = [], []
    for k in range(len(profile) - 1):
        a0, a1 = ring_start[k], ring_start[k + 1]
        r0, r1 = profile[k][1], profile[k + 1][1]
        for j in range(around):
            jn = (j + 1) % around
            if r0 == 0.0:  # bottom pole
                counts.append(3)
                idx += [a0, a1 + jn, a1 + j]
            elif r1 == 0.0:  # top pole
                counts.append(3)
                idx += [a0 + j, a0 + jn, a1]
            else:
                counts.append(4)
                idx += [a0 + j, a0 + jn, a1 + jn, a1 + j]
    if cap_polygons:
        counts.append(around)
        idx += [ring_start[0] + j for j in reversed(range(around))]  # bottom, facing -Z
        counts.append(around)
        idx += [ring_start[-1] + j for j in range(around)]  # top, facing +Z
    return np.asarray(pts), np.asarray(counts), np.asarray(idx), np.asarray(ring_of)


def uv_sphere(radius: float, around: int = 20, rings: int = 10):
    theta = np.linspace(np.pi, 0.0, rings + 1)
    profile = [(radius * np.cos(t), 0.0 if k in (0, rings) else radius * np.sin(t)) for k, t in enumerate(theta)]
    pts, counts, idx, _ = revolution(profile, around)
    return pts, counts, idx


def capsule_profile(length: float, radius: float, cap_rings: int = 4, body_rings: int = 5):
    """(z, r) profile of a capsule from z = -radius to z = length + radius."""
    prof = []
    for k in range(cap_rings + 1):  # bottom hemisphere, pole first
        t = np.pi / 2 * k / cap_rings
        prof.append((-radius * np.cos(t), radius * np.sin(t) if k else 0.0))
    for k in range(1, body_rings):
        prof.append((length * k / body_rings, radius))
    for k in range(cap_rings, -1, -1):  # top hemisphere, pole last
        t = np.pi / 2 * k / cap_rings
        prof.append((length + radius * np.cos(t), radius * np.sin(t) if k else 0.0))
    return prof


def box(size: float, cells: int = 4):
    """An axis-aligned cube centred at the origin; each face a cells x cells quad grid."""
    pts, counts, idx = [], [], []
    s = np.linspace(-size / 2, size / 2, cells + 1)
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u_axis, v_axis = (axis + 1) % 3, (axis + 2) % 3
            if sign < 0:
                u_axis, v_axis = v_axis, u_axis  # keep (u, v, outward) right-handed
            base = len(pts)
            for a in s:
                for b in s:
                    p = [0.0, 0.0, 0.0]
                    p[axis] = sign * size / 2
                    p[u_axis], p[v_axis] = a, b
                    pts.append(p)
            n = cells + 1
            for i in range(cells):
                for j in range(cells):
                    v00 = base + i * n + j
                    counts.append(4)
                    idx += [v00, v00 + n, v00 + n + 1, v00 + 1]
    return np.asarray(pts), np.asarray(counts), np.asarray(idx)


def _orthonormal_side(direction, hint=(1.0, 0.0, 0.0)):
    """``direction`` normalised, and the unit vector perpendicular to it closest to ``hint``."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    side = np.asarray(hint, float) - np.dot(hint, d) * d
    return d, side / np.linalg.norm(side)


def tube(origin, direction, knots, around, rings, caps, cap_rings=5, hint=(1.0, 0.0, 0.0)):
    """A closed tube along a straight axis with an elliptical, varying cross-section.

    Args:
        origin: where the axis parameter s = 0 lies (skeleton space).
        direction: the axis (normalised here).
        knots: (s, rx, ry) rows, s increasing: radii along the side axis (``hint`` made
            perpendicular to the axis) and along ``direction x side``, interpolated smoothly
            (monotone cubic) over the ``rings`` evenly spaced rings from the first to the last s.
        around: vertices per ring.
        caps: lengths of the rounded (elliptical quarter-circle) ends before the first and after
            the last knot, each with ``cap_rings`` rings and a pole.

    Returns:
        points (N, 3), counts, indices, and each point's axis parameter s (N,).
    """
    knots = np.asarray(knots, float)
    s_body = np.linspace(knots[0, 0], knots[-1, 0], rings)
    radii = PchipInterpolator(knots[:, 0], knots[:, 1:], axis=0)(s_body)
    ring_s, ring_r = [], []
    t = np.linspace(0.0, np.pi / 2, cap_rings + 1)[:-1]  # pole first
    ring_s += list(s_body[0] - caps[0] * np.cos(t))
    ring_r += [radii[0] * np.sin(a) for a in t]
    ring_s += list(s_body)
    ring_r += list(radii)
    ring_s += list(s_body[-1] + caps[1] * np.cos(t[::-1]))
    ring_r += [radii[-1] * np.sin(a) for a in t[::-1]]
    profile = [(s, 0.0 if k in (0, len(ring_s) - 1) else 1.0) for k, s in enumerate(ring_s)]
    pts, counts, idx, ring_of = revolution(profile, around)
    ring_r = np.asarray(ring_r)
    local = pts * np.concatenate([ring_r[ring_of], np.ones((len(pts), 1))], 1)
    d, side = _orthonormal_side(direction, hint)
    other = np.cross(d, side)
    world = np.asarray(origin, float) + local[:, :1] * side + local[:, 1:2] * other + local[:, 2:3] * d
    return world, counts, idx, local[:, 2]


def torus_knot(p, q, scale, tube, segments, around, u_repeat):
    """A tube of radius ``tube`` around the (p, q) torus knot
    ``scale * ((2 + cos q t) cos p t, (2 + cos q t) sin p t, -sin q t)``, lifted to rest on z = 0.

    The cross-section frame is the knot's offset from the torus core circle made perpendicular
    to the tangent (smooth and periodic), so normals are exact: the radial direction of each
    ring. The seam ring and seam column are duplicated so UVs can be per vertex.

    Returns:
        points (V, 3), counts, indices, normals (V, 3), uvs (V, 2) with
        ``u = u_repeat * t / 2 pi`` along the knot and ``v = angle / 2 pi`` around it.
    """
    t = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    a = np.linspace(0.0, 2.0 * np.pi, around + 1)
    radius = 2.0 + np.cos(q * t)
    core = scale * np.stack([radius * np.cos(p * t), radius * np.sin(p * t), -np.sin(q * t)], 1)
    d_radius = -q * np.sin(q * t)
    tangent = np.stack([d_radius * np.cos(p * t) - p * radius * np.sin(p * t),
                        d_radius * np.sin(p * t) + p * radius * np.cos(p * t), -q * np.cos(q * t)], 1)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    offset = core - scale * 2.0 * np.stack([np.cos(p * t), np.sin(p * t), np.zeros_like(t)], 1)
    normal = offset - np.sum(offset * tangent, axis=1, keepdims=True) * tangent
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    binormal = np.cross(tangent, normal)
    ring = np.cos(a)[None, :, None] * normal[:, None, :] + np.sin(a)[None, :, None] * binormal[:, None, :]
    points = core[:, None, :] + tube * ring
    points[..., 2] += scale + tube  # lowest point on the ground
    n_around = around + 1
    i, j = np.meshgrid(np.arange(segments), np.arange(around), indexing="ij")
    v00 = (i * n_around + j).ravel()
    # (t, angle) is left-handed about the outward normal: go round the angle first (CCW outside)
    quads = np.stack([v00, v00 + 1, v00 + n_around + 1, v00 + n_around], 1)
    u, v = np.meshgrid(u_repeat * t / (2.0 * np.pi), a / (2.0 * np.pi), indexing="ij")
    return (points.reshape(-1, 3), np.full(len(quads), 4), quads.ravel(), ring.reshape(-1, 3),
            np.stack([u.ravel(), v.ravel()], 1))
