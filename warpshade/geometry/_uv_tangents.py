"""Per-vertex tangent directions from texture coordinates: the direction of increasing ``u``.

For a triangle with corners ``p0, p1, p2`` and UVs ``(u_k, v_k)`` the surface derivative
``dP/du`` solves ``[e1 e2] = [dP/du dP/dv] [[du1 du2], [dv1 dv2]]`` with ``e_k = p_k - p0``,
``du_k = u_k - u0``, ``dv_k = v_k - v0``::

    dP/du = (dv2 e1 - dv1 e2) / (du1 dv2 - du2 dv1)

(the tangent of normal-mapping pipelines). A vertex's tangent is the sum of ``dP/du`` of the
triangles around it, projected on the tangent plane of its unit normal and normalised; where
that vanishes (no triangle with a usable UV parameterisation, or ``dP/du`` along the normal) it
is the orthonormal-basis tangent of the normal (Duff et al.). The per-triangle coefficients
``(a, b)`` with ``dP/du = a e1 + b e2`` depend on the UVs only, so the tangents follow a
deforming surface: :class:`UVTangents` computes them per frame from the frame's points and
normals with a Warp kernel (one thread per vertex over its triangles, no atomics);
:func:`uv_tangents_f64` is its float64 mirror.
"""

from __future__ import annotations

import numpy as np

from .._wp import wp

__all__ = ["UVTangents", "scene_uv_rows", "uv_tangent_coefficients", "uv_tangents_f64"]

wp.set_module_options({"enable_backward": False})

#: A triangle whose UV determinant is below this (relative to its UV edge lengths squared) has no
#: usable parameterisation and contributes nothing.
UV_DEGENERATE = 1e-10


def uv_tangent_coefficients(faces, uvs) -> np.ndarray:
    """Per-triangle ``(a, b)`` with ``dP/du = a (p1 - p0) + b (p2 - p0)``, (F, 2) float64 (0 for
    triangles with degenerate UVs).

    Args:
        faces: triangles, (F, 3) int vertex indices. uvs: per-vertex texture coordinates, (V, 2).
    """
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    uv = np.asarray(uvs, np.float64).reshape(-1, 2)
    if not np.all(np.isfinite(uv)):
        raise ValueError("uv_tangent_coefficients: UVs must be finite")
    d1 = uv[f[:, 1]] - uv[f[:, 0]]
    d2 = uv[f[:, 2]] - uv[f[:, 0]]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    scale = np.maximum(np.sum(d1 * d1, 1) * np.sum(d2 * d2, 1), 1e-300)
    ok = np.abs(det) > UV_DEGENERATE * np.sqrt(scale)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    return np.stack([d2[:, 1] * inv, -d1[:, 1] * inv], -1)


