"""Ray-traced ground truth, cached on disk, and the error of a run against it.

* :func:`ground_truth` -- reference radiance and its Monte Carlo standard error per frame
  (:func:`warpshade.reference.shade`, or :func:`~warpshade.reference.shade_glossy` for a
  stage whose ``reference_model`` names a BRDF), cached by a content hash of the scene, the
  frame, the lighting, the samples, the seed, the estimator version and the model;
* :func:`reference_model` -- what a run's output is measured against;
* :func:`measure_error` -- a run's recorded (or freshly stepped) output against ground truth on
  a few frames: relative RMS, the 99th percentile, the ground truth's own noise.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._hashing import hash_json
from .metrics import combine_metrics, error_metrics

__all__ = ["GT_SEED", "VALIDATE_SEED", "Measurement", "ground_truth", "reference_model", "measure_error", "truth_cache"]

#: Seed of the cached ground truth of the harness and the error budgets.
GT_SEED = 12345
#: Seed of the ground truth of validated runs (``warpshade run --validate``, the demo).
VALIDATE_SEED = 7


def truth_cache(cache_dir="default"):
    """The :class:`~warpshade.graph.cache.ArtifactCache` ground truth is kept in.

    ``"default"``: ``<default cache dir>/truth``; None: no cache; a path or an ArtifactCache."""
    from ..graph.cache import ArtifactCache, default_cache_dir

    if isinstance(cache_dir, ArtifactCache):
        return cache_dir
    if cache_dir == "default":
        return ArtifactCache(default_cache_dir() / "truth")
    return ArtifactCache(None if cache_dir is None else Path(cache_dir))


def _model_description(model) -> dict:
    if model is None:
        return {"reference": "diffuse"}
    return {"brdf": model["brdf"].describe(), "eye": np.asarray(model["eye"], np.float64).tolist(),
            "color": np.asarray(model["color"], np.float64).tolist()}


def ground_truth(scene, lighting, frames, samples: int = 1024, device="cpu", cache_dir="default", model=None,
                 seed: int = GT_SEED, progress: bool = False) -> dict:
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
        progress: print one line per frame computed.
    """
    from ..reference import shade, shade_glossy
    from ..reference.shading import ESTIMATOR_VERSION

    cache = truth_cache(cache_dir)
    fp = scene.fingerprint()
    desc = _model_description(model)
    out = {}
    for f in frames:
        key = ("gt-" if model is None else "gt-glossy-") + hash_json(
            {"scene": fp, "frame": float(f), "samples": int(samples), "seed": int(seed), "estimator": ESTIMATOR_VERSION,
             "lighting": lighting.fingerprint(), **desc})[:32]
        hit = cache.load(key)
        if hit is None or set(hit) != {"radiance", "stderr"}:
            t0 = time.perf_counter()
            lights = lighting.lights_at(f)
            if model is None:
                res = shade(scene, f, lights, samples, device=device, seed=seed)
            else:
                res = shade_glossy(scene, f, lighting=lights, samples=samples, device=device, seed=seed, **model)
            hit = {"radiance": np.asarray(res.radiance), "stderr": np.asarray(res.stderr)}
            cache.store(key, hit)
            if progress:
                kind = "ground truth" if model is None else "glossy ground truth"
                print(f"    {kind} frame {float(f):g}: {samples} spp in {time.perf_counter() - t0:.1f} s", flush=True)
        out[float(f)] = hit
    return out


def reference_model(runtime) -> dict | None:
    """What the run's output is measured against: None (diffuse) or glossy reference arguments."""
    return runtime.output_stage().reference_model()


@dataclass
class Measurement:
    """The error of a run against ground truth.

    Attributes:
        error: ``{"per_frame": [...], "mean": {...}, "samples", "reference"}`` (metrics of
            :func:`~warpshade.measure.metrics.error_metrics` per frame and combined).
        references: ground-truth radiance per frame, (V, 3) float32.
        estimates: the run's radiance per frame, (V, 3) float32.
    """

    error: dict
    references: dict = field(default_factory=dict)
    estimates: dict = field(default_factory=dict)


def measure_error(runtime, frames=None, samples: int | None = None, seed: int = VALIDATE_SEED,
                  cache_dir="default") -> Measurement:
    """A run's output against ray-traced ground truth.

    Args:
        runtime: a :class:`~warpshade.graph.Runtime`; frames it recorded (``runtime.results``)
            are reused, others are stepped.
        frames: time codes (default: the graph's ``[validate]`` frames, else the first frame).
        samples: ground-truth rays per vertex (default: ``[validate]`` samples, else 1024).
        seed: ground-truth seed.
        cache_dir: where the ground truth is cached (:func:`truth_cache`).
    """
    from ..graph.runtime import parse_frames

    spec = runtime.spec.validate_spec
    if frames is None:
        frames = spec.get("frames", [float(runtime.scene.frames[0])])
    samples = int(spec.get("samples", 1024) if samples is None else samples)
    model = reference_model(runtime)
    sel = parse_frames(list(frames), runtime.scene)
    truth = ground_truth(runtime.scene, runtime.lighting, sel, samples, runtime.device, cache_dir, model, seed)
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
             "reference": "diffuse" if model is None else f"glossy {model['brdf'].describe()}"}
    return Measurement(error, refs, ests)
