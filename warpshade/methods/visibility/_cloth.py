"""Cloth inputs of data-driven visibility (Nowrouzezahrai, Kalogerakis, Fiume 2009, sec. 5).

A point-cached mesh (cloth) has no joints: the paper's pose input for it is the **dihedral angle
of every interior edge**, reduced by PCA of the training clip, and its as-rigid-as-possible
clusters come from the **rotation sequences of its triangles** over the training clip (James and
Twigg 2005). This module holds both, for any triangle mesh with time-sampled points:

* :func:`interior_edges` -- the interior edges of a triangle mesh and their two wing vertices
  (boundary and non-manifold edges are left out);
* :func:`dihedral_angles_f64` -- signed dihedral angles of the interior edges, float64 (the
  mirror of :data:`dihedral_angles_kernel`);
* :class:`DihedralFeatures` -- PCA of the training angles, its size chosen from a retained
  variance target (the paper keeps about 90 %), ``transform`` (NumPy) and ``bind`` (a
  :class:`DihedralFeatureProgram` that fills a device feature vector from a ``wp.array`` of vec3
  points with two recordable kernel launches);
* :func:`triangle_rotations_f64` -- per-triangle rotation from the rest pose to each frame (polar
  factor of the triangle's deformation gradient);
* :func:`rotation_clusters` -- k-means clusters of triangles by their rotation sequences, the count
  chosen from a rigid-fit residual budget (:func:`rigid_fit_residual`), with per-vertex labels
  (:class:`RotationClusters`);
* what the visibility stages call: :func:`dihedral_angles` (angles alone), :class:`DihedralInputs`
  (a scene's raw angles on the device, per frame from ``state.points``) and :func:`cluster_labels`
  (clusters of a training artifact's moving triangles).

Conventions. Points are (T, V, 3) or (V, 3), metres, any frame; faces (F, 3) integer vertex
indices. An interior edge ``(a, b)`` has wings ``c`` (the third vertex of the triangle in which
the edge runs a -> b, or of the first triangle found when both run the same way) and ``d`` (the
other triangle's third vertex). Its **dihedral angle** is the signed bending angle between the
normals ``n0 = (b - a) x (c - a)`` of triangle (a, b, c) and ``n1 = (a - b) x (d - b)`` of (b, a, d):
``atan2((n1 x n0) . (b - a) / |b - a|, n0 . n1)``, radians in (-pi, pi]: **0 for a flat sheet**,
positive when the two triangles fold towards their normals (the front is concave, a valley),
negative for a ridge, +-pi folded flat onto each other. It depends on the four points only, so
it does not matter whether the mesh's windings agree. A degenerate triangle (zero area, up to
:data:`DEGENERATE_RELATIVE_AREA` of the edge length squared) or a zero-length edge has angle 0:
bounded, never NaN.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.cluster.vq import kmeans2

from ..._wp import wp

wp.set_module_options({"enable_backward": False})

__all__ = [
    "DEGENERATE_RELATIVE_AREA",
    "DihedralFeatures",
    "DihedralFeatureProgram",
    "DihedralInputs",
    "RotationClusters",
    "cluster_labels",
    "dihedral_angles",
    "dihedral_angles_f64",
    "dihedral_angles_kernel",
    "dihedral_features_kernel",
    "interior_edges",
    "rigid_fit_residual",
    "rotation_clusters",
    "triangle_rotations_f64",
]

#: A triangle whose doubled area |n| is below this times its hinge edge's squared length is
#: degenerate (a sliver or a point): its dihedral angles are 0. 1e-6 is well above float32
#: round-off of the cross product (~1e-7 relative) and far below any real cloth triangle
#: (1e-6 of an edge squared is a triangle 1e-6 times as tall as it is wide).
DEGENERATE_RELATIVE_AREA = 1.0e-6
_DEGENERATE = wp.constant(DEGENERATE_RELATIVE_AREA)


# ---- edges and angles -----------------------------------------------------------------------------
def _check_faces(faces, vertex_count: int | None = None) -> np.ndarray:
    faces = np.asarray(faces)
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must be an integer array of shape (F, 3), got {faces.dtype} {faces.shape}")
    if faces.size and (faces.min() < 0 or (vertex_count is not None and faces.max() >= vertex_count)):
        raise ValueError(f"faces index vertices outside 0..{vertex_count - 1 if vertex_count else '?'}")
    return faces.astype(np.int64)


def _check_points(points, name: str = "points") -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim not in (2, 3) or points.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (V, 3) or (T, V, 3), got {points.shape}")
    if not np.all(np.isfinite(points)):
        bad = np.argwhere(~np.isfinite(points))[0]
        raise ValueError(f"{name} has a non-finite coordinate at index {tuple(int(i) for i in bad)}")
    return points


def interior_edges(faces) -> tuple[np.ndarray, np.ndarray]:
    """The interior edges of a triangle mesh and their wing vertices.

    An edge is interior when exactly two triangles share it; boundary edges (one triangle) and
    non-manifold edges (three or more) have no single dihedral angle and are left out, and so
    are edges of triangles that repeat a vertex.

    Args:
        faces: triangles, shape (F, 3), integer vertex indices.

    Returns:
        ``(edges, wings)``: edges (E, 2) int64 ``(a, b)``, sorted by (min, max) vertex, and wings
        (E, 2) int64 ``(c, d)`` (the module docstring's convention).
    """
    faces = _check_faces(faces)
    good = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
    faces = faces[good]
    # directed half-edges (a -> b) with the triangle's third vertex
    a = faces.ravel()
    b = faces[:, [1, 2, 0]].ravel()
    c = faces[:, [2, 0, 1]].ravel()
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.lexsort((hi, lo))
    lo, hi, a, c = lo[order], hi[order], a[order], c[order]
    new = np.ones(len(lo), dtype=bool)
    new[1:] = (lo[1:] != lo[:-1]) | (hi[1:] != hi[:-1])
    starts = np.flatnonzero(new)
    counts = np.diff(np.append(starts, len(lo)))
    pair = starts[counts == 2]
    first, second = pair, pair + 1
    # orient each edge as it runs in its first triangle: a -> b with wing c there
    ea = a[first]
    eb = np.where(ea == lo[first], hi[first], lo[first])
    edges = np.stack([ea, eb], axis=1)
    wings = np.stack([c[first], c[second]], axis=1)
    return edges, wings


def _angles_f64(points: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Dihedral angles (..., E) of points (..., V, 3) for quads (E, 4) = (a, b, c, d)."""
    pa, pb = points[..., quads[:, 0], :], points[..., quads[:, 1], :]
    pc, pd = points[..., quads[:, 2], :], points[..., quads[:, 3], :]
    e = pb - pa
    n0 = np.cross(e, pc - pa)
    n1 = np.cross(-e, pd - pb)
    e2 = np.einsum("...i,...i->...", e, e)
    len0 = np.linalg.norm(n0, axis=-1)
    len1 = np.linalg.norm(n1, axis=-1)
    elen = np.sqrt(e2)
    ok = (len0 > DEGENERATE_RELATIVE_AREA * e2) & (len1 > DEGENERATE_RELATIVE_AREA * e2) & (elen > 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        u0 = n0 / np.where(ok, len0, 1.0)[..., None]
        u1 = n1 / np.where(ok, len1, 1.0)[..., None]
        s = np.einsum("...i,...i->...", np.cross(u1, u0), e) / np.where(ok, elen, 1.0)
    cth = np.einsum("...i,...i->...", u0, u1)
    return np.where(ok, np.arctan2(s, cth), 0.0)


def dihedral_angles_f64(points, faces) -> tuple[np.ndarray, np.ndarray]:
    """Signed dihedral angles of every interior edge, float64 (the kernel's mirror).

    Args:
        points: vertex positions, shape (T, V, 3) or (V, 3), metres.
        faces: triangles, shape (F, 3), integer.

    Returns:
        ``(edges, angles)``: edges (E, 2) int64 from :func:`interior_edges`, and angles (T, E)
        (or (E,) for one frame) float64 radians in (-pi, pi], 0 for flat (module docstring).

    Raises:
        ValueError: malformed points or faces, a non-finite point, an index out of range.
    """
    points = _check_points(points)
    faces = _check_faces(faces, points.shape[-2])
    edges, wings = interior_edges(faces)
    return edges, _angles_f64(points, np.concatenate([edges, wings], axis=1))


@wp.func
def _dihedral(pa: wp.vec3, pb: wp.vec3, pc: wp.vec3, pd: wp.vec3) -> float:
    e = pb - pa
    n0 = wp.cross(e, pc - pa)
    n1 = wp.cross(-e, pd - pb)
    e2 = wp.dot(e, e)
    len0 = wp.length(n0)
    len1 = wp.length(n1)
    elen = wp.sqrt(e2)
    angle = float(0.0)
    if len0 > _DEGENERATE * e2 and len1 > _DEGENERATE * e2 and elen > 0.0:
        u0 = n0 / len0
        u1 = n1 / len1
        angle = wp.atan2(wp.dot(wp.cross(u1, u0), e) / elen, wp.dot(u0, u1))
    return angle


@wp.kernel
def dihedral_angles_kernel(points: wp.array(dtype=wp.vec3), quads: wp.array(dtype=wp.int32, ndim=2),
                           vertex_offset: int, angles: wp.array(dtype=wp.float32)):
    """One thread per interior edge: ``angles[e]`` (radians) of ``quads[e] = (a, b, c, d)``
    (mesh-local indices; ``vertex_offset`` is added to read ``points``, the scene's points)."""
    e = wp.tid()
    o = vertex_offset
    angles[e] = _dihedral(points[quads[e, 0] + o], points[quads[e, 1] + o], points[quads[e, 2] + o], points[quads[e, 3] + o])


@wp.kernel
def dihedral_features_kernel(angles: wp.array(dtype=wp.float32), mean: wp.array(dtype=wp.float32),
                             basis: wp.array(dtype=wp.float32, ndim=2), features: wp.array(dtype=wp.float32)):
    """One thread per PCA component k: ``features[k] = sum_e basis[k, e] (angles[e] - mean[e])``."""
    k = wp.tid()
    acc = float(0.0)
    for e in range(angles.shape[0]):
        acc += basis[k, e] * (angles[e] - mean[e])
    features[k] = acc


# ---- PCA of the angles ----------------------------------------------------------------------------
def _principal_directions(centred: np.ndarray):
    """PCA of centred rows (T, E): variances (min(T, E),) decreasing, and ``basis_of(k)``, the
    leading k orthonormal directions (k, E).

    Eigen-decomposes the smaller Gram matrix (T x T for T <= E: 120 frames x 3,000 edges takes
    milliseconds, where LAPACK's SVD of the (T, E) matrix took seconds here); directions with zero
    variance are never asked for, except the one of a constant input (then the first edge).
    """
    frames, edges = centred.shape
    if frames <= edges:
        w, u = np.linalg.eigh(centred @ centred.T)
        w, u = np.maximum(w[::-1], 0.0), u[:, ::-1]

        def basis_of(k):
            if w[0] <= 0.0:
                return np.eye(1, edges)
            rows = u[:, :k].T @ centred
            return rows / np.linalg.norm(rows, axis=1, keepdims=True)
    else:
        w, v = np.linalg.eigh(centred.T @ centred)
        w, v = np.maximum(w[::-1], 0.0), v[:, ::-1]

        def basis_of(k):
            return np.eye(1, edges) if w[0] <= 0.0 else v[:, :k].T.copy()
    return w / frames, basis_of


@dataclasses.dataclass
class DihedralFeatures:
    """PCA of a training clip's dihedral angles: the per-frame input of cloth visibility models.

    Made by :meth:`fit`; ``transform`` projects angles of new frames (NumPy), ``bind`` makes the
    device program that does it inside a recorded frame.

    Attributes:
        quads: (E, 4) int32, ``(a, b, c, d)`` of each interior edge (mesh-local vertex indices).
        mean: (E,) float64, the training angles' mean (radians).
        basis: (k, E) float64, orthonormal rows, the leading principal directions, each signed so
            that its largest-magnitude entry is positive (deterministic).
        variances: (k,) float64, the training variance along each kept direction (radians^2).
        total_variance: float, the training angles' total variance (sum over edges).
        feature_min, feature_max: (k,) float64, the training features' range (for novelty).
        variance_target: the retained-variance fraction the size was chosen for.
    """

    quads: np.ndarray
    mean: np.ndarray
    basis: np.ndarray
    variances: np.ndarray
    total_variance: float
    feature_min: np.ndarray
    feature_max: np.ndarray
    variance_target: float

    @classmethod
    def fit(cls, train_points, faces, variance: float = 0.9, max_components: int | None = None) -> "DihedralFeatures":
        """Fit the PCA to a training clip and keep the fewest components that retain ``variance``.

        Args:
            train_points: (T, V, 3) points of the training clip, T >= 2.
            faces: (F, 3) triangles.
            variance: fraction of the angles' total variance to retain, in (0, 1]; equivalently
                the relative RMS reconstruction error of the training angles is at most
                ``sqrt(1 - variance)``.
            max_components: upper bound on the count (default: min(T, E)).

        Returns:
            The fitted features. When the training angles do not vary (constant input) one
            component is kept; its feature is 0 on every frame (``retained_variance`` is 1 and
            ``constant`` is True).

        Raises:
            ValueError: fewer than 2 frames, no interior edge, ``variance`` outside (0, 1].
        """
        if not 0.0 < variance <= 1.0:
            raise ValueError(f"DihedralFeatures.fit: variance must be in (0, 1], got {variance}")
        points = _check_points(train_points, "train_points")
        if points.ndim != 3 or points.shape[0] < 2:
            raise ValueError(f"DihedralFeatures.fit: train_points must be (T >= 2, V, 3), got {points.shape}")
        edges, angles = dihedral_angles_f64(points, faces)
        if len(edges) == 0:
            raise ValueError("DihedralFeatures.fit: the mesh has no interior edge (two triangles sharing one edge)")
        _, wings = interior_edges(faces)
        quads = np.concatenate([edges, wings], axis=1).astype(np.int32)
        mean = angles.mean(axis=0)
        centred = angles - mean
        var, basis_of = _principal_directions(centred)
        total = float(var.sum())
        limit = len(var) if max_components is None else max(1, min(int(max_components), len(var)))
        if total <= 0.0:
            count = 1
        else:
            kept = np.cumsum(var) / total
            count = min(int(np.searchsorted(kept, variance - 1e-12) + 1), limit, int(np.count_nonzero(var > 0.0)))
        basis = basis_of(count)
        peak = np.argmax(np.abs(basis), axis=1)
        basis = basis * np.where(basis[np.arange(count), peak] < 0.0, -1.0, 1.0)[:, None]
        feats = centred @ basis.T
        return cls(quads=quads, mean=mean, basis=basis, variances=var[:count], total_variance=total,
                   feature_min=feats.min(axis=0), feature_max=feats.max(axis=0), variance_target=float(variance))

    # -- what was kept
    @property
    def component_count(self) -> int:
        """k, the number of kept components."""
        return int(self.basis.shape[0])

    @property
    def edge_count(self) -> int:
        """E, the number of interior edges."""
        return int(self.quads.shape[0])

    @property
    def constant(self) -> bool:
        """True when the training angles did not vary (the features are always 0)."""
        return self.total_variance <= 0.0

    @property
    def retained_variance(self) -> float:
        """The fraction of the training angles' variance the kept components hold (1 when constant)."""
        return 1.0 if self.constant else float(self.variances.sum() / self.total_variance)

    def report(self) -> dict:
        """A JSON-ready summary: counts, retained variance, target."""
        return {"edges": self.edge_count, "components": self.component_count,
                "retained_variance": self.retained_variance, "variance_target": self.variance_target,
                "constant": self.constant}

    # -- applying it
    def angles(self, points) -> np.ndarray:
        """Dihedral angles (T, E) or (E,) of points (T, V, 3) or (V, 3), float64, in this model's edge order."""
        points = _check_points(points)
        if points.shape[-2] <= int(self.quads.max()):
            raise ValueError(f"DihedralFeatures: points have {points.shape[-2]} vertices, the mesh needs {int(self.quads.max()) + 1}")
        return _angles_f64(points, self.quads.astype(np.int64))

    def transform(self, points) -> np.ndarray:
        """PCA features (T, k) or (k,) of points (T, V, 3) or (V, 3), float64."""
        return (self.angles(points) - self.mean) @ self.basis.T

    def reconstruct(self, features) -> np.ndarray:
        """Angles (..., E) rebuilt from features (..., k)."""
        return np.asarray(features, dtype=np.float64) @ self.basis + self.mean

    def novelty(self, features) -> np.ndarray:
        """How far features (..., k) lie outside the training range, in training standard deviations
        (0 inside the range), per frame: max over components."""
        f = np.asarray(features, dtype=np.float64)
        std = np.sqrt(np.maximum(self.variances, 1e-30))
        out = np.maximum(self.feature_min - f, 0.0) + np.maximum(f - self.feature_max, 0.0)
        return (out / std).max(axis=-1)

    def bind(self, device=None, vertex_offset: int = 0) -> "DihedralFeatureProgram":
        """The device program that fills a (k,) feature vector from device points (see
        :class:`DihedralFeatureProgram`); ``vertex_offset`` is the cloth's first vertex in the
        points array it will read (a scene's ``state.points``: the mesh's ``vertex_offset``)."""
        return DihedralFeatureProgram(self, device, vertex_offset)

    # -- the cache
    def arrays(self) -> dict:
        """The arrays a cache stores (:meth:`from_arrays` rebuilds and checks them)."""
        return {"quads": self.quads, "mean": self.mean, "basis": self.basis, "variances": self.variances,
                "total_variance": np.array(self.total_variance), "feature_min": self.feature_min,
                "feature_max": self.feature_max, "variance_target": np.array(self.variance_target)}

    @classmethod
    def from_arrays(cls, arrays: dict) -> "DihedralFeatures":
        """Rebuild from :meth:`arrays`, checking shapes and finiteness (``ValueError`` otherwise)."""
        try:
            quads = np.asarray(arrays["quads"])
            mean, basis = np.asarray(arrays["mean"], np.float64), np.asarray(arrays["basis"], np.float64)
            fields = {name: np.asarray(arrays[name], np.float64) for name in ("variances", "feature_min", "feature_max")}
            total, target = float(arrays["total_variance"]), float(arrays["variance_target"])
        except KeyError as exc:
            raise ValueError(f"DihedralFeatures: the cached arrays lack {exc.args[0]!r}") from None
        edges = quads.shape[0] if quads.ndim == 2 else -1
        if quads.ndim != 2 or quads.shape[1] != 4 or not np.issubdtype(quads.dtype, np.integer) or quads.min(initial=0) < 0:
            raise ValueError(f"DihedralFeatures: quads must be non-negative integers of shape (E, 4), got {quads.shape}")
        if mean.shape != (edges,) or basis.ndim != 2 or basis.shape[1] != edges or basis.shape[0] < 1:
            raise ValueError(f"DihedralFeatures: mean {mean.shape} and basis {basis.shape} do not match {edges} edges")
        k = basis.shape[0]
        if any(v.shape != (k,) for v in fields.values()):
            raise ValueError(f"DihedralFeatures: variances and feature ranges must have shape ({k},)")
        if not all(np.all(np.isfinite(v)) for v in (mean, basis, *fields.values(), total, target)):
            raise ValueError("DihedralFeatures: a cached array is not finite")
        return cls(quads=quads.astype(np.int32), mean=mean, basis=basis, total_variance=total, variance_target=target, **fields)


class DihedralFeatureProgram:
    """Device buffers and launches that compute :class:`DihedralFeatures` features each frame.

    ``launch(points)`` launches :data:`dihedral_angles_kernel` and :data:`dihedral_features_kernel`
    on arrays allocated here and the given points array: kernel launches only, so it can be
    recorded (call it from a frame stage's ``launch`` with the ``state.points`` array bound in
    ``setup``).

    Attributes:
        features: (k,) float32 device array, the PCA features of the last launch.
        angles: (E,) float32 device array, the dihedral angles of the last launch (radians).
        device: the Warp device.
    """

    def __init__(self, model: DihedralFeatures, device=None, vertex_offset: int = 0):
        self.device = wp.get_device(device)
        self.vertex_offset = int(vertex_offset)
        self.vertex_count = int(model.quads.max()) + 1
        self._quads = wp.array(model.quads.astype(np.int32), dtype=wp.int32, device=self.device)
        self._mean = wp.array(model.mean.astype(np.float32), dtype=wp.float32, device=self.device)
        self._basis = wp.array(model.basis.astype(np.float32), dtype=wp.float32, device=self.device)
        self.angles = wp.zeros(model.edge_count, dtype=wp.float32, device=self.device)
        self.features = wp.zeros(model.component_count, dtype=wp.float32, device=self.device)

    def launch(self, points) -> None:
        """Fill ``angles`` and ``features`` from ``points`` (wp.array of vec3 on this device, at least
        ``vertex_offset + vertex_count`` long)."""
        if points.shape[0] < self.vertex_offset + self.vertex_count:
            raise ValueError(f"DihedralFeatureProgram: points hold {points.shape[0]} vertices, the cloth needs "
                             f"{self.vertex_offset + self.vertex_count} (offset {self.vertex_offset})")
        wp.launch(dihedral_angles_kernel, dim=self.angles.shape[0], inputs=[points, self._quads, self.vertex_offset],
                  outputs=[self.angles], device=self.device)
        wp.launch(dihedral_features_kernel, dim=self.features.shape[0], inputs=[self.angles, self._mean, self._basis],
                  outputs=[self.features], device=self.device)


# ---- rotation clusters ----------------------------------------------------------------------------
def _triangle_frames(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(..., F, 3, 3) matrices [e1, e2, n / sqrt|n|] per triangle (columns)."""
    p0, p1, p2 = points[..., faces[:, 0], :], points[..., faces[:, 1], :], points[..., faces[:, 2], :]
    e1, e2 = p1 - p0, p2 - p0
    n = np.cross(e1, e2)
    n = n / np.sqrt(np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300))
    return np.stack([e1, e2, n], axis=-1)


def _polar_rotations(m: np.ndarray) -> np.ndarray:
    """The rotation (det +1) nearest each 3x3 matrix (..., 3, 3), by SVD; identity for a zero matrix."""
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    d = np.where(d == 0.0, 1.0, d)
    u[..., :, 2] *= d[..., None]
    return u @ vt


def triangle_rotations_f64(points, faces, rest=None) -> np.ndarray:
    """Per-triangle rotation from the rest pose to each frame, float64.

    The rotation is the polar factor of the triangle's deformation gradient ``F = D_s D_r^-1``,
    with ``D = [e1, e2, n / sqrt|n|]`` (edges from the first vertex and the scaled normal), the
    nearest rotation to F (SVD, reflection removed). A degenerate triangle gets a rotation too
    (never NaN): the pseudo-inverse maps its collapsed directions to zero.

    Args:
        points: (T, V, 3) or (V, 3) points.
        faces: (F, 3) triangles.
        rest: (V, 3) rest points (default: the first frame).

    Returns:
        (T, F, 3, 3) or (F, 3, 3) rotation matrices (world frame, acting on column vectors).
    """
    points = _check_points(points)
    faces = _check_faces(faces, points.shape[-2])
    rest = points.reshape(-1, *points.shape[-2:])[0] if rest is None else _check_points(rest, "rest")
    d_rest = _triangle_frames(rest, faces)
    gradient = _triangle_frames(points, faces) @ np.linalg.pinv(d_rest)
    return _polar_rotations(gradient)


def _majority(triangle_labels: np.ndarray, faces: np.ndarray, vertex_count: int, count: int) -> np.ndarray:
    votes = np.zeros((vertex_count, max(count, 1)), dtype=np.int64)
    for corner in range(3):
        np.add.at(votes, (faces[:, corner], triangle_labels), 1)
    return np.argmax(votes, axis=1)  # ties: the smallest label; unreferenced vertices: 0


def _consistent_labels(tri: np.ndarray, faces: np.ndarray, vertex_count: int):
    """Per-vertex labels by majority and matching triangle labels, both consecutive from 0.

    Clusters are numbered in the order of their first vertex. A triangle whose cluster owns no
    vertex after the vote takes the label of the majority of its vertices (of its first vertex
    when all three differ), so every label in ``0..count-1`` has vertices and triangles.
    """
    labels = _majority(tri, faces, vertex_count, int(tri.max()) + 1)
    used = np.unique(labels)
    first = np.array([np.flatnonzero(labels == c)[0] for c in used])
    order = used[np.argsort(first)]
    remap = np.full(int(tri.max()) + 1 if tri.size else 1, -1, dtype=np.int64)
    remap[order] = np.arange(len(order))
    labels = remap[labels]
    tri = remap[tri]
    orphan = np.flatnonzero(tri < 0)
    if orphan.size:
        corner = labels[faces[orphan]]  # (n, 3)
        tri[orphan] = np.where(corner[:, 1] == corner[:, 2], corner[:, 1], corner[:, 0])
    return tri, labels, len(order)


def rigid_fit_residual(points, labels, rest=None) -> float:
    """RMS distance (metres) between the points and each cluster's best rigid motion of its rest points.

    For every cluster and frame the rigid transform (rotation and translation, Kabsch) that best
    maps the cluster's rest points onto its points is fitted; the residual is the RMS over all
    vertices and frames of the distance left. 0 when every cluster moves rigidly.

    Args:
        points: (T, V, 3) points; labels: (V,) cluster per vertex; rest: (V, 3) (default frame 0).
    """
    points = _check_points(points)
    points = points.reshape(-1, *points.shape[-2:])
    rest = points[0] if rest is None else _check_points(rest, "rest")
    labels = np.asarray(labels)
    sq, total = 0.0, 0
    for c in np.unique(labels):
        idx = np.flatnonzero(labels == c)
        x = rest[idx] - rest[idx].mean(axis=0)
        y = points[:, idx] - points[:, idx].mean(axis=1, keepdims=True)
        h = np.einsum("vi,tvj->tij", x, y)
        rot = _polar_rotations(np.swapaxes(h, 1, 2))  # R maximising trace(R H) = polar(H^T)
        fit = np.einsum("tij,vj->tvi", rot, x)
        sq += float(((fit - y) ** 2).sum())
        total += y.shape[0] * y.shape[1]
    return float(np.sqrt(sq / max(total, 1)))


#: The cluster counts :func:`rotation_clusters` tries, in order, up to ``max_clusters``.
CLUSTER_COUNTS = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128)


@dataclasses.dataclass
class RotationClusters:
    """Triangles clustered by their rotation sequences (James and Twigg 2005).

    Attributes:
        labels: (V,) int64, each vertex's cluster (the majority of its triangles'; ties to the
            smallest k-means label), 0..count-1, numbered in the order of their first vertex.
        triangle_labels: (F,) int64, each triangle's cluster, in the same numbering (a triangle
            whose k-means cluster won no vertex joins the majority of its vertices).
        count: the number of clusters (every label has vertices and triangles).
        residual: the rigid-fit residual of ``labels`` (:func:`rigid_fit_residual`, metres).
        tolerance: the residual budget (metres) the count was chosen for.
        tried: ``[(clusters asked, residual m), ...]`` for every count tried (clusters vs error).
        within_budget: False when even the largest count tried missed the budget.
    """

    labels: np.ndarray
    triangle_labels: np.ndarray
    count: int
    residual: float
    tolerance: float
    tried: list
    within_budget: bool


def rotation_clusters(points, faces, tolerance: float = 0.01, seed: int = 0, max_clusters: int = 64,
                      rest=None, counts=CLUSTER_COUNTS) -> RotationClusters:
    """Cluster triangles by their rotation sequences; the fewest clusters that fit the budget.

    Each triangle's feature is its rotation from the rest pose at every frame, concatenated
    (:func:`triangle_rotations_f64`, 9 T numbers); k-means (``scipy.cluster.vq.kmeans2``, k-means++
    start, seeded) groups them for each count in ``counts`` up to ``max_clusters``,
    and the first count whose per-vertex labels fit rigid motions within ``tolerance``
    (:func:`rigid_fit_residual`) is kept (the largest tried otherwise, ``within_budget`` False).

    Args:
        points: (T, V, 3) points of the training clip, metres.
        faces: (F, 3) triangles.
        tolerance: the budget: RMS rigid-fit residual in metres (e.g. 0.01 m on a 1.6 m cloth).
        seed: k-means seed; the labels are deterministic for a seed.
        max_clusters: the largest count tried.
        rest: (V, 3) rest points (default: the first frame).
        counts: the cluster counts to try, increasing (default :data:`CLUSTER_COUNTS`); one
            count gives exactly that clustering (for charts of clusters against residual).

    Returns:
        :class:`RotationClusters`.
    """
    if not tolerance > 0.0:
        raise ValueError(f"rotation_clusters: tolerance must be a positive distance in metres, got {tolerance}")
    points = _check_points(points)
    points = points.reshape(-1, *points.shape[-2:])
    faces = _check_faces(faces, points.shape[1])
    if len(faces) == 0:
        raise ValueError("rotation_clusters: the mesh has no triangle")
    rest = points[0] if rest is None else _check_points(rest, "rest")
    rotations = triangle_rotations_f64(points, faces, rest)  # (T, F, 3, 3)
    data = np.ascontiguousarray(np.moveaxis(rotations, 1, 0).reshape(len(faces), -1))
    asked = [int(k) for k in counts if 1 <= k <= max(1, min(max_clusters, len(faces)))]
    if not asked:
        raise ValueError(f"rotation_clusters: no cluster count in {tuple(counts)} is between 1 and {max_clusters}")
    tried, best = [], None
    for k in asked:
        if k == 1:
            tri = np.zeros(len(faces), dtype=np.int64)
        else:
            _, tri = kmeans2(data, k, minit="++", rng=np.random.default_rng(seed), iter=30)
        tri, labels, count = _consistent_labels(tri, faces, points.shape[1])
        residual = rigid_fit_residual(points, labels, rest)
        tried.append((k, residual))
        best = (tri, labels, count, residual)
        if residual <= tolerance:
            break
    tri, labels, count, residual = best
    return RotationClusters(labels=labels, triangle_labels=tri, count=count, residual=residual, tolerance=float(tolerance),
                            tried=tried, within_budget=residual <= tolerance)


# ---- what the visibility stages call --------------------------------------------------------------
def dihedral_angles(points, faces) -> np.ndarray:
    """The angles of :func:`dihedral_angles_f64` alone: (E,) for points (V, 3), (T, E) for (T, V, 3),
    float64 radians, edges in the order of :func:`interior_edges` of ``faces``."""
    return dihedral_angles_f64(points, faces)[1]


class DihedralInputs:
    """A scene's dihedral angles on the device, each frame: the raw input of a cloth visibility model.

    Covers every interior edge of ``scene.faces`` (all meshes, in the order of
    :func:`dihedral_angles` on ``scene.points_at(t)``, ``scene.faces``); static meshes give
    constant angles, which an input PCA drops. ``launch(state)`` is one kernel launch on arrays
    allocated here and ``state.points`` (recordable).

    Attributes:
        features: (E,) float32 device array, the angles of the last launch (radians).
        quads: (E, 4) int32 host array, ``(a, b, c, d)`` of each edge (scene vertex indices).
    """

    def __init__(self, scene, device=None):
        self.device = wp.get_device(device)
        edges, wings = interior_edges(np.asarray(scene.faces))
        if len(edges) == 0:
            raise ValueError(f"DihedralInputs: scene {getattr(scene, 'source', None) or '<arrays>'} has no interior edge")
        self.quads = np.concatenate([edges, wings], axis=1).astype(np.int32)
        self._quads = wp.array(self.quads, dtype=wp.int32, device=self.device)
        self.features = wp.zeros(len(self.quads), dtype=wp.float32, device=self.device)

    def launch(self, state) -> None:
        """Fill ``features`` from ``state.points`` (wp.array of vec3, every scene vertex)."""
        wp.launch(dihedral_angles_kernel, dim=self.features.shape[0], inputs=[state.points, self._quads, 0],
                  outputs=[self.features], device=self.device)


def cluster_labels(data, tolerance: float = 0.01, seed: int = 0, max_clusters: int = 64) -> np.ndarray:
    """Per-vertex rotation-sequence clusters of a training artifact's moving triangles.

    Args:
        data: a mapping with ``points`` (T, V, 3) (every scene vertex at each training frame),
            ``faces`` (F, 3) and optionally ``rest_points`` (V, 3) (default: the first frame).
        tolerance, seed, max_clusters: as :func:`rotation_clusters` (the budget in metres is
            measured over the moving vertices only).

    Returns:
        (V,) int64 labels: the clusters of :func:`rotation_clusters` over the triangles that move
        (a vertex moves more than 1e-9 m over the clip), and one more label for every vertex of
        the static triangles.
    """
    points = _check_points(np.asarray(data["points"], np.float64), "data['points']")
    points = points.reshape(-1, *points.shape[-2:])
    faces = _check_faces(data["faces"], points.shape[1])
    rest = np.asarray(data["rest_points"], np.float64) if "rest_points" in data else points[0]
    moving_vertex = np.ptp(points, axis=0).max(axis=1) > 1e-9
    moving = moving_vertex[faces].any(axis=1)
    labels = np.zeros(points.shape[1], np.int64)
    if not moving.any():
        return labels
    used = np.unique(faces[moving])
    local = np.full(points.shape[1], -1, np.int64)
    local[used] = np.arange(len(used))
    clusters = rotation_clusters(points[:, used], local[faces[moving]], tolerance=tolerance, seed=seed,
                                 max_clusters=max_clusters, rest=rest[used])
    labels[:] = clusters.count
    labels[used] = clusters.labels
    return labels
