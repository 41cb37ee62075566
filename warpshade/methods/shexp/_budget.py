"""Model no more than the scene needs: the candidate settings of SHEXP for an error budget.

A candidate is an SH order x a leaf-sphere budget x an exp method; the measuring layer
(:func:`warpshade.measure._budget.choose`) measures each on the scene at hand -- error against
ray-traced ground truth on a few sampled frames, and the median time per frame of the shading
stage -- and picks the cheapest that meets the target (or, when none does, the most accurate,
flagged as not meeting it)::

    python -m warpshade.measure._budget --method shexp --scene figure --target 0.2
    python -m warpshade.measure._budget --method shexp --scene bundled:blockers --target 0.14 \\
        --grid orders=3,4,6 spheres=8,32 methods=ol,hyb

The chosen sphere count is what the blockers stage really fitted (its report's
``leaf_spheres``), which can be fewer than the budget on small meshes.
"""

from __future__ import annotations

from ...basis import sh
from ._rows import graph_stages

__all__ = ["DEFAULT_ORDERS", "DEFAULT_SPHERE_BUDGETS", "DEFAULT_METHODS", "GRID", "candidates"]

DEFAULT_ORDERS = (3, 4, 5, 6)
DEFAULT_SPHERE_BUDGETS = (8, 16, 32, 64)
DEFAULT_METHODS = ("ol", "hyb", "ps_star")
#: The default candidate grid.
GRID = {"orders": DEFAULT_ORDERS, "spheres": DEFAULT_SPHERE_BUDGETS, "methods": DEFAULT_METHODS}


def candidates(orders=DEFAULT_ORDERS, spheres=DEFAULT_SPHERE_BUDGETS, methods=DEFAULT_METHODS, hierarchy: bool = False,
               blocker_params=None) -> list[dict]:
    """Every (sphere budget, order, exp method) as ``{"label", "stages", "facts", "timed_stage"}``.

    Raises:
        ValueError: an unknown exp method.
    """
    for m in methods:
        if m not in sh.EXP_METHODS:
            raise ValueError(f"shexp budget: unknown exp method {m!r} (known: {', '.join(sh.EXP_METHODS)})")
    out = []
    for count in spheres:
        for order in orders:
            for method in methods:
                out.append({
                    "label": f"n{int(order)} {int(count)} spheres {method}",
                    "stages": graph_stages(int(order), method, int(count), hierarchy=hierarchy, blocker_params=blocker_params),
                    "facts": {"order": int(order), "spheres": int(count), "method": method},
                    "timed_stage": "shade",
                })
    return out
