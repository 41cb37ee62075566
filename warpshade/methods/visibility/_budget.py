"""Model no more than the scene needs: the candidate settings of data-driven visibility for an error budget.

The PCA sizes (inputs and per-cluster visibility) come from variance budgets inside the fit and
the regulariser and neuron count from cross-validation; what remains for the measuring layer to
choose between is the model kind and the retained variance::

    python -m warpshade.measure._budget --method visibility --scene figure --target 0.08
"""

from __future__ import annotations

from ._rows import TRAINING_CLIPS, TRAINING_RAYS, stages_for

__all__ = ["GRID", "candidates"]

#: The default candidate grid: model kind x retained variance of the per-cluster PCA.
GRID = {"models": ("linear", "quadratic", "network"), "variances": (0.9, 0.95)}


def candidates(models=GRID["models"], variances=GRID["variances"], scene: str = "figure") -> list[dict]:
    """Every (model, variance) setting as ``{"label", "stages", "facts", "timed_stage"}``."""
    training, frames = TRAINING_CLIPS.get(scene, ("", None))
    rays = TRAINING_RAYS.get(scene, 128)
    out = []
    for model in models:
        for variance in variances:
            out.append({"label": f"{model} v{variance:g}",
                        "stages": stages_for(training, frames, model, samples=rays, fit={"variance": float(variance)}),
                        "facts": {"model": model, "variance": float(variance)}, "timed_stage": "predict"})
    return out
