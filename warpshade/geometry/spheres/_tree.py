"""Sphere hierarchy, receiver clusters and the hierarchy cut (the public names are re-exported
by :mod:`warpshade.geometry.spheres`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..._wp import resolve_device, wp
from . import _kernels as _k
from ._core import _check_spheres

#: Angular radius threshold of the hierarchy cut (the paper uses 20-30 degrees).
DEFAULT_THETA_MAX_DEGREES = 25.0

#: Refit bounds of :func:`refit_f64` / :class:`SphereTreeRefit`.
REFIT_MODES = ("min", "anchored", "pair")

#: Relative growth applied to refit parent radii (and cluster radii) in float32 kernels so the
#: bound survives rounding: float32 has 2^-24 ~ 6e-8 relative precision and the refit adds a
#: handful of terms.
REFIT_RADIUS_PAD = 1.0e-6


# ---- hierarchy --------------------------------------------------------------------------------
@dataclass
class SphereTree:
    """A bounding-sphere hierarchy over a sphere set, as flat arrays (sec. 6.3).

    Nodes are stored in depth-first preorder: node 0 is the root, a node's first child is the
    next node, ``skip[i]`` is the first node after its subtree (stackless traversal: descend
    with ``i + 1``, jump over a subtree with ``skip[i]``). Leaves are nodes with no children,
    one per sphere; in preorder the leaves under any node are a contiguous range of *leaf
    slots* ``leaf_start[i] : leaf_start[i] + leaf_count[i]``, with ``leaf_sphere[slot]`` the
    sphere and ``leaf_node[slot]`` the node of each slot.

    Attributes:
        node_centre: rest centres, (N, 3) float64; ``node_radius`` (N,): rest radii.
        child_start, child_count: each node's children are ``child_index[child_start[i] :
            child_start[i] + child_count[i]]``, (N,) int32; ``child_index`` (C,) int32.
        anchor_weight: per child entry, the convex weight of that child's centre in its
            parent's centre (anchored refit), (C,) float64, summing to 1 per parent.
        skip, leaf_start, leaf_count: (N,) int32, see above.
        leaf_sphere, leaf_node: (L,) int32, L = number of spheres.
        node_sphere: sphere of a leaf node, -1 for inner nodes, (N,) int32.
        node_height: 0 for leaves, 1 + max child height otherwise, (N,) int32.
        level_offsets, level_nodes: inner nodes grouped by height 1, 2, ...: the nodes of
            height ``h`` are ``level_nodes[level_offsets[h - 1] : level_offsets[h]]`` (refit
            order, bottom-up).
        branching: the target branching factor.
    """

    node_centre: np.ndarray
    node_radius: np.ndarray
    child_start: np.ndarray
    child_count: np.ndarray
    child_index: np.ndarray
    anchor_weight: np.ndarray
    skip: np.ndarray
    leaf_start: np.ndarray
    leaf_count: np.ndarray
    leaf_sphere: np.ndarray
    leaf_node: np.ndarray
    node_sphere: np.ndarray
    node_height: np.ndarray
    level_offsets: np.ndarray
    level_nodes: np.ndarray
    branching: int = 4

    _ARRAYS = (
        "node_centre",
        "node_radius",
        "child_start",
        "child_count",
        "child_index",
        "anchor_weight",
        "skip",
        "leaf_start",
        "leaf_count",
        "leaf_sphere",
        "leaf_node",
        "node_sphere",
        "node_height",
        "level_offsets",
        "level_nodes",
    )

    @property
    def node_count(self) -> int:
        return int(self.node_radius.shape[0])

    @property
    def leaf_total(self) -> int:
        return int(self.leaf_sphere.shape[0])

    @property
    def height(self) -> int:
        return int(self.node_height[0]) if self.node_count else 0

    def children(self, node: int) -> np.ndarray:
        s = int(self.child_start[node])
        return self.child_index[s : s + int(self.child_count[node])]

    def leaves(self, node: int) -> np.ndarray:
        """Sphere indices under a node, (leaf_count,) int32."""
        s = int(self.leaf_start[node])
        return self.leaf_sphere[s : s + int(self.leaf_count[node])]

    def to_arrays(self) -> dict:
        out = {n: np.asarray(getattr(self, n)) for n in self._ARRAYS}
        out["branching"] = np.array(self.branching)
        return out

    @classmethod
    def from_arrays(cls, arrays: dict) -> SphereTree:
        return cls(**{n: np.array(arrays[n]) for n in cls._ARRAYS}, branching=int(arrays["branching"]))


def _enclosing_radius(centre: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> float:
    return float(np.max(np.linalg.norm(centres - centre, axis=1) + radii))


def _min_enclosing_centre(centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Powell (scipy): the centre minimising the radius of the sphere bounding child spheres."""
    from scipy.optimize import minimize

    start = centres.mean(axis=0)
    if centres.shape[0] == 1:
        return centres[0].copy()
    scale = float(np.max(np.linalg.norm(centres - start, axis=1) + radii)) or 1.0
    res = minimize(
        lambda c: _enclosing_radius(c, centres, radii),
        start,
        method="Powell",
        options={"xtol": 1e-6 * scale, "ftol": 1e-9, "direc": np.eye(3) * 0.1 * scale},
    )
    best = np.asarray(res.x, np.float64)
    return best if _enclosing_radius(best, centres, radii) <= _enclosing_radius(start, centres, radii) else start


