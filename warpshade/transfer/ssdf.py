"""Spherical signed distance functions (SSDFs) for visibility (Wang et al. 2009, sec. 5).

Per receiver vertex, the binary visibility ``V(i)`` of its upper hemisphere is turned into the
signed angular distance to the nearest visibility boundary (eq. 23)::

    Vd(i) = + min_{V(t) = 0} angle(t, i)   where V(i) = 1 (visible: positive),
    Vd(i) = - min_{V(t) = 1} angle(t, i)   where V(i) = 0 (blocked: negative),

compressed over the vertices with PCA (eq. 24) and multiplied with spherical-Gaussian lobes by
the hemisphere reconstruction of eq. 25-31 (``mu f_h(Vd(p), lambda)``).

Maps and frames. A map is a ``R x R`` square over ``[-1, 1]^2`` mapped to the upper hemisphere of
the vertex's tangent frame (:mod:`warpshade.geometry.frames`, rows (t, b, n), ``w_local = F w``)
by the Shirley-Chiu concentric map with the area-preserving lift
(:func:`warpshade.scene.materials.concentric_to_hemisphere`): texel ``[ia, ib]`` is centred at
``((ia + 0.5) / R * 2 - 1, (ib + 0.5) / R * 2 - 1)`` (:func:`warpshade.scene.materials.view_grid`,
row-major, ``a`` first; flat texel index ``ia * R + ib``). Every texel has the same solid angle,
``2 pi / R^2``. The square's edge is the horizon.

Pipeline (the paper's 512 -> 128):

1. :func:`bake_visibility`: one ray per texel centre of the fine ``(R s) x (R s)`` map from
   ``p + offset n`` (the origin offset of :mod:`warpshade.geometry.bvh`) into the world
   direction ``F^T d_local``; 1 = no hit (Warp kernel
   :data:`~warpshade.transfer.ssdf_warp.trace_hemisphere_kernel`).
2. :func:`signed_distance`: the fine map's visibility is taken as constant over each fine texel,
   so its boundary is the union of the texel edges between 4-neighbours of opposite visibility
   (the horizon, the square's edge, is *not* a boundary). That boundary is sampled at every edge
   midpoint and edge end (half a fine texel apart, :func:`boundary_points`) and mapped to the
   sphere; each output texel centre gets the angle to the nearest sample, exact in angle (the
   nearest point in chord distance is the nearest in angle: ``angle = 2 asin(chord / 2)``), by a
   k-d tree (float64, :class:`scipy.spatial.cKDTree`) or a brute-force Warp kernel. The sign is
   the fine visibility at the output texel centre (its fine texel for odd ``s``; for even ``s``
   the centre is a fine texel corner: the majority of the four texels around it, ties visible --
   when they disagree the corner is itself a boundary sample, so the value there is 0 either
   way). Evaluating the distance of the fine boundary at coarse centres is the down-sampling:
   the boundary is resolved to the fine texel, and the coarse map samples a 1-Lipschitz function
   that bilinear interpolation reconstructs without aliasing.
3. Clamping: distances are clamped to ``[-pi/2, pi/2]`` (:data:`SSDF_LIMIT`). The product of
   eq. 30 only uses that range (at ``+-pi/2`` the reconstructed visible hemisphere is the one
   centred on / opposite to the lobe axis), and the clamp makes fully visible (``+pi/2``
   everywhere, no boundary) and fully blocked (``-pi/2``) hemispheres exact fixed points.
4. :func:`compress_ssdf`: PCA of the ``(V, R*R)`` maps, the term count from an RMS error budget
   in radians (:class:`SSDFModel`).
5. :func:`ssdf_lookup` / :func:`~warpshade.transfer.ssdf_warp.ssdf_eval`: bilinear between texel
   centres at the concentric coordinates of a local direction (edge-clamped; directions below the
   horizon are clamped to it). :func:`ssdf_product` / :func:`ssdf_integral`: eq. 31 / eq. 30.

Validation oracle: :func:`trace_lobe_visibility` ray traces ``integral G(i; p, lambda, 1) V(i)``
over the upper hemisphere by sampling the lobe itself (independent of the maps).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .._wp import launch_parallel, resolve_device, wp
from ..basis import sg
from ..geometry.bvh import Visibility
from ..geometry.frames import TangentFrames
from ..scene.materials import concentric_to_hemisphere, hemisphere_to_concentric, view_grid
from . import ssdf_warp
from .raytrace import receiver_indices

__all__ = [
    "DISTANCE_METHODS",
    "SSDFModel",
    "SSDF_LIMIT",
    "bake_ssdf",
    "bake_visibility",
    "bilinear_taps",
    "boundary_points",
    "compress_ssdf",
    "evaluate_ssdf_warp",
    "product_warp",
    "sample_maps",
    "signed_distance",
    "ssdf_integral",
    "ssdf_lookup",
    "ssdf_product",
    "texel_directions",
    "texel_diameter",
    "trace_lobe_visibility",
]

#: |SSDF| is clamped to this (radians): the range the hemisphere product of eq. 30 uses.
SSDF_LIMIT = 0.5 * math.pi
#: ``signed_distance`` back ends.
DISTANCE_METHODS = ("auto", "kdtree", "warp")
#: Rays per launch of a bake: ~4 M on the CPU (a fraction of a second, 4 MB of visibility bytes),
#: 32 M on CUDA.
RAYS_PER_CHUNK_CPU = 1 << 22
RAYS_PER_CHUNK_CUDA = 1 << 25
#: Randomised SVD above this many matrix entries (V * R^2), exact SVD below. Measured on two CPU
#: cores (``benchmarks/bench_ssdf.py``): 64 x 64^2 maps, exact 2.6 s vs randomised 4.6 s;
#: 512 x 128^2 maps, exact 22 s vs randomised 11 s (error curves equal to 4e-7 rad).
PCA_EXACT_MAX_ENTRIES = 1 << 22
#: Oversampling and power iterations of the randomised SVD (Halko et al. 2011).
PCA_OVERSAMPLE = 16
PCA_POWER_ITERATIONS = 4


# ------------------------------------------------------------------------------------------------
# small helpers


def _check_resolution(value, name: str, minimum: int = 2) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) < minimum:
        raise ValueError(f"ssdf: {name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def texel_directions(resolution: int) -> np.ndarray:
    """Local directions of the texel centres of a ``resolution^2`` map, (R*R, 3) float64, row-major."""
    return view_grid(_check_resolution(resolution, "resolution"))


def texel_diameter(resolution: int) -> float:
    """The largest angular diameter (radians) of a texel of a ``resolution^2`` map: the largest
    angle between two corners of one texel (the concentric map stretches texels near the
    diagonals of the square). The staircase boundary of a fine map lies within this of the true
    boundary."""
    r = _check_resolution(resolution, "resolution", 1)
    g = np.linspace(-1.0, 1.0, r + 1)
    a, b = np.meshgrid(g, g, indexing="ij")
    c = concentric_to_hemisphere(np.stack([a, b], -1))  # (r+1, r+1, 3)
    corners = [c[:-1, :-1], c[1:, :-1], c[:-1, 1:], c[1:, 1:]]
    best = 0.0
    for i in range(4):
        for j in range(i + 1, 4):
            dots = np.clip(np.sum(corners[i] * corners[j], axis=-1), -1.0, 1.0)
            best = max(best, float(np.arccos(dots).max()))
    return best


class _Progress:
    """``progress``: None/False (nothing), True (a tqdm bar), a callable ``(done, total)`` or an
    object with ``update(count)`` (a tqdm bar of the caller's)."""

    def __init__(self, progress, total: int, desc: str):
        self.total = int(total)
        self.done = 0
        self._bar = None
        self._call = None
        self._own = False
        if progress is None or progress is False:
            return
        if progress is True:
            from tqdm.auto import tqdm

            self._bar = tqdm(total=self.total, desc=desc, unit="vertex", leave=False)
            self._own = True
        elif hasattr(progress, "update"):
            self._bar = progress
        elif callable(progress):
            self._call = progress
        else:
            raise ValueError(f"ssdf: progress must be None, a bool, a callable (done, total) or have update(), got {progress!r}")

    def update(self, count: int) -> None:
        self.done += int(count)
        if self._bar is not None:
            self._bar.update(int(count))
        elif self._call is not None:
            self._call(self.done, self.total)

    def close(self) -> None:
        if self._bar is not None and self._own:
            self._bar.close()


# ------------------------------------------------------------------------------------------------
# 1. ray-traced hemisphere visibility


class _HemisphereTracer:
    """BVH, tangent frames and texel directions of one frame; traces vertex chunks."""

    def __init__(self, scene, frame, resolution: int, vertices, device, offset):
        self.device = resolve_device(device)
        self.resolution = _check_resolution(resolution, "resolution")
        frame = scene.frames[0] if frame is None else frame
        state = scene.evaluate(frame, device=self.device)
        self.points, self.normals = state.points, state.normals
        self.bvh = Visibility(self.points, scene.faces, device=self.device, offset=offset)
        self.frames = TangentFrames.from_scene(scene, device=self.device).compute(self.points, self.normals)
        self.vertices = receiver_indices(vertices, scene.vertex_count)
        self.receivers = wp.array(self.vertices.astype(np.int32), dtype=wp.int32, device=self.device)
        self.dirs = wp.array(texel_directions(self.resolution).astype(np.float32), dtype=wp.vec3, device=self.device)
        texels = self.resolution**2
        per_launch = RAYS_PER_CHUNK_CPU if self.device.is_cpu else RAYS_PER_CHUNK_CUDA
        self.chunk_vertices = max(1, per_launch // texels)

    @property
    def count(self) -> int:
        return int(self.vertices.shape[0])

    def trace(self, lo: int, hi: int) -> np.ndarray:
        """Visibility of receivers ``lo:hi``: (hi - lo, R, R) uint8, 1 = visible."""
        r = self.resolution
        items = (hi - lo) * r * r
        out = wp.empty(items, dtype=wp.uint8, device=self.device)

        def inputs(start, stop):
            return [self.bvh.id, self.points, self.normals, self.frames, self.receivers, int(lo), self.dirs,
                    float(self.bvh.offset), int(start), out]

        launch_parallel(ssdf_warp.trace_hemisphere_kernel, items, inputs, self.device)
        return out.numpy().reshape(hi - lo, r, r)


def bake_visibility(scene, frame, resolution: int = 512, vertices=None, device=None, progress=None,
                    offset: float | None = None) -> np.ndarray:
    """Ray-traced binary visibility over each receiver's upper tangent hemisphere.

    Args:
        scene: a :class:`~warpshade.scene.Scene`.
        frame: time code (None: the first frame).
        resolution: side of the square map R (>= 2); one ray per texel centre.
        vertices: receiver vertex indices (None: every vertex).
        device: Warp device.
        progress: None, True (tqdm), a callable ``(done, total)`` or an object with ``update(n)``.
        offset: ray-origin offset in scene units (default :func:`warpshade.geometry.bvh.ray_offset`).

    Returns:
        uint8 array (receiver_count, R, R): 1 where the ray leaves unoccluded, 0 where it hits;
        texel ``[ia, ib]`` as in the module docstring, local tangent frame. It holds R^2 bytes per
        receiver (256 KiB at R = 512): :func:`bake_ssdf` processes receivers in chunks instead.
    """
    tracer = _HemisphereTracer(scene, frame, resolution, vertices, device, offset)
    r = tracer.resolution
    out = np.empty((tracer.count, r, r), dtype=np.uint8)
    bar = _Progress(progress, tracer.count, f"visibility {r}x{r}")
    try:
        for lo in range(0, tracer.count, tracer.chunk_vertices):
            hi = min(tracer.count, lo + tracer.chunk_vertices)
            out[lo:hi] = tracer.trace(lo, hi)
            bar.update(hi - lo)
    finally:
        bar.close()
    return out


# ------------------------------------------------------------------------------------------------
# 2. signed distance


def _as_visibility(visibility) -> np.ndarray:
    v = np.asarray(visibility)
    if v.ndim == 2:
        v = v[None]
    if v.ndim != 3 or v.shape[1] != v.shape[2] or v.shape[1] < 2:
        raise ValueError(f"ssdf: visibility must have shape (V, R, R) or (R, R) with R >= 2, got {v.shape}")
    if v.dtype != np.bool_:
        if not np.issubdtype(v.dtype, np.number) or not np.all(np.isfinite(v)):
            raise ValueError("ssdf: visibility must be boolean or 0/1 numbers")
        if not np.all((v == 0) | (v == 1)):
            raise ValueError("ssdf: visibility must hold only 0 (blocked) and 1 (visible)")
        v = v != 0
    return v


def _boundary_lattice(vis: np.ndarray) -> np.ndarray:
    """Boundary samples of one (R, R) bool map in half-texel lattice units: (n, 2) int64, unique."""
    da = np.argwhere(vis[1:, :] != vis[:-1, :])  # edge between (i, j) and (i + 1, j): a = 2 (i + 1)
    db = np.argwhere(vis[:, 1:] != vis[:, :-1])  # edge between (i, j) and (i, j + 1): b = 2 (j + 1)
    parts = []
    for k in range(3):  # edge start, midpoint, end
        parts.append(np.stack([2 * (da[:, 0] + 1), 2 * da[:, 1] + k], 1))
        parts.append(np.stack([2 * db[:, 0] + k, 2 * (db[:, 1] + 1)], 1))
    lattice = np.concatenate(parts) if parts else np.zeros((0, 2), np.int64)
    if lattice.shape[0] == 0:
        return lattice.astype(np.int64)
    return np.unique(lattice.astype(np.int64), axis=0)


def boundary_points(visibility) -> np.ndarray:
    """The visibility boundary of one fine map, sampled every half texel, on the unit sphere.

    Args:
        visibility: (R, R) bool or 0/1 map (texel layout of the module docstring).

    Returns:
        (n, 3) float64 unit local directions: the midpoints and ends of every texel edge between
        4-neighbours of opposite visibility (none on the horizon unless an edge ends there).
    """
    vis = _as_visibility(visibility)
    if vis.shape[0] != 1:
        raise ValueError("ssdf.boundary_points: pass one (R, R) map")
    r = vis.shape[1]
    lattice = _boundary_lattice(vis[0])
    return concentric_to_hemisphere(lattice / r - 1.0)


def _centre_signs(vis: np.ndarray, supersample: int) -> np.ndarray:
    """+1 / -1 per output texel (V, Ro, Ro): the fine visibility at the output texel centre."""
    s = supersample
    c = s // 2
    if s % 2 == 1:
        inside = vis[:, c::s, c::s]
    else:
        votes = (vis[:, c - 1::s, c - 1::s].astype(np.int8) + vis[:, c::s, c - 1::s] + vis[:, c - 1::s, c::s]
                 + vis[:, c::s, c::s])
        inside = votes >= 2
    return np.where(inside, 1, -1).astype(np.int8)


def _distance_kdtree(lattices, r_fine: int, queries: np.ndarray, signs: np.ndarray, workers: int) -> np.ndarray:
    from scipy.spatial import cKDTree

    out = np.empty(signs.shape, dtype=np.float64)
    bound = math.sqrt(2.0) * (1.0 + 1e-12)  # chord of pi/2: anything further clamps
    for m, lattice in enumerate(lattices):
        if lattice.shape[0] == 0:
            out[m] = SSDF_LIMIT
            continue
        pts = concentric_to_hemisphere(lattice / r_fine - 1.0)
        chord, _ = cKDTree(pts).query(queries, k=1, distance_upper_bound=bound, workers=workers)
        angle = 2.0 * np.arcsin(np.minimum(0.5 * np.where(np.isfinite(chord), chord, 2.0), 1.0))
        out[m] = np.minimum(angle, SSDF_LIMIT)
    return out * signs


def _distance_warp(lattices, r_fine: int, queries: np.ndarray, signs: np.ndarray, device) -> np.ndarray:
    dev = resolve_device(device)
    counts = np.array([lat.shape[0] for lat in lattices], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
    pts = (concentric_to_hemisphere(np.concatenate(lattices) / r_fine - 1.0) if counts.sum()
           else np.zeros((1, 3)))
    q = wp.array(queries.astype(np.float32), dtype=wp.vec3, device=dev)
    b = wp.array(pts.astype(np.float32), dtype=wp.vec3, device=dev)
    o = wp.array(offsets, dtype=wp.int32, device=dev)
    sg_ = wp.array(signs.reshape(-1), dtype=wp.int8, device=dev)
    items = signs.size
    out = wp.empty(items, dtype=float, device=dev)
    launch_parallel(ssdf_warp.boundary_distance_kernel, items, lambda start, stop: [q, b, o, sg_, int(start), out], dev)
    return out.numpy().reshape(signs.shape).astype(np.float64)


def signed_distance(visibility, resolution_out: int = 128, method: str = "auto", device=None,
                    workers: int | None = None) -> np.ndarray:
    """The SSDF (eq. 23) of fine visibility maps, at the texel centres of a coarser map.

    Args:
        visibility: (V, Rf, Rf) or (Rf, Rf) bool or 0/1 (1 = visible), e.g. :func:`bake_visibility`.
        resolution_out: output side Ro; must divide Rf (supersampling ``Rf // Ro``).
        method: ``"kdtree"`` (float64, scipy), ``"warp"`` (brute force on ``device``, float32) or
            ``"auto"`` (k-d tree on the CPU device, Warp on CUDA). On two CPU cores at 512 -> 128
            the k-d tree takes 29 ms per vertex and the Warp kernel 67 ms
            (``benchmarks/bench_ssdf.py``); on CUDA the brute force (16384 queries x ~1500
            boundary samples per vertex, all vertices of a chunk in one launch) has not been
            measured here.
        device: Warp device of the ``"warp"`` method.
        workers: k-d tree query threads (default :func:`warpshade._wp.cpu_workers`).

    Returns:
        float32 (V, Ro, Ro): signed angle in radians to the nearest boundary, positive where the
        output texel centre is visible, clamped to [-pi/2, pi/2]; a map without boundary is
        +pi/2 (all visible) or -pi/2 (all blocked) everywhere. Local tangent frame, texel layout
        of the module docstring.
    """
    vis = _as_visibility(visibility)
    r_fine = vis.shape[1]
    r_out = _check_resolution(resolution_out, "resolution_out")
    if r_fine % r_out != 0:
        raise ValueError(f"ssdf: resolution_out {r_out} must divide the visibility resolution {r_fine}")
    if method not in DISTANCE_METHODS:
        raise ValueError(f"ssdf: method must be one of {DISTANCE_METHODS}, got {method!r}")
    if method == "auto":
        method = "kdtree" if resolve_device(device).is_cpu else "warp"
    signs = _centre_signs(vis, r_fine // r_out).reshape(vis.shape[0], -1)
    queries = texel_directions(r_out)
    lattices = [_boundary_lattice(m) for m in vis]
    if method == "kdtree":
        from .._wp import cpu_workers

        out = _distance_kdtree(lattices, r_fine, queries, signs, cpu_workers() if workers is None else int(workers))
    else:
        out = _distance_warp(lattices, r_fine, queries, signs, device)
    return out.reshape(vis.shape[0], r_out, r_out).astype(np.float32)


def bake_ssdf(scene, frame, resolution: int = 128, supersample: int = 4, vertices=None, device=None, progress=None,
              method: str = "auto", offset: float | None = None, timings: dict | None = None) -> np.ndarray:
    """Ray trace and convert: the SSDF of every receiver (the paper's 512 -> 128 by default).

    Receivers are processed in chunks (a few million rays each), so only one chunk's fine
    visibility is held at a time.

    Args:
        scene, frame, vertices, device, progress, offset: as :func:`bake_visibility`.
        resolution: output side R (>= 2).
        supersample: fine map side = ``resolution * supersample`` (>= 1).
        method: :func:`signed_distance` back end.
        timings: optional dict that receives ``trace_s`` and ``distance_s`` (wall seconds).

    Returns:
        float32 (receiver_count, R, R), radians in [-pi/2, pi/2], local tangent frame.
    """
    r_out = _check_resolution(resolution, "resolution")
    s = _check_resolution(supersample, "supersample", 1)
    tracer = _HemisphereTracer(scene, frame, r_out * s, vertices, device, offset)
    out = np.empty((tracer.count, r_out, r_out), dtype=np.float32)
    bar = _Progress(progress, tracer.count, f"SSDF {r_out * s} -> {r_out}")
    t_trace = t_dist = 0.0
    try:
        for lo in range(0, tracer.count, tracer.chunk_vertices):
            hi = min(tracer.count, lo + tracer.chunk_vertices)
            t0 = time.perf_counter()
            vis = tracer.trace(lo, hi)
            t1 = time.perf_counter()
            out[lo:hi] = signed_distance(vis, r_out, method=method, device=tracer.device)
            t_dist += time.perf_counter() - t1
            t_trace += t1 - t0
            bar.update(hi - lo)
    finally:
        bar.close()
    if timings is not None:
        timings.update(trace_s=t_trace, distance_s=t_dist)
    return out


# ------------------------------------------------------------------------------------------------
# 3. PCA


@dataclass
class SSDFModel:
    """PCA-compressed SSDFs of a set of vertices (eq. 24).

    Attributes:
        mean: mean map, shape (R*R,), float32, radians, flat texel ``ia * R + ib``.
        basis: orthonormal principal maps, shape (N, R*R), float32 (rows).
        coeffs: per-vertex coefficients, shape (V, N), float32 (rows in the order of the maps).
        resolution: map side R.
        error_curve: RMS reconstruction error (radians, over all texels and vertices, float64
            basis) with ``n + 1`` terms at index n, shape (max_terms,), float64, non-increasing.
        error_budget: the RMS budget N was chosen for (radians).
    """

    mean: np.ndarray
    basis: np.ndarray
    coeffs: np.ndarray
    resolution: int
    error_curve: np.ndarray
    error_budget: float = field(default=float("nan"))

    @property
    def terms(self) -> int:
        return int(self.basis.shape[0])

    @property
    def vertex_count(self) -> int:
        return int(self.coeffs.shape[0])

    @property
    def budget_met(self) -> bool:
        return bool(self.error_curve[self.terms - 1] <= self.error_budget)

    @property
    def rms_error(self) -> float:
        """RMS error of the chosen term count (radians)."""
        return float(self.error_curve[self.terms - 1])

    def arrays(self) -> dict:
        """The artifact arrays (what a cache stores)."""
        return {
            "mean": self.mean,
            "basis": self.basis,
            "coeffs": self.coeffs,
            "resolution": np.asarray(self.resolution, np.int64),
            "error_curve": self.error_curve,
            "error_budget": np.asarray(self.error_budget, np.float64),
        }

    @classmethod
    def from_arrays(cls, arrays: dict, vertex_count: int | None = None) -> "SSDFModel":
        """Rebuild from :meth:`arrays`; raises ValueError naming the array for anything that is not
        one: a missing array, wrong shape or dtype, a non-finite value."""
        names = ("mean", "basis", "coeffs", "resolution", "error_curve")
        missing = [n for n in names if n not in arrays]
        if missing:
            raise ValueError(f"ssdf: model arrays lack {missing}")
        r = np.asarray(arrays["resolution"])
        if r.shape != () or not np.issubdtype(r.dtype, np.integer) or int(r) < 2:
            raise ValueError(f"ssdf: resolution must be an integer scalar >= 2, got {r!r}")
        r = int(r)
        texels = r * r
        mean, basis, coeffs = (np.asarray(arrays[n]) for n in ("mean", "basis", "coeffs"))
        curve = np.asarray(arrays["error_curve"])
        for name, a, ndim in (("mean", mean, 1), ("basis", basis, 2), ("coeffs", coeffs, 2)):
            if a.dtype != np.float32 or a.ndim != ndim:
                raise ValueError(f"ssdf: {name} must be a float32 array of {ndim} dims, got {a.dtype} {a.shape}")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"ssdf: {name} contains NaN or infinite values")
        if mean.shape != (texels,):
            raise ValueError(f"ssdf: mean has shape {mean.shape}, resolution {r} needs ({texels},)")
        if basis.shape[1] != texels or basis.shape[0] < 1:
            raise ValueError(f"ssdf: basis has shape {basis.shape}, expected (N >= 1, {texels})")
        if coeffs.shape[1] != basis.shape[0]:
            raise ValueError(f"ssdf: coeffs has shape {coeffs.shape}, expected (V, {basis.shape[0]})")
        if vertex_count is not None and coeffs.shape[0] != vertex_count:
            raise ValueError(f"ssdf: coeffs has {coeffs.shape[0]} rows for {vertex_count} vertices")
        if curve.dtype != np.float64 or curve.ndim != 1 or curve.shape[0] < basis.shape[0]:
            raise ValueError(f"ssdf: error_curve must be float64 of length >= {basis.shape[0]}, got {curve.dtype} {curve.shape}")
        if not np.all(np.isfinite(curve)) or np.any(curve < 0.0):
            raise ValueError("ssdf: error_curve must be finite and >= 0")
        budget = float(np.asarray(arrays.get("error_budget", np.nan)))
        return cls(mean, basis, coeffs, r, curve, budget)

    def reconstruct(self, vertices=None) -> np.ndarray:
        """Decompressed maps (float64 arithmetic), shape (V', R, R), float64, radians (not clamped).

        Args:
            vertices: rows of :attr:`coeffs` (None: all).
        """
        c = self.coeffs if vertices is None else self.coeffs[receiver_indices(vertices, self.vertex_count)]
        maps = self.mean.astype(np.float64) + c.astype(np.float64) @ self.basis.astype(np.float64)
        return maps.reshape(-1, self.resolution, self.resolution)


def _as_maps(maps) -> np.ndarray:
    m = np.asarray(maps)
    if m.ndim != 3 or m.shape[1] != m.shape[2] or m.shape[1] < 2 or m.shape[0] < 1:
        raise ValueError(f"ssdf: maps must have shape (V >= 1, R, R) with R >= 2, got {m.shape}")
    if not np.issubdtype(m.dtype, np.floating) or not np.all(np.isfinite(m)):
        raise ValueError("ssdf: maps must be finite floating-point values")
    return m


def _principal_rows(xc: np.ndarray, k: int, method: str, seed: int) -> np.ndarray:
    """Orthonormal rows (k, T) spanning the leading principal directions of the centred xc (V, T)."""
    if method == "exact":
        _, _, vt = np.linalg.svd(xc, full_matrices=False)
        return vt[:k]
    # randomised range finder with power iterations on the row space (Halko et al. 2011, alg. 4.4)
    rng = np.random.default_rng(seed)
    width = min(k + PCA_OVERSAMPLE, min(xc.shape))
    y, _ = np.linalg.qr(xc @ rng.standard_normal((xc.shape[1], width)))
    for _ in range(PCA_POWER_ITERATIONS):
        z, _ = np.linalg.qr(xc.T @ y)
        y, _ = np.linalg.qr(xc @ z)
    _, _, vt = np.linalg.svd(y.T @ xc, full_matrices=False)
    return vt[:k]


def compress_ssdf(maps, error_budget: float = 0.02, max_terms: int = 64, method: str = "auto",
                  seed: int = 0) -> SSDFModel:
    """PCA of SSDF maps with the term count chosen from an RMS error budget.

    The error with n terms is the exact RMS residual (radians) of projecting the centred maps on
    the first n principal rows, over all texels and vertices:
    ``sqrt((|X - mean|_F^2 - sum_{j<n} |(X - mean) b_j|^2) / (V R^2))``. N is the smallest n in
    1..max_terms within the budget, or max_terms when none is (:attr:`SSDFModel.budget_met`).

    Args:
        maps: (V, R, R) float SSDFs (radians), e.g. :func:`bake_ssdf`.
        error_budget: RMS budget in radians (> 0).
        max_terms: the most terms considered (>= 1); the curve has this length (beyond the rank,
            min(V, R^2), it stays at the last value).
        method: ``"exact"`` (numpy SVD), ``"randomized"`` (range finder, ``seed``) or ``"auto"``
            (exact up to :data:`PCA_EXACT_MAX_ENTRIES` matrix entries).
        seed: random seed of the randomised method.

    Returns:
        :class:`SSDFModel`.
    """
    m = _as_maps(maps)
    budget = float(error_budget) if isinstance(error_budget, (int, float, np.floating, np.integer)) else float("nan")
    if not math.isfinite(budget) or budget <= 0.0:
        raise ValueError(f"ssdf: error_budget must be a finite number > 0 (radians), got {error_budget!r}")
    if isinstance(max_terms, bool) or not isinstance(max_terms, (int, np.integer)) or int(max_terms) < 1:
        raise ValueError(f"ssdf: max_terms must be an integer >= 1, got {max_terms!r}")
    if method not in ("auto", "exact", "randomized"):
        raise ValueError(f"ssdf: method must be 'auto', 'exact' or 'randomized', got {method!r}")
    max_terms = int(max_terms)
    v, r = m.shape[0], m.shape[1]
    x = m.reshape(v, r * r).astype(np.float64)
    mean = x.mean(axis=0)
    xc = x - mean
    k = min(max_terms, v, r * r)
    if method == "auto":
        method = "exact" if x.size <= PCA_EXACT_MAX_ENTRIES else "randomized"
    rows = _principal_rows(xc, k, method, seed)
    rows, _ = np.linalg.qr(rows.T)  # re-orthonormalise (exact projection residuals below)
    rows = rows.T
    proj = xc @ rows.T  # (V, k)
    total = float(np.sum(xc * xc))
    residual = np.maximum(total - np.cumsum(np.sum(proj * proj, axis=0)), 0.0)
    curve = np.sqrt(residual / x.size)
    curve = np.concatenate([curve, np.full(max_terms - k, curve[-1])])
    curve = np.minimum.accumulate(curve)  # guard against round-off upticks
    within = np.flatnonzero(curve[:k] <= budget)
    terms = int(within[0]) + 1 if within.size else k
    return SSDFModel(mean=mean.astype(np.float32), basis=rows[:terms].astype(np.float32),
                     coeffs=proj[:, :terms].astype(np.float32), resolution=r, error_curve=curve, error_budget=budget)


# ------------------------------------------------------------------------------------------------
# 4. lookups


def _dirs(dirs_local, name: str = "dirs_local") -> np.ndarray:
    d = np.asarray(dirs_local, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(f"ssdf: {name} must have shape (P, 3), got {d.shape}")
    n = np.linalg.norm(d, axis=1)
    if not np.all(np.isfinite(d)) or np.any(n == 0.0):
        raise ValueError(f"ssdf: {name} must be finite and nonzero")
    return d / n[:, None]


def bilinear_taps(dirs_local, resolution: int):
    """Bilinear taps between texel centres at the concentric coordinates of local directions.

    Args:
        dirs_local: (P, 3) local directions (normalised here; below the horizon clamped to it).
        resolution: map side R (>= 2).

    Returns:
        ``(texels, weights)``: flat texel indices (P, 4) int64 and weights (P, 4) float64 summing
        to 1 (edge-clamped: outside the outermost texel centres the edge value is held).
    """
    r = _check_resolution(resolution, "resolution")
    ab = hemisphere_to_concentric(_dirs(dirs_local))
    f = (ab + 1.0) * 0.5 * r - 0.5
    i = np.clip(np.floor(f).astype(np.int64), 0, r - 2)
    t = np.clip(f - i, 0.0, 1.0)
    ia, ib, ta, tb = i[:, 0], i[:, 1], t[:, 0], t[:, 1]
    t00 = ia * r + ib
    texels = np.stack([t00, t00 + 1, t00 + r, t00 + r + 1], 1)
    weights = np.stack([(1 - ta) * (1 - tb), (1 - ta) * tb, ta * (1 - tb), ta * tb], 1)
    return texels, weights


def sample_maps(maps, dirs_local) -> np.ndarray:
    """Uncompressed lookup: map p at direction p, bilinear (float64).

    Args:
        maps: (P, R, R) SSDFs, one per direction.
        dirs_local: (P, 3) local directions.

    Returns:
        (P,) float64 radians.
    """
    m = _as_maps(maps)
    d = _dirs(dirs_local)
    if d.shape[0] != m.shape[0]:
        raise ValueError(f"ssdf: {m.shape[0]} maps but {d.shape[0]} directions")
    texels, w = bilinear_taps(d, m.shape[1])
    flat = m.reshape(m.shape[0], -1).astype(np.float64)
    return np.sum(np.take_along_axis(flat, texels, axis=1) * w, axis=1)


def _coeff_rows(model: SSDFModel, coeffs_rows, count: int) -> np.ndarray:
    c = np.asarray(coeffs_rows, dtype=np.float64)
    if c.ndim != 2 or c.shape != (count, model.terms):
        raise ValueError(f"ssdf: coeffs_rows must have shape ({count}, {model.terms}), got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError("ssdf: coeffs_rows contains NaN or infinite values")
    return c


def ssdf_lookup(model: SSDFModel, coeffs_rows, dirs_local) -> np.ndarray:
    """The compressed SSDF (eq. 24) of per-point coefficients at local directions (float64).

    Args:
        model: :class:`SSDFModel`.
        coeffs_rows: (P, N) coefficients per point (a vertex's row of ``model.coeffs`` or any blend).
        dirs_local: (P, 3) local directions.

    Returns:
        (P,) float64 radians (not clamped), bilinear between texel centres.
    """
    d = _dirs(dirs_local)
    c = _coeff_rows(model, coeffs_rows, d.shape[0])
    texels, w = bilinear_taps(d, model.resolution)
    mean = model.mean.astype(np.float64)[texels]  # (P, 4)
    basis = model.basis.astype(np.float64)[:, texels]  # (N, P, 4)
    values = mean + np.einsum("pn,npk->pk", c, basis)
    return np.sum(values * w, axis=1)


def _lobe_args(sharpness, amplitude, count: int):
    lam = np.broadcast_to(np.asarray(sharpness, np.float64), (count,))
    if not np.all(np.isfinite(lam)) or np.any(lam < 0.0):
        raise ValueError("ssdf: sharpness must be finite and >= 0")
    mu = np.broadcast_to(np.asarray(amplitude, np.float64), (count,))
    if not np.all(np.isfinite(mu)):
        raise ValueError("ssdf: amplitude must be finite")
    return lam, mu


def ssdf_product(model: SSDFModel, coeffs_rows, axis_local, sharpness, amplitude=1.0, fh_method: str = "erf") -> np.ndarray:
    """eq. 31: the amplitude of ``G(i; p, lambda, mu) (x) V(i)``, ``mu f_h(Vd(p), lambda) / f_h(pi/2, lambda)``.

    Args:
        model, coeffs_rows: as :func:`ssdf_lookup`.
        axis_local: (P, 3) lobe axes in the local tangent frame.
        sharpness: lambda, scalar or (P,).
        amplitude: mu, scalar or (P,).
        fh_method: :func:`warpshade.basis.sg.hemisphere_integral` method.

    Returns:
        (P,) float64; the product lobe keeps the axis and sharpness.
    """
    theta = ssdf_lookup(model, coeffs_rows, axis_local)
    lam, mu = _lobe_args(sharpness, amplitude, theta.shape[0])
    return mu * sg.visible_fraction(np.clip(theta, -SSDF_LIMIT, SSDF_LIMIT), lam, method=fh_method)


def ssdf_integral(model: SSDFModel, coeffs_rows, axis_local, sharpness, amplitude=1.0, fh_method: str = "erf") -> np.ndarray:
    """eq. 30: ``integral G(i; p, lambda, mu) V(i) di ~ mu f_h(Vd(p), lambda)``, (P,) float64."""
    theta = ssdf_lookup(model, coeffs_rows, axis_local)
    lam, mu = _lobe_args(sharpness, amplitude, theta.shape[0])
    return mu * sg.hemisphere_integral(np.clip(theta, -SSDF_LIMIT, SSDF_LIMIT), lam, method=fh_method)


def _model_arrays(model: SSDFModel, dev):
    return (wp.array(model.mean, dtype=float, device=dev), wp.array(model.basis, dtype=float, device=dev),
            wp.array(model.coeffs, dtype=float, device=dev))


def _blend_args(model: SSDFModel, vertex_ids, weights, count: int):
    ids = np.asarray(vertex_ids)
    if ids.shape != (count, 3) or (ids.size and not np.issubdtype(ids.dtype, np.integer)):
        raise ValueError(f"ssdf: vertex_ids must be integer (P, 3) = ({count}, 3), got {ids.dtype} {ids.shape}")
    if ids.size and (ids.min() < 0 or ids.max() >= model.vertex_count):
        raise ValueError(f"ssdf: vertex_ids must index 0..{model.vertex_count - 1}")
    w = np.asarray(weights, np.float64)
    if w.shape != (count, 3) or not np.all(np.isfinite(w)):
        raise ValueError(f"ssdf: weights must be finite (P, 3) = ({count}, 3), got {w.shape}")
    return ids.astype(np.int32), w.astype(np.float32)


def evaluate_ssdf_warp(model: SSDFModel, vertex_ids, weights, dirs_local, device=None) -> np.ndarray:
    """:func:`~warpshade.transfer.ssdf_warp.ssdf_eval` over a batch (Warp, float32).

    Args:
        model: :class:`SSDFModel`.
        vertex_ids: (P, 3) int rows of ``model.coeffs`` (the same id three times for a vertex).
        weights: (P, 3) barycentric weights.
        dirs_local: (P, 3) local directions.
        device: Warp device.

    Returns:
        (P,) float32 radians.
    """
    dev = resolve_device(device)
    d = _dirs(dirs_local)
    ids, w = _blend_args(model, vertex_ids, weights, d.shape[0])
    mean, basis, coeffs = _model_arrays(model, dev)
    out = wp.empty(d.shape[0], dtype=float, device=dev)
    if d.shape[0]:
        wp.launch(ssdf_warp.ssdf_eval_kernel, dim=d.shape[0],
                  inputs=[mean, basis, coeffs, wp.array(ids, dtype=wp.vec3i, device=dev), wp.array(w, dtype=wp.vec3, device=dev),
                          wp.array(d.astype(np.float32), dtype=wp.vec3, device=dev), model.resolution, model.terms, out],
                  device=dev)
    return out.numpy()


def product_warp(model: SSDFModel, vertex_ids, weights, axes_local, sharpness, device=None):
    """eq. 31 over a batch (Warp): ``(theta_d, fraction)``, each (P,) float32, ``theta_d`` clamped
    to [-pi/2, pi/2] and ``fraction = f_h(theta_d, lambda) / f_h(pi/2, lambda)`` (erf form)."""
    dev = resolve_device(device)
    d = _dirs(axes_local, "axes_local")
    ids, w = _blend_args(model, vertex_ids, weights, d.shape[0])
    lam, _ = _lobe_args(sharpness, 1.0, d.shape[0])
    mean, basis, coeffs = _model_arrays(model, dev)
    theta = wp.empty(d.shape[0], dtype=float, device=dev)
    frac = wp.empty(d.shape[0], dtype=float, device=dev)
    if d.shape[0]:
        wp.launch(ssdf_warp.ssdf_product_kernel, dim=d.shape[0],
                  inputs=[mean, basis, coeffs, wp.array(ids, dtype=wp.vec3i, device=dev), wp.array(w, dtype=wp.vec3, device=dev),
                          wp.array(d.astype(np.float32), dtype=wp.vec3, device=dev),
                          wp.array(lam.astype(np.float32), dtype=float, device=dev), model.resolution, model.terms, theta, frac],
                  device=dev)
    return theta.numpy(), frac.numpy()


# ------------------------------------------------------------------------------------------------
# 5. ray-traced oracle of the lobe-visibility integral


def trace_lobe_visibility(scene, frame, axes_local, sharpness, samples: int = 4096, vertices=None, device=None,
                          seed: int = 0, offset: float | None = None) -> np.ndarray:
    """``integral_{upper hemisphere} G(i; p, lambda, 1) V(i) di`` by ray tracing (the Fig. 7 truth).

    Directions are drawn from the lobe itself (exact inverse CDF of ``exp(lambda (cos - 1))``,
    ``samples`` strata in the polar variable with golden-ratio azimuths, a random spin per item),
    so the estimate is ``F(lambda) * (fraction of samples unoccluded and above the horizon)`` with
    ``F`` the lobe's integral over the sphere; the same origin offset and BVH as the bake.

    Args:
        scene, frame, vertices, device, offset: as :func:`bake_visibility`.
        axes_local: (receiver_count, A, 3) unit lobe axes per receiver, local tangent frame.
        sharpness: (L,) lambdas (> 0).
        samples: rays per (receiver, axis, lambda).
        seed: seed of the spins.

    Returns:
        (receiver_count, A, L) float64.
    """
    dev = resolve_device(device)
    tracer = _HemisphereTracer(scene, frame, 2, vertices, dev, offset)
    axes = np.asarray(axes_local, np.float64)
    if axes.ndim != 3 or axes.shape[0] != tracer.count or axes.shape[2] != 3:
        raise ValueError(f"ssdf: axes_local must have shape ({tracer.count}, A, 3), got {axes.shape}")
    norms = np.linalg.norm(axes, axis=-1, keepdims=True)
    if not np.all(np.isfinite(axes)) or np.any(norms == 0.0):
        raise ValueError("ssdf: axes_local must be finite and nonzero")
    lam = np.asarray(sharpness, np.float64).reshape(-1)
    if lam.size == 0 or not np.all(np.isfinite(lam)) or np.any(lam <= 0.0):
        raise ValueError("ssdf: sharpness must be finite and > 0")
    samples = _check_resolution(samples, "samples", 1)
    a = wp.array((axes / norms).astype(np.float32), dtype=wp.vec3, device=dev)
    lam_wp = wp.array(lam.astype(np.float32), dtype=float, device=dev)
    items = tracer.count * axes.shape[1] * lam.size
    count = wp.zeros(items, dtype=wp.int32, device=dev)
    if items:
        launch_parallel(
            ssdf_warp.lobe_visibility_kernel, items,
            lambda start, stop: [tracer.bvh.id, tracer.points, tracer.normals, tracer.frames, tracer.receivers, a, lam_wp,
                                 samples, float(tracer.bvh.offset), int(seed), int(start), count],
            dev)
    frac = count.numpy().reshape(tracer.count, axes.shape[1], lam.size).astype(np.float64) / samples
    return frac * sg.integral(lam)[None, None, :]
