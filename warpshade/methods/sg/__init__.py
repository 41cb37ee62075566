"""All-frequency shading with spherical Gaussians and SSDF visibility (Wang, Ng, Liu, Snyder 2009).

Reflectance is a microfacet model whose NDF is a few spherical Gaussians (:mod:`._brdf`; closed
forms for Beckmann, Cook-Torrance, Blinn-Phong and Ward, fits for anisotropic and tabulated NDFs),
warped to each view (eq. 17-22) per vertex or per pixel (:mod:`._brdf_warp`), so materials are
per-pixel textures edited at run time with no precompute. Visibility is a per-vertex spherical
signed distance function (:mod:`warpshade.transfer._ssdf`, PCA to an error budget), integrated
against SG lobes by the hemisphere integral ``f_h`` (:func:`warpshade.basis.sg.hemisphere_integral`).
The environment is an SG mixture for the diffuse term and a prefiltered table for the specular
term; sphere and distant lights are SG lobes (:mod:`.lighting`, :mod:`._lighting_warp`).

Anisotropic and measured materials (sec. 4.2-4.3): anisotropic Ward and Ashikhmin-Shirley NDFs
fitted with free-axis SG lobes (the lobe count from an error budget) and tabulated (measured)
materials, whose NDF and 1-D shadowing factor :mod:`._measured` extracts from a MERL-layout table
by eq. 13, are shaded by :mod:`._lobes_warp`: each lobe warped to the view in the tangent frame of
every vertex or pixel (tangents from the meshes' UVs, :mod:`warpshade.geometry._uv_tangents`, or a
direction), the warped lobe taken as isotropic as in the paper.
Spatially varying measured materials (sec. 4.2, ``brdf = "svbrdf"``): a texture of eq.-13
materials whose per-texel NDFs are fitted with SG lobes and whose shadowing curves are compressed
by PCA (:mod:`._svbrdf`), looked up per vertex or per pixel at the meshes' UVs and decoded in the
kernels (:mod:`._svbrdf_warp`).

Modules, in the shape of :mod:`warpshade.methods.prt`: :mod:`._stages` (``sg.ssdf``, ``sg.shade``; the
shade stage's materials in :mod:`._shade_materials`, lights in :mod:`._shade_lights`, kernel inputs in
:mod:`._shade_inputs`, reference models in :mod:`._shade_reference`), :mod:`._kernels`, :mod:`._model`, :mod:`._mirror` (float64 mirror of the kernels), :mod:`._rows`,
:mod:`._budget`, plus :mod:`._brdf`, :mod:`._brdf_warp`, :mod:`._lobes_warp`, :mod:`._measured`,
:mod:`.lighting`, :mod:`._lighting_warp`.
"""

from ._brdf import microfacet_brdf
from ._envfit import EnvironmentSG, fit_environment
from ._lights import point_light_lobe
from ._model import EnvironmentLighting, bake_ssdf_model, decode_maps, environment_lighting
from ._ndf import ndf_lobes
from ._prefilter import PrefilteredEnvironment
from ._mirror import shade_f64
from ._rows import harness_rows
from ._slices import view_slice
from ._stages import SgSsdfStage, SgShadeStage

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
