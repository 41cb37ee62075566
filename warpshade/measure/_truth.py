"""Ray-traced ground truth, cached on disk, and the error of a run against it.

* :func:`ground_truth` -- reference radiance and its Monte Carlo standard error per frame
  (:func:`warpshade.reference.shade`, or :func:`~warpshade.reference.shade_glossy` for a
  stage whose reference model names a BRDF, :mod:`._protocols`), cached by a content hash of the scene, the
  frame, the lighting, the samples, the seed, the estimator version and the model -- each frame
  stored as soon as it is computed, so that an interrupted run resumes where it stopped;
* :func:`reference_model` -- what a run's output is measured against;
* :func:`measure_error` -- a run's recorded (or freshly stepped) output against ground truth on
  a few frames: relative RMS, the 99th percentile, the ground truth's own noise.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._hashing import hash_json
from ..tasks import progress_bar
from ._metrics import combine_metrics, error_metrics
from ._protocols import ground_truth_model

__all__: list[str] = []

#: Seed of the cached ground truth of the harness and the error budgets.
GT_SEED = 12345
#: Seed of the ground truth of validated runs (``warpshade run --validate``, the demo).
VALIDATE_SEED = 7


def truth_cache(cache_dir="default"):
    """The :class:`~warpshade.graph._cache.ArtifactCache` ground truth is kept in.

    ``"default"``: ``<default cache dir>/truth``; None: no cache; a path or an ArtifactCache."""
    from ..graph._cache import ArtifactCache, default_cache_dir

    if isinstance(cache_dir, ArtifactCache):
        return cache_dir
    if cache_dir == "default":
        return ArtifactCache(default_cache_dir() / "truth")
    return ArtifactCache(None if cache_dir is None else Path(cache_dir))


def _is_diffuse(model) -> bool:
    """The diffuse reference: no model, or only diffuse bounces (``{"bounces": k}``)."""
    return model is None or set(model) == {"bounces"}


def _model_description(model) -> dict:
    if model is None:
        return {"reference": "diffuse"}
    if _is_diffuse(model):
        return {"reference": "diffuse", "bounces": int(model["bounces"])}
    color = np.asarray(model["color"], np.float64)
    out = {"brdf": model["brdf"].describe(), "eye": np.asarray(model["eye"], np.float64).tolist()}
    if color.ndim == 1:
        out["color"] = color.tolist()
    else:  # per vertex (textured materials)
        from .._hashing import hash_arrays

        out["color"] = hash_arrays({"color": color})
    if model.get("roughness") is not None:
        from .._hashing import hash_arrays

        out["roughness"] = hash_arrays({"roughness": np.asarray(model["roughness"], np.float64)})
    if model.get("tangents") is not None:
        from .._hashing import hash_arrays

        t = model["tangents"]
        out["tangents"] = t if isinstance(t, str) else hash_arrays({"tangents": np.asarray(t, np.float64)})
    if model.get("groups"):
        from .._hashing import hash_arrays

        out["groups"] = [{"brdf": g["brdf"].describe(), "vertices": hash_arrays({"v": np.asarray(g["vertices"], np.int64)})}
                         for g in model["groups"]]
    return out


def _valid_truth(hit, vertex_count: int) -> bool:
    """A cached ground-truth frame is used only when it is one: radiance and standard error,
    (V, 3) each, finite (anything else is computed again and overwritten)."""
    if hit is None or set(hit) != {"radiance", "stderr"}:
        return False
    return all(hit[k].shape == (vertex_count, 3) and np.isfinite(hit[k]).all() for k in hit)


def _truth_task(task: dict) -> dict:
    """One ground-truth frame (an executor task: everything it needs, its seed included)."""
    from ..reference import shade, shade_glossy

    model = task["model"]
    if _is_diffuse(model):
        res = shade(task["scene"], task["frame"], task["lights"], task["samples"], device=task["device"], seed=task["seed"],
                    bounces=int(model["bounces"]) if model else 0)
    elif model.get("groups"):
        # meshes with BRDFs of their own: each group of vertices against its BRDF
        v = task["scene"].vertex_count
        radiance, stderr = np.zeros((v, 3), np.float32), np.zeros((v, 3), np.float32)
        base = {k: x for k, x in model.items() if k != "groups"}
        for g in model["groups"]:
            idx = np.asarray(g["vertices"], np.int64)
            if idx.size == 0:
                continue
            res = shade_glossy(task["scene"], task["frame"], lighting=task["lights"], samples=task["samples"],
                               device=task["device"], seed=task["seed"], vertices=idx, **{**base, "brdf": g["brdf"]})
            radiance[idx], stderr[idx] = np.asarray(res.radiance), np.asarray(res.stderr)
        return {"radiance": radiance, "stderr": stderr}
    else:
        res = shade_glossy(task["scene"], task["frame"], lighting=task["lights"], samples=task["samples"],
                           device=task["device"], seed=task["seed"], **task["model"])
    return {"radiance": np.asarray(res.radiance), "stderr": np.asarray(res.stderr)}


def ground_truth(scene, lighting, frames, samples: int = 1024, device="cpu", cache_dir="default", model=None,
                 seed: int = GT_SEED, progress: bool = False, executor=None) -> dict:
    """``{frame: {"radiance": (V, 3), "stderr": (V, 3)}}`` ray traced with MIS, cached on disk.

    Args:
        scene: the :class:`~warpshade.scene.Scene`.
        lighting: a :class:`~warpshade.scene.LightingSource` (the lights of each frame).
        frames: time codes.
        samples: environment rays per vertex.
        device: Warp device.
        cache_dir: see :func:`truth_cache`.
        model: None for the diffuse reference, or keyword arguments of
            :func:`~warpshade.reference.shade_glossy` (``brdf``, ``eye``, ``color``).
        seed: random seed of the estimator.
        progress: show a progress bar over the frames computed (:func:`warpshade.tasks.progress_bar`).
        executor: a :class:`warpshade.tasks.Executor` to compute the frames missing from the
            cache as independent tasks (local worker processes, a Dask cluster); None computes
            them here, one after another. Same seeds either way, so the same result. Tasks run on
            the worker's default Warp device (its GPU on a CUDA cluster).

    Each frame is stored in the cache as soon as it is computed (by the executor's
    ``on_result``), so an interrupted call loses only the frames that were running.
    """
    from ..reference._shading import ESTIMATOR_VERSION

    cache = truth_cache(cache_dir)
    fp = scene.fingerprint()
    desc = _model_description(model)
    out, missing = {}, []
    keys = {}
    for f in frames:
        key = ("gt-" if _is_diffuse(model) else "gt-glossy-") + hash_json(
            {"scene": fp, "frame": float(f), "samples": int(samples), "seed": int(seed), "estimator": ESTIMATOR_VERSION,
             "lighting": lighting.fingerprint(), **desc})[:32]
        keys[float(f)] = key
        hit = cache.load(key)
        if not _valid_truth(hit, scene.vertex_count):
            missing.append(float(f))
        else:
            out[float(f)] = hit
    kind = "ground truth" if _is_diffuse(model) else "glossy ground truth"
    tasks = [{"scene": scene, "frame": f, "lights": lighting.lights_at(f), "samples": int(samples), "seed": int(seed),
              "model": model, "device": device if executor is None else None}
             for f in missing]
    if executor is not None and tasks:
        def keep(index: int, hit: dict) -> None:
            cache.store(keys[tasks[index]["frame"]], hit)

        results = executor.map(_truth_task, tasks, desc=f"{kind} ({samples} spp)", progress=progress, on_result=keep)
        for task, hit in zip(tasks, results):
            out[task["frame"]] = hit
    else:
        with progress_bar(total=len(tasks), desc=f"{kind} ({samples} spp)", unit="frame",
                          disable=not progress or not tasks) as bar:
            for task in tasks:
                hit = _truth_task(task)
                cache.store(keys[task["frame"]], hit)
                out[task["frame"]] = hit
                bar.update(1)
    return {float(f): out[float(f)] for f in frames}


def reference_model(runtime, frame=None) -> dict | None:
    """What the run's output is measured against: None (diffuse) or the reference's arguments
    (:func:`~warpshade.measure._protocols.ground_truth_model` of the output stage), for time code
    ``frame`` -- with the material assignment and eye of that frame -- or, when None, for the
    run's current materials and eye."""
    st = runtime.output_stage()
    if frame is None:
        return ground_truth_model(st)
    return ground_truth_model(st, runtime.materials_at(frame), runtime.evaluator.eye_at(frame))


