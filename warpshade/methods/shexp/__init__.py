"""SHEXP: soft shadows from sphere blockers by log-space SH accumulation (Ren et al. 2006).

Modules, in the shape of every method (see :mod:`warpshade.methods.prt`): :mod:`._stages`
(``shexp.tables``, ``shexp.blockers``, ``shexp.static_bake``, ``shexp.shade``,
``shexp.sphere_trace``), :mod:`._kernels` (the per-receiver Warp pass, its phases as Warp
functions, its inputs and outputs as structs),
:mod:`._model` (the blocker model artifact -- sphere sets, hierarchy, receiver clusters --
and its per-frame animation), :mod:`._mirror` (float64 oracle), :mod:`._rows` (harness
settings), :mod:`._budget` (candidate settings of an error budget); SHEXP's own parts:
:mod:`._pipeline` (the shader's fixed buffers and launches, also usable on host arrays),
:mod:`._trace_kernels` (ray tracing against the spheres), :mod:`._cut_kernels` (ratio vectors of
the hierarchy cut),
:mod:`._spheres` (sphere sets attached to the scene's animation), :mod:`._tables` (sphere-light
lobe fits, windows).
"""

from ._rows import graph_stages, harness_rows
from ._stages import ShexpBlockersStage, ShexpShadeStage, ShexpSphereTraceStage, ShexpStaticBakeStage, ShexpTablesStage

__all__ = ["ShexpBlockersStage", "ShexpShadeStage", "ShexpSphereTraceStage", "ShexpStaticBakeStage", "ShexpTablesStage", "graph_stages", "harness_rows"]
