"""The stage-graph runtime: stages wired by name, validated, cached, one recorded frame per step.

Public surface::

    import warpshade.graph as graph
    spec = graph.load("stages/bunny_prt.toml")       # GraphSpec (validated when compiled)
    rt = spec.compile(device="cpu")                   # Runtime: precompute (cached) + set-up
    radiance = rt.step(frame)                         # wp.array (vertex_count, 3), per frame
    rt.run()                                          # every frame, recorded in rt.results

Writing USD, pictures and reports, and measuring against ground truth, are in
:mod:`warpshade.measure`.
"""

from ..methods.stage import (FrameStage, Param, Port, PrecomputeStage, Stage, StageContext, StageError, get_stage_type,
                             register_stage, stage_types)
from .cache import ArtifactCache, default_cache_dir
from .errors import GraphError
from .runtime import Runtime, parse_frames
from .spec import SCENE_PORTS, GraphSpec, StageSpec, extend_static_frames, lighting_from_spec, load

__all__ = [
    "ArtifactCache",
    "GraphError",
    "FrameStage",
    "GraphSpec",
    "Param",
    "Port",
    "PrecomputeStage",
    "Runtime",
    "SCENE_PORTS",
    "Stage",
    "StageContext",
    "StageError",
    "StageSpec",
    "default_cache_dir",
    "extend_static_frames",
    "get_stage_type",
    "lighting_from_spec",
    "load",
    "parse_frames",
    "register_stage",
    "stage_types",
]
