"""Settings of data-driven visibility for the speed-vs-accuracy harness (``benchmarks/run.py``)."""

from __future__ import annotations

from ..rows import HarnessRow

__all__ = [
    "TRAINING_CLIPS",
    "stages_for",
]

#: Held-out test scene -> its training clip and frames (the graphs' selections, so that the cached
#: training data is shared with stages/*_visibility.toml).
TRAINING_CLIPS = {"figure": ("bundled:figure_train", "0:600:3"), "figure_walk": ("bundled:figure_train", "0:600:3"),
                  "wanderer": ("bundled:wanderer_train", "0:1000:8"), "cloth_heldout": ("bundled:cloth_train", None)}
#: Rays per vertex of the training visibility of each clip (the wanderer's frames cost ~4x).
TRAINING_RAYS = {"figure": 128, "figure_walk": 128, "wanderer": 64, "cloth_heldout": 128}
#: Pose inputs of each clip: joint rotations of a skinned character, dihedral angles of the
#: simulated cloth (its inputs' PCA keeps 90 % of their variance, as stages/cloth_visibility.toml).
FEATURES = {"cloth_heldout": ("dihedral", {"input_variance": 0.9})}
#: Fit settings of the diffuse rows (stages/figure_visibility_diffuse.toml): per-cluster PCA to 99 %
#: of the variance, at most 64 components, the model chosen per cluster (``model = "auto"``) among
#: maps from the joint rotations (or dihedral angles) and from the 4 or 8 nearest clusters' centroids
#: in the cluster's frame (``relative``).
DIFFUSE_FIT = {"variance": 0.99, "k_max": 64, "relative": 8}
#: The glossy material of the RPO rows (:mod:`warpshade.methods.rpo.rows`).
GLOSSY = {"brdf": "ggx", "roughness": 0.5}


def stages_for(training: str, frames: str | None, model: str = "network", order: int = 4, samples: int = 128,
               shade: str = "glossy", fit: dict | None = None, features: str = "joints") -> tuple:
    """Training data, fit, per-frame prediction and shading (``"glossy"``: rpo.shade, ``"diffuse"``:
    visibility.diffuse)."""
    data = {"training": training, "order": order, "samples": samples, "features": features}
    if frames is not None:
        data["frames"] = frames
    stages = [("data", "visibility.data", data, {}),
              ("fit", "visibility.fit", {"model": model, **(fit or {})}, {"data": "data.data"}),
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
