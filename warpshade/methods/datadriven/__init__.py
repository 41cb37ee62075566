"""Data-driven PRT for skinned characters (Nowrouzezahrai, Kalogerakis, Fiume 2007).

Transfer vectors predicted from joint angles by linear maps learnt from ray-traced transfer on
a training clip: full, or reduced by PCA of the pose vectors and of the per-vertex coefficients.

* :mod:`.pose` -- pose vectors from UsdSkel joint transforms (three parameterisations, root apart);
* :mod:`.training` -- the training data, one task per few frames for an executor;
* :mod:`.model` -- Tikhonov fits with closed-form leave-one-out alpha, PCA, the error budget;
* :mod:`.kernels` / :mod:`.mirror` -- the per-frame products and their float64 mirror;
* :mod:`.stages` -- ``datadriven.data``, ``datadriven.fit``, ``datadriven.transfer``;
* :mod:`.rows` / :mod:`.budget` -- harness rows and error-budget candidates.
"""

from .model import DataDrivenModel, choose_sizes, fit_full, fit_reduced, novelty
from .pose import PARAMETERISATIONS, pose_features, pose_layout
from .mirror import hemisphere_transfer_error, transfer_f64
from .rows import harness_rows
from .stages import DataDrivenDataStage, DataDrivenFitStage, DataDrivenTransferStage

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
    "pose_features",
    "pose_layout",
    "transfer_f64",
]
