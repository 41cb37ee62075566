"""One subpackage per technique; importing this package registers every built-in stage type.

Each method subpackage holds ``kernels.py`` (Warp kernels) beside ``stages.py`` (the stages
that orchestrate them). Stage types:

* ``prt.transfer``, ``prt.shade``, ``prt.unshadowed`` -- static PRT (Sloan et al. 2002) and
  unshadowed irradiance, :mod:`warpshade.methods.prt`.
"""

from . import prt  # noqa: F401  (registers stages)
from .stage import Param, Port, Stage, StageError, get_stage_type, register_stage, stage_types

__all__ = ["Param", "Port", "Stage", "StageError", "get_stage_type", "register_stage", "stage_types"]
