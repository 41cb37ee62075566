"""What the hybrid tracer builds at set-up: the surface neighbourhood its filter reuses over.

:class:`SurfaceNeighbours` holds, per vertex, its neighbours along mesh edges (compressed rows:
``offsets`` (V + 1,), ``neighbours`` (E,)) and a length scale ``scale`` (the mean length of its
edges in the rest pose; the filter's distance weight and the motion test are in these units).
:func:`surface_neighbours` makes it from triangles and points for any topology: an edge shared
by more than two triangles (non-manifold) is kept once and counted, a vertex in no triangle
(or only in degenerate ones) has no neighbours and the scene's median edge length as its scale,
and both are reported (:attr:`SurfaceNeighbours.report`), never an error.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__: list[str] = []


@dataclass
class SurfaceNeighbours:
    """Vertex adjacency along mesh edges (host arrays).

    Attributes:
        offsets: (V + 1,) int32; the neighbours of ``v`` are ``neighbours[offsets[v]:offsets[v+1]]``.
        neighbours: (E,) int32 vertex indices (each undirected edge listed from both ends).
        scale: (V,) float32, mean rest-pose edge length at each vertex (> 0).
        report: counts worth reporting (isolated vertices, non-manifold edges, ...).
    """

    offsets: np.ndarray
    neighbours: np.ndarray
    scale: np.ndarray
    report: dict = field(default_factory=dict)

    def arrays(self) -> dict:
        return {"offsets": self.offsets, "neighbours": self.neighbours, "scale": self.scale}

    @classmethod
    def from_arrays(cls, arrays: dict, vertex_count: int | None = None) -> "SurfaceNeighbours":
        """Rebuild and check; ValueError for anything that is not a valid adjacency."""
        try:
            offsets = np.asarray(arrays["offsets"])
            neighbours = np.asarray(arrays["neighbours"])
            scale = np.asarray(arrays["scale"])
        except KeyError as exc:
            raise ValueError(f"surface neighbours: missing {exc}") from None
        v = offsets.shape[0] - 1 if offsets.ndim == 1 else -1
        if v < 0 or offsets.dtype != np.int32 or neighbours.dtype != np.int32 or neighbours.ndim != 1:
            raise ValueError("surface neighbours: offsets and neighbours must be 1-D int32 arrays")
        if vertex_count is not None and v != vertex_count:
            raise ValueError(f"surface neighbours: {v} vertices, the scene has {vertex_count}")
        if offsets[0] != 0 or offsets[-1] != neighbours.shape[0] or np.any(np.diff(offsets) < 0):
            raise ValueError("surface neighbours: offsets must rise from 0 to the neighbour count")
        if neighbours.size and (neighbours.min() < 0 or neighbours.max() >= v):
            raise ValueError("surface neighbours: a neighbour index is outside the vertices")
        if scale.shape != (v,) or scale.dtype != np.float32 or not np.all(np.isfinite(scale)) or np.any(scale <= 0):
            raise ValueError("surface neighbours: scale must be (V,) float32, finite and > 0")
        return cls(offsets, neighbours, scale)


def surface_neighbours(faces, points) -> SurfaceNeighbours:
    """The edge adjacency and rest edge lengths of a triangle mesh of any topology.

    Args:
        faces: (F, 3) vertex indices.
        points: (V, 3) rest positions.

    Returns:
        :class:`SurfaceNeighbours` with ``report`` = ``{"vertices", "edges",
        "isolated_vertices", "non_manifold_edges", "boundary_edges", "degenerate_triangles"}``.
    """
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    tri = np.asarray(faces, np.int64).reshape(-1, 3)
    v = pts.shape[0]
    if tri.size and (tri.min() < 0 or tri.max() >= v):
        raise ValueError(f"surface neighbours: a triangle index is outside 0..{v - 1}")
    degenerate = (tri[:, 0] == tri[:, 1]) | (tri[:, 1] == tri[:, 2]) | (tri[:, 0] == tri[:, 2])
    edges = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    edges = edges[edges[:, 0] != edges[:, 1]]
    edges = np.sort(edges, axis=1)
    unique, uses = np.unique(edges, axis=0, return_counts=True) if edges.size else (np.zeros((0, 2), np.int64), np.zeros(0))
    both = np.concatenate([unique, unique[:, ::-1]])
    order = np.lexsort((both[:, 1], both[:, 0]))
    both = both[order]
    counts = np.bincount(both[:, 0], minlength=v) if both.size else np.zeros(v, np.int64)
    offsets = np.zeros(v + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    length = np.linalg.norm(pts[both[:, 0]] - pts[both[:, 1]], axis=1) if both.size else np.zeros(0)
    total = np.bincount(both[:, 0], weights=length, minlength=v) if both.size else np.zeros(v)
    positive = length[length > 0]
    fallback = float(np.median(positive)) if positive.size else 1.0
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(counts > 0, total / np.maximum(counts, 1), 0.0)
    scale = np.where(np.isfinite(scale) & (scale > 0), scale, fallback)
    report = {"vertices": int(v), "edges": int(unique.shape[0]), "isolated_vertices": int(np.count_nonzero(counts == 0)),
              "non_manifold_edges": int(np.count_nonzero(uses > 2)), "boundary_edges": int(np.count_nonzero(uses == 1)),
              "degenerate_triangles": int(np.count_nonzero(degenerate))}
    return SurfaceNeighbours(offsets.astype(np.int32), both[:, 1].astype(np.int32), scale.astype(np.float32), report)
