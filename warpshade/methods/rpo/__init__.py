"""Reflectance product operators (Nowrouzezahrai, Kalogerakis, Fiume 2009, sec. 3-4 and 6).

A BRDF becomes k light factors in SH with their product matrices and k view factors
(:mod:`.model`, built in well under a second, cached per BRDF); per frame, eq. 11 turns any
per-vertex SH visibility into glossy radiance toward the eye (:mod:`.kernels`), so BRDFs are
swapped at run time (``Runtime.set_material``, the ``[[material]]`` track) with no visibility
precompute. The lighting reaches each tangent frame by a full SH rotation or the paper's 3-lobe
ZH approximation (:mod:`.lighting`). Visibility generators: per-frame ray tracing, a static bake
(:mod:`.stages`), SHEXP's blocker spheres (``shexp.visibility``) and dynamic height fields
(:mod:`warpshade.methods.heightfield`, whose shading stage shares :class:`GlossyStage`).

Modules: :mod:`.model` (the operators), :mod:`.kernels`, :mod:`.mirror` (float64 mirrors and
the exact-BRDF oracle), :mod:`.stages`, :mod:`.rows`, :mod:`.budget`, :mod:`.lighting`.
"""

from .lighting import ZHLighting, fit_zh_lighting
from .model import OperatorCache, ReflectanceOperator, build_operator
from .mirror import shade_exact_brdf, shade_f64
from .rows import harness_rows
from .stages import OPERATORS, SHADE_PARAMS, GlossyStage, RpoShadeStage, RpoVisibilityStaticStage, RpoVisibilityTracedStage

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
