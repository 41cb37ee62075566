"""The stage-graph runtime: stages wired by name, validated, cached, stepped per frame.

Public surface::

    import warpshade.graph as g
    spec = g.load("stages/blockers_prt.toml")      # GraphSpec (validated when compiled)
    rt = spec.compile(scene, device="cpu")          # Runtime: precompute (cached) + set-up
    radiance = rt.step(frame)                       # wp.array (vertex_count, 3), per frame
    rt.run(); rt.write_usd("out.usda"); rt.write_report("report.json")
"""

from ..methods.stage import (
    Param,
    Port,
    Stage,
    StageError,
    get_stage_type,
    register_stage,
    stage_types,
)
from .cache import ArtifactCache, default_cache_dir
from .graph import SCENE_PORTS, GraphError, GraphSpec, StageSpec, load
from .lighting import LightingSource
from .metrics import combine_metrics, error_metrics
from .runtime import Context, Runtime, parse_frames

__all__ = [
    "ArtifactCache",
    "Context",
    "GraphError",
    "GraphSpec",
    "LightingSource",
    "Param",
    "Port",
    "Runtime",
    "SCENE_PORTS",
    "Stage",
    "StageError",
    "StageSpec",
    "combine_metrics",
    "default_cache_dir",
    "error_metrics",
    "get_stage_type",
    "load",
    "parse_frames",
    "register_stage",
    "stage_types",
]
