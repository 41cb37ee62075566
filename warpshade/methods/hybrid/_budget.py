"""Model no more than the scene needs: the candidate settings of the hybrid tracer for an error budget.

The measuring layer (:func:`warpshade.measure._budget.choose`) runs each candidate and picks the
cheapest meeting the target; the model here is the ray count per frame (and the SH order)::

    python -m warpshade.measure._budget --method hybrid --scene cloth --target 0.05
"""

from __future__ import annotations

from ._rows import stages_for

__all__ = ["GRID", "candidates"]

#: The default candidate grid: SH order x rays per vertex per frame (control: the last estimate).
GRID = {"orders": (4, 6), "samples": (8, 16, 32, 64), "controls": ("previous",)}


def candidates(orders=GRID["orders"], samples=GRID["samples"], controls=GRID["controls"]) -> list[dict]:
    """Every (order, samples, control) setting as ``{"label", "stages", "facts", "timed_stage"}``."""
    out = []
    for order in orders:
        for count in samples:
            for control in controls:
                out.append({
                    "label": f"n{int(order)} K{int(count)} {control}",
                    "stages": stages_for(control, int(count), order=int(order)),
                    "facts": {"order": int(order), "samples": int(count), "control": control},
                    "timed_stage": "trace",
                })
    return out
