"""Scene description (static), per-frame state and its evaluation, lights and materials."""

from .lighting import (
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
from .scene import ANIMATION_KINDS, Camera, Mesh, Scene, Skeleton, SkinBinding, ground_plane
from .state import Change, FrameEvaluator, FrameState, MaterialAssignment
from .textures import SurfaceMaps, Texture

__all__ = [
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
