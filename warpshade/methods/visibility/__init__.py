"""Data-driven visibility for characters and cloth (Nowrouzezahrai, Kalogerakis, Fiume 2009, sec. 5).

Per-vertex SH visibility (no cosine) predicted from the pose by small models per cluster, in
temporally coherent local frames, and shaded glossy by reflectance product operators
(``rpo.shade``, :mod:`warpshade.methods.rpo`) or diffuse by re-applying the cosine (eq. 14):

* :mod:`._training` -- the training data (world-frame visibility ray traced per training frame by
  the executor tasks of :mod:`warpshade.methods._shared.training`, turned into local frames
  by exact SH rotations);
* :mod:`._clusters` -- mean shift on skinning weights (or positions), cluster tangent frames;
* :mod:`._fit` -- per-cluster PCA and the linear / quadratic / tanh-network models, cross-validated;
* :mod:`._model` -- the artifact and :func:`fit_visibility`;
* :mod:`._kernels` / :mod:`._mirror` -- the per-frame launches and their float64 mirror;
* :mod:`._stages` -- ``visibility.data``, ``visibility.fit``, ``visibility.predict``, ``visibility.diffuse``;
* :mod:`._rows` / :mod:`._budget` -- harness rows and error-budget candidates.

Built on :mod:`warpshade.methods._shared` (shared with :mod:`warpshade.methods.datadriven`): the
pose vectors and their device form, the pose space and its novelty, and the training clip.
"""

from ._clusters import cluster_frame_rule, cluster_frames_f64, cluster_vertices, mean_shift
from ._fit import fit_cluster
from ._mirror import diffuse_f64, predict_f64
from ._model import MODELS, VisibilityModel, fit_visibility, model_from_arrays
from ._rows import harness_rows
from ._stages import VisibilityDataStage, VisibilityDiffuseStage, VisibilityFitStage, VisibilityPredictStage
from ._training import to_local

__all__ = [
    "MODELS",
    "VisibilityDataStage",
    "VisibilityDiffuseStage",
    "VisibilityFitStage",
    "VisibilityModel",
    "VisibilityPredictStage",
    "cluster_frame_rule",
    "cluster_frames_f64",
    "cluster_vertices",
    "diffuse_f64",
    "fit_cluster",
    "fit_visibility",
    "harness_rows",
    "mean_shift",
    "model_from_arrays",
    "predict_f64",
    "to_local",
]
