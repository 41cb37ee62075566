"""Scene description (static), per-frame state and its evaluation, lights and materials."""

from ._lighting import (
    USD_DOME_FROM_MAP,
    DistantLight,
    Environment,
    LightingSource,
    LightTrack,
    SphereLight,
    lights_to_sh,
    sky_radiance,
    up_rotation,
    usd_dome_texel_directions,
)
from ._materials import BRDF, AnisotropicMicrofacet, BlinnPhong, Lambert, Microfacet, Phong
from ._scene import ANIMATION_KINDS, Camera, Mesh, Scene, Skeleton, SkinBinding, ground_plane
from ._state import Change, FrameEvaluator, FrameState, MaterialAssignment
from ._svbrdf import SVBRDFTable, read_svbrdf, write_svbrdf
from ._tabulated import TabulatedBRDF, read_merl, write_merl
from ._tabulated_aniso import AnisotropicTable, read_anisotropic_table, write_anisotropic_table
from ._textures import SurfaceMaps, Texture

__all__ = [
    "AnisotropicMicrofacet",
    "AnisotropicTable",
    "BRDF",
    "BlinnPhong",
    "Lambert",
    "Microfacet",
    "Phong",
    "SVBRDFTable",
    "TabulatedBRDF",
    "read_anisotropic_table",
    "read_merl",
    "read_svbrdf",
    "write_anisotropic_table",
    "write_merl",
    "write_svbrdf",
    "ANIMATION_KINDS",
    "Camera",
    "Change",
    "DistantLight",
    "Environment",
    "FrameEvaluator",
    "FrameState",
    "LightTrack",
    "LightingSource",
    "MaterialAssignment",
    "Mesh",
    "Scene",
    "Skeleton",
    "SkinBinding",
    "SphereLight",
    "SurfaceMaps",
    "Texture",
    "USD_DOME_FROM_MAP",
    "ground_plane",
    "lights_to_sh",
    "sky_radiance",
    "up_rotation",
    "usd_dome_texel_directions",
]
