"""Data-driven visibility (Nowrouzezahrai, Kalogerakis, Fiume 2009, sec. 5) as graph stages.

* ``visibility.data`` (precompute): the training data (:mod:`._training`): ray-traced SH
  visibility (no cosine, open below the horizon), world frame, at every training frame of the
  clip ``training`` (tasks for an executor, each kept in the run's cache as it finishes), with
  the frame's points and normals, the inputs (joint rotations or dihedral angles) and what the
  clustering reads.
* ``visibility.fit`` (precompute): clusters, cluster tangent frames, input PCA, per-cluster PCA
  of the local visibility and one model per cluster (linear, quadratic or a tanh network), sizes
  from an error budget (:mod:`._model`, :mod:`._clusters`, :mod:`._fit`); clusters are executor tasks.
* ``visibility.predict`` (per frame): pose features -> input PCA -> per-cluster model ->
  per-vertex local visibility and the tangent frames it is expressed in (:mod:`._kernels`),
  for ``rpo.shade`` (``visibility_space = "local"``) or ``visibility.diffuse``.
* ``visibility.diffuse`` (per frame): the clamped cosine re-applied to the local visibility
  (eq. 14), turned to the world and dotted with the lighting: diffuse radiance
  ``albedo / pi * L . t``.
"""

from __future__ import annotations

import numpy as np

from .._shared.pose import PARAMETERISATIONS, ROOT_MODES, pose_features, pose_layout, root_references
from .._shared.pose_kernels import PoseInputs
from .._shared.training import (TrainingClipStage, check_same_character, parse_frame_selection, topology_key,
                                trace_training)
from .._common import order_param, rays_param
from ..stage import FrameStage, Param, Port, PrecomputeStage, StageError, register_stage
from . import _cloth as cloth, _kernels as kernels
from ._model import FRAME_KINDS, METRICS, MODELS, fit_visibility, model_from_arrays
from ._relative import relative_features_f64
from ._select import FOLD_TRAIN_MIN, fewest_frames
from ._stack import TOTALS
from ._training import FEATURE_SOURCES, dense_skin_weights, mesh_ids, rest_points

__all__: list[str] = []

_ORDER = order_param(4, minimum=2, maximum=6)


