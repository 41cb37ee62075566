"""Data-driven PRT (Nowrouzezahrai, Kalogerakis, Fiume 2007) as graph stages.

* ``datadriven.data`` (precompute): the training data -- ray-traced transfer of every vertex at
  every training frame (order ``order``, world frame, optionally with ``bounces`` diffuse
  bounces) and the pose vectors of those frames in every parameterisation (:mod:`.pose`). The
  training clip is ``training`` (a USD file, relative to the stage graph; default: the graph's
  own scene); it must hold the same character as the scene the graph runs on. The frames are
  independent tasks for an executor (:mod:`.training`; ``warpshade run --scheduler``), each kept
  in the run's cache as it finishes, so that an interrupted run resumes where it stopped.
* ``datadriven.fit`` (precompute): the linear model from pose to transfer (:mod:`._model`): full,
  or reduced by PCA in pose and coefficient space with the sizes from an error budget on
  validation frames held out of the training clip; alpha per coefficient by closed-form LOO.
* ``datadriven.transfer`` (per frame): the pose vector from the frame's joint transforms, then
  the model's products (:mod:`._kernels`), giving transfer vectors (V, C) for ``prt.shade`` --
  or (V, 3, C) per colour channel for ``prt.shade_rgb`` when trained with bounces.

Radiance = albedo / pi * dot(L, t), the static-PRT convention (:mod:`warpshade.methods.prt`).
"""

from __future__ import annotations

import numpy as np

from ..._wp import cpu_workers, launch_parallel, wp
from .._common import order_param, rays_param
from .._shared.pose import PARAMETERISATIONS, ROOT_MODES, pose_features, pose_layout, root_references
from .._shared.pose_kernels import PoseInputs
from .._shared.pose_space import PoseSpace, novelty, pose_space
from .._shared.training import (TrainingClipStage, check_same_character, parse_frame_selection, pose_columns, topology_key,
                                trace_training)
from ..stage import FrameStage, Param, Port, PrecomputeStage, StageError, register_stage
from . import _kernels as kernels
from ._model import DataDrivenModel, choose_sizes, fit_full, fit_reduced, lighting_weights, validation_split

__all__ = [
    "model_to_arrays",
    "model_from_arrays",
]

_ORDER = order_param(6, minimum=1, maximum=8)
_SPACES = {"world": 0, "local": 1}
_MODELS = ("reduced", "full")
#: Vertices per chunk below which the frame's products are one launch (CPU thread pool cost).
_CHUNK_MIN_VERTICES = 4096


@register_stage
class DataDrivenDataStage(TrainingClipStage):
    type_name = "datadriven.data"
    description = "ray-traced transfer and pose vectors at every frame of a training clip (tasks for an executor)"
    #: The graphs as written trace hundreds of training poses (minutes): every 50th of the first 600
    #: frames with 16 rays runs the same stages.
    quick = {"samples": 16, "frames": "0:600:50"}
    parameters = {
        "training": TrainingClipStage.TRAINING,
        "frames": Param(None, str, "training frames as 'start:stop[:step]' over frame indices (default: all)"),
        "order": _ORDER,
        "samples": rays_param(256, "rays per vertex per training frame"),
        "bounces": Param(0, int, "diffuse bounces of the training transfer (0 = direct only)", minimum=0, maximum=8),
        "space": Param("world", str, "frame of the transfer vectors (the paper: world; 'local' = per-vertex tangent "
                       "frames, for measuring: datadriven.fit accepts world only)", choices=tuple(_SPACES)),
        "seed": Param(0, int, "base seed of the per-frame ray rotations"),
    }

    def output_ports(self):
        return {"data": Port("arrays", (), "training transfer (p, V, M), poses per parameterisation, frames")}

    def precompute(self, ctx, inputs):
        p = self.params
        where = f"stage {self.name!r} ({self.type_name})"
        train = self.training_scene(ctx)
        try:
            check_same_character(train, ctx.scene, where)
            idx = parse_frame_selection(p["frames"], train, where + ": parameter 'frames'")
            layouts = {kind: pose_layout(train, kind, "include") for kind in PARAMETERISATIONS}
        except ValueError as exc:
            raise StageError(str(exc) if str(exc).startswith("stage") else f"{where}: {exc}") from None
        if p["bounces"] and p["space"] != "world":
            raise StageError(f"{where}: interreflected transfer (bounces > 0) is traced in the world frame only")
        tasks: dict = {}
        with ctx.executor() as ex:
            transfer = trace_training(train, idx, p["order"], p["samples"], seed=p["seed"], bounces=p["bounces"],
                                      space=p["space"], executor=ex, progress=ctx.progress, cache=ctx.cache,
                                      report=tasks)
        ref = root_references(train, int(idx[0]))
        out = {"transfer": transfer, "frames": np.asarray(train.frames[idx], np.float64),
               "frame_indices": idx.astype(np.int64), "topology": topology_key(train), "root_reference": ref,
               "settings": np.array([p["order"], p["samples"], p["bounces"], _SPACES[p["space"]], p["seed"]], np.int64)}
        for kind, layout in layouts.items():
            out[f"poses_{kind}"] = pose_features(train, idx, layout, root_reference=ref)
            root = np.zeros(layout.size, np.int8)
            for j in np.flatnonzero(layout.parents < 0):
                if layout.offsets[j] >= 0:
                    root[layout.offsets[j]:layout.offsets[j] + layout.widths[j]] = 1
            out[f"root_{kind}"] = root
        self.report = {"training": train.source, "frames": int(idx.size), "vertices": int(train.vertex_count),
                       "coefficients": int(transfer.shape[2]), "bytes": int(transfer.nbytes),
                       "executor": getattr(ex, "name", "?"), **tasks}
        return {"data": out}

    def check_artifact(self, outputs):
        d = outputs["data"]
        t = d.get("transfer")
        if t is None or t.ndim != 3 or t.dtype != np.float32:
            raise ValueError("datadriven.data: transfer must be a float32 (p, V, M) array")
        for kind in PARAMETERISATIONS:
            if d.get(f"poses_{kind}") is None or d[f"poses_{kind}"].shape[0] != t.shape[0]:
                raise ValueError(f"datadriven.data: poses_{kind} missing or not one row per training frame")


