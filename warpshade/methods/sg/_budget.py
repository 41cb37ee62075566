"""Model no more than the scene needs: candidate SSDF resolutions and environment lobe counts.

The measuring layer (:func:`warpshade.measure._budget.choose`) runs each candidate against the
glossy reference and picks the cheapest that meets the target; the PCA term count inside each
candidate is chosen by its own RMS budget (``sg.ssdf`` ``error_budget``)::

    python -m warpshade.measure._budget --method sg --scene sunlit --target 0.1
"""

from __future__ import annotations

from ._rows import sg_stages

__all__ = ["GRID", "candidates"]

#: SSDF map resolution x environment lobes.
GRID = {"resolutions": (16, 32, 64), "env_lobes": (3, 6, 9)}


def candidates(resolutions=GRID["resolutions"], env_lobes=GRID["env_lobes"]) -> list[dict]:
    """Every (resolution, lobes) setting as ``{"label", "stages", "facts", "timed_stage"}``."""
    return [{"label": f"ssdf {int(r)} e{int(k)}", "stages": sg_stages(int(r), 4, env_lobes=int(k)),
             "facts": {"resolution": int(r), "env_lobes": int(k)}, "timed_stage": "shade"}
            for r in resolutions for k in env_lobes]
