"""The stage-graph runtime: stages wired by name, validated, cached, one recorded frame per step.

Public surface::

    import warpshade.graph as graph
    spec = graph.load("stages/bunny_prt.toml")       # GraphSpec (validated when compiled)
    rt = spec.compile(device="cpu")                   # Runtime: precompute (cached) + set-up
    radiance = rt.step(frame)                         # wp.array (vertex_count, 3), per frame
    rt.run()                                          # every frame, recorded in rt.results

Modules: :mod:`._spec` (a graph, its wiring and validation), :mod:`._loader` (TOML files),
:mod:`._scene_inputs` (frames, lighting, scene options), :mod:`._precompute` (cached artifacts),
:mod:`._frame` (set-up, the recorded frame), :mod:`._changes` (run-time changes),
:mod:`._runtime` (the run).

Writing USD, pictures and reports, and measuring against ground truth, are in
:mod:`warpshade.measure`.
"""

from ..methods.stage import (FrameStage, Param, Port, PrecomputeStage, Stage, StageContext, StageError, get_stage_type,
                             register_stage, stage_types)
from ._cache import ArtifactCache, default_cache_dir
from ._errors import GraphError
from ._loader import load
from ._runtime import Runtime
from ._scene_inputs import extend_static_frames, lighting_from_spec, parse_frames
from ._spec import SCENE_PORTS, GraphSpec, StageSpec

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
