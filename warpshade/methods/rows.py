"""Rows of the speed-vs-accuracy harness (``benchmarks/run.py``).

Each method package exposes ``harness_rows(quick: bool) -> list[HarnessRow]``: the settings of
that method worth charting (SH order, samples, lobes, ...), each as the stages of a graph and
the scenes it applies to. The harness runs every row on every applicable scene and device in
one run and measures time per frame, precompute time, model size and error against ray-traced
ground truth.
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["HarnessRow", "SCENE_KINDS", "all_rows"]

#: Scene selectors a row can name besides explicit scene keys.
SCENE_KINDS = ("all", "static", "dynamic", "skinned", "deforming")


@dataclass(frozen=True)
class HarnessRow:
    """One method setting to benchmark.

    Attributes:
        method: method family shown in the chart legend ("prt", "unshadowed", "shexp", ...).
        setting: short label of the setting ("n4 s256").
        stages: tuple of ``(name, type, params, inputs)`` tuples (see ``warpshade.graph.StageSpec``).
        output: the output port, ``"stage.port"``.
        scenes: scene keys or kinds (:data:`SCENE_KINDS`) the row applies to.
        quick: include the row in ``--quick`` runs.
        notes: what the row measures, for the table.
    """

    method: str
    setting: str
    stages: tuple
    output: str
    scenes: tuple = ("all",)
    quick: bool = True
    notes: str = ""
    params: dict = field(default_factory=dict)

    @property
    def label(self) -> str:
        return f"{self.method} {self.setting}"


def all_rows(quick: bool = False) -> list:
    """Rows of every method package that defines ``harness_rows``."""
    import importlib

    import warpshade.methods as methods

    rows = []
    for name in methods.METHOD_PACKAGES:
        mod = importlib.import_module(f"warpshade.methods.{name}")
        fn = getattr(mod, "harness_rows", None)
        if fn is not None:
            rows.extend(r for r in fn(quick) if r.quick or not quick)
    return rows
