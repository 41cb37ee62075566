"""Data-driven visibility (Nowrouzezahrai, Kalogerakis, Fiume 2009, sec. 5) as graph stages.

* ``visibility.data`` (precompute): the training data (:mod:`.training`): ray-traced SH
  visibility (no cosine, open below the horizon), world frame, at every training frame of the
  clip ``training`` (tasks for an executor, each kept in the run's cache as it finishes), with
  the frame's points and normals, the inputs (joint rotations or dihedral angles) and what the
  clustering reads.
* ``visibility.fit`` (precompute): clusters, cluster tangent frames, input PCA, per-cluster PCA
  of the local visibility and one model per cluster (linear, quadratic or a tanh network), sizes
  from an error budget (:mod:`.model`, :mod:`.clusters`, :mod:`.fit`); clusters are executor tasks.
* ``visibility.predict`` (per frame): pose features -> input PCA -> per-cluster model ->
  per-vertex local visibility and the tangent frames it is expressed in (:mod:`.kernels`),
  for ``rpo.shade`` (``visibility_space = "local"``) or ``visibility.diffuse``.
* ``visibility.diffuse`` (per frame): the clamped cosine re-applied to the local visibility
  (eq. 14), turned to the world and dotted with the lighting: diffuse radiance
  ``albedo / pi * L . t``.
"""

from __future__ import annotations

import numpy as np

from ..common import order_param, rays_param
from ..datadriven.pose import PARAMETERISATIONS, pose_features, pose_layout, root_references
from ..datadriven.training import check_same_character, parse_frame_selection, topology_key, trace_training
from ..stage import Param, Port, PrecomputeStage, StageError, register_stage
from .training import FEATURE_SOURCES, dense_skin_weights, mesh_ids, rest_points

__all__: list[str] = []

_ORDER = order_param(4, minimum=2, maximum=6)


def _load_training(ctx, stage):
    """The training scene of a data stage (the graph's scene when ``training`` is empty)."""
    from ..datadriven.stages import _load_training as load

    return load(ctx, stage)


def _dihedral_module():
    try:
        from . import cloth
    except ImportError:
        return None
    return cloth


