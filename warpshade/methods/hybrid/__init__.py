"""Per-frame ray tracing with few rays: a fast model as control variate, reuse over frames and
over the mesh.

Every frame, ``samples`` rays per vertex (8..64) estimate the diffuse transfer's *difference*
from a control model's transfer (the data-driven transfer, LDPRT's local transfer, the last
frame's estimate, or nothing), an unbiased control-variate estimate whose variance is that of the
model's residual; the residual is filtered over mesh neighbours and averaged per vertex over
frames, the history cut where the surface moves fast or fresh rays disagree with it.

* :mod:`._stages` -- ``hybrid.trace`` (per frame): ports, parameters, buffers; and
  ``hybrid.visibility_transfer``: a data-driven visibility model's prediction as world-frame
  transfer, the control of ``hybrid.trace``;
* :mod:`._kernels` -- the residual (rays), the edge-aware filter, the moving average, the
  history-aware filter (more filtering where a vertex's history is short);
* :mod:`._mirror` -- their float64 mirror, the tests' oracle;
* :mod:`._model` -- the surface neighbourhood built at set-up (any topology, reported);
* :mod:`._rows` -- the harness rows (K in {8, 16, 32, 64} x each control);
* :mod:`._budget` -- the candidate settings an error budget chooses from.
"""

from ._mirror import (cycle_directions_f64, estimate_f64, filter_f64, reproject_f64, residual_f64, temporal_f64,
                     visibility_transfer_f64, warm_blend_f64, warm_filter_f64, warm_weight_f64,
                     world_visibility_transfer_f64)
from ._model import SurfaceNeighbours, surface_neighbours
from ._rows import glossy_stages_for, harness_rows, stages_for
from ._stages import HybridTraceStage, HybridVisibilityTransferStage

__all__ = [
    "HybridTraceStage",
    "HybridVisibilityTransferStage",
    "SurfaceNeighbours",
    "cycle_directions_f64",
    "estimate_f64",
    "filter_f64",
    "glossy_stages_for",
    "reproject_f64",
    "harness_rows",
    "residual_f64",
    "stages_for",
    "surface_neighbours",
    "temporal_f64",
    "visibility_transfer_f64",
    "warm_blend_f64",
    "warm_filter_f64",
    "warm_weight_f64",
    "world_visibility_transfer_f64",
]