def _convex_weights(centres: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Convex weights w (w >= 0, sum 1) with sum_k w_k c_k closest to the target (NNLS).

    The minimal enclosing sphere of spheres has its centre in the convex hull of their centres,
    so the rest-pose parent is reproduced; convex weights keep the animated parent centre
    inside the children's hull (affine weights can extrapolate and inflate the refit radius).
    """
    from scipy.optimize import nnls

    scale = float(np.max(np.abs(centres - target))) or 1.0
    a = np.vstack([(centres - target).T / scale, 1e3 * np.ones(centres.shape[0])])
    b = np.concatenate([np.zeros(3), [1e3]])
    w, _ = nnls(a, b)
    total = w.sum()
    return w / total if total > 1e-12 else np.full(centres.shape[0], 1.0 / centres.shape[0])


def _cluster_level(centres: np.ndarray, radii: np.ndarray, branching: int, iterations: int, rng) -> list[np.ndarray]:
    """Lloyd clustering of spheres by centre distance into ceil(n / branching) groups."""
    n = centres.shape[0]
    k = max(1, math.ceil(n / branching))
    if k == 1:
        return [np.arange(n)]
    # farthest-point seeding (deterministic given the first pick)
    seeds = [int(rng.integers(n))]
    d = np.linalg.norm(centres - centres[seeds[0]], axis=1)
    for _ in range(k - 1):
        seeds.append(int(np.argmax(d)))
        d = np.minimum(d, np.linalg.norm(centres - centres[seeds[-1]], axis=1))
    cluster_centres = centres[seeds].copy()
    labels = np.full(n, -1)
    for _ in range(iterations):
        new = np.argmin(np.linalg.norm(centres[:, None] - cluster_centres[None], axis=2), axis=1)
        # an emptied cluster takes the sphere farthest from its own cluster centre
        for j in range(k):
            if not np.any(new == j):
                far = int(np.argmax(np.linalg.norm(centres - cluster_centres[new], axis=1)))
                new[far] = j
        if np.array_equal(new, labels):
            break
        labels = new
        for j in range(k):
            m = labels == j
            cluster_centres[j] = _min_enclosing_centre(centres[m], radii[m])
    return [np.nonzero(labels == j)[0] for j in range(k)]


def build_sphere_tree(centres, radii, groups=None, branching: int = 4, iterations: int = 20, seed: int = 0) -> SphereTree:
    """Build a sphere hierarchy bottom-up by Lloyd clustering (sec. 6.3).

    Each level clusters the spheres of the level below by centre distance into
    ``ceil(n / branching)`` clusters (so the average branching is about ``branching``); each
    cluster becomes a parent whose centre minimises (Powell) the radius of the sphere bounding
    its children. With ``groups`` (e.g. the mesh of each sphere) every group gets its own
    subtree first and the group roots are then clustered the same way, so spheres of
    independently moving meshes are not mixed low in the tree.

    Args:
        centres: leaf sphere centres, (S, 3); radii: (S,), S >= 1.
        groups: optional group label per sphere, (S,).
        branching: target children per parent (>= 2).
        iterations: Lloyd iterations per level.
        seed: seeds the clustering.

    Returns:
        :class:`SphereTree`; its rest node spheres bound their children exactly (anchored
        centres, see :func:`refit_f64`).
    """
    c, r = _check_spheres(centres, radii, "build_sphere_tree")
    if c.shape[0] == 0:
        raise ValueError("build_sphere_tree: needs at least one sphere")
    if branching < 2:
        raise ValueError(f"build_sphere_tree: branching must be >= 2, got {branching}")
    rng = np.random.default_rng(seed)
    # node records: centre, radius, children (record ids), sphere, anchor weights
    records: list[dict] = [{"c": c[i], "r": float(r[i]), "children": [], "sphere": i} for i in range(c.shape[0])]

    def make_parent(kids: list[int]) -> int:
        kc = np.array([records[k]["c"] for k in kids])
        kr = np.array([records[k]["r"] for k in kids])
        if len(kids) == 1:
            return kids[0]
        target = _min_enclosing_centre(kc, kr)
        w = _convex_weights(kc, target)
        centre = w @ kc
        records.append({"c": centre, "r": _enclosing_radius(centre, kc, kr), "children": list(kids), "sphere": -1, "w": w})
        return len(records) - 1

    def build(ids: list[int]) -> int:
        level = list(ids)
        while len(level) > 1:
            lc = np.array([records[k]["c"] for k in level])
            lr = np.array([records[k]["r"] for k in level])
            parts = _cluster_level(lc, lr, branching, iterations, rng)
            if len(parts) == len(level):  # no progress possible: join everything
                parts = [np.arange(len(level))]
            level = [make_parent([level[j] for j in part]) for part in parts]
        return level[0]

    if groups is None:
        root = build(list(range(c.shape[0])))
    else:
        g = np.asarray(groups).reshape(-1)
        if g.shape[0] != c.shape[0]:
            raise ValueError(f"build_sphere_tree: {g.shape[0]} group labels for {c.shape[0]} spheres")
        roots = [build(list(np.nonzero(g == label)[0])) for label in np.unique(g)]
        root = build(roots)

    # flatten in preorder
    order: list[int] = []
    stack = [root]
    while stack:
        rec = stack.pop()
        order.append(rec)
        stack.extend(reversed(records[rec]["children"]))
    pos = {rec: i for i, rec in enumerate(order)}
    n = len(order)
    node_c = np.array([records[rec]["c"] for rec in order])
    node_r = np.array([records[rec]["r"] for rec in order])
    child_start = np.zeros(n, np.int32)
    child_count = np.zeros(n, np.int32)
    child_index, anchor = [], []
    node_sphere = np.array([records[rec]["sphere"] for rec in order], np.int32)
    for i, rec in enumerate(order):
        kids = records[rec]["children"]
        child_start[i] = len(child_index)
        child_count[i] = len(kids)
        child_index.extend(pos[k] for k in kids)
        if kids:
            anchor.extend(records[rec]["w"])
    height = np.zeros(n, np.int32)
    skip = np.zeros(n, np.int32)
    leaf_start = np.zeros(n, np.int32)
    leaf_count = np.zeros(n, np.int32)
    leaf_sphere, leaf_node = [], []
    for i in range(n):
        if child_count[i] == 0:
            leaf_sphere.append(int(node_sphere[i]))
            leaf_node.append(i)
    leaf_slot = {node: k for k, node in enumerate(leaf_node)}
    for i in reversed(range(n)):  # children come after parents in preorder
        kids = child_index[child_start[i] : child_start[i] + child_count[i]]
        if kids:
            height[i] = 1 + max(height[k] for k in kids)
            last = kids[-1]
            skip[i] = skip[last]
            leaf_start[i] = leaf_start[kids[0]]
            leaf_count[i] = sum(leaf_count[k] for k in kids)
        else:
            skip[i] = i + 1
            leaf_start[i] = leaf_slot[i]
            leaf_count[i] = 1
    inner = np.nonzero(height > 0)[0]
    level_nodes = inner[np.argsort(height[inner], kind="stable")].astype(np.int32)
    max_h = int(height.max())
    level_offsets = np.searchsorted(height[level_nodes], np.arange(1, max_h + 2)).astype(np.int32)
    return SphereTree(
        node_centre=node_c,
        node_radius=node_r,
        child_start=child_start,
        child_count=child_count,
        child_index=np.asarray(child_index, np.int32),
        anchor_weight=np.asarray(anchor, np.float64),
        skip=skip,
        leaf_start=leaf_start,
        leaf_count=leaf_count,
        leaf_sphere=np.asarray(leaf_sphere, np.int32),
        leaf_node=np.asarray(leaf_node, np.int32),
        node_sphere=node_sphere,
        node_height=height,
        level_offsets=np.concatenate([[0], level_offsets[1:]]).astype(np.int32) if max_h else np.zeros(1, np.int32),
        level_nodes=level_nodes,
        branching=int(branching),
    )


def refit_f64(tree: SphereTree, centres, radii, mode: str = "min") -> tuple[np.ndarray, np.ndarray]:
    """Float64 mirror of the per-frame refit: node spheres for new leaf spheres.

    Args:
        tree: the hierarchy.
        centres, radii: the leaf spheres of this frame (sphere indexing), (S, 3) and (S,).
        mode: "anchored" (parent centre = the fixed convex combination of the child centres
            that reproduces the rest parent, radius = max over children of distance + child
            radius), "pair" (children merged one at a time into the smallest sphere containing
            both, sec. 6.3), or "min" (the smaller of the two). Every mode bounds every child
            for any child positions.

    Returns:
        node centres (N, 3) and radii (N,), float64.
    """
    if mode not in REFIT_MODES:
        raise ValueError(f"refit: mode must be one of {REFIT_MODES}, got {mode!r}")
    c, r = _check_spheres(centres, radii, "refit_f64")
    nc = np.zeros((tree.node_count, 3))
    nr = np.zeros(tree.node_count)
    nc[tree.leaf_node] = c[tree.leaf_sphere]
    nr[tree.leaf_node] = r[tree.leaf_sphere]
    for node in tree.level_nodes:
        s, k = int(tree.child_start[node]), int(tree.child_count[node])
        kids = tree.child_index[s : s + k]
        anchored = tree.anchor_weight[s : s + k] @ nc[kids]
        pair, rad = nc[kids[0]].copy(), nr[kids[0]]
        for ch in kids[1:]:
            d = float(np.linalg.norm(nc[ch] - pair))
            if d + nr[ch] <= rad:
                continue
            if d + rad <= nr[ch]:
                pair, rad = nc[ch].copy(), nr[ch]
                continue
            new_r = 0.5 * (d + rad + nr[ch])
            pair = pair + (new_r - rad) / d * (nc[ch] - pair)
            rad = new_r
        options = {"anchored": [anchored], "pair": [pair], "min": [anchored, pair]}[mode]
        radii_options = [_enclosing_radius(o, nc[kids], nr[kids]) for o in options]
        best = int(np.argmin(radii_options))
        nc[node] = options[best]
        nr[node] = radii_options[best]
    return nc, nr


class SphereTreeRefit:
    """Per-frame bottom-up refit of a :class:`SphereTree` on a Warp device.

    Holds the tree's topology on the device and fixed node buffers; :meth:`launch` copies the
    frame's leaf spheres in and refits one height level per launch, bottom-up.

    Attributes:
        node_centres: wp.array(vec3), (N,); node_radii: wp.array(float32), (N,).
        child_count, skip, leaf_start, leaf_count, leaf_node, leaf_sphere: the tree's int32
            arrays on the device (for traversal and per-cut-node leaf loops).
    """

    def __init__(self, tree: SphereTree, device=None, mode: str = "min"):
        if mode not in REFIT_MODES:
            raise ValueError(f"SphereTreeRefit: mode must be one of {REFIT_MODES}, got {mode!r}")
        dev = resolve_device(device)
        self.device = dev
        self.tree = tree
        self.mode = {"anchored": _k.REFIT_ANCHORED, "pair": _k.REFIT_PAIR, "min": _k.REFIT_MIN}[mode]

        def i32(a):
            return wp.array(np.asarray(a, np.int32), dtype=wp.int32, device=dev)

        self.node_centres = wp.array(tree.node_centre.astype(np.float32), dtype=wp.vec3, device=dev)
        self.node_radii = wp.array(tree.node_radius.astype(np.float32), dtype=wp.float32, device=dev)
        self.child_start = i32(tree.child_start)
        self.child_count = i32(tree.child_count)
        self.child_index = i32(tree.child_index if tree.child_index.size else np.zeros(1))
        self.anchor_weight = wp.array(
            (tree.anchor_weight if tree.anchor_weight.size else np.zeros(1)).astype(np.float32), dtype=wp.float32, device=dev
        )
        self.skip = i32(tree.skip)
        self.leaf_start = i32(tree.leaf_start)
        self.leaf_count = i32(tree.leaf_count)
        self.leaf_node = i32(tree.leaf_node)
        self.leaf_sphere = i32(tree.leaf_sphere)
        self.level_nodes = i32(tree.level_nodes if tree.level_nodes.size else np.zeros(1))
        self._levels = [(int(a), int(b)) for a, b in zip(tree.level_offsets[:-1], tree.level_offsets[1:]) if b > a]

    def launch(self, sphere_centres, sphere_radii) -> None:
        """Refit from this frame's leaf spheres (wp arrays vec3 (S,), float32 (S,))."""
        dev = self.device
        wp.launch(
            _k.tree_leaves_kernel,
            dim=self.tree.leaf_total,
            inputs=[self.leaf_sphere, self.leaf_node, sphere_centres, sphere_radii, self.node_centres, self.node_radii],
            device=dev,
        )
        for start, stop in self._levels:
            wp.launch(
                _k.tree_refit_kernel,
                dim=stop - start,
                inputs=[
                    self.level_nodes,
                    start,
                    self.child_start,
                    self.child_count,
                    self.child_index,
                    self.anchor_weight,
                    self.mode,
                    REFIT_RADIUS_PAD,
                    self.node_centres,
                    self.node_radii,
                ],
                device=dev,
            )


# ---- receiver clusters and the hierarchy cut ---------------------------------------------------
@dataclass
class ReceiverClusters:
    """Lloyd clusters of receiver vertices (the vertex indexing of the clustered points), sec. 6.3.

    Attributes:
        cluster_start: CSR offsets, (C + 1,) int32: cluster ``c`` holds
            ``cluster_vertices[cluster_start[c] : cluster_start[c + 1]]``.
        cluster_vertices: vertex indices (of the clustered points), int32.
        cluster_mesh: mesh index of each cluster, (C,) int32.
        representative: the vertex p* of each cluster (closest to its centroid at the frame
            the clusters were built), (C,) int32, vertex index. Fixed over the animation
            so ratio vectors do not flicker.
        vertices_per_cluster: the target used.
    """

    cluster_start: np.ndarray
    cluster_vertices: np.ndarray
    cluster_mesh: np.ndarray
    representative: np.ndarray
    vertices_per_cluster: int = 300

    @property
    def cluster_count(self) -> int:
        return int(self.cluster_mesh.shape[0])

    def vertices(self, cluster: int) -> np.ndarray:
        return self.cluster_vertices[self.cluster_start[cluster] : self.cluster_start[cluster + 1]]

    def bounds_f64(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Float64 mirror of :class:`ReceiverBounds`: (centres (C, 3), radii (C,), p* (C, 3))."""
        p = np.asarray(points, np.float64).reshape(-1, 3)
        centres = np.zeros((self.cluster_count, 3))
        radii = np.zeros(self.cluster_count)
        for c in range(self.cluster_count):
            v = p[self.vertices(c)]
            centres[c] = v.mean(axis=0)
            radii[c] = np.max(np.linalg.norm(v - centres[c], axis=1))
        return centres, radii, p[self.representative]

    def to_arrays(self) -> dict:
        return {
            "cluster_start": self.cluster_start,
            "cluster_vertices": self.cluster_vertices,
            "cluster_mesh": self.cluster_mesh,
            "representative": self.representative,
            "vertices_per_cluster": np.array(self.vertices_per_cluster),
        }

    @classmethod
    def from_arrays(cls, arrays: dict) -> ReceiverClusters:
        return cls(
            cluster_start=np.array(arrays["cluster_start"]),
            cluster_vertices=np.array(arrays["cluster_vertices"]),
            cluster_mesh=np.array(arrays["cluster_mesh"]),
            representative=np.array(arrays["representative"]),
            vertices_per_cluster=int(arrays["vertices_per_cluster"]),
        )


def cluster_receivers(
    points,
    mesh_offsets,
    vertices_per_cluster: int = 300,
    meshes=None,
    iterations: int = 30,
    seed: int = 0,
    names=None,
) -> ReceiverClusters:
    """Lloyd (k-means) clustering of each receiver mesh's vertices.

    Args:
        points: positions of all vertices, meshes concatenated, (V, 3) float (the frame the
            clusters are built at; world space).
        mesh_offsets: first vertex of each mesh, then V, (M + 1,) int: mesh ``m`` owns
            vertices ``mesh_offsets[m] : mesh_offsets[m + 1]``.
        vertices_per_cluster: target cluster size; a mesh of n vertices gets
            ``max(1, round(n / vertices_per_cluster))`` clusters (the paper uses several hundred).
        meshes: indices of the meshes to cluster (default: all).
        iterations: Lloyd iterations.
        seed: seeds the k-means++ initialisation (mesh ``m`` uses the stream ``[seed, m]``).
        names: mesh names for error messages (default ``"mesh <m>"``).

    Returns:
        :class:`ReceiverClusters` in the indexing of ``points`` (empty clusters dropped).
    """
    from scipy.cluster.vq import kmeans2

    if vertices_per_cluster < 1:
        raise ValueError(f"cluster_receivers: vertices_per_cluster must be >= 1, got {vertices_per_cluster}")
    world = np.asarray(points, np.float64).reshape(-1, 3)
    offsets = np.asarray(mesh_offsets, np.int64).reshape(-1)
    if offsets.size < 2 or offsets[0] != 0 or offsets[-1] != world.shape[0] or np.any(np.diff(offsets) < 0):
        raise ValueError(f"cluster_receivers: mesh_offsets must rise from 0 to the {world.shape[0]} points, got {offsets.tolist()}")
    ids = range(offsets.size - 1) if meshes is None else [int(m) for m in meshes]
    starts, verts, owners, reps = [0], [], [], []
    for m in ids:
        first, count = int(offsets[m]), int(offsets[m + 1] - offsets[m])
        p = world[first : first + count]
        if not np.all(np.isfinite(p)):
            name = names[m] if names is not None else f"mesh {m}"
            raise ValueError(f"cluster_receivers: {name} has NaN or infinite points")
        k = max(1, round(count / vertices_per_cluster))
        if k == 1:
            labels = np.zeros(count, dtype=np.int64)
        else:
            _, labels = kmeans2(p, k, iter=iterations, minit="++", seed=np.random.default_rng([seed, m]))
        for j in np.unique(labels):
            local = np.nonzero(labels == j)[0]
            centroid = p[local].mean(axis=0)
            rep = local[int(np.argmin(np.linalg.norm(p[local] - centroid, axis=1)))]
            verts.append(local + first)
            starts.append(starts[-1] + local.size)
            owners.append(m)
            reps.append(rep + first)
    return ReceiverClusters(
        cluster_start=np.asarray(starts, np.int32),
        cluster_vertices=np.concatenate(verts).astype(np.int32) if verts else np.zeros(0, np.int32),
        cluster_mesh=np.asarray(owners, np.int32),
        representative=np.asarray(reps, np.int32),
        vertices_per_cluster=int(vertices_per_cluster),
    )


class ReceiverBounds:
    """Per-frame bounding sphere and representative point of each receiver cluster (Warp).

    Attributes:
        centres: wp.array(vec3), (C,): mean of the cluster's deformed points.
        radii: wp.array(float32), (C,): max distance from that centre (times 1 + pad).
        representative_points: wp.array(vec3), (C,): the deformed p* of each cluster.
        representative: wp.array(int32), (C,): p*'s vertex index.
    """

    def __init__(self, clusters: ReceiverClusters, device=None):
        dev = resolve_device(device)
        self.device = dev
        self.clusters = clusters
        n = max(clusters.cluster_count, 1)
        self.cluster_start = wp.array(clusters.cluster_start.astype(np.int32), dtype=wp.int32, device=dev)
        self.cluster_vertices = wp.array(clusters.cluster_vertices.astype(np.int32), dtype=wp.int32, device=dev)
        self.representative = wp.array(clusters.representative.astype(np.int32), dtype=wp.int32, device=dev)
        self.centres = wp.zeros(n, dtype=wp.vec3, device=dev)
        self.radii = wp.zeros(n, dtype=wp.float32, device=dev)
        self.representative_points = wp.zeros(n, dtype=wp.vec3, device=dev)

    def launch(self, points) -> None:
        """Recompute from the frame's world-space points, wp.array(vec3) (the clusters' vertex indexing)."""
        if self.clusters.cluster_count:
            wp.launch(
                _k.cluster_bounds_kernel,
                dim=self.clusters.cluster_count,
                inputs=[points, self.cluster_start, self.cluster_vertices, self.representative, REFIT_RADIUS_PAD, self.centres, self.radii, self.representative_points],
                device=self.device,
            )


class HierarchyCut:
    """Per receiver cluster, the list of tree nodes to shade with (eq. 36), on a Warp device.

    For each cluster the tree is walked from the root: a node passing
    ``r_i < sin(theta_max) (|P_i - p_R| - r_R)`` (or a leaf) joins the cut and its subtree is
    skipped, otherwise the walk descends. Results are flat fixed-size buffers:

    Attributes:
        cut_nodes: wp.array2d(int32), (C, capacity): node indices in preorder, then -1.
        cut_count: wp.array(int32), (C,): entries used.
        cut_overflow: wp.array(int32), (C,): 0, or the full cut length when it did not fit
            (only possible with a capacity below the leaf count; check it with :meth:`overflowed`).
        capacity: row length (default: the number of leaves, which no cut can exceed).
        sin_theta_max: sine of the angular threshold.

    The leaves of a cut node ``i`` (for the detailed log visibility of eq. 37) are the slots
    ``leaf_start[i] .. leaf_start[i] + leaf_count[i]`` of :class:`SphereTreeRefit`, with
    sphere ``leaf_sphere[slot]`` and this frame's sphere at node ``leaf_node[slot]``.
    """

    def __init__(self, refit: SphereTreeRefit, cluster_count: int, theta_max_degrees: float = DEFAULT_THETA_MAX_DEGREES, capacity: int | None = None):
        if not 0.0 < theta_max_degrees < 90.0:
            raise ValueError(f"HierarchyCut: theta_max_degrees must be in (0, 90), got {theta_max_degrees}")
        self.refit = refit
        self.device = refit.device
        self.capacity = int(capacity or refit.tree.leaf_total)
        if self.capacity < 1:
            raise ValueError(f"HierarchyCut: capacity must be >= 1, got {capacity}")
        self.sin_theta_max = float(math.sin(math.radians(theta_max_degrees)))
        n = max(int(cluster_count), 1)
        self.cluster_count = int(cluster_count)
        self.cut_nodes = wp.full((n, self.capacity), -1, dtype=wp.int32, device=self.device)
        self.cut_count = wp.zeros(n, dtype=wp.int32, device=self.device)
        self.cut_overflow = wp.zeros(n, dtype=wp.int32, device=self.device)

    def launch(self, cluster_centres, cluster_radii) -> None:
        """Cut the refit tree for each cluster (cluster spheres as wp arrays vec3 / float32)."""
        if self.cluster_count:
            r = self.refit
            wp.launch(
                _k.cut_kernel,
                dim=self.cluster_count,
                inputs=[cluster_centres, cluster_radii, r.node_centres, r.node_radii, r.child_count, r.skip, self.sin_theta_max, self.cut_nodes, self.cut_count, self.cut_overflow],
                device=self.device,
            )

    def overflowed(self) -> bool:
        """True when some cut did not fit its row (host check; synchronises)."""
        return bool(np.any(self.cut_overflow.numpy() > 0))


def cut_f64(tree: SphereTree, node_centres, node_radii, cluster_centres, cluster_radii, theta_max_degrees: float = DEFAULT_THETA_MAX_DEGREES) -> list[list[int]]:
    """Float64 brute-force reference of :class:`HierarchyCut`: recursive eq. 36 per cluster.

    Returns:
        per cluster, the cut's node indices in preorder.
    """
    s = math.sin(math.radians(theta_max_degrees))
    nc = np.asarray(node_centres, np.float64)
    nr = np.asarray(node_radii, np.float64)

    def visit(i: int, pc: np.ndarray, rc: float, cut: list) -> None:
        if tree.child_count[i] == 0 or nr[i] < s * (np.linalg.norm(nc[i] - pc) - rc):
            cut.append(i)
            return
        for ch in tree.children(i):
            visit(int(ch), pc, rc, cut)

    out = []
    for pc, rc in zip(np.asarray(cluster_centres, np.float64), np.asarray(cluster_radii, np.float64)):
        cut: list[int] = []
        visit(0, pc, float(rc), cut)
        out.append(cut)
    return out
