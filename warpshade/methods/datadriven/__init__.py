"""Data-driven PRT for skinned characters (Nowrouzezahrai, Kalogerakis, Fiume 2007).

Transfer vectors predicted from joint angles by linear maps learnt from ray-traced transfer on
a training clip: full, or reduced by PCA of the pose vectors and of the per-vertex coefficients.

* :mod:`._model` -- Tikhonov fits with closed-form leave-one-out alpha, PCA, the error budget;
* :mod:`._kernels` / :mod:`._mirror` -- the per-frame products and their float64 mirror;
* :mod:`._stages` -- ``datadriven.data``, ``datadriven.fit``, ``datadriven.transfer``;
* :mod:`._rows` / :mod:`._budget` -- harness rows and error-budget candidates.

Built on :mod:`warpshade.methods._shared` (shared with :mod:`warpshade.methods.visibility`): the
pose vectors from UsdSkel joint transforms (three parameterisations, root apart; their host and
device forms), the pose space (standardisation, PCA, novelty) and the training clip, traced as
tasks of a few frames for an executor. ``PARAMETERISATIONS``, ``pose_layout``, ``pose_features``,
``pose_space`` and ``novelty`` are public here.
"""

from .._shared.pose import PARAMETERISATIONS, pose_features, pose_layout
from .._shared.pose_space import novelty, pose_space
from ._model import DataDrivenModel, choose_sizes, fit_full, fit_reduced
from ._mirror import hemisphere_transfer_error, transfer_f64
from ._rows import harness_rows
from ._stages import DataDrivenDataStage, DataDrivenFitStage, DataDrivenTransferStage

__all__ = [
    "PARAMETERISATIONS",
    "DataDrivenModel",
    "DataDrivenDataStage",
    "DataDrivenFitStage",
    "DataDrivenTransferStage",
    "choose_sizes",
    "fit_full",
    "fit_reduced",
    "harness_rows",
    "hemisphere_transfer_error",
    "novelty",
    "pose_space",
    "pose_features",
    "pose_layout",
    "transfer_f64",
]
