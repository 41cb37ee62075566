"""Variational sphere-set construction (see :mod:`warpshade.geometry.spheres`).

The construction of Ren et al. 2006, section 6.2 (after Wang et al. 2006):

1. the solid T is discretised into *surface samples* (vertices, triangle midpoints and a
   barycentric lattice on triangles larger than the grid cell) and *interior samples* (grid
   cell centres inside T, every ``interior_step``-th cell), linked into a k-nearest-neighbour
   graph;
2. Lloyd iterations alternate
   * flood-fill clustering: a priority queue grows clusters away from the sphere centres; a
     popped (sample, cluster) pair costs the outside volume of the cluster sphere extended
     to include the sample, the cheapest pair wins, and the sample's neighbours are queued;
   * centre update: per cluster, Powell's method moves the centre to minimise the outside
     volume of the smallest sphere about it that bounds the cluster;
3. cluster teleportation: the worst cluster is split at its farthest-apart sample pair and
   the cluster sharing most of its volume with others is deleted; the perturbed state is
   re-clustered and kept only if the total outside volume drops.

Outside volume inside the loop (the *grid estimator*). T is voxelised once on a grid of
spacing ``h``: a Warp kernel computes the signed distance ``d_j`` of every cell centre
(winding-number sign), giving a fractional occupancy ``o_j = clamp(1/2 - d_j / h, 0, 1)``.
The volume of T inside a sphere (c, r) is ``h^3 sum_j o_j clamp(1/2 + (r - |x_j - c|)/h, 0, 1)``
and ``V(S - T) = 4/3 pi r^3 - V(S n T)``. Both ramps make it continuous in (c, r), which Powell
needs; its error is O(h) relative to the area of the surface inside the sphere (tested
against analytic volumes in tests/test_spheres.py). Reported errors use the independent
quasi-Monte Carlo estimator of :func:`._core.outside_volume`.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np

from ..._wp import launch_parallel, resolve_device, wp
from . import _kernels as K

#: Relative tolerance for merging coincident vertices before the closedness test (fraction of
#: the bounding-box diagonal): split normals / UV seams duplicate positions bit-for-bit or to
#: float32 round-off, never by more than this.
MERGE_TOLERANCE_RELATIVE = 1.0e-7

#: A closed mesh enclosing less than this fraction of its bounding-box volume is refused.
MIN_VOLUME_FRACTION = 1.0e-6

#: Radii are grown by this fraction (plus the same fraction of the mesh diagonal) after the
#: fit, so float32 coverage tests of the exact-bound samples do not fail by round-off.
RADIUS_PAD_RELATIVE = 2.0e-6

#: The clustering keeps one surface sample per cube of this side (in grid cells); the rest
#: join their clusters afterwards (see fit_spheres).
CLUSTER_SAMPLE_SPACING = 1.0

#: Classification launches (signed distances, QMC samples) of fewer items run as one launch;
#: larger ones are split over the CPU thread pool (:func:`warpshade._wp.launch_parallel`).
SPLIT_MIN = 4096

#: Centre-update launches with fewer candidates run unsplit: their cost is launch overhead,
#: and splitting them over the 2-core pool measured no faster on the bunny (35.0 s vs 36.5 s).
CLUSTER_SPLIT_MIN = 256

#: Neighbours per sample in the flood-fill graph.
FLOOD_NEIGHBOURS = 8

#: Unit-ball samples per sphere used to estimate overlap ratios for teleportation.
OVERLAP_SAMPLES = 256


# ---- the solid --------------------------------------------------------------------------
@dataclass
class Solid:
    """A validated solid: classification mesh on the device plus facts about it.

    Attributes:
        name: mesh name used in every error message.
        points: the caller's points (V, 3) float64 (unchanged).
        faces: the caller's faces (F, 3) int64 (unchanged).
        merged_points / merged_faces: vertices merged by position, degenerate faces dropped and
            faces oriented outward (closed meshes); what the classification BVH is built on.
        merged_index: original vertex -> merged vertex, (V,) int64.
        closed: whether the merged mesh is watertight.
        shell_thickness: half-thickness of the solid around an open surface; 0 when closed.
        diagonal: bounding-box diagonal of the points.
    """

    name: str
    points: np.ndarray
    faces: np.ndarray
    merged_points: np.ndarray
    merged_faces: np.ndarray
    merged_index: np.ndarray
    closed: bool
    shell_thickness: float
    diagonal: float
    device: object
    _wp_points: object = None
    _wp_faces: object = None
    _mesh: object = None

    @property
    def mesh_id(self):
        if self._mesh is None:
            self._wp_points = wp.array(self.merged_points.astype(np.float32), dtype=wp.vec3, device=self.device)
            self._wp_faces = wp.array(self.merged_faces.astype(np.int32).ravel(), dtype=wp.int32, device=self.device)
            self._mesh = wp.Mesh(points=self._wp_points, indices=self._wp_faces, support_winding_number=True)
        return self._mesh.id

    def signed_distance(self, x: np.ndarray) -> np.ndarray:
        """Signed distance (negative inside) of points (N, 3) to the solid, float32 kernel."""
        x = np.ascontiguousarray(x, np.float32).reshape(-1, 3)
        xs = wp.array(x, dtype=wp.vec3, device=self.device)
        out = wp.empty(x.shape[0], dtype=wp.float32, device=self.device)
        mid = self.mesh_id
        th = float(self.shell_thickness)
        launch_parallel(K.signed_distance_kernel, x.shape[0], lambda start, stop: [mid, xs, th, start, out], self.device,
                        min_count=SPLIT_MIN)
        return out.numpy().astype(np.float64)


def make_solid(points, faces, name: str, open_mesh: str = "error", shell_thickness: float | None = None, device=None) -> Solid:
    """Validate a triangle mesh and build its classification solid (see :class:`Solid`)."""
    dev = resolve_device(device)
    if open_mesh not in ("error", "shell"):
        raise ValueError(f"mesh {name}: open_mesh must be 'error' or 'shell', got {open_mesh!r}")
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 4:
        raise ValueError(f"mesh {name}: points must have shape (vertex_count >= 4, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(p), axis=1)))
        raise ValueError(f"mesh {name}: {bad} point(s) are NaN or infinite")
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise ValueError(f"mesh {name}: faces must have shape (triangle_count > 0, 3), got {f.shape}")
    f = f.astype(np.int64)
    if f.min() < 0 or f.max() >= p.shape[0]:
        raise ValueError(f"mesh {name}: face indices {int(f.min())}..{int(f.max())} outside 0..{p.shape[0] - 1}")
    lo, hi = p.min(axis=0), p.max(axis=0)
    diagonal = float(np.linalg.norm(hi - lo))
    if not diagonal > 0.0:
        raise ValueError(f"mesh {name}: all points coincide (zero extent)")

    # merge coincident vertices (split normals, UV seams) so closedness is a topology question
    tol = MERGE_TOLERANCE_RELATIVE * diagonal
    keys = np.round((p - lo) / tol).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    mp = p[first]
    mf = inverse[f]
    mf = mf[(mf[:, 0] != mf[:, 1]) & (mf[:, 1] != mf[:, 2]) & (mf[:, 0] != mf[:, 2])]
    if mf.shape[0] == 0:
        raise ValueError(f"mesh {name}: every triangle is degenerate")

    import trimesh

    tm = trimesh.Trimesh(mp, mf, process=False, validate=False)
    closed = bool(tm.is_watertight)
    if closed:
        with np.errstate(invalid="ignore", divide="ignore"):  # flat meshes: centre of mass 0/0
            trimesh.repair.fix_normals(tm, multibody=True)
            volume = abs(float(tm.volume))
        mf = np.asarray(tm.faces, dtype=np.int64)
        box = float(np.prod(np.maximum(hi - lo, 1e-12 * diagonal)))
        if not volume > MIN_VOLUME_FRACTION * max(box, diagonal**3 * 1e-9):
            raise ValueError(
                f"mesh {name}: closed but encloses (almost) zero volume ({volume:.3g}); "
                "a flat or collapsed mesh cannot be bounded by blocker spheres"
            )
        thickness = 0.0
    else:
        if open_mesh == "error":
            boundary = _boundary_edge_count(mf)
            raise ValueError(
                f"mesh {name}: not closed ({boundary} boundary edge(s)); sphere sets bound solids. "
                "Pass open_mesh='shell' (with shell_thickness) to bound a thickened shell instead"
            )
        thickness = float(shell_thickness) if shell_thickness is not None else 0.01 * diagonal
        if not thickness > 0.0:
            raise ValueError(f"mesh {name}: shell_thickness must be > 0, got {shell_thickness!r}")
    return Solid(
        name=name,
        points=p,
        faces=f,
        merged_points=mp,
        merged_faces=mf,
        merged_index=inverse.astype(np.int64),
        closed=closed,
        shell_thickness=thickness,
        diagonal=diagonal,
        device=dev,
    )


def _boundary_edge_count(faces: np.ndarray) -> int:
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return int(np.count_nonzero(counts == 1))


# ---- discretisation ---------------------------------------------------------------------
class Discretisation:
    """Occupancy grid, samples and neighbour graph of a :class:`Solid` (see module docstring).

    Attributes:
        h: grid spacing (scene units).
        origin: centre of cell (0, 0, 0), (3,).
        occupancy: fractional occupancy per cell, shape grid_shape, float64 in [0, 1].
        volume: grid estimate of the solid's volume, ``h^3 sum occupancy``.
        samples: all samples, surface first, (N, 3) float64.
        surface: every surface sample, (Ns, 3) float64, as barycentric points ``sample_face``
            (Ns,) / ``sample_bary`` (Ns, 3) of the caller's faces.
        surface_clustered: which surface samples take part in the clustering, (Ns,) bool.
        samples: the clustered samples: clustered surface samples, then interior samples.
        surface_count: number of clustered surface samples (rows 0 .. surface_count - 1).
        interior: interior samples, (Ni, 3).
        neighbours: k-nearest-neighbour lists, (N, FLOOD_NEIGHBOURS) int64.
    """

    def __init__(self, solid: Solid, grid_cells: int = 120_000, interior_step: int = 3):
        if grid_cells < 1000:
            raise ValueError(f"mesh {solid.name}: grid_cells must be >= 1000, got {grid_cells}")
        if interior_step < 1:
            raise ValueError(f"mesh {solid.name}: interior_step must be >= 1, got {interior_step}")
        self.solid = solid
        p = solid.points
        lo, hi = p.min(axis=0), p.max(axis=0)
        ext = np.maximum(hi - lo, 1e-3 * solid.diagonal) + 2.0 * solid.shell_thickness
        h = float(np.cbrt(np.prod(ext) / grid_cells))
        h = min(h, float(ext.max()) / 24.0)  # thin or flat boxes: keep >= 24 cells along the longest side
        pad = 2.0 * h + solid.shell_thickness
        shape = np.maximum(np.ceil((hi - lo + 2 * pad) / h).astype(int), 4)
        origin = (lo + hi) / 2 - (shape - 1) * h / 2
        self.h = h
        self.origin = origin
        self.shape = tuple(int(s) for s in shape)
        self.axes = [origin[a] + h * np.arange(shape[a]) for a in range(3)]
        gx, gy, gz = np.meshgrid(*self.axes, indexing="ij")
        centres = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
        sd = solid.signed_distance(centres).reshape(self.shape)
        self.signed_distance = sd
        self.occupancy = np.clip(0.5 - sd / h, 0.0, 1.0)
        self.volume = h**3 * float(self.occupancy.sum())
        if not np.any(sd < 0.0):
            raise ValueError(
                f"mesh {solid.name}: no grid cell lies inside the solid (grid spacing {h:.3g}); the mesh "
                "encloses (almost) no volume or is thinner than the grid -- raise grid_cells"
            )
        self.occupancy_device = wp.array(self.occupancy.astype(np.float32), dtype=wp.float32, device=solid.device)
        prefix = np.zeros(self.shape[:2] + (self.shape[2] + 1,), dtype=np.float64)
        prefix[:, :, 1:] = np.cumsum(self.occupancy, axis=2)
        self.occupancy_prefix_device = wp.array(prefix.astype(np.float32), dtype=wp.float32, device=solid.device)
        occ_mask = self.occupancy > 0.0
        self.occupied_points = centres[occ_mask.ravel()]
        self.occupied_weights = self.occupancy.ravel()[occ_mask.ravel()]

        # interior samples: inside cells on a coarser lattice
        sel = np.zeros(self.shape, dtype=bool)
        off = interior_step // 2
        sel[off::interior_step, off::interior_step, off::interior_step] = True
        interior = centres[((sd < 0.0) & sel).ravel()]
        if interior.shape[0] == 0:  # thin solids: every inside cell
            interior = centres[(sd < 0.0).ravel()]
        self.interior = interior

        face, bary = surface_samples(p, solid.faces, 2.0 * h)
        surface = np.einsum("nk,nkj->nj", bary, p[solid.faces[face]])
        self.sample_face = face
        self.sample_bary = bary
        self.surface = surface
        # The clustering sees one surface sample per grid cell (vertices first): finer
        # samples add nothing at the resolution of the outside-volume grid. The others are
        # covered afterwards by growing the sphere that needs the least growth.
        keys = np.floor((surface - origin) / (CLUSTER_SAMPLE_SPACING * h)).astype(np.int64)
        _, first = np.unique(keys, axis=0, return_index=True)
        self.surface_clustered = np.zeros(surface.shape[0], dtype=bool)
        self.surface_clustered[first] = True
        self.surface_count = int(np.count_nonzero(self.surface_clustered))
        self.samples = np.concatenate([surface[self.surface_clustered], interior])
        from scipy.spatial import cKDTree

        self.kdtree = cKDTree(self.samples)
        k = min(FLOOD_NEIGHBOURS + 1, self.samples.shape[0])
        _, nb = self.kdtree.query(self.samples, k=k)
        self.neighbours = np.asarray(nb, dtype=np.int64)[:, 1:]
        # table resolution of the per-centre outside-volume function g(r)
        self.table_step = h / 4.0
        self.table_radius = float(np.linalg.norm(np.asarray(self.shape) * h)) + 2 * h

    # -- grid estimator --
    def inside_volume(self, centre: np.ndarray, radius: float) -> float:
        """Volume of the solid inside the sphere (grid estimator), scene units cubed."""
        h = self.h
        reach = radius + h
        idx = []
        for a in range(3):
            i0 = max(0, math.floor((centre[a] - reach - self.origin[a]) / h))
            i1 = min(self.shape[a], math.ceil((centre[a] + reach - self.origin[a]) / h) + 1)
            if i1 <= i0:
                return 0.0
            idx.append((i0, i1))
        occ = self.occupancy[idx[0][0] : idx[0][1], idx[1][0] : idx[1][1], idx[2][0] : idx[2][1]]
        dx = (self.axes[0][idx[0][0] : idx[0][1]] - centre[0]) ** 2
        dy = (self.axes[1][idx[1][0] : idx[1][1]] - centre[1]) ** 2
        dz = (self.axes[2][idx[2][0] : idx[2][1]] - centre[2]) ** 2
        d = np.sqrt(dx[:, None, None] + dy[None, :, None] + dz[None, None, :])
        s = np.clip(0.5 + (radius - d) / h, 0.0, 1.0)
        return h**3 * float(np.sum(occ * s))

    def outside_volume(self, centre: np.ndarray, radius: float) -> float:
        """V(S - T) of one sphere (grid estimator), clamped at 0."""
        return max(0.0, 4.0 / 3.0 * math.pi * radius**3 - self.inside_volume(centre, radius))

    def outside_tables(self, centres: np.ndarray) -> np.ndarray:
        """g_i(r) = V(S(c_i, r) - T) tabulated at r = k * table_step, shape (S, table_len).

        Monotone non-decreasing in r (exactly so for the true volumes; enforced here against
        the discretisation's wiggles), so ``g_i(max(r, d)) = max(g_i(r), g_i(d))``.
        """
        delta = self.table_step
        n = math.ceil(self.table_radius / delta) + 2
        r = delta * np.arange(n)
        tables = np.empty((centres.shape[0], n))
        width = round(self.h / delta)
        kernel = np.full(width, 1.0 / width)
        for i, c in enumerate(centres):
            d = np.linalg.norm(self.occupied_points - c, axis=1)
            hist = np.bincount(np.minimum((d / delta).astype(np.int64), n - 1), weights=self.occupied_weights, minlength=n)
            cum = np.cumsum(hist)
            # ramp of width h = moving average of the cumulative count over h
            smooth = np.convolve(np.concatenate([np.zeros(width // 2), cum, np.full(width, cum[-1])]), kernel, "valid")[:n]
            tables[i] = np.maximum.accumulate(np.maximum(0.0, 4.0 / 3.0 * math.pi * r**3 - self.h**3 * smooth))
        return tables


def surface_samples(points: np.ndarray, faces: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Surface samples as (face index, barycentric) pairs: vertices, midpoints and a lattice.

    Every vertex (once, through one of its faces), every triangle midpoint, and on triangles
    with an edge longer than ``spacing`` the barycentric lattice of step ``1/m``,
    ``m = ceil(longest edge / spacing)``, so no point of the surface is further than about
    ``spacing`` from a sample.

    Returns:
        face (N,) int64 and bary (N, 3) float64.
    """
    f = faces
    v_face = np.full(points.shape[0], -1, dtype=np.int64)
    v_corner = np.zeros(points.shape[0], dtype=np.int64)
    for k in range(3):
        fresh = v_face[f[:, k]] < 0
        v_face[f[fresh, k]] = np.nonzero(fresh)[0]
        v_corner[f[fresh, k]] = k
    used = v_face >= 0
    face_list = [v_face[used]]
    bary_list = [np.eye(3)[v_corner[used]]]
    face_list.append(np.arange(f.shape[0]))
    bary_list.append(np.full((f.shape[0], 3), 1.0 / 3.0))
    tri = points[f]
    edge = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    m_all = np.ceil(edge / spacing).astype(np.int64)
    for m in np.unique(m_all[m_all >= 2]):
        ids = np.nonzero(m_all == m)[0]
        i, j = np.meshgrid(np.arange(m + 1), np.arange(m + 1), indexing="ij")
        keep = i + j <= m
        a = i[keep] / m
        b = j[keep] / m
        lattice = np.stack([1 - a - b, a, b], axis=1)
        # drop the three corners (already vertex samples)
        lattice = lattice[np.max(lattice, axis=1) < 1.0 - 1e-12]
        face_list.append(np.repeat(ids, lattice.shape[0]))
        bary_list.append(np.tile(lattice, (ids.shape[0], 1)))
    return np.concatenate(face_list), np.concatenate(bary_list)


# ---- Lloyd construction -----------------------------------------------------------------
def flood_fill(disc: Discretisation, centres: np.ndarray) -> np.ndarray:
    """Flood-fill clustering of every sample to one of the spheres (see module docstring).

    Returns:
        cluster index per sample, (N,) int64; every cluster gets at least its seed sample.
    """
    x = disc.samples
    n = x.shape[0]
    s_count = centres.shape[0]
    tables = disc.outside_tables(centres)
    inv_step = 1.0 / disc.table_step
    last = tables.shape[1] - 2
    tables_l = tables.tolist()
    x_l = [tuple(r) for r in x.tolist()]
    c_l = [tuple(r) for r in centres.tolist()]
    dist = math.dist

    def cost_of(p: int, i: int) -> tuple[float, float]:
        """(g_i(d), d) for sample p and sphere i, d = |x_p - c_i|, g_i linearly interpolated."""
        d = dist(x_l[p], c_l[i])
        pos = d * inv_step
        k = int(pos)
        if k > last:
            k, pos = last, last + 1.0
        t = tables_l[i]
        return t[k] + (pos - k) * (t[k + 1] - t[k]), d

    nbrs = disc.neighbours.tolist()
    assigned = [-1] * n
    radius_cost = [0.0] * s_count  # g_i(r_i)
    heap: list = []
    # distinct seeds: each sphere starts at the nearest sample not already a seed
    taken = set()
    _, cand = disc.kdtree.query(centres, k=min(n, s_count + 1))
    cand = np.atleast_2d(cand)
    for i in range(s_count):
        seed = next(int(c) for c in cand[i] if int(c) not in taken)
        taken.add(seed)
        heap.append((0.0, 0.0, seed, i))
    heapq.heapify(heap)
    remaining = n
    push, pop = heapq.heappush, heapq.heappop
    while remaining:
        if not heap:  # a component of the graph no flood reached: seed it by cost
            p = assigned.index(-1)
            options = [(max(radius_cost[j], cost_of(p, j)[0]), cost_of(p, j)[1], p, j) for j in range(s_count)]
            push(heap, min(options))
        c, d, p, i = pop(heap)
        if assigned[p] >= 0:
            continue
        rc = radius_cost[i]
        if rc > c:
            push(heap, (rc, d, p, i))  # the cluster grew since this pair was queued
            continue
        assigned[p] = i
        remaining -= 1
        if c > rc:
            radius_cost[i] = c
        for q in nbrs[p]:
            if assigned[q] < 0:
                cq, dq = cost_of(q, i)
                push(heap, (max(radius_cost[i], cq), dq, q, i))
    return np.asarray(assigned, dtype=np.int64)


def bounding_radius(points: np.ndarray, centre: np.ndarray) -> float:
    return float(np.sqrt(np.max(np.sum((points - centre) ** 2, axis=1))))


def hull_points(points: np.ndarray) -> np.ndarray:
    """Convex-hull vertices of a point cluster (all points when the hull is degenerate)."""
    if points.shape[0] > 16:
        try:
            from scipy.spatial import ConvexHull

            return points[ConvexHull(points).vertices]  # the farthest point is a hull vertex
        except Exception:  # noqa: BLE001, S110 -- qhull raises several types on coplanar / collinear clusters
            pass
    return points


def update_centre(disc: Discretisation, points: np.ndarray, centre: np.ndarray, max_evaluations: int = 400) -> tuple[np.ndarray, float, float]:
    """Float64 mirror of one centre update: scipy's Powell on the NumPy grid estimator.

    Minimises the outside volume of the smallest sphere about the centre that bounds
    ``points``. Returns (centre (3,), radius, outside volume), never worse than the start.
    """
    from scipy.optimize import minimize

    pts = hull_points(points)

    def objective(c):
        return disc.outside_volume(c, bounding_radius(pts, c))

    f0 = objective(centre)
    if pts.shape[0] == 1:
        return pts[0].copy(), 0.0, 0.0
    res = minimize(
        objective,
        centre,
        method="Powell",
        options={"xtol": 0.05 * disc.h, "ftol": 1e-5, "maxfev": max_evaluations, "direc": np.eye(3) * disc.h},
    )
    c = np.asarray(res.x, dtype=np.float64)
    fc = objective(c)
    if not fc <= f0:
        c, fc = centre.copy(), f0
    return c, bounding_radius(pts, c), fc


class ClusterObjective:
    """The centre-update objective of many clusters, evaluated in one Warp launch.

    ``evaluate(cluster, centres)`` returns, for each (cluster index, candidate centre) pair, the
    radius of the smallest sphere about the centre bounding the cluster and its outside volume
    (grid estimator, :func:`._kernels.cluster_outside_volume_kernel`).
    """

    def __init__(self, disc: Discretisation, clusters: list[np.ndarray]):
        self.disc = disc
        dev = disc.solid.device
        hulls = [hull_points(c) for c in clusters]
        start = np.zeros(len(hulls) + 1, dtype=np.int32)
        start[1:] = np.cumsum([h.shape[0] for h in hulls])
        self.device = dev
        self.hull_start = wp.array(start, dtype=wp.int32, device=dev)
        self.hull_points = wp.array(np.concatenate(hulls).astype(np.float32), dtype=wp.vec3, device=dev)
        self.origin = wp.vec3(*[float(v) for v in disc.origin])
        self.evaluations = 0

    def evaluate(self, cluster: np.ndarray, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = cluster.shape[0]
        dev = self.device
        cl = wp.array(cluster.astype(np.int32), dtype=wp.int32, device=dev)
        cand = wp.array(np.ascontiguousarray(centres, np.float32).reshape(-1, 3), dtype=wp.vec3, device=dev)
        radius = wp.empty(n, dtype=wp.float32, device=dev)
        outside = wp.empty(n, dtype=wp.float32, device=dev)
        occ, prefix = self.disc.occupancy_device, self.disc.occupancy_prefix_device
        origin, h = self.origin, float(self.disc.h)
        launch_parallel(
            K.cluster_outside_volume_kernel,
            n,
            lambda start, stop: [occ, prefix, origin, h, self.hull_start, self.hull_points, cl, cand, start, radius, outside],
            dev,
            min_count=CLUSTER_SPLIT_MIN,
        )
        self.evaluations += n
        return radius.numpy().astype(np.float64), np.maximum(outside.numpy().astype(np.float64), 0.0)


_GOLDEN = 0.5 * (math.sqrt(5.0) - 1.0)
#: Trial steps (in units of the direction vector) that bracket each line minimum.
_BRACKET = np.array([-4.0, -2.0, -1.0, 0.0, 1.0, 2.0, 4.0])


def _line_search(objective: ClusterObjective, ids: np.ndarray, x: np.ndarray, fx: np.ndarray, d: np.ndarray, golden_steps: int):
    """Batched line minimisation along d: a bracketing scan, then golden-section refinement."""
    n = x.shape[0]
    t = _BRACKET
    trial = x[:, None, :] + t[None, :, None] * d[:, None, :]
    _, f = objective.evaluate(np.repeat(ids, t.size), trial.reshape(-1, 3))
    f = f.reshape(n, t.size)
    f[:, 3] = fx  # t = 0 is the current point
    b = np.argmin(f, axis=1)
    best_t = t[b]
    best_f = f[np.arange(n), b]
    lo = t[np.maximum(b - 1, 0)]
    hi = t[np.minimum(b + 1, t.size - 1)]
    c1 = hi - _GOLDEN * (hi - lo)
    c2 = lo + _GOLDEN * (hi - lo)
    _, f12 = objective.evaluate(np.concatenate([ids, ids]), np.concatenate([x + c1[:, None] * d, x + c2[:, None] * d]))
    f1, f2 = f12[:n], f12[n:]
    for _ in range(golden_steps):
        left = f1 < f2  # the minimum lies in [lo, c2], else in [c1, hi]
        hi_n = np.where(left, c2, hi)
        lo_n = np.where(left, lo, c1)
        c1_n = np.where(left, hi_n - _GOLDEN * (hi_n - lo_n), c2)
        c2_n = np.where(left, c1, lo_n + _GOLDEN * (hi_n - lo_n))
        probe = np.where(left, c1_n, c2_n)
        _, fp = objective.evaluate(ids, x + probe[:, None] * d)
        f1, f2 = np.where(left, fp, f2), np.where(left, f1, fp)
        lo, hi, c1, c2 = lo_n, hi_n, c1_n, c2_n
    for cand_t, cand_f in ((c1, f1), (c2, f2)):
        better = cand_f < best_f
        best_t = np.where(better, cand_t, best_t)
        best_f = np.where(better, cand_f, best_f)
    return x + best_t[:, None] * d, best_f


def batched_powell(objective: ClusterObjective, ids: np.ndarray, x0: np.ndarray, step, sweeps: int = 3, golden_steps: int = 8, ftol: float = 1e-4):
    """Powell's conjugate-direction method, run in lockstep for many clusters.

    Each sweep line-minimises along the current three directions and then along the sweep's
    net displacement, which replaces the direction of largest decrease (Powell 1964 / Press
    et al. 10.7). Line minimisations are batched over clusters (:func:`_line_search`). The
    result is never worse than the start.

    Args:
        step: initial direction length per cluster, scalar or (n,).

    Returns:
        (centres (n, 3), outside volumes (n,)).
    """
    n = x0.shape[0]
    x = np.array(x0, dtype=np.float64)
    _, fx = objective.evaluate(ids, x)
    step = np.broadcast_to(np.asarray(step, np.float64), (n,))
    dirs = np.eye(3)[None] * step[:, None, None]
    for _ in range(sweeps):
        x_start, f_start = x.copy(), fx.copy()
        gains = np.zeros((n, 3))
        for k in range(3):
            x, f_new = _line_search(objective, ids, x, fx, dirs[:, k], golden_steps)
            gains[:, k] = fx - f_new
            fx = f_new
        delta = x - x_start
        length = np.linalg.norm(delta, axis=1)
        moved = length > 1e-3 * step
        dvec = np.where(moved[:, None], delta / np.maximum(length, 1e-30)[:, None] * step[:, None], dirs[:, 0])
        x, fx = _line_search(objective, ids, x, fx, dvec, golden_steps)
        worst = np.argmax(gains, axis=1)
        dirs[moved, worst[moved]] = dvec[moved]
        if np.all(f_start - fx <= ftol * np.maximum(np.abs(f_start), 1e-30)):
            break
    return x, fx


def update_centres(disc: Discretisation, clusters: list[np.ndarray], centres: np.ndarray, sweeps: int) -> np.ndarray:
    """Centre update of many clusters at once; returns the new centres (n, 3).

    Powell starts from the best of the current centre, the cluster's mean and the centre of
    its bounding box (a freshly seeded cluster's centre is one of its samples, far from where
    the optimum usually is), with initial steps of a tenth of the cluster's extent (at least
    one grid cell).
    """
    objective = ClusterObjective(disc, clusters)
    n = len(clusters)
    ids = np.arange(n)
    means = np.array([c.mean(axis=0) for c in clusters])
    boxes = np.array([(c.min(axis=0) + c.max(axis=0)) / 2 for c in clusters])
    starts = np.stack([centres, means, boxes], axis=1)  # (n, 3, 3)
    _, f = objective.evaluate(np.repeat(ids, 3), starts.reshape(-1, 3))
    best = np.argmin(f.reshape(n, 3), axis=1)
    x0 = starts[ids, best]
    extent = np.array([np.linalg.norm(c.max(axis=0) - c.min(axis=0)) for c in clusters])
    step = np.maximum(disc.h, 0.1 * extent)
    x, _ = batched_powell(objective, ids, x0, step, sweeps=sweeps)
    return x


@dataclass
class LloydState:
    centres: np.ndarray
    radii: np.ndarray
    errors: np.ndarray
    labels: np.ndarray

    @property
    def error(self) -> float:
        return float(self.errors.sum())


def lloyd(disc: Discretisation, centres: np.ndarray, iterations: int, tolerance: float, sweeps: int, cache: dict) -> LloydState:
    """Alternate flood-fill clustering and Powell centre updates until E stops dropping.

    Updates are cached by cluster membership: a cluster whose members did not change keeps its
    optimised centre. All changed clusters are updated together (:func:`batched_powell`).
    """
    centres = np.array(centres, dtype=np.float64)
    state = None
    for _ in range(iterations):
        labels = flood_fill(disc, centres)
        order = np.argsort(labels, kind="stable")
        bounds = np.searchsorted(labels[order], np.arange(centres.shape[0] + 1))
        members = [order[bounds[i] : bounds[i + 1]] for i in range(centres.shape[0])]
        keys = [m.tobytes() for m in members]
        todo = [i for i in range(centres.shape[0]) if keys[i] not in cache]
        if todo:
            clusters = [disc.samples[members[i]] for i in todo]
            x = update_centres(disc, clusters, centres[todo], sweeps)
            # exact float64 bound and grid outside volume of the optimised spheres
            for k, i in enumerate(todo):
                r = bounding_radius(clusters[k], x[k])
                cache[keys[i]] = (x[k], r, disc.outside_volume(x[k], r))
        new_c = np.array([cache[k][0] for k in keys])
        new_r = np.array([cache[k][1] for k in keys])
        errors = np.array([cache[k][2] for k in keys])
        new_state = LloydState(new_c, new_r, errors, labels)
        converged = state is not None and new_state.error > (1.0 - tolerance) * state.error
        if state is None or new_state.error <= state.error:
            state = new_state
        centres = new_c
        if converged:
            break
    return state


def overlap_ratios(centres: np.ndarray, radii: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Fraction of each sphere's volume inside some other sphere (unit-ball samples)."""
    u = rng.normal(size=(OVERLAP_SAMPLES, 3))
    u *= (rng.random(OVERLAP_SAMPLES) ** (1 / 3) / np.linalg.norm(u, axis=1))[:, None]
    out = np.zeros(centres.shape[0])
    for i in range(centres.shape[0]):
        x = centres[i] + radii[i] * u
        d = np.linalg.norm(x[:, None, :] - centres[None, :, :], axis=2) <= radii[None, :]
        d[:, i] = False
        out[i] = float(np.mean(np.any(d, axis=1)))
    return out


def teleport(state: LloydState, disc: Discretisation, worst: int, rng) -> tuple[np.ndarray, int] | None:
    """(centres, deleted index) after splitting ``worst`` and deleting the most-overlapped other."""
    overlap = overlap_ratios(state.centres, state.radii, rng)
    overlap[worst] = -1.0
    victim = int(np.argmax(overlap))
    if victim == worst:
        return None
    pts = disc.samples[state.labels == worst]
    if pts.shape[0] < 2:
        return None
    a = pts[np.argmax(np.linalg.norm(pts - state.centres[worst], axis=1))]
    b = pts[np.argmax(np.linalg.norm(pts - a, axis=1))]
    centres = state.centres.copy()
    centres[worst] = a
    centres[victim] = b
    return centres, victim


def prune_redundant(state: LloydState, disc: Discretisation) -> LloydState:
    """Drop spheres whose samples are all covered by the other kept spheres (largest E first)."""
    keep = np.ones(state.centres.shape[0], dtype=bool)
    x = disc.samples
    for i in np.argsort(-state.errors):
        if keep.sum() <= 1:
            break
        members = x[state.labels == i]
        others = np.nonzero(keep & (np.arange(keep.size) != i))[0]
        d = np.linalg.norm(members[:, None, :] - state.centres[None, others, :], axis=2)
        if np.all(np.any(d <= state.radii[None, others], axis=1)):
            keep[i] = False
            # reassign its samples to the covering sphere nearest to the centre
            owner = others[np.argmin(np.where(d <= state.radii[None, others], d, np.inf), axis=1)]
            state.labels[state.labels == i] = owner
    remap = -np.ones(keep.size, dtype=np.int64)
    remap[keep] = np.arange(int(keep.sum()))
    return LloydState(state.centres[keep], state.radii[keep], state.errors[keep], remap[state.labels])


def construct(
    disc: Discretisation,
    sphere_count: int,
    iterations: int,
    teleport_attempts: int,
    tolerance: float,
    sweeps: int,
    seed: int,
    progress: bool,
    prune: bool = True,
) -> tuple[LloydState, dict]:
    """The full variational construction; returns the final state and a history dict."""
    rng = np.random.default_rng(seed)
    n = disc.samples.shape[0]
    start = rng.choice(n, size=sphere_count, replace=False)
    cache: dict = {}
    state = lloyd(disc, disc.samples[start], iterations, tolerance, sweeps, cache)
    history = {"initial_error": state.error, "teleports_accepted": 0, "teleports_tried": 0}
    bar = None
    if progress:
        from ...tasks import progress_bar

        bar = progress_bar(total=teleport_attempts, desc=f"spheres {disc.solid.name} ({sphere_count})", leave=False)
    tried: set = set()
    failures = 0
    for _ in range(teleport_attempts if sphere_count > 2 else 0):
        order = [int(i) for i in np.argsort(-state.errors) if int(i) not in tried]
        if not order or failures >= 3:
            break
        worst = order[0]
        tried.add(worst)
        moved = teleport(state, disc, worst, rng)
        history["teleports_tried"] += 1
        if moved is not None:
            centres, _ = moved
            trial = lloyd(disc, centres, 3, tolerance, sweeps, cache)
            if trial.error < state.error * (1.0 - 1e-4):
                state = trial
                tried.clear()
                failures = 0
                history["teleports_accepted"] += 1
            else:
                failures += 1
        if bar is not None:
            bar.update(1)
            bar.set_postfix(E=f"{state.error / disc.volume:.3f}", refresh=False)
    if bar is not None:
        bar.close()
    # exact bounds of the final clusters, then drop spheres that became redundant
    for i in range(state.centres.shape[0]):
        members = disc.samples[state.labels == i]
        state.radii[i] = bounding_radius(members, state.centres[i])
        state.errors[i] = disc.outside_volume(state.centres[i], state.radii[i])
    if prune:
        state = prune_redundant(state, disc)
    history["final_error"] = state.error
    return state, history
