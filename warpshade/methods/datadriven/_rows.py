"""Settings of data-driven PRT for the speed-vs-accuracy harness (``benchmarks/run.py``)."""

from __future__ import annotations

from .._rows import HarnessRow, training_clips

__all__ = [
    "TRAINING_CLIPS",
    "stages_for",
]

#: Training frames where not every frame of the clip (as in the graphs in stages/, so that the cached
#: training data is shared): every other frame of the wanderer's 1000.
TRAINING_FRAMES = {"wanderer": "0:1000:2"}
#: Held-out test scene of a skinned character -> its training clip (the same character in a
#: range-of-motion clip, :func:`warpshade.methods._rows.training_clips`) and the training frames.
TRAINING_CLIPS = {scene: (clip, TRAINING_FRAMES.get(scene)) for scene, clip in training_clips("joints").items()}


def stages_for(training: str, reduction: str = "reduced", order: int = 6, samples: int = 256, fit: dict | None = None,
               bounces: int = 0, frames: str | None = None) -> tuple:
    """The stages of a data-driven graph: training data, fit, per-frame transfer, PRT shading."""
    fit = {"reduction": reduction, **(fit or {})}
    data = {"training": training, "order": order, "samples": samples, "bounces": bounces}
    if frames is not None:
        data["frames"] = frames
    return (("data", "datadriven.data", data, {}),
            ("fit", "datadriven.fit", fit, {"data": "data.data"}),
            ("transfer", "datadriven.transfer", {"order": order}, {"model": "fit.model"}),
            ("shade", "prt.shade", {"order": order}, {"transfer": "transfer.transfer"}))


def harness_rows(quick: bool = False) -> list:
    """Full and reduced models on each held-out clip, trained on its character's training clip."""
    rows = []
    for scene, (training, frames) in TRAINING_CLIPS.items():
        for model in ("reduced", "full"):
            rows.append(HarnessRow(
                "datadriven", f"{model} n6",
                stages_for(training, model, frames=frames), "shade.radiance", scenes=(scene,), quick=False,
                notes=f"trained on {training.split(':')[-1]} (256 rays per vertex per frame); {model} linear model",
            ))
    return rows
