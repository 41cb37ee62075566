"""SHEXP: soft shadows from sphere blockers by log-space SH accumulation (Ren et al. 2006).

Modules, in the shape of every method (see :mod:`warpshade.methods.prt`): :mod:`.stages`
(``shexp.tables``, ``shexp.blockers``, ``shexp.static_bake``, ``shexp.shade``,
``shexp.sphere_trace``), :mod:`.kernels` (the per-receiver Warp pass, its phases as Warp
functions, its inputs and outputs as structs),
:mod:`.model` (the blocker model artifact -- sphere sets, hierarchy, receiver clusters --
and its per-frame animation), :mod:`.mirror` (float64 oracle), :mod:`.rows` (harness
settings), :mod:`.budget` (candidate settings of an error budget); SHEXP's own parts:
:mod:`.pipeline` (the shader's fixed buffers and launches, also usable on host arrays),
:mod:`.trace_kernels` (ray tracing against the spheres), :mod:`.cut_kernels` (ratio vectors of
the hierarchy cut),
:mod:`.spheres` (sphere sets attached to the scene's animation), :mod:`.tables` (sphere-light
lobe fits, windows).
"""

from .rows import graph_stages, harness_rows
from .stages import ShexpBlockersStage, ShexpShadeStage, ShexpSphereTraceStage, ShexpStaticBakeStage, ShexpTablesStage

__all__ = ["ShexpBlockersStage", "ShexpShadeStage", "ShexpSphereTraceStage", "ShexpStaticBakeStage", "ShexpTablesStage", "graph_stages", "harness_rows"]
