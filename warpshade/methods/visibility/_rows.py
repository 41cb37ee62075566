"""Settings of data-driven visibility for the speed-vs-accuracy harness (``benchmarks/run.py``)."""

from __future__ import annotations

from .._rows import BENCH_SCENES, HarnessRow, training_clips

__all__ = [
    "TRAINING_CLIPS",
    "stages_for",
]

#: Training frames where not every frame of the clip (the graphs' selections, so that the cached
#: training data is shared with stages/*_visibility.toml).
TRAINING_FRAMES = {"figure": "0:600:3", "figure_walk": "0:600:3", "wanderer": "0:1000:8"}
#: Held-out test scene -> its training clip (:func:`warpshade.methods._rows.training_clips`) and frames.
TRAINING_CLIPS = {scene: (clip, TRAINING_FRAMES.get(scene)) for scene, clip in training_clips(None).items()}
#: Rays per vertex of the training visibility of each clip: 128, 64 on the wanderer (its frames cost ~4x).
TRAINING_RAYS = {scene: {"wanderer": 64}.get(scene, 128) for scene in TRAINING_CLIPS}
#: Fit settings per pose input besides the joint rotations of a skinned character: the dihedral angles
#: of a simulated cloth (their PCA keeps 90 % of their variance, as stages/cloth_visibility.toml).
FEATURE_FIT = {"dihedral": {"input_variance": 0.9}}
#: Pose inputs and their fit settings per held-out scene whose inputs are not joint rotations.
FEATURES = {scene: (BENCH_SCENES[scene]["inputs"], FEATURE_FIT[BENCH_SCENES[scene]["inputs"]])
            for scene in TRAINING_CLIPS if BENCH_SCENES[scene].get("inputs", "joints") != "joints"}
#: Fit settings of the diffuse rows (stages/figure_visibility_diffuse.toml): per-cluster PCA to 99 %
#: of the variance, at most 64 components, the model chosen per cluster (``regressor = "auto"``) among
#: maps from the joint rotations (or dihedral angles) and from the 4 or 8 nearest clusters' centroids
#: in the cluster's frame (``relative``).
DIFFUSE_FIT = {"variance": 0.99, "k_max": 64, "relative": 8}
#: The glossy material of the RPO rows (:mod:`warpshade.methods.rpo._rows`).
GLOSSY = {"brdf": "ggx", "roughness": 0.5}


def stages_for(training: str, frames: str | None, regressor: str = "network", order: int = 4, samples: int = 128,
               shade: str = "glossy", fit: dict | None = None, features: str = "joints") -> tuple:
    """Training data, fit, per-frame prediction and shading (``"glossy"``: rpo.shade, ``"diffuse"``:
    visibility.diffuse)."""
    data = {"training": training, "order": order, "samples": samples, "features": features}
    if frames is not None:
        data["frames"] = frames
    stages = [("data", "visibility.data", data, {}),
              ("fit", "visibility.fit", {"regressor": regressor, **(fit or {})}, {"data": "data.data"}),
              ("predict", "visibility.predict", {"order": order}, {"model": "fit.model"})]
    if shade == "glossy":
        stages.append(("shade", "rpo.shade", {"order": order, "rank": 8, **GLOSSY}, {}))
    else:
        stages.append(("shade", "visibility.diffuse", {"order": order}, {}))
    return tuple(stages)


def harness_rows(quick: bool = False) -> list:
    """The three models per held-out clip, glossy (against the glossy reference; RPO over traced
    visibility is the rpo rows' 'traced n4 k8 s256'), and the diffuse graph's settings (order 6,
    the model chosen per cluster by cross-validation on the training clip)."""
    rows = []
    for scene, (training, frames) in TRAINING_CLIPS.items():
        rays = TRAINING_RAYS[scene]
        features, fit = FEATURES.get(scene, ("joints", {}))
        for model in ("linear", "quadratic", "network"):
            rows.append(HarnessRow(
                "visibility", f"{model} n4 k8", stages_for(training, frames, model, samples=rays, fit=fit, features=features),
                "shade.radiance",
                scenes=(scene,), quick=False,
                notes=f"trained on {training.split(':')[-1]} frames {frames} ({rays} rays); {model} per cluster; "
                      "RPO GGX 0.5 vs the glossy reference"))
        rows.append(HarnessRow(
            "visibility", "auto n6 diffuse", stages_for(training, frames, "auto", order=6, samples=rays, shade="diffuse",
                                                        fit={**DIFFUSE_FIT, **fit}, features=features),
            "shade.radiance", scenes=(scene,), quick=False,
            notes="stages/figure_visibility_diffuse.toml's settings: order 6, per-cluster model chosen by blocked "
                  "cross-validation on the training clip; cosine re-applied to the predicted visibility (eq. 14) vs the "
                  "diffuse reference"))
    return rows