@register_stage
class VisibilityDataStage(TrainingClipStage):
    type_name = "visibility.data"
    version = 1
    description = ("ray-traced SH visibility (no cosine), points, normals and inputs at every frame of a training "
                   "clip (tasks for an executor)")

    @classmethod
    def quick_params(cls, params):
        """16 rays on 10 training frames instead of hundreds (minutes): every 60th of a 600-frame
        character clip -- two blocks of the blocked cross-validation, at least
        :func:`~warpshade.methods.visibility._select.fewest_frames` = 8; three of them are the rest pose
        the range-of-motion part returns to between sweeps, so one fold trains on a single pose, the
        case in which the selection once changed from host to host (issue 37) -- or every 12th of the
        cloth's 120-frame clip."""
        return {"samples": 16, "frames": "0:120:12" if "cloth" in str(params.get("training", "")) else "0:600:60"}
    parameters = {
        "training": TrainingClipStage.TRAINING,
        "frames": Param(None, str, "training frames as 'start:stop[:step]' over frame indices (default: all)"),
        "order": _ORDER,
        "samples": rays_param(128, "rays per vertex per training frame"),
        "seed": Param(0, int, "base seed of the per-frame ray rotations"),
        "features": Param("joints", str, "inputs: joint rotations of a skinned mesh, or dihedral angles of the "
                          "interior edges of a point-cached mesh", choices=FEATURE_SOURCES),
    }

    def output_ports(self):
        return {"data": Port("arrays", (), "training visibility (p, V, C) world frame, points, normals, inputs")}

    def _training_frames(self, train) -> np.ndarray:
        """The indices of the training frames ``frames`` selects in ``train``; StageError naming the
        parameter when the selection is malformed or too short for the fit's cross-validation."""
        where = f"stage {self.name!r} ({self.type_name})"
        try:
            idx = parse_frame_selection(self.params["frames"], train, where + ": parameter 'frames'")
        except ValueError as exc:
            raise StageError(str(exc) if str(exc).startswith("stage") else f"{where}: {exc}") from None
        fewest = fewest_frames()
        if idx.size < fewest:
            raise StageError(f"{where}: parameter 'frames' selects {idx.size} frame(s); the model needs at least "
                             f"{fewest} (its blocked cross-validation trains every fold on at least "
                             f"{FOLD_TRAIN_MIN} frames)")
        return idx

    def check_scene(self, scene, ctx):
        # trained on the graph's own scene: the frame selection is known before anything is traced
        if not self.params["training"]:
            self._training_frames(scene)

    def precompute(self, ctx, inputs):
        p = self.params
        where = f"stage {self.name!r} ({self.type_name})"
        train = self.training_scene(ctx)
        try:
            if p["features"] == "joints":
                check_same_character(train, ctx.scene, where)
            elif train.vertex_count != ctx.scene.vertex_count or not np.array_equal(train.faces, ctx.scene.faces):
                raise ValueError(f"training clip {train.source} and scene {ctx.scene.source} differ in vertices or "
                                 "faces: a model applies to the same mesh only")
        except ValueError as exc:
            raise StageError(str(exc) if str(exc).startswith("stage") else f"{where}: {exc}") from None
        idx = self._training_frames(train)
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
        if v.shape[0] < fewest_frames():  # left by a version that did not check the selection: traced again
            raise ValueError(f"visibility.data: {v.shape[0]} training frame(s), fewer than the fit needs "
                             f"({fewest_frames()})")
        for key in ("points", "normals"):
            if d.get(key) is None or d[key].shape != v.shape[:2] + (3,):
                raise ValueError(f"visibility.data: {key} missing or not (p, V, 3)")
        source = FEATURE_SOURCES[int(np.asarray(d["settings"]).reshape(-1)[3])]
        need = [f"poses_{k}" for k in PARAMETERISATIONS] if source == "joints" else ["dihedral"]
        for key in need:
            if d.get(key) is None or d[key].shape[0] != v.shape[0]:
                raise ValueError(f"visibility.data: {key} missing or not one row per training frame")


