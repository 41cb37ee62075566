"""Local, deformable PRT with zonal-harmonic lobes (Sloan, Luna, Snyder 2005).

Transfer is ray traced once in each vertex's tangent frame, fitted with a few ZH lobes, and
rotated with the surface every frame (``ldprt.fit`` -> ``ldprt.tangents`` -> ``ldprt.shade``);
parametric models (thin membrane, sinusoidal wrinkles) and glossy LDPRT build on the same
lobes, and so do texture patches (Sec. 5): a tileable height field's transfer fitted per texel
(``ldprt.patch``) and mapped by UV onto a deforming surface, per vertex and per pixel
(``ldprt.patch_shade``, :mod:`._patch`, :mod:`._patch_warp`). Captures local shadowing that moves with the surface; distant occlusion that changes
with the pose (an arm over the torso) is not modelled.

Modules, in the shape of every method (see :mod:`warpshade.methods.prt`): :mod:`._stages`,
:mod:`._kernels`, :mod:`._model` (the fitted lobes), :mod:`._mirror` (float64 mirrors),
:mod:`._rows` (harness settings), :mod:`._budget` (candidate settings); and the variants
:mod:`._glossy`, :mod:`._membrane`, :mod:`._wrinkle`, :mod:`._patch` (with its kernels :mod:`._patch_warp`).
"""

from ._model import LDPRTModel, fit_transfer, local_transfer
from ._mirror import shade_f64, world_transfer_f64
from ._rows import harness_rows
from ._stages import LdprtFitStage, LdprtTangentsStage, LdprtTransferStage, LdprtShadeRotatedStage, LdprtShadeStage

__all__ = [
    "LdprtFitStage",
    "LdprtTangentsStage",
    "LDPRTModel",
    "LdprtTransferStage",
    "LdprtShadeRotatedStage",
    "LdprtShadeStage",
    "fit_transfer",
    "harness_rows",
    "local_transfer",
    "shade_f64",
    "world_transfer_f64",
]
