"""Reflectance product operators (Nowrouzezahrai, Kalogerakis, Fiume 2009, sec. 3-4 and 6).

A BRDF becomes k light factors in SH with their product matrices and k view factors
(:mod:`.model`, built in well under a second, cached per BRDF); per frame, eq. 11 turns any
per-vertex SH visibility into glossy radiance toward the eye (:mod:`.kernels`), so BRDFs are
swapped at run time (``Runtime.set_material``, the ``[[material]]`` track) with no visibility
precompute. The lighting reaches each tangent frame by a full SH rotation or the paper's 3-lobe
ZH approximation (:mod:`.lighting`). Visibility generators: per-frame ray tracing, a static bake
(:mod:`.stages`), SHEXP's blocker spheres (``shexp.visibility``) and dynamic height fields
(:mod:`.heightfield`: horizon angles from a max pyramid, SH wedges placed by z-rotations, and a
shading path at full resolution with visibility sub-sampled).

Modules: :mod:`.model` (the operators), :mod:`.kernels`, :mod:`.reference` (float64 mirrors and
the exact-BRDF oracle), :mod:`.stages`, :mod:`.rows`, :mod:`.budget`, :mod:`.lighting`,
:mod:`.heightfield` (+ :mod:`.heightfield_reference`).
"""

from . import heightfield  # noqa: F401  (registers rpo.heightfield_visibility, rpo.heightfield_shade)
from .lighting import ZHLighting, fit_zh_lighting
from .model import OperatorCache, ReflectanceOperator, build_operator
from .reference import shade_exact_brdf, shade_reference
from .rows import harness_rows
from .stages import RpoShadeStage, RpoVisibilityStaticStage, RpoVisibilityTracedStage

__all__ = [
    "OperatorCache",
    "ReflectanceOperator",
    "RpoShadeStage",
    "RpoVisibilityStaticStage",
    "RpoVisibilityTracedStage",
    "ZHLighting",
    "build_operator",
    "fit_zh_lighting",
    "harness_rows",
    "shade_exact_brdf",
    "shade_reference",
]
