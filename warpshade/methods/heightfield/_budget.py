"""Model no more than the scene needs: the candidate settings of the height field for an error
budget.

The candidates are (order n, visibility texels per side) at k = 8 factors and 16 azimuths; the
measuring layer (:func:`warpshade.measure._budget.choose`) runs each against the glossy reference
and picks the one with the least time per frame (visibility and shading) that meets the target::

    python -m warpshade.measure._budget --method heightfield --scene bundled:ripples --target 0.1
"""

from __future__ import annotations

from ._rows import heightfield_stages

__all__ = ["GRID", "candidates"]

#: The default candidate grid: SH order x visibility texels per side.
GRID = {"orders": (3, 4), "resolutions": (32, 64, 128, 256)}


def candidates(orders=GRID["orders"], resolutions=GRID["resolutions"]) -> list[dict]:
    """Every (order, resolution) setting as ``{"label", "stages", "facts", "timed_stage"}``."""
    return [{"label": f"n{int(order)} {int(res)}^2", "stages": heightfield_stages(int(order), 8, int(res)),
             "facts": {"order": int(order), "resolution": int(res)}, "timed_stage": None}
            for order in orders for res in resolutions]
