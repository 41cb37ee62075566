"""Model no more than the scene needs: the candidate settings of static PRT for an error budget.

The measuring layer (:func:`warpshade.measure._budget.choose`) runs each candidate on the scene,
measures its error against ray-traced ground truth and its time per frame, and picks the
cheapest one that meets the target; this module only says what the candidates are::

    python -m warpshade.measure._budget --method prt --scene bunny --target 0.08
"""

from __future__ import annotations

__all__ = ["GRID", "candidates"]

#: The default candidate grid: SH order x rays per vertex of the bake.
GRID = {"orders": (2, 3, 4, 6), "samples": (64, 256, 1024)}


def candidates(orders=GRID["orders"], samples=GRID["samples"]) -> list[dict]:
    """Every (order, samples) setting as ``{"label", "stages", "facts", "timed_stage"}``."""
    out = []
    for order in orders:
        for count in samples:
            out.append({
                "label": f"n{int(order)} s{int(count)}",
                "stages": (("bake", "prt.transfer", {"order": int(order), "samples": int(count)}, {}),
                           ("shade", "prt.shade", {"order": int(order)}, {"transfer": "bake.transfer"})),
                "facts": {"order": int(order), "samples": int(count)},
                "timed_stage": "shade",
            })
    return out
