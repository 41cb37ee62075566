"""Model no more than the scene needs: the candidate settings of LDPRT for an error budget.

Two budgets: the per-vertex lobe count of ``ldprt.fit`` (``target_error``: the fewest lobes
meeting a fit-error target per vertex, :func:`warpshade.basis.zh.fit_budget`), and this
module's grid over SH order and lobe capacity, from which
:func:`warpshade.measure._budget.choose` picks the cheapest setting meeting a target error
against ray-traced ground truth::

    python -m warpshade.measure._budget --method ldprt --scene figure --target 0.12
"""

from __future__ import annotations

__all__ = ["GRID", "candidates"]

#: The default candidate grid: SH order x maximum lobes x per-vertex fit-error target.
GRID = {"orders": (3, 4, 6), "lobes": (1, 2, 4), "fit_targets": (0.05,)}


def candidates(orders=GRID["orders"], lobes=GRID["lobes"], fit_targets=GRID["fit_targets"]) -> list[dict]:
    """Every setting as ``{"label", "stages", "facts", "timed_stage"}`` (table evaluation)."""
    out = []
    for order in orders:
        for count in lobes:
            for target in fit_targets:
                fit = {"order": int(order), "lobes": int(count), "samples": 256, "target_error": float(target)}
                out.append({
                    "label": f"n{int(order)} N<={int(count)} fit {float(target):g}",
                    "stages": (("fit", "ldprt.fit", fit, {}), ("tangents", "ldprt.tangents", {}, {}),
                               ("shade", "ldprt.shade", {"order": int(order), "lobes": int(count)}, {})),
                    "facts": {"order": int(order), "lobes": int(count), "fit_target": float(target)},
                    "timed_stage": "shade",
                })
    return out