# ---- the fit -------------------------------------------------------------------------------------
@register_stage
class VisibilityFitStage(PrecomputeStage):
    type_name = "visibility.fit"
    version = 3  # 3: relative inputs (pose_mean may hold them; relative_neighbours)
    uses_scene = False
    description = ("clusters, cluster frames, input PCA, per-cluster visibility PCA and a linear / quadratic / "
                   "network model per cluster (sizes from the error budget, cross-validated)")
    #: One network size (4 hidden neurons) with a short fit (10 iterations).
    quick = {"hidden": (4,), "max_iterations": 10}
    parameters = {
        "regressor": Param("network", str, "per-cluster model: ridge, ridge on second-order features, a "
                       "one-hidden-layer tanh network (eq. 12-13), or 'auto': each cluster's ridge map (linear or "
                       "quadratic, global or nearby-joint inputs, input count, penalty) chosen by blocked "
                       "cross-validation over contiguous segments of the training clip, or 'stack': each cluster's "
                       "non-negative combination of the best of those candidates, weighted to minimise their "
                       "blocked out-of-fold error (stacked regression)", choices=MODELS),
        "space": Param("cluster", str, "frames the visibility is modelled in: cluster PCA directions in the "
                        "tangent plane, the one-ring frames of warpshade.geometry._frames, or the world frame "
                        "(measurements only: the frame stages take local frames)", choices=FRAME_KINDS),
        "pose": Param("quaternion", str, "joint-angle parameterisation", choices=tuple(PARAMETERISATIONS)),
        "root": Param("include", str, "root joint: world translation + rotation as inputs, or ignored",
                      choices=ROOT_MODES),
        "input_variance": Param(0.99, float, "input PCA: variance of the inputs kept (the budget)", minimum=0.5,
                                maximum=1.0),
        "input_max": Param(24, int, "input PCA: most components", minimum=1),
        "variance": Param(0.95, float, "per-cluster visibility PCA: variance kept (the budget)", minimum=0.5,
                          maximum=1.0),
        "predictable": Param(0.99, float, "per-cluster components kept after the fit: variance of the model's "
                             "predictions kept (the budget; 1 keeps every fitted component)", minimum=0.5, maximum=1.0),
        "k_max": Param(32, int, "per-cluster visibility PCA: most components", minimum=1),
        "bandwidth": Param(0.3, float, "mean-shift radius in skinning-weight space", minimum=1e-3),
        "min_cluster": Param(8, int, "smallest cluster (smaller ones are merged into the nearest)", minimum=1),
        "hidden": Param((8.0, 16.0), tuple, "network: neuron counts cross-validated"),
        "max_iterations": Param(300, int, "network: most L-BFGS-B iterations per fit", minimum=1),
        "margin": Param(0.25, float, "inputs clamped to their training range widened by this fraction",
                        minimum=0.0),
        "seed": Param(0, int, "seed of the networks' extra hidden units"),
        "metric": Param("visibility", str, "error the per-cluster PCA, model selection and fits minimise: of the "
                        "local visibility (any shading), or of the cosine-weighted transfer M_cos v of eq. 14, the "
                        "part of the visibility diffuse shading sees (visibility.diffuse only)", choices=METRICS),
        "stack_top": Param(0, int, "stack: candidates (least blocked cross-validation error first) a cluster's "
                           "combination may use; 0: every candidate", minimum=0),
        "relative": Param(0, int, "auto, stack: candidate inputs of each cluster from its nearest clusters' "
                          "centroids in its rigid frame, at most this many neighbours (0: none; "
                          "methods/visibility/relative.py)", minimum=0),
        "stack_total": Param("one", str, "stack: non-negative weights summing to one ('one'), non-negative "
                             "least squares ('free': a shrinkage towards the cluster mean), or equal weights "
                             "('equal', a plain average of the stack_top best)", choices=TOTALS),
    }

    def __init__(self, name, params=None):
        super().__init__(name, params)
        # parameter-only problems: refused when the graph is checked, not after the training data is traced
        p = self.params
        where = f"stage {self.name!r} ({self.type_name})"
        if not p["hidden"] or any(h < 1 or h != int(h) for h in p["hidden"]):
            raise StageError(f"{where}: parameter 'hidden' needs positive whole neuron counts, got {p['hidden']!r}")
        if p["relative"] > 0 and p["regressor"] not in ("auto", "stack"):
            raise StageError(f"{where}: parameter 'relative' = {p['relative']} applies to regressor = 'auto' or 'stack' "
                             f"only (the models that choose among candidate inputs), not regressor = {p['regressor']!r}")
        if p["metric"] == "diffuse" and p["space"] == "world":
            raise StageError(f"{where}: parameter 'metric' = 'diffuse' applies to local frames only (the cosine is "
                             "about the local normal), not space = 'world'")
        #: The SH order of the training data on port 'data' when its provider is known (check_wiring).
        self.data_order: int | None = None
        self._predictors: dict = {}  # visibility.predict stages wired to 'model', checked once data_order is known

    def input_ports(self):
        return {"data": Port("arrays", (), "training data of visibility.data")}

    def output_ports(self):
        return {"model": Port("arrays", (), "fitted data-driven visibility model (visibility.model)")}

    def check_wiring(self, upstream):
        provider, port = upstream["data"]
        if not isinstance(provider, VisibilityDataStage):
            what = "the scene" if provider is None else f"stage {provider.name!r} ({provider.type_name})"
            raise StageError(f"stage {self.name!r} ({self.type_name}): input 'data' is fed by {what}'s {port!r}, "
                             "which is not visibility training data; wire a visibility.data stage's 'data'")
        self.data_order = int(provider.params["order"])
        for predictor in self._predictors.values():  # those whose wiring was checked before this stage's
            predictor._check_fit()

    def precompute(self, ctx, inputs):
        p = self.params
        where = f"stage {self.name!r} ({self.type_name})"
        hidden = [int(h) for h in p["hidden"]]
        data = inputs["data"]
        labels = None
        if int(np.asarray(data["settings"]).reshape(-1)[3]) == FEATURE_SOURCES.index("dihedral"):
            labels = cloth.cluster_labels(data)
        try:
            with ctx.executor() as ex:
                model = fit_visibility(data, regressor=p["regressor"], space=p["space"], pose=p["pose"], root=p["root"],
                                       input_variance=p["input_variance"], input_max=p["input_max"],
                                       variance=p["variance"], predictable=p["predictable"], k_max=p["k_max"], bandwidth=p["bandwidth"],
                                       min_cluster=p["min_cluster"], hidden=hidden,
                                       max_iterations=p["max_iterations"], margin=p["margin"], seed=p["seed"],
                                       labels=labels, executor=ex, progress=ctx.progress, metric=p["metric"],
                                       stack_top=p["stack_top"], stack_total=p["stack_total"],
                                       relative=p["relative"])
        except ValueError as exc:
            raise StageError(f"{where}: {exc}") from None
        self.report = model.report
        return {"model": model.arrays}

    def check_artifact(self, outputs):
        model_from_arrays(outputs["model"])


