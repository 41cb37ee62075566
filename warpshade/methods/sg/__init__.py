"""All-frequency shading with spherical Gaussians and SSDF visibility (Wang, Ng, Liu, Snyder 2009).

Reflectance is a microfacet model whose NDF is a few spherical Gaussians (:mod:`.brdf`; closed
forms for Beckmann, Cook-Torrance, Blinn-Phong and Ward, fits for anisotropic and tabulated NDFs),
warped to each view (eq. 17-22) per vertex or per pixel (:mod:`.brdf_warp`), so materials are
per-pixel textures edited at run time with no precompute. Visibility is a per-vertex spherical
signed distance function (:mod:`warpshade.transfer.ssdf`, PCA to an error budget), integrated
against SG lobes by the hemisphere integral ``f_h`` (:func:`warpshade.basis.sg.hemisphere_integral`).
The environment is an SG mixture for the diffuse term and a prefiltered table for the specular
term; sphere and distant lights are SG lobes (:mod:`.lighting`, :mod:`.lighting_warp`).

Anisotropic and measured materials (sec. 4.2-4.3): anisotropic Ward and Ashikhmin-Shirley NDFs
fitted with free-axis SG lobes (the lobe count from an error budget) and tabulated (measured)
materials, whose NDF and 1-D shadowing factor :mod:`.measured` extracts from a MERL-layout table
by eq. 13, are shaded by :mod:`.lobes_warp`: each lobe warped to the view in the tangent frame of
every vertex or pixel (tangents from the meshes' UVs, :mod:`warpshade.geometry.uv_tangents`, or a
direction), the warped lobe taken as isotropic as in the paper.
Spatially varying measured materials (sec. 4.2, ``brdf = "svbrdf"``): a texture of eq.-13
materials whose per-texel NDFs are fitted with SG lobes and whose shadowing curves are compressed
by PCA (:mod:`.svbrdf`), looked up per vertex or per pixel at the meshes' UVs and decoded in the
kernels (:mod:`.svbrdf_warp`).

Modules, in the shape of :mod:`warpshade.methods.prt`: :mod:`.stages` (``sg.ssdf``, ``sg.shade``; the
shade stage's materials in :mod:`.shade_materials`, lights in :mod:`.shade_lights`, kernel inputs in
:mod:`.shade_inputs`, reference models in :mod:`.shade_reference`), :mod:`.kernels`, :mod:`.model`, :mod:`.mirror` (float64 mirror of the kernels), :mod:`.rows`,
:mod:`.budget`, plus :mod:`.brdf`, :mod:`.brdf_warp`, :mod:`.lobes_warp`, :mod:`.measured`,
:mod:`.lighting`, :mod:`.lighting_warp`.
"""

from .brdf import microfacet_brdf
from .envfit import EnvironmentSG, fit_environment
from .lights import point_light_lobe
from .model import EnvironmentLighting, bake_ssdf_model, decode_maps, environment_lighting
from .ndf import ndf_lobes
from .prefilter import PrefilteredEnvironment
from .mirror import shade_f64
from .rows import harness_rows
from .slices import view_slice
from .stages import SgSsdfStage, SgShadeStage

__all__ = [
    "EnvironmentLighting",
    "EnvironmentSG",
    "PrefilteredEnvironment",
    "SgSsdfStage",
    "SgShadeStage",
    "bake_ssdf_model",
    "decode_maps",
    "environment_lighting",
    "fit_environment",
    "harness_rows",
    "microfacet_brdf",
    "ndf_lobes",
    "point_light_lobe",
    "shade_f64",
    "view_slice",
]
