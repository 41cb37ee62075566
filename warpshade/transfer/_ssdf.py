"""Spherical signed distance functions (SSDFs) for visibility (Wang et al. 2009, sec. 5).

Per receiver vertex, the binary visibility ``V(i)`` of its upper hemisphere is turned into the
signed angular distance to the nearest visibility boundary (eq. 23)::

    Vd(i) = + min_{V(t) = 0} angle(t, i)   where V(i) = 1 (visible: positive),
    Vd(i) = - min_{V(t) = 1} angle(t, i)   where V(i) = 0 (blocked: negative),

compressed over the vertices with PCA (eq. 24) and multiplied with spherical-Gaussian lobes by
the hemisphere reconstruction of eq. 25-31 (``mu f_h(Vd(p), lambda)``).

Maps and frames. A map is a ``R x R`` square over ``[-1, 1]^2`` mapped to the upper hemisphere of
the vertex's tangent frame (:mod:`warpshade.geometry._frames`, rows (t, b, n), ``w_local = F w``)
by the Shirley-Chiu concentric map with the area-preserving lift
(:func:`warpshade.scene._materials.concentric_to_hemisphere`): texel ``[ia, ib]`` is centred at
``((ia + 0.5) / R * 2 - 1, (ib + 0.5) / R * 2 - 1)`` (:func:`warpshade.scene._materials.view_grid`,
row-major, ``a`` first; flat texel index ``ia * R + ib``). Every texel has the same solid angle,
``2 pi / R^2``. The square's edge is the horizon.

Pipeline (the paper's 512 -> 128):

1. :func:`bake_visibility`: one ray per texel centre of the fine ``(R s) x (R s)`` map from
   ``p + offset n`` (the origin offset of :mod:`warpshade.geometry._bvh`) into the world
   direction ``F^T d_local``; 1 = no hit (Warp kernel
   :data:`~warpshade.transfer._ssdf_warp.trace_hemisphere_kernel`).
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
4. :func:`._ssdf_pca.compress_ssdf`: PCA of the ``(V, R*R)`` maps, the term count from an RMS error budget
   in radians (:class:`._ssdf_pca.SSDFModel`).
5. :func:`._ssdf_products.ssdf_lookup` / :func:`~warpshade.transfer._ssdf_warp.ssdf_eval`: bilinear between texel
   centres at the concentric coordinates of a local direction (edge-clamped; directions below the
   horizon are clamped to it). :func:`._ssdf_products.ssdf_product` /
   :func:`._ssdf_products.ssdf_integral`: eq. 31 / eq. 30.

Validation oracle: :func:`trace_lobe_visibility` ray traces ``integral G(i; p, lambda, 1) V(i)``
over the upper hemisphere by sampling the lobe itself (independent of the maps).

This module bakes the maps (steps 1-3) and holds the oracle; :mod:`._ssdf_pca` compresses them,
:mod:`._ssdf_products` looks them up and multiplies them with SG lobes.
"""

from __future__ import annotations

import math
import time

import numpy as np

from .._wp import launch_parallel, resolve_device, wp
from ..basis import sg
from ..geometry._bvh import Visibility
from ..geometry._frames import TangentFrames
from ..scene._materials import concentric_to_hemisphere, view_grid
from . import _ssdf_warp as ssdf_warp
from ._raytrace import receiver_indices

__all__ = [
    "DISTANCE_METHODS",
    "boundary_points",
    "check_resolution",
    "texel_directions",
    "texel_diameter",
]

#: |SSDF| is clamped to this (radians): the range the hemisphere product of eq. 30 uses.
SSDF_LIMIT = 0.5 * math.pi
#: ``signed_distance`` back ends.
DISTANCE_METHODS = ("auto", "kdtree", "warp")
#: Rays per launch of a bake: ~4 M on the CPU (a fraction of a second, 4 MB of visibility bytes),
#: 32 M on CUDA.
RAYS_PER_CHUNK_CPU = 1 << 22
RAYS_PER_CHUNK_CUDA = 1 << 25


# ------------------------------------------------------------------------------------------------
# small helpers


def check_resolution(value, name: str, minimum: int = 2) -> int:
    """``value`` as an int >= ``minimum`` (ValueError naming ``name`` otherwise)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) < minimum:
        raise ValueError(f"ssdf: {name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def texel_directions(resolution: int) -> np.ndarray:
    """Local directions of the texel centres of a ``resolution^2`` map, (R*R, 3) float64, row-major."""
    return view_grid(check_resolution(resolution, "resolution"))


def texel_diameter(resolution: int) -> float:
    """The largest angular diameter (radians) of a texel of a ``resolution^2`` map: the largest
    angle between two corners of one texel (the concentric map stretches texels near the
    diagonals of the square). The staircase boundary of a fine map lies within this of the true
    boundary."""
    r = check_resolution(resolution, "resolution", 1)
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
            from ..tasks import progress_bar

            self._bar = progress_bar(total=self.total, desc=desc, unit="vertex", leave=False)
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
        self.resolution = check_resolution(resolution, "resolution")
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
        offset: ray-origin offset in scene units (default :func:`warpshade.geometry._bvh.ray_offset`).

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
    r_out = check_resolution(resolution_out, "resolution_out")
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
    r_out = check_resolution(resolution, "resolution")
    s = check_resolution(supersample, "supersample", 1)
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
# ray-traced oracle of the lobe-visibility integral


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
    samples = check_resolution(samples, "samples", 1)
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
