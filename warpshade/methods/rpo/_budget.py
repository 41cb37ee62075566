"""Model no more than the scene needs: the candidate settings of the RPOs for an error budget.

The candidates are (order n, factors k) over per-frame ray-traced visibility; the measuring layer
(:func:`warpshade.measure._budget.choose`) runs each against the glossy reference and picks the
one with the least time per frame (visibility and shading) that meets the target::

    python -m warpshade.measure._budget --method rpo --scene bend --target 0.1
"""

from __future__ import annotations

from ._rows import rpo_stages

__all__ = ["GRID", "candidates"]

#: The default candidate grid: SH order x BRDF factors.
GRID = {"orders": (3, 4, 5, 6), "ranks": (1, 2, 4, 8, 16)}


def candidates(orders=GRID["orders"], ranks=GRID["ranks"]) -> list[dict]:
    """Every (order, rank) setting as ``{"label", "stages", "facts", "timed_stage"}``."""
    out = []
    for order in orders:
        for rank in ranks:
            if rank > order * order:
                continue
            out.append({"label": f"n{int(order)} k{int(rank)}", "stages": rpo_stages("traced", int(order), int(rank)),
                        "facts": {"order": int(order), "rank": int(rank)}, "timed_stage": None})
    return out
