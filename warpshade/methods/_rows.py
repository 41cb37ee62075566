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

#: The scenes the harness measures, one entry each, by key (the name rows, charts and results use;
#: :func:`warpshade.measure.load_bench_scene` loads them): the scene spec, its load options and, for a
#: held-out clip, the training clip of the same character or cloth (what the data-driven methods train
#: on) with what varies between its frames (``inputs``: ``"joints"`` of a skinned character, the
#: default, or ``"dihedral"`` angles of a simulated cloth). The methods' rows take their training
#: clips from here (:func:`training_clips`), so a new scene is one entry here.
BENCH_SCENES = {
    "bunny": {"spec": "warp-example:bunny", "options": {"ground_plane": True}},
    "bear": {"spec": "warp-example:bear", "options": {"ground_plane": True}},
    "blockers": {"spec": "bundled:blockers", "options": {}},
    "figure": {"spec": "bundled:figure", "options": {}, "training": "bundled:figure_train"},
    "figure_walk": {"spec": "bundled:figure_walk", "options": {}, "training": "bundled:figure_train"},
    "wanderer": {"spec": "bundled:wanderer_test", "options": {}, "training": "bundled:wanderer_train"},
    "cloth": {"spec": "bundled:cloth", "options": {}},
    "cloth_heldout": {"spec": "bundled:cloth_heldout", "options": {}, "training": "bundled:cloth_train",
                      "inputs": "dihedral"},
    "bend": {"spec": "bundled:bend", "options": {}},
}


def training_clips(inputs: str | None = "joints") -> dict:
    """Held-out scene key -> the spec of its training clip, for the :data:`BENCH_SCENES` whose frames
    vary by ``inputs`` (None: every one with a training clip), in the order of :data:`BENCH_SCENES`."""
    return {key: cfg["training"] for key, cfg in BENCH_SCENES.items()
            if "training" in cfg and inputs in (None, cfg.get("inputs", "joints"))}


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