@dataclass
class Measurement:
    """The error of a run against ground truth.

    Attributes:
        error: ``{"per_frame": [...], "mean": {...}, "samples", "reference"}`` (metrics of
            :func:`~warpshade.measure._metrics.error_metrics` per frame and combined).
        references: ground-truth radiance per frame, (V, 3) float32.
        estimates: the run's radiance per frame, (V, 3) float32.
    """

    error: dict
    references: dict = field(default_factory=dict)
    estimates: dict = field(default_factory=dict)


def measure_error(runtime, frames=None, samples: int | None = None, seed: int = VALIDATE_SEED,
                  cache_dir="default", executor=None) -> Measurement:
    """A run's output against ray-traced ground truth.

    Args:
        runtime: a :class:`~warpshade.graph.Runtime`; frames it recorded (``runtime.results``)
            are reused, others are stepped.
        frames: time codes (default: the graph's ``[validate]`` frames, else the first frame).
        samples: ground-truth rays per vertex (default: ``[validate]`` samples, else 1024).
        seed: ground-truth seed.
        cache_dir: where the ground truth is cached (:func:`truth_cache`).
        executor: computes missing ground-truth frames as tasks (:func:`ground_truth`).
    """
    from ..graph._scene_inputs import parse_frames

    spec = runtime.spec.validate_spec
    if frames is None:
        frames = spec.get("frames", [float(runtime.scene.frames[0])])
    samples = int(spec.get("samples", 1024) if samples is None else samples)
    sel = parse_frames(list(frames), runtime.scene)
    # the reference of each frame (a material track or a moving eye make it differ between frames)
    models = {float(f): reference_model(runtime, f) for f in sel}
    truth = {}
    for desc in {hash_json(_model_description(m)) for m in models.values()}:
        fs = [f for f in sel if hash_json(_model_description(models[float(f)])) == desc]
        truth.update(ground_truth(runtime.scene, runtime.lighting, fs, samples, runtime.device, cache_dir,
                                  models[float(fs[0])], seed, progress=runtime.progress, executor=executor))
    model = models[float(sel[0])]
    per_frame, refs, ests = [], {}, {}
    for f in sel:
        est = runtime.results.get(float(f))
        if est is None:
            est = runtime.step(f).numpy().copy()
        gt = truth[float(f)]
        m = error_metrics(est, gt["radiance"], gt["stderr"])
        m["frame"] = float(f)
        per_frame.append(m)
        refs[float(f)] = np.asarray(gt["radiance"])
        ests[float(f)] = est
    error = {"per_frame": per_frame, "mean": combine_metrics(per_frame), "samples": samples,
             "reference": ("diffuse" if model is None else f"diffuse, {model['bounces']} bounces") if _is_diffuse(model)
             else f"glossy {model['brdf'].describe()}"}
    return Measurement(error, refs, ests)
