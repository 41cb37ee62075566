"""Reflectance product operators (Nowrouzezahrai, Kalogerakis, Fiume 2009, sec. 3-4 and 6).

A BRDF becomes k light factors in SH with their product matrices and k view factors
(:mod:`._model`, built in well under a second, cached per BRDF); per frame, eq. 11 turns any
per-vertex SH visibility into glossy radiance toward the eye (:mod:`._kernels`), so BRDFs are
swapped at run time (``Runtime.set_material``, the ``[[material]]`` track) with no visibility
precompute. The lighting reaches each tangent frame by a full SH rotation or the paper's 3-lobe
ZH approximation (:mod:`._lighting`). Visibility generators: per-frame ray tracing, a static bake
(:mod:`._stages`), SHEXP's blocker spheres (``shexp.visibility``) and dynamic height fields
(:mod:`warpshade.methods.heightfield`, whose shading stage shares :class:`GlossyStage`).

Modules: :mod:`._model` (the operators), :mod:`._kernels`, :mod:`._mirror` (float64 mirrors and
the exact-BRDF oracle), :mod:`._stages`, :mod:`._rows`, :mod:`._budget`, :mod:`._lighting`.
"""

from ._lighting import ZHLighting, fit_zh_lighting
from ._model import OperatorCache, ReflectanceOperator, build_operator
from ._mirror import shade_exact_brdf, shade_f64
from ._rows import harness_rows
from ._stages import OPERATORS, SHADE_PARAMS, GlossyStage, RpoShadeStage, RpoVisibilityStaticStage, RpoVisibilityTracedStage

__all__ = [
    "GlossyStage",
    "OPERATORS",
    "OperatorCache",
    "ReflectanceOperator",
    "RpoShadeStage",
    "RpoVisibilityStaticStage",
    "RpoVisibilityTracedStage",
    "SHADE_PARAMS",
    "ZHLighting",
    "build_operator",
    "fit_zh_lighting",
    "harness_rows",
    "shade_exact_brdf",
    "shade_f64",
]
