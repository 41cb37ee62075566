"""Per-vertex local tangent frames that rotate with a deforming surface.

This frame is what "local" means for transfer vectors (``space="local"`` in
:mod:`warpshade.transfer`) and for local deformable PRT: a direction ``w`` in world space has
local coordinates ``w_local = F @ w`` with ``F`` the vertex's frame, and ``w = F.T @ w_local``.

Definition. ``F`` is a 3x3 rotation whose rows are (tangent, bitangent, normal):

* ``normal`` ``n``: the vertex normal of the current frame (the FrameState normals), unit length;
* ``tangent`` ``t``: derived from the mesh itself. In the *rest pose* (fixed once, e.g. the
  authored points) every vertex ``i`` gets weights over its one-ring neighbours ``j``::

      e_j   = p_j - p_i,   q_j = e_j - (e_j . n_i) n_i     (edge projected on the tangent plane)
      k     = argmax_j |q_j|                               (the reference edge)
      w_j   = max(0, q_j . q_k / (|q_j| |q_k|))**2 / |q_j|  (0 where |q_j| is ~0)

  so the reference edge has unit weight and every other edge with a positive component along it
  contributes its unit direction weighted by cos**2. In *any* pose the raw tangent is the same
  combination of the *current* projected edges::

      t_raw = sum_j w_j (e_j - (e_j . n) n)

  which is dimensionless (1 up to the number of aligned edges in the rest pose; it scales with
  the local stretch). Because the weights are fixed in the rest pose, the tangent is carried by
  the surface: under a rigid motion ``F`` rotates exactly with it, and under a smooth deformation
  it changes smoothly (temporally coherent).
* Fallback (degenerate cases): if the projected edges collapse (``|t_raw| < DEGENERATE_STRETCH``:
  zero-length edges, a neighbourhood folded onto the normal, an isolated vertex) the tangent is
  blended smoothly with the rest tangent parallel-transported to the current normal (the minimal
  rotation taking the rest normal to ``n``)::

      a = (1 - |t_raw| / DEGENERATE_STRETCH)**2  (0 above the threshold, C1 at it)
      t = normalise(t_raw + a * DEGENERATE_STRETCH * transport(t_rest, n_rest -> n))

  and the transport itself falls back to Duff et al.'s branchless orthonormal basis of ``n``
  when ``n`` is (almost) opposite to the rest normal. Finally ``t`` is re-projected onto the
  plane of ``n`` and ``b = n x t``. No step can produce NaN: every normalisation is guarded.

The Warp kernel (float32) is :meth:`TangentFrames.compute`; :func:`tangent_frames_f64` is
the float64 NumPy reference with the same definition.
"""

import numpy as np

from .._wp import resolve_device, wp
from ._normals import vertex_normals_f64

__all__ = [
    "DEGENERATE_STRETCH",
    "TangentFrames",
    "FrameRule",
    "frame_rule",
    "tangent_frames_f64",
]

wp.set_module_options({"enable_backward": False})

#: Below this |t_raw| (the weighted projected edges, relative to their rest length) the tangent is
#: blended with the transported rest tangent. 0.02 means a fifty-fold local shrink of the edges.
DEGENERATE_STRETCH = 0.02

_DEGENERATE_STRETCH_WP = wp.constant(DEGENERATE_STRETCH)

# Projected rest edges shorter than this fraction of the vertex's longest edge get no weight.
_REST_EDGE_EPS = 1.0e-6


