"""Model no more than the scene needs: the candidate settings of data-driven PRT for an error budget.

The PCA sizes and alpha are chosen inside the fit (:func:`._model.choose_sizes`, on frames held
out of the training clip); what remains for the measuring layer to choose between is the SH
order of the training transfer and the model kind::

    python -m warpshade.measure._budget --method datadriven --scene figure --target 0.08
"""

from __future__ import annotations

from ._rows import TRAINING_CLIPS, stages_for

__all__ = ["GRID", "candidates"]

#: The default candidate grid: SH order x model kind.
GRID = {"orders": (4, 6), "models": ("reduced", "full")}


def candidates(orders=GRID["orders"], models=GRID["models"], scene: str = "figure", samples: int = 256) -> list[dict]:
    """Every (order, model) setting as ``{"label", "stages", "facts", "timed_stage"}``."""
    training, frames = TRAINING_CLIPS.get(scene, ("", None))
    out = []
    for order in orders:
        for model in models:
            out.append({"label": f"{model} n{int(order)}", "stages": stages_for(training, model, int(order), samples,
                                                                                  frames=frames),
                        "facts": {"order": int(order), "model": model}, "timed_stage": "shade"})
    return out