def _onb_tangent_f64(n: np.ndarray) -> np.ndarray:
    sign = np.where(n[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[:, 2])
    return np.stack([1.0 + sign * n[:, 0] ** 2 * a, sign * n[:, 0] * n[:, 1] * a, -sign * n[:, 0]], -1)


def uv_tangents_f64(points, normals, faces, uvs) -> np.ndarray:
    """Float64 mirror of :meth:`UVTangents.compute`: unit tangents (V, 3), orthogonal to the normals."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    ab = uv_tangent_coefficients(f, uvs)
    du = ab[:, :1] * (p[f[:, 1]] - p[f[:, 0]]) + ab[:, 1:] * (p[f[:, 2]] - p[f[:, 0]])
    t = np.zeros_like(p)
    for k in range(3):
        np.add.at(t, f[:, k], du)
    t = t - np.sum(t * n, 1, keepdims=True) * n
    length = np.linalg.norm(t, axis=1, keepdims=True)
    ok = length[:, 0] > 1e-12 * np.maximum(np.linalg.norm(du, axis=1).max(initial=0.0), 1e-300)
    return np.where(ok[:, None], t / np.maximum(length, 1e-300), _onb_tangent_f64(n))


@wp.kernel
def _uv_tangents_kernel(points: wp.array(dtype=wp.vec3), normals: wp.array(dtype=wp.vec3), faces: wp.array2d(dtype=wp.int32),
                        coeffs: wp.array(dtype=wp.vec2), offsets: wp.array(dtype=wp.int32), incident: wp.array(dtype=wp.int32),
                        tangents: wp.array(dtype=wp.vec3)):
    """One vertex: the sum of dP/du over its triangles, projected and normalised (module docstring)."""
    v = wp.tid()
    n = normals[v]
    t = wp.vec3(0.0)
    scale = float(0.0)
    for k in range(offsets[v], offsets[v + 1]):
        f = incident[k]
        p0 = points[faces[f, 0]]
        c = coeffs[f]
        du = c[0] * (points[faces[f, 1]] - p0) + c[1] * (points[faces[f, 2]] - p0)
        scale = wp.max(scale, wp.length(du))
        t += du
    t = t - wp.dot(t, n) * n
    length = wp.length(t)
    if length > 1.0e-6 * scale and length > 0.0:
        tangents[v] = t / length
    else:
        sign = wp.where(n[2] >= 0.0, 1.0, -1.0)
        a = -1.0 / (sign + n[2])
        tangents[v] = wp.vec3(1.0 + sign * n[0] * n[0] * a, sign * n[0] * n[1] * a, -sign * n[0])


class UVTangents:
    """Per-frame UV tangents of a triangle mesh on the device (module docstring).

    Args:
        faces: triangles, (F, 3) int. uvs: per-vertex UVs, (V, 2); rows of vertices without UVs
            may hold anything when no triangle with a usable parameterisation touches them.
        has_uv: optional (F,) bool, triangles whose UVs count (False: contributes nothing).
        device: Warp device.
    """

    def __init__(self, faces, uvs, has_uv=None, device=None):
        f = np.asarray(faces, np.int64).reshape(-1, 3)
        uv = np.asarray(uvs, np.float64).reshape(-1, 2)
        self.vertex_count = int(uv.shape[0])
        coeffs = uv_tangent_coefficients(f, uv)
        if has_uv is not None:
            coeffs[~np.asarray(has_uv, bool).reshape(-1)] = 0.0
        order = np.argsort(f.reshape(-1), kind="stable")
        incident = (order // 3).astype(np.int32)
        counts = np.bincount(f.reshape(-1), minlength=self.vertex_count)
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
        self.device = wp.get_device(device)
        self._faces = wp.array(f.astype(np.int32), dtype=wp.int32, device=self.device)
        self._coeffs = wp.array(coeffs.astype(np.float32), dtype=wp.vec2, device=self.device)
        self._offsets = wp.array(offsets, dtype=wp.int32, device=self.device)
        self._incident = wp.array(incident, dtype=wp.int32, device=self.device)

    def compute(self, points, normals, out) -> None:
        """Unit tangents of the frame into ``out`` (wp.array(vec3), (V,)) from its points and unit normals."""
        wp.launch(_uv_tangents_kernel, dim=self.vertex_count, device=self.device,
                  inputs=[points, normals, self._faces, self._coeffs, self._offsets, self._incident, out])

    @classmethod
    def from_scene(cls, scene, device=None) -> "UVTangents":
        """The tangents of every mesh of a :class:`~warpshade.scene.Scene` (its ``faces`` and the
        meshes' per-vertex ``uvs``); meshes without UVs get orthonormal-basis tangents."""
        uv, has = scene_uv_rows(scene)
        faces = np.asarray(scene.faces, np.int64).reshape(-1, 3)
        return cls(faces, uv, has[faces[:, 0]], device)


def scene_uv_rows(scene):
    """Per-vertex UVs of every mesh of a scene, (V, 2) float64 (0 for meshes without), and a
    per-vertex flag (V,) bool: the vertex belongs to a mesh with UVs."""
    uv = np.zeros((scene.vertex_count, 2))
    has = np.zeros(scene.vertex_count, bool)
    for m in scene.meshes:
        if m.uvs is not None:
            sl = slice(m.vertex_offset, m.vertex_offset + m.vertex_count)
            uv[sl] = np.asarray(m.uvs, np.float64).reshape(m.vertex_count, 2)
            has[sl] = True
    return uv, has