@register_stage
class VisibilityDataStage(PrecomputeStage):
    type_name = "visibility.data"
    version = 1
    description = ("ray-traced SH visibility (no cosine), points, normals and inputs at every frame of a training "
                   "clip (tasks for an executor)")
    parameters = {
        "training": Param("", str, "training clip: a USD file relative to the graph, or a scene spec such as "
                          "'bundled:figure_train' (default: the graph's own scene)"),
        "frames": Param(None, str, "training frames as 'start:stop[:step]' over frame indices (default: all)"),
        "order": _ORDER,
        "samples": rays_param(128, "rays per vertex per training frame"),
        "seed": Param(0, int, "base seed of the per-frame ray rotations"),
        "features": Param("joints", str, "inputs: joint rotations of a skinned mesh, or dihedral angles of the "
                          "interior edges of a point-cached mesh", choices=FEATURE_SOURCES),
    }

    def __init__(self, name, params=None):
        super().__init__(name, params)
        self.uses_scene = not self.params["training"]

    def output_ports(self):
        return {"data": Port("arrays", (), "training visibility (p, V, C) world frame, points, normals, inputs")}

    def cache_params(self):
        return {k: v for k, v in self.params.items() if k != "training"}

    def cache_key(self, ctx):
        if not self.params["training"]:
            return {}
        return {"training": _load_training(ctx, self).fingerprint()}

    def precompute(self, ctx, inputs):
        p = self.params
        where = f"stage {self.name!r} ({self.type_name})"
        train = _load_training(ctx, self)
        try:
            if p["features"] == "joints":
                check_same_character(train, ctx.scene, where)
            elif train.vertex_count != ctx.scene.vertex_count or not np.array_equal(train.faces, ctx.scene.faces):
                raise ValueError(f"training clip {train.source} and scene {ctx.scene.source} differ in vertices or "
                                 "faces: a model applies to the same mesh only")
            idx = parse_frame_selection(p["frames"], train, where + ": parameter 'frames'")
        except ValueError as exc:
            raise StageError(str(exc) if str(exc).startswith("stage") else f"{where}: {exc}") from None
        if idx.size < 4:
            raise StageError(f"{where}: parameter 'frames' selects {idx.size} frame(s); the model needs at least 4")
        out = {}
        if p["features"] == "joints":
            try:
                layouts = {kind: pose_layout(train, kind, "include") for kind in PARAMETERISATIONS}
            except ValueError as exc:
                raise StageError(f"{where}: {exc} (features = 'joints' needs a skinned mesh; point-cached meshes "
                                 "take features = 'dihedral')") from None
            ref = root_references(train, int(idx[0]))
            out["root_reference"] = ref
            for kind, layout in layouts.items():
                out[f"poses_{kind}"] = pose_features(train, idx, layout, root_reference=ref)
                root = np.zeros(layout.size, np.int8)
                for j in np.flatnonzero(layout.parents < 0):
                    if layout.offsets[j] >= 0:
                        root[layout.offsets[j]:layout.offsets[j] + layout.widths[j]] = 1
                out[f"root_{kind}"] = root
        else:
            cloth = _dihedral_module()
            if cloth is None:
                raise StageError(f"{where}: features = 'dihedral' needs warpshade.methods.visibility.cloth, "
                                 "which this installation does not have")
            out["dihedral"] = np.stack([cloth.dihedral_angles(train.points_at(float(train.frames[i])), train.faces)
                                        for i in idx]).astype(np.float64)
        tasks: dict = {}
        with ctx.executor() as ex:
            vis = trace_training(train, idx, p["order"], p["samples"], seed=p["seed"], space="world", executor=ex,
                                 progress=ctx.progress, cache=ctx.cache, report=tasks, quantity="visibility")
        frames = train.frames[idx]
        out.update({
            "visibility": vis,
            "points": np.stack([train.points_at(float(f)) for f in frames]).astype(np.float32),
            "normals": np.stack([train.normals_at(float(f)) for f in frames]).astype(np.float32),
            "rest_points": rest_points(train), "faces": np.asarray(train.faces, np.int32),
            "skin_weights": dense_skin_weights(train), "mesh_ids": mesh_ids(train),
            "frames": np.asarray(frames, np.float64), "frame_indices": idx.astype(np.int64),
            "topology": topology_key(train),
            "settings": np.array([p["order"], p["samples"], p["seed"], FEATURE_SOURCES.index(p["features"])], np.int64),
        })
        self.report = {"training": train.source, "frames": int(idx.size), "vertices": int(train.vertex_count),
                       "coefficients": int(vis.shape[2]), "bytes": int(vis.nbytes),
                       "executor": getattr(ex, "name", "?"), **tasks}
        return {"data": out}

    def check_artifact(self, outputs):
        d = outputs["data"]
        v = d.get("visibility")
        if v is None or v.ndim != 3 or v.dtype != np.float32 or not np.all(np.isfinite(v)):
            raise ValueError("visibility.data: visibility must be a finite float32 (p, V, C) array")
        for key in ("points", "normals"):
            if d.get(key) is None or d[key].shape != v.shape[:2] + (3,):
                raise ValueError(f"visibility.data: {key} missing or not (p, V, 3)")
        source = FEATURE_SOURCES[int(np.asarray(d["settings"]).reshape(-1)[3])]
        need = [f"poses_{k}" for k in PARAMETERISATIONS] if source == "joints" else ["dihedral"]
        for key in need:
            if d.get(key) is None or d[key].shape[0] != v.shape[0]:
                raise ValueError(f"visibility.data: {key} missing or not one row per training frame")