# ---- per frame -------------------------------------------------------------------------------------
#: Vertices per CPU chunk below which a launch is not split over cores.
_CHUNK_MIN = 2048
#: The same for the per-frame model's own launches (the reconstruction and the frames: well under a
#: microsecond per vertex), where a chunked launch costs more than it saves below this many vertices
#: (its pool round trip and the break of the recorded frame: ~0.5 ms each, measured on the figure).
_PREDICT_CHUNK_MIN = 16384


def _f32(a, dev, dtype=None):
    from ..._wp import wp

    return wp.array(np.ascontiguousarray(np.asarray(a, np.float32)), dtype=dtype or wp.float32, device=dev)


def _i32(a, dev):
    from ..._wp import wp

    return wp.array(np.ascontiguousarray(np.asarray(a, np.int32)), dtype=wp.int32, device=dev)


@register_stage
class VisibilityPredictStage(FrameStage):
    type_name = "visibility.predict"
    description = ("per-vertex SH visibility in local frames from the frame's pose by the data-driven model "
                   "(pose -> input PCA -> per-cluster model -> PCA basis), with their tangent frames")
    parameters = {"order": _ORDER,
                  "basis": Param("half", str, "device storage of the per-vertex PCA basis (the bulk of a frame's "
                                 "memory reads): float16 or float32", choices=kernels.BASIS_PRECISIONS)}

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def input_ports(self):
        return {"model": Port("arrays", (), "fitted model of visibility.fit"), "points": Port("vec3", ("V",)),
                "normals": Port("vec3", ("V",))}

    def output_ports(self):
        return {"visibility": Port("float32", ("V", "C"), "SH visibility (no cosine, open below the horizon), "
                                   "tangent frames", space="local"),
                "tangents": Port("mat33", ("V",), "the tangent frames of the visibility, rows (t, b, n)")}

    def check_wiring(self, upstream):
        self._fit = upstream["model"][0] if isinstance(upstream["model"][0], VisibilityFitStage) else None
        if self._fit is not None:
            self._fit._predictors[self.name] = self  # the fit checks this stage again once its own data is known
        self._check_fit()

    def _check_fit(self):
        """What the parameters of the ``visibility.fit`` on port 'model' (and of the data feeding it)
        say about the model, checked with the graph's wiring, before anything is traced or fitted
        (``setup`` checks the model's arrays again, whatever made them)."""
        fit = getattr(self, "_fit", None)
        if fit is None:
            return
        where = f"stage {self.name!r} ({self.type_name})"
        if fit.params["space"] == "world":
            raise StageError(f"{where}: input 'model' is fed by stage {fit.name!r} ({fit.type_name}) with parameter "
                             "'space' = 'world' (a model in the world frame is for measurements; this stage predicts "
                             "in local frames): fit it with space = 'cluster' or 'one_ring'")
        if fit.data_order is not None and fit.data_order != self.params["order"]:
            raise StageError(f"{where}: parameter 'order' = {self.params['order']}, but the model of stage "
                             f"{fit.name!r} is trained on visibility of order {fit.data_order} (its training data's "
                             "parameter 'order'); give both the same order")

    def setup(self, ctx, inputs):
        from ..._wp import cpu_workers, wp

        where = f"stage {self.name!r} ({self.type_name})"
        try:
            model = model_from_arrays(inputs["model"])
        except ValueError as exc:
            raise StageError(f"{where}: {exc}") from None
        a = model.arrays
        meta = a["meta"].reshape(-1)
        order, _, frames_code, source, kind, root, kin, d, _, kc = (int(x) for x in meta[:10])
        scene, dev = ctx.scene, ctx.device
        if order != self.params["order"]:
            raise StageError(f"{where}: the model was trained at order {order}; the stage has order {self.params['order']}")
        if FRAME_KINDS[frames_code] == "world":
            raise StageError(f"{where}: the model was fitted in the world frame (space = 'world', for measurements); "
                             "fit it with space = 'cluster' or 'one_ring'")
        if a["labels"].shape[0] != scene.vertex_count:
            raise StageError(f"{where}: the model has {a['labels'].shape[0]} vertices, scene "
                             f"{scene.source or '<arrays>'} has {scene.vertex_count}")
        self.model, self._device = model, dev
        self._source = FEATURE_SOURCES[source]
        if self._source == "joints":
            if not np.array_equal(a["topology"], topology_key(scene)):
                raise StageError(f"{where}: scene {scene.source or '<arrays>'} is not the character the model was "
                                 "trained on (vertex count, faces, skin weights, rest or bind transforms differ)")
            self._pose = PoseInputs(scene, list(PARAMETERISATIONS)[kind], ROOT_MODES[root], a["root_reference"], dev)
            if self._pose.layout.size != a["pose_scale"].size:
                raise StageError(f"{where}: the model expects {a['pose_scale'].size} pose inputs, the scene gives "
                                 f"{self._pose.layout.size}")
            features = self._pose.features
            poses = pose_features(scene, np.arange(len(scene.frames)), self._pose.layout,
                                  root_reference=a["root_reference"])
        else:
            self._pose = cloth.DihedralInputs(scene, dev)
            features = self._pose.features
            poses = np.stack([cloth.dihedral_angles(scene.points_at(float(f)), scene.faces) for f in scene.frames])
        self._relative = _RelativeInputs(a, features, dev)
        features = self._relative.features
        if self._relative.count:
            poses = np.concatenate([poses, relative_features_f64(np.stack([scene.points_at(float(f)) for f in scene.frames]),
                                                                 a["rest_points"], a["labels"], a["relative_neighbours"])], 1)
        if features.shape[0] != max(a["pose_mean"].size, 1):
            raise StageError(f"{where}: the model expects {a['pose_mean'].size} inputs, the scene gives "
                             f"{features.shape[0]}")
        self._mean = _f32(a["pose_mean"], dev)
        self._w_in = wp.array(np.asarray(a["input_weights"], np.float32), dtype=wp.float32, device=dev)
        self._rows = tuple(_i32(r, dev) for r in kernels.input_rows(a["input_weights"]))
        self._low, self._high = _f32(a["x_low"], dev), _f32(a["x_high"], dev)
        self._x = wp.zeros(kin, dtype=wp.float32, device=dev)
        self._quad_i, self._quad_j = _i32(a["quad_i"], dev), _i32(a["quad_j"], dev)
        hidden = int(a["hidden_offset"][-1])
        self._act = wp.zeros(d + max(hidden, 1), dtype=wp.float32, device=dev)
        self._hidden = hidden
        self._d = d
        self._w1 = wp.array(np.asarray(a["w1"], np.float32), dtype=wp.float32, device=dev)
        self._b1 = _f32(a["b1"], dev)
        self._w2, self._b2 = _f32(a["w2"], dev), _f32(a["b2"], dev)
        self._src, self._len, self._woff = _i32(a["source"], dev), _i32(a["length"], dev), _i32(a["w_offset"], dev)
        self._y = wp.zeros(max(int(a["y_offset"][-1]), 1), dtype=wp.float32, device=dev)
        self._outputs = int(a["y_offset"][-1])
        self._recon, self._vmean, self._basis = kernels.reconstruct_setup(a["mean"], a["basis"], dev,
                                                                          self.params["basis"])
        self._labels, self._comps, self._yoff = _i32(a["labels"], dev), _i32(a["components"], dev), _i32(a["y_offset"], dev)
        v = scene.vertex_count
        self._vis = wp.zeros((v, order * order), dtype=wp.float32, device=dev)
        self._frames = wp.zeros(v, dtype=wp.mat33, device=dev)
        self._points, self._normals = inputs["points"], inputs["normals"]
        self._frame_kind = FRAME_KINDS[frames_code]
        if self._frame_kind == "cluster":
            self._order, self._offsets = _i32(a["frame_order"], dev), _i32(a["frame_offsets"], dev)
            self._fweights = wp.array(np.asarray(a["frame_weights"], np.float32), dtype=wp.float32, device=dev)
            self._rest_axes = wp.array(np.asarray(a["rest_axes"], np.float32), dtype=wp.vec3, device=dev)
            self._axes = wp.zeros((kc, 2), dtype=wp.vec3, device=dev)
        else:
            from ...geometry._frames import TangentFrames

            self._tf = TangentFrames(a["rest_points"], a["faces"], device=dev)
        self._workers = cpu_workers() if dev.is_cpu else 1
        self._features = features
        self._novelty = novelty_report(model, poses)
        self._frame_times = np.asarray(scene.frames, np.float64)
        return {"visibility": self._vis, "tangents": self._frames}

    def launch(self, state):
        from ..._wp import launch_parallel, wp

        dev = self._device
        self._pose.launch(state)
        self._relative.launch(self._points)
        wp.launch(kernels.inputs_kernel, dim=self._x.shape[0], device=dev,
                  inputs=[self._features, self._mean, self._w_in, *self._rows, self._low, self._high, self._x])
        wp.launch(kernels.features_kernel, dim=self._d, device=dev, inputs=[self._x, self._quad_i, self._quad_j, self._act])
        if self._hidden:
            wp.launch(kernels.hidden_kernel, dim=self._hidden, device=dev,
                      inputs=[self._x, self._w1, self._b1, self._d, self._act])
        if self._outputs:
            wp.launch(kernels.outputs_kernel, dim=self._outputs, device=dev,
                      inputs=[self._act, self._w2, self._b2, self._src, self._len, self._woff, self._y])
        launch_parallel(self._recon, self._vis.shape[0],
                        lambda a, b: [self._vmean, self._basis, self._labels, self._comps, self._yoff, self._y, a,
                                      self._vis], dev, self._workers, min_count=_PREDICT_CHUNK_MIN)
        if self._frame_kind == "cluster":
            wp.launch(kernels.cluster_axes_kernel, dim=self._axes.shape[0], device=dev,
                      inputs=[self._points, self._order, self._offsets, self._fweights, self._rest_axes, self._axes])
            launch_parallel(kernels.cluster_frames_kernel, self._frames.shape[0],
                            lambda a, b: [self._normals, self._labels, self._axes, a, self._frames], dev, self._workers,
                            min_count=_PREDICT_CHUNK_MIN)
        else:
            self._tf.compute(self._points, self._normals, out=self._frames)

    def diagnostics(self) -> dict:
        """Novelty of the scene's inputs against the training inputs, and how many frames clamp."""
        return dict(self._novelty)

    def model_bytes(self) -> int:
        """Bytes of the model on the device: float32 arrays, the basis at its precision."""
        half = self.params["basis"] == "half"
        return 4 * self.model.stored_floats() - (2 * int(np.asarray(self.model.arrays["basis"]).size) if half else 0)


