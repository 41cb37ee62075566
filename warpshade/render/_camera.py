"""Pinhole cameras: the scene's camera, or one framing the scene bounds from a 3/4 view.

Image convention: row 0 is the top of the image, column 0 the left; pixel ``(row, col)`` looks
through the point ``(col + 0.5, row + 0.5)`` of the image plane. The camera looks from
``position`` toward ``target``; ``right = normalise(forward x up)`` and the image's up is
``right x forward``. ``vertical_fov`` is the full vertical field of view in degrees.
"""

from __future__ import annotations

import math

import numpy as np

from ..scene._scene import Camera

__all__: list[str] = []

# Direction from the target toward the eye for the automatic 3/4 view, in a z-up world:
# 40 degrees of azimuth off the -y axis toward +x, 28 degrees of elevation.
_AZIMUTH_DEG = 40.0
_ELEVATION_DEG = 28.0
# Margin around the bounding sphere when framing (fraction of its radius).
_FRAME_MARGIN = 1.08


def frame_camera(lo, hi, up_axis: str = "Z", vertical_fov: float = 40.0, aspect: float = 4.0 / 3.0) -> Camera:
    """A camera that frames the axis-aligned box ``[lo, hi]`` from a pleasant 3/4 view.

    Args:
        lo, hi: box corners (3,), world space.
        up_axis: the world's up axis, "Y" or "Z".
        vertical_fov: full vertical field of view in degrees.
        aspect: image width / height (the bounding sphere fits the narrower field of view).
    """
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-6)
    az, el = math.radians(_AZIMUTH_DEG), math.radians(_ELEVATION_DEG)
    offset_z_up = np.array([math.cos(el) * math.sin(az), -math.cos(el) * math.cos(az), math.sin(el)])
    if up_axis.upper() == "Z":
        offset, up = offset_z_up, np.array([0.0, 0.0, 1.0])
    elif up_axis.upper() == "Y":
        # z-up (x, y, z) -> y-up (x, z, -y): the same view of a y-up world
        offset, up = np.array([offset_z_up[0], offset_z_up[2], -offset_z_up[1]]), np.array([0.0, 1.0, 0.0])
    else:
        raise ValueError(f"frame_camera: up axis must be 'Y' or 'Z', got {up_axis!r}")
    half_v = math.radians(vertical_fov) / 2.0
    half_h = math.atan(math.tan(half_v) * aspect)
    distance = _FRAME_MARGIN * radius / math.sin(min(half_v, half_h))
    return Camera(position=centre + distance * offset, target=centre, up=up, vertical_fov=vertical_fov)


def camera_for(scene, frame=None, aspect: float = 4.0 / 3.0) -> Camera:
    """``scene.camera`` when the scene has one, else :func:`frame_camera` of its bounds."""
    if getattr(scene, "camera", None) is not None:
        return scene.camera
    lo, hi = scene.bounds(frame)
    return frame_camera(lo, hi, getattr(scene, "up_axis", "Z"), aspect=aspect)


def camera_basis(camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit (forward, right, up) vectors of a camera, world space."""
    position = np.asarray(camera.position, np.float64)
    forward = np.asarray(camera.target, np.float64) - position
    norm = np.linalg.norm(forward)
    if not norm > 0.0:
        raise ValueError(f"camera {camera.path or '<auto>'}: position equals target")
    forward /= norm
    right = np.cross(forward, np.asarray(camera.up, np.float64))
    rnorm = np.linalg.norm(right)
    if not rnorm > 1e-12:
        raise ValueError(f"camera {camera.path or '<auto>'}: up vector is parallel to the view direction")
    right /= rnorm
    return forward, right, np.cross(right, forward)
