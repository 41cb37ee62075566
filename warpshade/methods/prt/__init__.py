"""Static PRT and unshadowed irradiance: the baselines every dynamic method is measured against.

This package is the worked example of a method (``docs/adding-a-method.md``); every method has
the same modules:

* :mod:`._stages` -- the graph stages: ports, parameters, binding buffers (thin);
* :mod:`._kernels` -- the Warp kernels;
* :mod:`._model` -- the precomputed artifact (a dataclass with its check) and how it is made;
* :mod:`._mirror` -- the float64 mirror of the kernels, the tests' oracle;
* :mod:`._rows` -- the settings the speed-vs-accuracy harness runs;
* :mod:`._budget` -- the candidate settings an error budget chooses from.
"""

from ._model import TransferModel, bake_transfer
from ._mirror import shade_transfer_f64, shade_unshadowed_f64
from ._rows import harness_rows
from ._stages import PrtShadeStage, PrtTransferStage, PrtUnshadowedStage

__all__ = [
    "PrtShadeStage",
    "TransferModel",
    "PrtTransferStage",
    "PrtUnshadowedStage",
    "bake_transfer",
    "harness_rows",
    "shade_transfer_f64",
    "shade_unshadowed_f64",
]