class _RelativeInputs:
    """The relative inputs of the frame (:mod:`._relative`) after the pose vector ``pose`` (a copy of it
    in front of them); without relative inputs ``features`` is ``pose`` and nothing is launched."""

    def __init__(self, arrays, pose, dev):
        from ..._wp import wp
        from ._relative import width

        nb = np.asarray(arrays.get("relative_neighbours", np.zeros((0, 0))), np.int32)
        self.count = int(nb.shape[1]) if nb.size else 0
        self.features, self._pose, self._dev = pose, pose, dev
        if not self.count:
            return
        labels = np.asarray(arrays["labels"])
        kc = nb.shape[0]
        rest = np.asarray(arrays["rest_points"], np.float64)
        self._base = int(np.asarray(arrays["pose_scale"]).size)
        self.features = wp.zeros(self._base + kc * width(self.count), dtype=wp.float32, device=dev)
        self._order = _i32(np.argsort(labels, kind="stable"), dev)
        self._offsets = _i32(np.concatenate([[0], np.cumsum(np.bincount(labels, minlength=kc))]), dev)
        self._rest = _f32(rest, dev, wp.vec3)
        self._rest_centroids = _f32(np.stack([rest[labels == k].mean(0) for k in range(kc)]), dev, wp.vec3)
        self._neighbours = wp.array(nb, dtype=wp.int32, device=dev)
        self._rotations = wp.zeros(kc, dtype=wp.mat33, device=dev)
        self._centroids = wp.zeros(kc, dtype=wp.vec3, device=dev)

    def launch(self, points):
        from ..._wp import wp

        if not self.count:
            return
        dev = self._dev
        if self._base:
            wp.launch(kernels.copy_prefix_kernel, dim=self._base, device=dev, inputs=[self._pose, self.features])
        kc = self._rotations.shape[0]
        wp.launch(kernels.cluster_rigid_kernel, dim=kc, device=dev,
                  inputs=[points, self._rest, self._order, self._offsets, self._rest_centroids, self._rotations,
                          self._centroids])
        wp.launch(kernels.relative_features_kernel, dim=kc * (self.count + 3), device=dev,
                  inputs=[self._rotations, self._centroids, self._neighbours, self._base, self.features])


