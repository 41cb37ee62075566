"""Mean value coordinates for closed triangle meshes, float64 (used to attach sphere centres to
deforming and skinned meshes, see :mod:`._attach`).

Ju, Schaefer and Warren 2005, "Mean value coordinates for closed triangular meshes": for a
point ``x`` and a closed mesh, weights ``lambda_v`` with ``sum_v lambda_v = 1`` and
``sum_v lambda_v p_v = x`` (linear precision), smooth in ``x`` and defined inside and outside
the surface. A mesh made of several closed components (a character built from overlapping
capsules) is handled per component: a sphere centre takes its coordinates from the component
its cluster's surface samples mostly lie on (or, without samples, from the component(s) whose
interior contains it), so a hand's sphere never depends on the legs.
"""

from __future__ import annotations

import numpy as np

#: Below this distance (relative to the mesh diagonal) a point is taken to coincide with a
#: vertex, and below this angle defect to lie on a triangle.
MVC_EPSILON = 1.0e-9


def mean_value_coordinates(points: np.ndarray, faces: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Mean value coordinates of one point w.r.t. a closed triangle mesh.

    Args:
        points: mesh vertices (V, 3), float64.
        faces: outward-oriented triangles (F, 3), int.
        x: the point (3,).

    Returns:
        weights (V,), float64, summing to 1; vertices not in ``faces`` get 0.
    """
    p = np.asarray(points, np.float64)
    f = np.asarray(faces, np.int64)
    x = np.asarray(x, np.float64)
    scale = float(np.linalg.norm(p.max(axis=0) - p.min(axis=0))) or 1.0
    eps = MVC_EPSILON * scale
    diff = p - x
    d = np.linalg.norm(diff, axis=1)
    out = np.zeros(p.shape[0])
    near = int(np.argmin(d))
    if d[near] < eps:
        out[near] = 1.0
        return out
    u = diff / d[:, None]
    u1, u2, u3 = u[f[:, 0]], u[f[:, 1]], u[f[:, 2]]
    d_t = d[f]  # (F, 3)
    # l_i: chord opposite to corner i on the unit sphere, theta_i the matching arc
    l_t = np.stack([np.linalg.norm(u2 - u3, axis=1), np.linalg.norm(u3 - u1, axis=1), np.linalg.norm(u1 - u2, axis=1)], axis=1)
    theta = 2.0 * np.arcsin(np.clip(l_t / 2.0, 0.0, 1.0))
    h = theta.sum(axis=1) / 2.0
    on_triangle = np.pi - h < MVC_EPSILON
    if np.any(on_triangle):
        t = int(np.nonzero(on_triangle)[0][0])
        w = np.sin(theta[t]) * np.roll(d_t[t], 1) * np.roll(d_t[t], -1)
        out[f[t]] += w / w.sum()
        return out
    sin_t = np.sin(theta)
    sin_next = np.roll(sin_t, -1, axis=1)  # sin(theta_{i+1})
    sin_prev = np.roll(sin_t, 1, axis=1)  # sin(theta_{i-1})
    with np.errstate(divide="ignore", invalid="ignore"):
        c = 2.0 * np.sin(h)[:, None] * np.sin(h[:, None] - theta) / (sin_next * sin_prev) - 1.0
    det = np.einsum("ij,ij->i", u1, np.cross(u2, u3))
    s = np.sign(det)[:, None] * np.sqrt(np.clip(1.0 - c**2, 0.0, None))
    # triangles in the plane of x (but not containing it) contribute nothing
    valid = np.all(np.abs(s) > MVC_EPSILON, axis=1) & np.all(np.isfinite(c), axis=1)
    c_next, c_prev = np.roll(c, -1, axis=1), np.roll(c, 1, axis=1)
    th_next, th_prev = np.roll(theta, -1, axis=1), np.roll(theta, 1, axis=1)
    s_prev = np.roll(s, 1, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = (theta - c_next * th_prev - c_prev * th_next) / (d_t * sin_next * s_prev)
    w = np.where(valid[:, None], w, 0.0)
    np.add.at(out, f.reshape(-1), w.reshape(-1))
    total = out.sum()
    if not np.isfinite(total) or abs(total) < 1e-300:
        raise ValueError("mean value coordinates are undefined for this point (degenerate mesh)")
    return out / total


def winding_number(points: np.ndarray, faces: np.ndarray, x: np.ndarray) -> float:
    """Generalised winding number of a point w.r.t. a triangle mesh (van Oosterom-Strackee)."""
    a = points[faces[:, 0]] - x
    b = points[faces[:, 1]] - x
    c = points[faces[:, 2]] - x
    la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
    num = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", b, c) * la + np.einsum("ij,ij->i", c, a) * lb
    return float(np.sum(np.arctan2(num, den)) / (2.0 * np.pi))


def vertex_components(faces: np.ndarray, vertex_count: int) -> np.ndarray:
    """Connected-component label of every vertex (vertices joined by triangle edges)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = np.asarray(faces, np.int64)
    rows = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    cols = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    graph = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(vertex_count, vertex_count))
    _, labels = connected_components(graph, directed=False)
    return labels


def face_components(faces: np.ndarray, vertex_count: int) -> np.ndarray:
    """Connected-component label of every face (faces sharing a vertex are connected)."""
    return vertex_components(faces, vertex_count)[np.asarray(faces, np.int64)[:, 0]]


def component_mvc(points: np.ndarray, faces: np.ndarray, x: np.ndarray, components: np.ndarray | None = None, component: int | None = None) -> np.ndarray:
    """Mean value coordinates restricted to one closed component, or to those containing ``x``.

    With ``component`` given, the coordinates are those w.r.t. that component alone (the
    caller picks the part the sphere's samples lie on). Otherwise: w.r.t. the component(s)
    whose interior contains ``x``, averaged when several overlap there (each reproduces ``x``,
    so the average does too), or the component with the nearest vertex when none does.
    """
    p = np.asarray(points, np.float64)
    f = np.asarray(faces, np.int64)
    comp = face_components(f, p.shape[0]) if components is None else components
    labels = np.unique(comp)
    if labels.size == 1:
        return mean_value_coordinates(p, f, x)
    if component is not None:
        return mean_value_coordinates(p, f[comp == component], x)
    inside = [lab for lab in labels if winding_number(p, f[comp == lab], x) > 0.5]
    if not inside:
        nearest = int(np.argmin(np.linalg.norm(p - x, axis=1)))
        inside = [comp[np.nonzero(np.any(f == nearest, axis=1))[0][0]]]
    w = np.zeros(p.shape[0])
    for lab in inside:
        w += mean_value_coordinates(p, f[comp == lab], x)
    return w / len(inside)
