"""Scene description (static), per-frame state, lights and materials."""

from .lighting import DistantLight, Environment, SphereLight, lights_to_sh, up_rotation
from .scene import ANIMATION_KINDS, Camera, FrameState, Mesh, Scene, Skeleton, SkinBinding

__all__ = [
    "ANIMATION_KINDS",
    "Camera",
    "DistantLight",
    "Environment",
    "FrameState",
    "Mesh",
    "Scene",
    "Skeleton",
    "SkinBinding",
    "SphereLight",
    "lights_to_sh",
    "up_rotation",
]