def novelty_report(model, poses: np.ndarray) -> dict:
    """How far the scene's inputs lie from the training inputs (:func:`warpshade.methods.datadriven.novelty`)
    and how many of its frames have an input-PCA coordinate clamped to the widened training range."""
    from .._shared.pose_space import novelty
    from ._mirror import inputs_f64
    from ._model import pose_space_of

    a = model.arrays
    nov = novelty(pose_space_of(model), np.atleast_2d(poses)[:, :np.asarray(a["pose_scale"]).size], a["training_poses"])
    x = (np.atleast_2d(poses) - a["pose_mean"]) @ a["input_weights"]
    clamped = np.any(np.abs(inputs_f64(a, poses) - x) > 0, axis=1)
    return {"novelty_max": float(nov["nearest"].max()), "novelty_mean": float(nov["nearest"].mean()),
            "range_excess_max": float(nov["range"].max()), "constant_drift_max": float(nov["constant"].max()),
            "frames_clamped": int(clamped.sum()), "frames": int(clamped.size)}


@register_stage
class VisibilityDiffuseStage(FrameStage):
    type_name = "visibility.diffuse"
    description = "diffuse radiance from local SH visibility: the clamped cosine re-applied (eq. 14), lit in the world"
    parameters = {"order": _ORDER}

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def input_ports(self):
        return {"visibility": Port("float32", ("V", "C"), space="local"), "tangents": Port("mat33", ("V",)),
                "albedo": Port("float32", ("V", 3)), "lighting": Port("lighting")}

    def output_ports(self):
        return {"radiance": Port("float32", ("V", 3), "outgoing diffuse radiance, linear RGB")}

    def setup(self, ctx, inputs):
        from ..._wp import wp
        from ...basis.sh_warp import sh_kernels
        from ...basis import sh
        from .._common import ShLighting

        n = self.params["order"]
        try:
            self._lighting = ShLighting(inputs["lighting"], n)
        except ValueError as exc:
            raise StageError(f"stage {self.name!r}: {exc}") from None
        if inputs["lighting"].sphere_light_count:
            raise StageError(f"stage {self.name!r}: shades distant lighting (SH) only; this run has sphere lights")
        dev = ctx.device
        self._vis, self._frames, self._albedo = inputs["visibility"], inputs["tangents"], inputs["albedo"]
        self._cos = _f32(sh.clamped_cosine_sh(n), dev)
        self._tables = sh_kernels(n).tables(dev)
        self._kernel = kernels.diffuse_kernel(n)
        self._radiance = wp.zeros((ctx.dims["V"], 3), dtype=wp.float32, device=dev)
        return {"radiance": self._radiance}

    def launch(self, state):
        from ..._wp import launch_parallel

        self._lighting.launch()
        launch_parallel(self._kernel, self._radiance.shape[0],
                        lambda a, b: [self._vis, self._frames, self._albedo, self._lighting.light, self._cos,
                                      self._tables, a, self._radiance], self._radiance.device,
                        min_count=_CHUNK_MIN)
