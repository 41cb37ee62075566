"""The blocker model of SHEXP: sphere sets, hierarchy and receiver clusters, per frame on a device.

Sphere geometry comes from :mod:`warpshade.geometry.spheres` (sphere sets bounding a solid, the
bounding-sphere tree, Lloyd receiver clusters, the eq. 36 cut) and the scene's spheres with
their animation from :mod:`._spheres` (:func:`._spheres.spheres_for_scene`,
:class:`._spheres.SphereAnimator`). This module

* bundles them as a :class:`BlockerModel` that a precompute stage stores as named arrays (an
  "arrays" artifact port, :meth:`BlockerModel.to_arrays`) and a frame stage rebuilds
  (:meth:`BlockerModel.from_arrays`);
* drives them per frame on fixed device buffers (:class:`BlockerFrames`): sphere centres from
  the frame state, bottom-up refit, receiver-cluster bounds, the cut per cluster and the
  per-band ratio vectors of eq. 37 (:func:`._cut_kernels.ratio_kernel`), ready for
  :class:`._pipeline.ShexpShader` -- kernels only, so a recorded frame replays them.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from ..._wp import resolve_device, wp
from ...geometry import spheres as sph
from . import _cut_kernels as cut_kernels
from ._spheres import SceneSpheres, SphereAnimator, scene_receiver_clusters, spheres_for_scene

__all__ = ["BlockerModel", "build_blocker_model", "BlockerFrames", "static_mesh_mask", "plane_blockers", "PLANE_FLATNESS"]


#: A static open mesh is a plane blocker when its points lie within this fraction of its
#: diagonal of their best-fit plane.
PLANE_FLATNESS = 1e-3


def plane_blockers(scene, skip_paths=None) -> np.ndarray:
    """Static planar open meshes (ground planes) as disc blockers, rows (centre, normal, radius).

    A mesh qualifies when it never moves, is not closed (closed meshes get spheres) -- i.e. its
    path is in ``skip_paths`` when given -- and its points lie on a plane (within
    :data:`PLANE_FLATNESS` of its diagonal). The disc has the mesh's area (``R = sqrt(A / pi)``),
    its centroid and the plane normal oriented towards the scene's up axis.
    """
    from ...scene._lighting import up_rotation

    static = static_mesh_mask(scene)
    up = up_rotation(scene.up_axis)[:, 2]
    world = scene.points_at(float(scene.frames[0]))
    rows = []
    for mesh, is_static in zip(scene.meshes, static):
        if not is_static or (skip_paths is not None and mesh.path not in skip_paths) or mesh.vertex_count < 3:
            continue
        pts = world[mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count]
        centroid = pts.mean(axis=0)
        _, sv, vt = np.linalg.svd(pts - centroid, full_matrices=False)
        diag = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
        thickness = float(np.abs((pts - centroid) @ vt[2]).max())
        if diag <= 0.0 or thickness > PLANE_FLATNESS * diag:
            continue
        tri = pts[mesh.faces]
        area = 0.5 * float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())
        normal = vt[2] if vt[2] @ up >= 0.0 else -vt[2]
        rows.append(np.concatenate([centroid, normal, [np.sqrt(area / np.pi)]]))
    return np.asarray(rows, np.float64).reshape(-1, 7)


def static_mesh_mask(scene) -> np.ndarray:
    """Per scene mesh: True when it never moves (static, or rigid with one transform)."""
    return np.array([m.animation == "static" or (m.animation == "rigid" and m.transforms.shape[0] == 1) for m in scene.meshes])


@dataclass
class BlockerModel:
    """Sphere sets (+ optional hierarchy and receiver clusters) of one scene.

    Attributes:
        spheres: :class:`._spheres.SceneSpheres` (leaf spheres, attached).
        tree: :class:`~warpshade.geometry.spheres.SphereTree` over the leaves, or None (flat list).
        clusters: :class:`~warpshade.geometry.spheres.ReceiverClusters` of all scene vertices
            (with the tree), or None.
        static_sphere: per leaf sphere, True when its mesh never moves, (S,) bool.
        summary: facts for reports (per-set sphere counts and outside-volume error E, seconds).
        planes: static planar blockers, rows (centre, normal, radius), (P, 7) (see
            :func:`plane_blockers`).
    """

    spheres: object
    tree: object = None
    clusters: object = None
    static_sphere: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    summary: dict = field(default_factory=dict)
    planes: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))

    @property
    def leaf_count(self) -> int:
        return int(self.spheres.sphere_count)

    @property
    def node_count(self) -> int:
        return self.tree.node_count if self.tree is not None else self.leaf_count

    def node_static(self) -> np.ndarray:
        """Per node (tree node or leaf sphere): True when every sphere under it is static."""
        if self.tree is None:
            return self.static_sphere.copy()
        t = self.tree
        out = np.zeros(t.node_count, bool)
        for i in range(t.node_count):
            out[i] = bool(np.all(self.static_sphere[t.leaves(i)]))
        return out

    def to_arrays(self) -> dict:
        """The model as named NumPy arrays (an "arrays" artifact port; inverse: :meth:`from_arrays`)."""
        arrays = {f"spheres/{k}": v for k, v in self.spheres.to_arrays().items()}
        if self.tree is not None:
            arrays.update({f"tree/{k}": v for k, v in self.tree.to_arrays().items()})
        if self.clusters is not None:
            arrays.update({f"clusters/{k}": v for k, v in self.clusters.to_arrays().items()})
        arrays["static_sphere"] = self.static_sphere.astype(np.int8)
        arrays["planes"] = np.asarray(self.planes, np.float64).reshape(-1, 7)
        arrays["summary_json"] = np.array(json.dumps(self.summary, default=float))
        return arrays

    @classmethod
    def from_arrays(cls, arrays: dict) -> "BlockerModel":
        """Rebuild a model from :meth:`to_arrays`; raises ValueError for anything else."""
        missing = {"static_sphere", "planes", "summary_json"} - set(arrays)
        if missing or not any(k.startswith("spheres/") for k in arrays):
            raise ValueError(f"shexp: not a blocker model (missing {sorted(missing) or ['spheres/*']})")

        def part(prefix):
            return {k.split("/", 1)[1]: v for k, v in arrays.items() if k.startswith(prefix + "/")}

        spheres = SceneSpheres.from_arrays(part("spheres"))
        tree = sph.SphereTree.from_arrays(part("tree")) if any(k.startswith("tree/") for k in arrays) else None
        clusters = sph.ReceiverClusters.from_arrays(part("clusters")) if any(k.startswith("clusters/") for k in arrays) else None
        return cls(spheres, tree, clusters, np.asarray(arrays["static_sphere"]).astype(bool),
                   json.loads(str(arrays["summary_json"])), np.asarray(arrays["planes"]).reshape(-1, 7))


def build_blocker_model(
    scene,
    budget: int = 48,
    *,
    hierarchy: bool = False,
    planes: bool = True,
    branching: int = 4,
    vertices_per_cluster: int = 300,
    frame: float | None = None,
    split: str = "volume",
    target_error: float | None = None,
    open_meshes: str = "skip",
    radius_scale: float = 1.0,
    calibrate: bool = False,
    seed: int = 0,
    device=None,
    **fit_options,
) -> BlockerModel:
    """Fit sphere sets to a scene's closed occluder meshes (and the hierarchy and clusters).

    Args:
        scene: the :class:`~warpshade.scene.Scene`.
        budget: total leaf spheres over all occluder meshes.
        hierarchy: also build the sphere tree (branching about ``branching``, one subtree per
            mesh) and Lloyd receiver clusters of ``vertices_per_cluster`` vertices.
        planes: model static planar open meshes (ground planes) as disc blockers
            (:func:`plane_blockers`; an extension of the paper, see :func:`._kernels.plane_cap`).
        frame, split, target_error, open_meshes, radius_scale, calibrate, seed, **fit_options:
            passed to :func:`._spheres.spheres_for_scene` (``calibrate`` grows
            radii so skinned/deforming spheres keep bounding their clusters on every frame).
        device: Warp device of the construction kernels.

    Returns:
        :class:`BlockerModel`.
    """
    import time

    t0 = time.perf_counter()
    spheres = spheres_for_scene(
        scene, frame, budget, split=split, target_error=target_error, open_meshes=open_meshes,
        radius_scale=radius_scale, calibrate=calibrate and not scene.is_static, seed=seed, device=device, **fit_options,
    )
    t1 = time.perf_counter()
    static = static_mesh_mask(scene)[spheres.sphere_mesh]
    tree = clusters = None
    if hierarchy:
        f0 = float(scene.frames[0]) if frame is None else float(frame)
        tree = sph.build_sphere_tree(spheres.centres_at(scene, f0), spheres.radii_at(scene, f0), groups=spheres.sphere_set,
                                     branching=branching, seed=seed)
        clusters = scene_receiver_clusters(scene, f0, vertices_per_cluster=vertices_per_cluster, seed=seed)
    plane_rows = plane_blockers(scene, {path for path, _ in spheres.skipped}) if planes else np.zeros((0, 7))
    summary = {
        "leaf_spheres": int(spheres.sphere_count),
        "plane_blockers": int(plane_rows.shape[0]),
        "sets": [{"mesh": s.source, "spheres": int(s.sphere_count), "outside_volume_E": float(s.error),
                  "outside_volume_E_union": float(s.error_union)} for s in spheres.sets],
        "skipped": [list(x) for x in spheres.skipped],
        "fit_seconds": t1 - t0,
        "hierarchy_nodes": int(tree.node_count) if tree is not None else None,
        "tree_height": int(tree.height) if tree is not None else None,
        "receiver_clusters": int(clusters.cluster_count) if clusters is not None else None,
        "seconds": time.perf_counter() - t0,
    }
    return BlockerModel(spheres, tree, clusters, static, summary, plane_rows)


class BlockerFrames:
    """Per-frame blocker spheres and cut lists on fixed device buffers.

    Flat model: ``node_centres``/``node_radii`` are the leaf spheres, one cluster whose list is
    every sphere. Hierarchy: the refit tree's nodes, the eq. 36 cut of every receiver cluster
    and, with ``ratio``, the per-band ratio vectors of eq. 37 at each cluster's representative
    vertex. :meth:`launch` only launches kernels that read the frame's
    :class:`~warpshade.scene._state.FrameState`, so a recorded frame replays it.

    Args:
        scene: the scene; model: its :class:`BlockerModel`.
        order: SH order of the ratio vectors.
        theta_max_degrees: angular threshold of the cut (paper: 20-30 degrees).
        theta_min_degrees: leaves below this angular radius are left out of the detailed log
            of the ratio vectors (0 = all).
        ratio: compute ratio vectors (else every cut entry has weight 1).
        device: Warp device.
        exp_tables: the :class:`~warpshade.basis.sh_warp.SHExpTables` of ``order`` to use
            (default: the process-wide ones).

    Attributes:
        animator: the :class:`._spheres.SphereAnimator` (leaf spheres of the frame).
        refit, bounds, cut: the :class:`~warpshade.geometry.spheres.SphereTreeRefit`,
            :class:`~warpshade.geometry.spheres.ReceiverBounds` and
            :class:`~warpshade.geometry.spheres.HierarchyCut` (None for a flat model).
        node_centres, node_radii: the spheres the shader reads, wp.array(vec3) / wp.array(float32),
            shape (node_count,) (tree nodes, or the leaf spheres of a flat model).
        node_static: per node, True when every sphere under it is static, (node_count,) bool.
        clusters: receiver clusters (1 for a flat model); capacity: entries per cut row.
        vertex_cluster: receiver cluster of each scene vertex, (vertex_count,) int32.
        cut_weights: ratio vectors per cut entry, wp.array3d(float32), shape
            (clusters, capacity, order), or None for a flat model.
    """

    def __init__(self, scene, model: BlockerModel, order: int, theta_max_degrees: float = sph.DEFAULT_THETA_MAX_DEGREES,
                 theta_min_degrees: float = 0.0, ratio: bool = True, device=None, exp_tables=None):
        from ...basis.sh_warp import sh_kernels

        dev = resolve_device(device)
        self.device = dev
        self.model = model
        self.order = int(order)
        self.animator = SphereAnimator(scene, model.spheres, dev)
        self.node_static = model.node_static()
        self.theta_min = float(np.radians(theta_min_degrees))
        self.ratio = bool(ratio)
        self._exp_tables = exp_tables if exp_tables is not None else sh_kernels(self.order).exp_tables(dev)
        if model.tree is None:
            self.clusters = 1
            self.capacity = max(model.leaf_count, 1)
            self.vertex_cluster = np.zeros(scene.vertex_count, np.int32)
            self.node_centres = self.animator.centres
            self.node_radii = self.animator.radii
            self.refit = self.bounds = self.cut = None
            self.cut_weights = None
        else:
            cl = model.clusters
            self.clusters = cl.cluster_count
            self.vertex_cluster = np.zeros(scene.vertex_count, np.int32)
            for c in range(cl.cluster_count):
                self.vertex_cluster[cl.vertices(c)] = c
            covered = np.zeros(scene.vertex_count, bool)
            covered[cl.cluster_vertices] = True
            if not covered.all():
                raise ValueError(f"shexp: {int((~covered).sum())} scene vertices belong to no receiver cluster")
            self.refit = sph.SphereTreeRefit(model.tree, dev)
            self.bounds = sph.ReceiverBounds(cl, dev)
            self.cut = sph.HierarchyCut(self.refit, cl.cluster_count, theta_max_degrees)
            self.capacity = self.cut.capacity
            self.node_centres = self.refit.node_centres
            self.node_radii = self.refit.node_radii
            self.cut_weights = wp.ones((max(self.clusters, 1), self.capacity, self.order), dtype=wp.float32, device=dev)
            self._ratio_kernel = cut_kernels.ratio_kernel(self.order)
            r = self.refit
            a = cut_kernels.RatioArrays()
            a.rep_points = self.bounds.representative_points
            a.node_centres = r.node_centres
            a.node_radii = r.node_radii
            a.leaf_first = r.leaf_start
            a.leaf_count = r.leaf_count
            a.leaf_index = r.leaf_node
            a.cut_nodes = self.cut.cut_nodes
            a.cut_count = self.cut.cut_count
            a.theta_min = self.theta_min
            a.weights = self.cut_weights
            self._ratio_arrays = a

    @property
    def hierarchical(self) -> bool:
        return self.model.tree is not None

    def bind(self, shader) -> None:
        """Point a :class:`._pipeline.ShexpShader` at these buffers (node spheres, cut lists)."""
        shader.bind_spheres(self.node_centres, self.node_radii, self.node_static)
        shader.set_planes(self.model.planes)
        shader.set_receiver_clusters(self.vertex_cluster)
        if self.hierarchical:
            shader.bind_cut(self.cut.cut_nodes, self.cut.cut_count, self.cut_weights if self.ratio else None)
        else:
            shader.set_flat_cut()

    def launch(self, state) -> None:
        """Centres, refit, cluster bounds, cut and ratio vectors of the frame (kernels only).

        Args:
            state: the frame's :class:`~warpshade.scene._state.FrameState` on this device.
        """
        self.animator.launch(state)
        if not self.hierarchical:
            return
        self.refit.launch(self.animator.centres, self.animator.radii)
        self.bounds.launch(state.points)
        self.cut.launch(self.bounds.centres, self.bounds.radii)
        if self.ratio:
            wp.launch(self._ratio_kernel, dim=(self.clusters, self.capacity), device=self.device,
                      inputs=[self._ratio_arrays, self._exp_tables])

    def mean_cut_length(self) -> float:
        """Average entries per cluster of the current cut (host; synchronises)."""
        if not self.hierarchical:
            return float(self.model.leaf_count)
        return float(self.cut.cut_count.numpy()[: self.clusters].mean())