# ---- the fitted model as arrays (the cache and the frame stage) --------------------------------
_MODEL_CODES = {"full": 0, "reduced": 1}


def model_to_arrays(model: DataDrivenModel, *, kind: str, root: str, order: int, channels: int, topology,
                    root_reference, training_poses) -> dict:
    s = model.pose
    out = {
        "meta": np.array([_MODEL_CODES["reduced" if model.reduced else "full"], list(PARAMETERISATIONS).index(kind),
                          ROOT_MODES.index(root), order, channels], np.int64),
        "pose_mean": s.mean, "pose_scale": s.scale, "pose_active": s.active.astype(np.int8),
        "pose_components": s.components, "pose_variance": s.variance, "pose_low": s.low, "pose_high": s.high,
        "pose_total_variance": np.array([s.total_variance]),
        "alphas": model.alphas, "loo_error": model.loo_error, "topology": np.asarray(topology, np.int64),
        "root_reference": np.asarray(root_reference, np.float64), "training_poses": np.asarray(training_poses, np.float64),
    }
    if model.reduced:
        out["coefficients"] = model.coefficients.astype(np.float32)
        out["basis"] = model.basis.astype(np.float32)
    else:
        out["weights"] = model.weights.astype(np.float32)
    return out


def model_from_arrays(arrays: dict) -> tuple[DataDrivenModel, dict]:
    """Rebuild a model and its metadata; ValueError for anything that is not one."""
    try:
        meta = np.asarray(arrays["meta"]).reshape(-1)
        code, kind, root, order, channels = (int(x) for x in meta[:5])
        space = PoseSpace(np.asarray(arrays["pose_mean"], np.float64), np.asarray(arrays["pose_scale"], np.float64),
                          np.asarray(arrays["pose_active"]).astype(bool), np.asarray(arrays["pose_components"], np.float64),
                          np.asarray(arrays["pose_variance"], np.float64), float(np.asarray(arrays["pose_total_variance"])[0]),
                          np.asarray(arrays["pose_low"], np.float64), np.asarray(arrays["pose_high"], np.float64))
    except (KeyError, ValueError, IndexError) as exc:
        raise ValueError(f"datadriven model: missing or malformed entry ({exc})") from None
    reduced = code == _MODEL_CODES["reduced"]
    a, k = space.components.shape
    m = order * order * channels
    if reduced:
        coeffs = np.asarray(arrays.get("coefficients"))
        basis = np.asarray(arrays.get("basis"))
        if coeffs.ndim != 3 or coeffs.shape[0] != m or coeffs.shape[2] != k + 1 or basis.ndim != 2 or basis.shape[1] != coeffs.shape[1]:
            raise ValueError(f"datadriven model: coefficients {coeffs.shape} / basis {basis.shape} do not match "
                             f"{m} outputs and {k} pose components")
        model = DataDrivenModel(space, None, coeffs, basis, np.asarray(arrays["alphas"]), np.asarray(arrays["loo_error"]))
    else:
        weights = np.asarray(arrays.get("weights"))
        if weights.ndim != 3 or weights.shape[1] != m or weights.shape[2] != k + 1:
            raise ValueError(f"datadriven model: weights {weights.shape} do not match {m} outputs and {k} pose components")
        model = DataDrivenModel(space, weights, None, None, np.asarray(arrays["alphas"]), np.asarray(arrays["loo_error"]))
    if space.mean.shape != (a,):
        raise ValueError("datadriven model: pose statistics do not match the pose components")
    return model, {"kind": list(PARAMETERISATIONS)[kind], "root": ROOT_MODES[root], "order": order, "channels": channels,
                   "topology": np.asarray(arrays["topology"], np.int64), "root_reference": np.asarray(arrays["root_reference"]),
                   "training_poses": np.asarray(arrays["training_poses"], np.float64)}


