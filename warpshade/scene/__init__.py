"""Scene description (static), per-frame state, lights and materials."""

from .lighting import (
    USD_DOME_FROM_MAP,
    DistantLight,
    Environment,
    LightTrack,
    SphereLight,
    lights_to_sh,
    sky_radiance,
    up_rotation,
    usd_dome_texel_directions,
)
from .scene import ANIMATION_KINDS, Camera, FrameState, Mesh, Scene, Skeleton, SkinBinding, ground_plane

__all__ = [
    "ANIMATION_KINDS",
    "Camera",
    "DistantLight",
    "Environment",
    "FrameState",
    "LightTrack",
    "Mesh",
    "Scene",
    "Skeleton",
    "SkinBinding",
    "SphereLight",
    "USD_DOME_FROM_MAP",
    "ground_plane",
    "lights_to_sh",
    "sky_radiance",
    "up_rotation",
    "usd_dome_texel_directions",
]
