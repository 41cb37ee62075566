"""Settings of SHEXP for the speed-vs-accuracy harness (``benchmarks/run.py``)."""

from __future__ import annotations

from .._rows import HarnessRow

__all__ = [
    "HARNESS_SCENES",
]

#: Scenes the harness runs SHEXP on (closed occluder meshes; the cloth is an open sheet).
HARNESS_SCENES = ("blockers", "figure", "figure_walk", "wanderer", "bunny", "bear", "bend")


def graph_stages(order: int = 4, method: str = "hyb", budget: int = 48, hierarchy: bool = False, accumulate: str = "log",
                 degree=None, shade: str = "direct", rule: str = "continuous", blocker_params=None, **shade_params) -> tuple:
    """The stage tuples ``(name, type, params, inputs)`` of a SHEXP graph (harness, budget, scripts).

    ``blocker_params`` go to ``shexp.blockers`` (e.g. ``grid_cells``), ``shade_params`` to
    ``shexp.shade``. The output port is ``"shade.radiance"``.
    """
    params = {"order": order, "method": method, "accumulate": accumulate, "shade": shade, "rule": rule, **shade_params}
    if degree is not None:
        params["degree"] = degree
    return (
        ("tables", "shexp.tables", {"order": order}, {}),
        ("blockers", "shexp.blockers", {"budget": budget, "hierarchy": hierarchy, **(blocker_params or {})}, {}),
        ("shade", "shexp.shade", params, {}),
    )


def harness_rows(quick: bool = False) -> list:
    """Harness settings (all under method "shexp", so ``--methods shexp`` runs them together):
    order and exp method on the flat list of 48 spheres, the hierarchy, accumulation at n = 6
    shaded at n = 4, the product-accumulation baseline and ray tracing against the spheres
    (the sources of error of the paper's Fig. 7)."""
    rows = []

    def row(setting, stages, quick_row, notes, output="shade.radiance"):
        rows.append(HarnessRow("shexp", setting, stages, output, scenes=HARNESS_SCENES, quick=quick_row, notes=notes))

    for order in (3, 4, 5, 6):
        row(f"n{order} HYB", graph_stages(order, "hyb"), order == 4, "48 leaf spheres, flat list, HYB")
    for budget in (8, 16):
        row(f"n4 HYB s{budget}", graph_stages(4, "hyb", budget=budget), budget == 8,
            f"{budget} leaf spheres (budget), flat list, HYB")
    row("n4 PS*-2", graph_stages(4, "ps_star", degree=2), False, "48 leaf spheres, flat list, PS*-2")
    row("n4 OL", graph_stages(4, "ol"), False, "48 leaf spheres, flat list, OL")
    row("n4 PS-10", graph_stages(4, "ps", degree=10), False, "48 leaf spheres, flat list, PS-10")
    row("n4 HYB tree", graph_stages(4, "hyb", hierarchy=True), False,
        "48 leaf spheres, hierarchy cut per receiver cluster with ratio vectors")
    row("n6->4 HYB", graph_stages(6, "hyb", shade_order=4), False,
        "accumulate and exponentiate at n=6, truncate to n=4 for shading (paper Fig. 7e)")
    row("product n4", graph_stages(4, accumulate="product"), quick,
        "Zhou et al. 2005 product accumulation of the same spheres (truncation after each product)")
    row("rt spheres", (("blockers", "shexp.blockers", {"budget": 48}, {}), ("trace", "shexp.sphere_trace", {"samples": 512}, {})),
        False, "ray traced against the 48 blocker spheres (512 spp): the sphere-approximation error alone",
        output="trace.radiance")
    return rows