@register_stage
class DataDrivenFitStage(PrecomputeStage):
    type_name = "datadriven.fit"
    uses_scene = False
    description = "linear maps pose -> transfer (Tikhonov, alpha by closed-form LOO), full or PCA-reduced"
    parameters = {
        "reduction": Param("reduced", str, "full: one map per coefficient and vertex; reduced: PCA in pose and vertex space",
                       choices=_MODELS),
        "pose": Param("quaternion", str, "joint-angle parameterisation (quaternion: the lowest held-out error "
                      "measured, see benchmarks/bench_datadriven.py)", choices=tuple(PARAMETERISATIONS)),
        "root": Param("include", str, "root joint: world translation + rotation as features, or ignored", choices=ROOT_MODES),
        "ka": Param(None, int, "pose components (default: from the error budget)", minimum=1),
        "kv": Param(None, int, "vertex-coefficient components (default: from the error budget)", minimum=1),
        "alpha": Param(None, float, "regularisation, in units of the largest pose singular value (default: LOO)",
                       minimum=0.0),
        "validation": Param(0.15, float, "fraction of the training frames held out to choose ka, kv", minimum=0.0,
                            maximum=0.5),
        "target_error": Param(None, float, "validation transfer error the reduced model must meet "
                              "(default: the full model's x (1 + tolerance))", minimum=0.0),
        "tolerance": Param(0.05, float, "budget slack over the full model's validation error", minimum=0.0),
        "kv_max": Param(512, int, "most vertex-coefficient components considered", minimum=1),
        "weighting": Param("lighting", str, "errors and the coefficient PCA weighted by the expected shading error "
                           "under the run's lighting, rotated (lighting), or plain SH L2 (none)", choices=("lighting", "none")),
        "seed": Param(0, int, "seed of the randomised SVD"),
    }

    def output_ports(self):
        return {"model": Port("arrays", (), "fitted data-driven model (datadriven._stages.model_to_arrays)")}

    def _weights(self, ctx, outputs: int, order: int):
        if self.params["weighting"] == "none" or ctx.lighting is None:
            return None
        light = ctx.lighting.sh(order, float(ctx.scene.frames[0]))
        return lighting_weights(light, outputs)

    def cache_key(self, ctx):
        if self.params["weighting"] == "none" or ctx.lighting is None:
            return {}
        # the band powers of the lighting (rotation invariant) are all the weights depend on
        light = np.asarray(ctx.lighting.sh(8, float(ctx.scene.frames[0])), np.float64)
        band = np.repeat(np.arange(8), 2 * np.arange(8) + 1)
        power = [np.bincount(band, weights=light[c] ** 2, minlength=8) for c in range(light.shape[0])]
        return {"lighting_band_power": np.round(np.asarray(power), 6).tolist()}

    def input_ports(self):
        return {"data": Port("arrays", (), "training data of datadriven.data")}

    def precompute(self, ctx, inputs):
        import time

        p = self.params
        where = f"stage {self.name!r} ({self.type_name})"
        data = inputs["data"]
        transfer = data["transfer"]
        settings = np.asarray(data["settings"]).reshape(-1)
        order, bounces = int(settings[0]), int(settings[2])
        if int(settings[3]) != _SPACES["world"]:
            raise StageError(f"{where}: the training data is in per-vertex tangent frames (space = 'local'); the "
                             f"per-frame stages shade world-frame transfer: train with space = 'world' (the local "
                             f"frame is measured by benchmarks/bench_datadriven.py)")
        channels = 3 if bounces else 1
        poses = pose_columns(data, p["pose"], p["root"])
        n = poses.shape[0]
        weights = self._weights(ctx, transfer.shape[2], order)
        t0 = time.perf_counter()
        report = {"poses": int(n), "pose_features": int(poses.shape[1]), "vertices": int(transfer.shape[1]),
                  "outputs_per_vertex": int(transfer.shape[2])}
        try:
            train, val = validation_split(n, p["validation"])
            if p["reduction"] == "reduced" and p["ka"] is not None:
                limit = pose_space(poses, pca=True).size
                if p["ka"] > limit:
                    raise ValueError(f"parameter 'ka' = {p['ka']} exceeds the {limit} pose components there "
                                     f"are ({n} training poses, {poses.shape[1]} pose features); set ka <= {limit}")
            if p["reduction"] == "reduced":
                choice = None
                if val.size and (p["ka"] is None or p["kv"] is None):
                    kw = {}
                    if p["ka"] is not None:
                        kw["ka_grid"] = (p["ka"],)
                    if p["kv"] is not None:
                        kw["kv_grid"] = (p["kv"],)
                    choice = choose_sizes(poses, transfer, train, val, target_error=p["target_error"],
                                          tolerance=p["tolerance"], kv_max=p["kv_max"], seed=p["seed"],
                                          progress=ctx.progress, weights=weights, **kw)
                    ka, kv = choice.ka, choice.kv
                    report["choice"] = {"reason": choice.reason, "met": choice.met, "target": choice.target,
                                        "full_validation_error": choice.full_error,
                                        "candidates": {f"{a},{v}": e for (a, v), e in choice.error.items()}}
                else:
                    ka = p["ka"] if p["ka"] is not None else 8
                    kv = p["kv"] if p["kv"] is not None else 22
                    report["choice"] = {"reason": f"PCA({ka},{kv}) as given" + ("" if val.size else
                                        " (too few frames for validation: defaults where not given)")}
                model = fit_reduced(poses, transfer, ka, kv, alpha=p["alpha"], seed=p["seed"], progress=ctx.progress,
                                    weights=weights)
            else:
                model = fit_full(poses, transfer, alpha=p["alpha"], progress=ctx.progress)
        except ValueError as exc:
            raise StageError(f"{where}: {exc}") from None
        report.update(model.info)
        report["weighting"] = p["weighting"] if weights is not None else "none"
        if weights is not None:
            report["band_weights"] = [float(weights[l * l]) for l in range(int(round(np.sqrt(transfer.shape[2] // (3 if bounces else 1)))))]
        report.update({"alpha_median": float(np.median(model.alphas)), "alpha_min": float(model.alphas.min()),
                       "alpha_max": float(model.alphas.max()), "loo_error_median": float(np.median(model.loo_error)),
                       "stored_floats": model.stored_floats(), "flops_per_frame": model.flops_per_frame(),
                       "one_mesh_prt_floats": int(transfer.shape[1] * transfer.shape[2]),
                       "training_floats": int(transfer.size), "total_fit_s": time.perf_counter() - t0})
        report["storage_of_one_mesh_prt"] = report["stored_floats"] / report["one_mesh_prt_floats"]
        report["storage_of_training_data"] = report["stored_floats"] / report["training_floats"]
        self.report = report
        return {"model": model_to_arrays(model, kind=p["pose"], root=p["root"], order=order, channels=channels,
                                         topology=data["topology"], root_reference=data["root_reference"],
                                         training_poses=poses)}

    def check_artifact(self, outputs):
        model_from_arrays(outputs["model"])


def _blocks(a: np.ndarray) -> np.ndarray:
    """Last axis zero-padded to a multiple of kernels.BLOCK and split into blocks: (..., nb, BLOCK)."""
    a = np.asarray(a, np.float32)
    k = a.shape[-1]
    nb = max(1, -(-k // kernels.BLOCK))
    out = np.zeros(a.shape[:-1] + (nb * kernels.BLOCK,), np.float32)
    out[..., :k] = a
    return out.reshape(a.shape[:-1] + (nb, kernels.BLOCK))


def _vec(a: np.ndarray, device):
    return wp.array(np.ascontiguousarray(a), dtype=kernels.vec_block, device=device)


@register_stage
class DataDrivenTransferStage(FrameStage):
    type_name = "datadriven.transfer"
    description = "transfer vectors from the frame's joint angles by the data-driven model (1-3 products per frame)"
    parameters = {
        "order": _ORDER,
        "color": Param(False, bool, "per-channel transfer (V, 3, C), from training with bounces"),
    }

    def dims(self):
        return {"C": self.params["order"] ** 2}

    def input_ports(self):
        return {"model": Port("arrays", (), "fitted data-driven model")}

    def output_ports(self):
        if self.params["color"]:
            return {"transfer_rgb": Port("float32", ("V", 3, "C"), "per-channel transfer after bounces, world frame")}
        return {"transfer": Port("float32", ("V", "C"), "diffuse transfer vectors, world frame", space="world")}

    def setup(self, ctx, inputs):
        where = f"stage {self.name!r} ({self.type_name})"
        try:
            model, meta = model_from_arrays(inputs["model"])
        except ValueError as exc:
            raise StageError(f"{where}: {exc}") from None
        p = self.params
        channels = 3 if p["color"] else 1
        if meta["order"] != p["order"] or meta["channels"] != channels:
            raise StageError(f"{where}: the model was trained at order {meta['order']} with {meta['channels']} channel(s); "
                             f"the stage has order {p['order']} and color={p['color']}")
        scene = ctx.scene
        if not np.array_equal(meta["topology"], topology_key(scene)):
            raise StageError(f"{where}: scene {scene.source or '<arrays>'} is not the character the model was trained on "
                             "(vertex count, faces, skin weights, rest or bind transforms differ)")
        layout = pose_layout(scene, meta["kind"], meta["root"])
        if layout.size != model.pose.mean.size:
            raise StageError(f"{where}: the model expects {model.pose.mean.size} pose features, the scene gives {layout.size}")
        dev = ctx.device
        self.model, self.meta, self.layout = model, meta, layout
        self._device = dev
        # pose features: per-joint inputs over every skeleton
        self._pose = PoseInputs(scene, meta["kind"], meta["root"], meta["root_reference"], dev)
        self._mean = wp.array(model.pose.mean.astype(np.float32), dtype=wp.float32, device=dev)
        self._weights = wp.array(model.pose.weights.astype(np.float32), dtype=wp.float32, device=dev)
        k = model.pose.size
        self._z = wp.zeros(-(-(k + 1) // kernels.BLOCK), dtype=kernels.vec_block, device=dev)
        v = scene.vertex_count
        m = model.coefficient_count
        if model.reduced:
            self._coefficients = _vec(_blocks(model.coefficients), dev)
            self._basis = _vec(_blocks(model.basis), dev)
            self._y = wp.zeros((m, self._basis.shape[1]), dtype=kernels.vec_block, device=dev)
        else:
            self._full = _vec(_blocks(model.weights), dev)
        self._transfer = wp.zeros((v, m), dtype=wp.float32, device=dev)
        self._workers = cpu_workers() if dev.is_cpu else 1
        # novelty of the scene's own poses (what the diagnostics report)
        poses = pose_features(scene, np.arange(len(scene.frames)), layout, root_reference=meta["root_reference"])
        self._novelty = novelty(model.pose, poses, meta["training_poses"])
        self._frames = np.asarray(scene.frames, np.float64)
        out = self._transfer.reshape((v, 3, m // 3)) if p["color"] else self._transfer
        return {"transfer_rgb" if p["color"] else "transfer": out}

    def launch(self, state):
        dev = self._device
        self._pose.launch(state)
        wp.launch(kernels.project_pose_kernel, dim=1, device=dev, inputs=[self._pose.features, self._mean, self._weights,
                                                                         self._z])
        count = self._transfer.shape[0]
        if self.model.reduced:
            wp.launch(kernels.coefficients_kernel, dim=self._y.shape[0], device=dev, inputs=[self._coefficients, self._z, self._y])
            launch_parallel(kernels.reconstruct_kernel, count, lambda a, b: [self._basis, self._y, a, self._transfer], dev,
                            self._workers, min_count=_CHUNK_MIN_VERTICES)
        else:
            launch_parallel(kernels.full_kernel, count, lambda a, b: [self._full, self._z, a, self._transfer], dev,
                            self._workers, min_count=_CHUNK_MIN_VERTICES)

    def diagnostics(self) -> dict:
        """Novelty of the scene's poses against the training poses (:func:`~warpshade.methods._shared.pose_space.novelty`)."""
        nov = self._novelty
        return {"novelty_max": float(nov["nearest"].max()), "novelty_mean": float(nov["nearest"].mean()),
                "subspace_max": float(nov["subspace"].max()), "range_excess_max": float(nov["range"].max()),
                "constant_drift_max": float(nov["constant"].max()),
                "novelty_per_frame": {f"{f:g}": float(x) for f, x in zip(self._frames, nov["nearest"])}}

    def novelty(self) -> dict:
        """Per-frame novelty arrays of the scene's frames (:func:`~warpshade.methods._shared.pose_space.novelty`), with ``frames``."""
        return {"frames": self._frames.copy(), **{k: v.copy() for k, v in self._novelty.items()}}

    def model_bytes(self) -> int:
        return 4 * self.model.stored_floats()