def _onb_tangent(n: np.ndarray) -> np.ndarray:
    """Tangent of Duff et al.'s branchless orthonormal basis of unit normals n, shape (..., 3)."""
    sign = np.where(n[..., 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[..., 2])
    b = n[..., 0] * n[..., 1] * a
    return np.stack([1.0 + sign * n[..., 0] ** 2 * a, sign * b, -sign * n[..., 0]], axis=-1)


def _transport(t: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Apply the minimal rotation taking unit a to unit b to vectors t (all shape (V, 3))."""
    v = np.cross(a, b)
    c = np.sum(a * b, axis=-1, keepdims=True)
    ok = c[:, 0] > -1.0 + 1e-6
    denom = np.where(ok[:, None], 1.0 + c, 1.0)
    out = t * c + np.cross(v, t) + v * np.sum(v * t, axis=-1, keepdims=True) / denom
    return np.where(ok[:, None], out, _onb_tangent(b))


class FrameRule:
    """The rest-pose part of the frame definition: one-ring CSR, weights, rest normal/tangent.

    Attributes:
        offsets: CSR row starts, shape (vertex_count + 1,), int64.
        neighbours: neighbour vertex indices, shape (edge_slots,), int64.
        weights: rest-pose weights ``w_j`` matching ``neighbours``, shape (edge_slots,), float64.
        rest_normals: unit rest normals, shape (vertex_count, 3), float64.
        rest_tangents: unit rest tangents (the frame rule applied to the rest pose), (vertex_count, 3).
    """

    def __init__(self, offsets, neighbours, weights, rest_normals, rest_tangents):
        self.offsets = offsets
        self.neighbours = neighbours
        self.weights = weights
        self.rest_normals = rest_normals
        self.rest_tangents = rest_tangents

    @property
    def vertex_count(self) -> int:
        return int(self.offsets.shape[0] - 1)


def _one_ring(faces: np.ndarray, vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    edges = np.concatenate([edges, edges[:, ::-1]])
    edges = edges[edges[:, 0] != edges[:, 1]]
    edges = np.unique(edges, axis=0)  # sorted by (vertex, neighbour)
    counts = np.bincount(edges[:, 0], minlength=vertex_count)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return offsets, edges[:, 1].astype(np.int64)


def frame_rule(rest_points, faces, rest_normals=None) -> FrameRule:
    """Fix the frame rule in the rest pose (float64; see module docstring).

    Args:
        rest_points: rest-pose positions, shape (vertex_count, 3).
        faces: triangles, shape (triangle_count, 3), indices into ``rest_points``.
        rest_normals: unit rest normals (vertex_count, 3); default area-weighted normals.
    """
    p = np.asarray(rest_points, np.float64).reshape(-1, 3)
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    vertex_count = p.shape[0]
    if faces.size and (faces.min() < 0 or faces.max() >= vertex_count):
        raise ValueError(f"frame_rule: faces index vertices outside 0..{vertex_count - 1}")
    n = vertex_normals_f64(p, faces) if rest_normals is None else np.asarray(rest_normals, np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    offsets, nbrs = _one_ring(faces, vertex_count)
    counts = np.diff(offsets)
    owner = np.repeat(np.arange(vertex_count), counts)
    e = p[nbrs] - p[owner]
    q = e - np.sum(e * n[owner], axis=1, keepdims=True) * n[owner]
    qlen = np.linalg.norm(q, axis=1)
    # longest projected edge per vertex (the reference edge k); first one on ties
    longest = np.zeros(vertex_count)
    has_ring = counts > 0
    longest[has_ring] = np.maximum.reduceat(qlen, offsets[:-1][has_ring])
    candidates = np.flatnonzero(qlen == longest[owner])
    first_owner, first_index = np.unique(owner[candidates], return_index=True)
    reference = np.zeros(vertex_count, dtype=np.int64)
    reference[first_owner] = candidates[first_index]
    ok = (qlen > _REST_EDGE_EPS * longest[owner]) & (longest[owner] > 0.0)
    unit = np.zeros_like(q)
    unit[ok] = q[ok] / qlen[ok, None]
    cos = np.sum(unit * unit[reference[owner]], axis=1)
    weights = np.where(ok, np.maximum(cos, 0.0) ** 2 / np.where(ok, qlen, 1.0), 0.0)
    t = np.zeros_like(p)
    np.add.at(t, owner, weights[:, None] * q)
    tlen = np.linalg.norm(t, axis=1, keepdims=True)
    # vertices without a usable edge keep the orthonormal-basis tangent of their normal
    tangents = np.where(tlen > 0.0, t / np.maximum(tlen, 1e-300), _onb_tangent(n))
    return FrameRule(offsets, nbrs, weights, n, tangents)


def tangent_frames_f64(points, normals, rule: FrameRule) -> np.ndarray:
    """Float64 mirror of the per-vertex frames, shape (vertex_count, 3, 3), rows (t, b, n)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    nlen = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.where(nlen > 1e-20, n / np.maximum(nlen, 1e-300), rule.rest_normals)
    owner = np.repeat(np.arange(p.shape[0]), np.diff(rule.offsets))
    e = p[rule.neighbours] - p[owner]
    q = e - np.sum(e * n[owner], axis=1, keepdims=True) * n[owner]
    t_raw = np.zeros_like(p)
    np.add.at(t_raw, owner, rule.weights[:, None] * q)
    length = np.linalg.norm(t_raw, axis=1, keepdims=True)
    alpha = np.clip(1.0 - length / DEGENERATE_STRETCH, 0.0, 1.0) ** 2
    fallback = _transport(rule.rest_tangents, rule.rest_normals, n)
    t = t_raw + alpha * DEGENERATE_STRETCH * fallback
    t = t - np.sum(t * n, axis=1, keepdims=True) * n
    tlen = np.linalg.norm(t, axis=1, keepdims=True)
    t = np.where(tlen > 1e-20, t / np.maximum(tlen, 1e-300), _onb_tangent(n))
    b = np.cross(n, t)
    return np.stack([t, b, n], axis=1)


@wp.func
def onb_tangent(n: wp.vec3) -> wp.vec3:
    """Tangent of Duff et al.'s branchless orthonormal basis of a unit normal."""
    sign = wp.where(n[2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    return wp.vec3(1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0])


@wp.func
def _transport_func(t: wp.vec3, a: wp.vec3, b: wp.vec3) -> wp.vec3:
    v = wp.cross(a, b)
    c = wp.dot(a, b)
    if c <= -1.0 + 1.0e-6:
        return onb_tangent(b)
    return t * c + wp.cross(v, t) + v * (wp.dot(v, t) / (1.0 + c))


@wp.kernel
def _frames_kernel(
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    offsets: wp.array(dtype=wp.int32),
    neighbours: wp.array(dtype=wp.int32),
    weights: wp.array(dtype=wp.float32),
    rest_normals: wp.array(dtype=wp.vec3),
    rest_tangents: wp.array(dtype=wp.vec3),
    frames: wp.array(dtype=wp.mat33),
):
    i = wp.tid()
    n = normals[i]
    nlen = wp.length(n)
    if nlen > 1.0e-20:
        n = n / nlen
    else:
        n = rest_normals[i]
    p = points[i]
    t = wp.vec3(0.0)
    for k in range(offsets[i], offsets[i + 1]):
        e = points[neighbours[k]] - p
        t += weights[k] * (e - wp.dot(e, n) * n)
    length = wp.length(t)
    if length < _DEGENERATE_STRETCH_WP:
        a = 1.0 - length / _DEGENERATE_STRETCH_WP
        t += (a * a * _DEGENERATE_STRETCH_WP) * _transport_func(rest_tangents[i], rest_normals[i], n)
    t = t - wp.dot(t, n) * n
    tlen = wp.length(t)
    if tlen > 1.0e-20:
        t = t / tlen
    else:
        t = onb_tangent(n)
    b = wp.cross(n, t)
    frames[i] = wp.mat33(t[0], t[1], t[2], b[0], b[1], b[2], n[0], n[1], n[2])


class TangentFrames:
    """Device-side frame rule; computes (vertex_count,) mat33 frames per frame, in place.

    Attributes:
        rule: the float64 :class:`FrameRule` (rest-pose weights).
        frames: output, wp.array(mat33), shape (vertex_count,), rows (tangent, bitangent, normal),
            world frame; overwritten by every :meth:`compute`.
    """

    def __init__(self, rest_points, faces, rest_normals=None, device=None):
        self.device = resolve_device(device)
        self.rule = frame_rule(rest_points, faces, rest_normals)
        r = self.rule
        self._offsets = wp.array(r.offsets.astype(np.int32), dtype=wp.int32, device=self.device)
        self._neighbours = wp.array(r.neighbours.astype(np.int32), dtype=wp.int32, device=self.device)
        self._weights = wp.array(r.weights.astype(np.float32), dtype=wp.float32, device=self.device)
        self._rest_normals = wp.array(r.rest_normals.astype(np.float32), dtype=wp.vec3, device=self.device)
        self._rest_tangents = wp.array(r.rest_tangents.astype(np.float32), dtype=wp.vec3, device=self.device)
        self.frames = wp.empty(r.vertex_count, dtype=wp.mat33, device=self.device)

    @classmethod
    def from_scene(cls, scene, device=None) -> "TangentFrames":
        """Frame rule of a scene, with its rest pose = every mesh's authored points placed by
        its first transform (``mesh.points`` for skinned meshes: the bind pose)."""
        parts = []
        for mesh in scene.meshes:
            xf = mesh.transforms[0]
            parts.append(mesh.points @ xf[:3, :3] + xf[3, :3])
        return cls(np.concatenate(parts), scene.faces, device=device)

    @property
    def vertex_count(self) -> int:
        return self.rule.vertex_count

    def compute(self, points, normals, out=None):
        """Frames for the current pose.

        Args:
            points: current positions, wp.array(vec3), shape (vertex_count,), world space.
            normals: current unit vertex normals, wp.array(vec3), shape (vertex_count,).
            out: optional wp.array(mat33) to write into (default: :attr:`frames`).

        Returns:
            wp.array(mat33), shape (vertex_count,), rows (t, b, n).
        """
        out = self.frames if out is None else out
        for name, arr in (("points", points), ("normals", normals)):
            if arr.shape[0] != self.vertex_count:
                raise ValueError(f"TangentFrames.compute: {name} has {arr.shape[0]} entries, expected {self.vertex_count}")
        wp.launch(
            _frames_kernel,
            dim=self.vertex_count,
            inputs=[points, normals, self._offsets, self._neighbours, self._weights, self._rest_normals, self._rest_tangents, out],
            device=self.device,
        )
        return out
