"""The measuring layer, above the runtime: ground truth, errors, pictures, outputs, budgets.

* :mod:`._protocols` -- what measuring asks of a stage (its reference model, per-pixel shading);
* :mod:`._truth` -- ray-traced ground truth cached on disk; a run's error against it;
* :mod:`._metrics` -- relative RMS, 99th percentile, ground-truth noise;
* :mod:`._pictures` -- previews and method | reference | error pictures of a run;
* :mod:`._outputs` -- the USD layer and JSON report of a run, the names of its files, planned
  before any work and never over a file warpshade did not write (the output folder's manifest);
* :mod:`._scenes` -- the bundled scenes under the measuring conventions;
* :mod:`._harness` -- one method setting on one scene, timed and measured;
* :mod:`._budget` -- choose a method's setting from an error budget;
* :mod:`._temporal` -- noise over seeds at a held frame, lag on the fastest-moving frames.

The runtime (:mod:`warpshade.graph`) steps and records; the CLI composes it with this layer.
"""

from ._budget import BudgetChoice, Candidate, choose, method_candidates, pick
from ._harness import run_setting, setting_error
from ._metrics import combine_metrics, error_metrics
from ._auto import shade_scene
from ._outputs import OutputPlan, check_output_directory, plan_outputs, preview_frames, report, write_report, write_usd
from ._pictures import comparison_figure, error_colors, render_comparisons, render_previews, run_exposure
from ._protocols import ground_truth_model
from ._scenes import BENCH_SCENES, error_frames, load_bench_scene, pick_frames, scene_kinds
from ._temporal import lag, noise
from ._truth import GT_SEED, VALIDATE_SEED, Measurement, ground_truth, measure_error, reference_model, truth_cache

__all__ = [
    "OutputPlan",
    "check_output_directory",
    "plan_outputs",
    "preview_frames",
    "shade_scene",
    "BENCH_SCENES",
    "BudgetChoice",
    "Candidate",
    "GT_SEED",
    "Measurement",
    "VALIDATE_SEED",
    "choose",
    "combine_metrics",
    "comparison_figure",
    "error_colors",
    "error_frames",
    "error_metrics",
    "ground_truth",
    "ground_truth_model",
    "lag",
    "load_bench_scene",
    "measure_error",
    "method_candidates",
    "noise",
    "pick",
    "pick_frames",
    "reference_model",
    "render_comparisons",
    "render_previews",
    "report",
    "run_exposure",
    "run_setting",
    "scene_kinds",
    "setting_error",
    "truth_cache",
    "write_report",
    "write_usd",
]
