"""UsdLux lights and the camera of a USD stage: dome, distant and sphere lights (with their
animated transforms as a :class:`~warpshade.scene.LightTrack`) and the first ``UsdGeom.Camera``.

Part of the stage reader of :mod:`warpshade.io._usd` (whose docstring states the rules): each
function takes the ``_StageReader`` doing the load as ``reader``.
"""

from __future__ import annotations

import math
import os
import warnings

import numpy as np

from ..scene import _lighting as lighting
from ..scene._scene import Camera

__all__ = ["read_light", "with_track", "read_camera"]


def _value_or(value, fallback: float) -> float:
    """A scalar attribute value, or the schema's documented fallback when the attribute is absent."""
    return float(fallback if value is None else value)


def read_light(reader, prim):
    """A warpshade light from a UsdLux light prim, or None (recorded in ``skipped``).

    Emission ``L = color * intensity * 2**exposure`` (times the blackbody colour when
    enabled) is radiance. ``DistantLight``: irradiance ``E = L * solid angle of the
    angular disc`` (``E = L`` for angle 0), or ``E = L`` when ``normalize`` is on (UsdLux:
    a normalised distant light's intensity is illuminance). ``SphereLight``: radiance ``L``,
    divided by the world-space surface area ``4 pi r**2`` when ``normalize`` is on.
    ``DomeLight``: the texture times ``L`` (or ``L`` alone without a texture).
    """
    from pxr import UsdLux

    path = str(prim.GetPath())
    api = UsdLux.LightAPI(prim)
    t0 = reader.times[0]
    intensity = _value_or(api.GetIntensityAttr().Get(t0), 1.0)
    exposure = _value_or(api.GetExposureAttr().Get(t0), 0.0)
    color_value = api.GetColorAttr().Get(t0)
    color = np.asarray((1.0, 1.0, 1.0) if color_value is None else color_value, dtype=np.float64)
    if api.GetEnableColorTemperatureAttr().Get(t0):
        color = color * np.asarray(UsdLux.BlackbodyTemperatureAsRgb(float(api.GetColorTemperatureAttr().Get(t0))))
    emission = color * intensity * 2.0**exposure
    normalize = bool(api.GetNormalizeAttr().Get(t0))
    world = reader._world_transforms(prim)[0]
    if not np.all(np.isfinite(emission)):
        raise ValueError(f"light {path} in {reader.path}: non-finite emission")
    type_name = str(prim.GetTypeName())
    if type_name in ("DomeLight", "DomeLight_1"):
        return _read_dome(reader, prim, emission, world)
    if type_name == "DistantLight":
        light = UsdLux.DistantLight(prim)
        angle = _value_or(light.GetAngleAttr().Get(t0), 0.53)
        # The light shines along its local -Z, so the direction towards it is local +Z.
        direction = world[2, :3]
        half = math.radians(angle) / 2.0
        solid = 2.0 * math.pi * (1.0 - math.cos(half)) if half > 0 else 1.0
        irradiance = emission if normalize else emission * solid
        return lighting.DistantLight(direction=direction, irradiance=irradiance, angle_deg=angle, path=path)
    if type_name == "SphereLight":
        light = UsdLux.SphereLight(prim)
        scale = abs(np.linalg.det(world[:3, :3])) ** (1.0 / 3.0)
        radius = _value_or(light.GetRadiusAttr().Get(t0), 0.5) * scale
        if light.GetTreatAsPointAttr().Get(t0):
            warnings.warn(f"light {path} in {reader.path}: treatAsPoint is ignored (sphere of radius {radius:g})", stacklevel=3)
        if not radius > 0:
            raise ValueError(f"light {path} in {reader.path}: SphereLight radius must be > 0, got {radius}")
        radiance = emission / (4.0 * math.pi * radius * radius) if normalize else emission
        return lighting.SphereLight(position=world[3, :3], radius=radius, radiance=radiance, path=path)
    reader.skipped.append((path, f"unsupported light type {type_name}"))
    return None


def with_track(reader, prim, light):
    """The light with a :class:`~warpshade.scene.LightTrack` when its transform is animated."""
    from dataclasses import replace

    mats = reader._world_transforms(prim)
    if len(mats) < 2:
        return light
    try:
        track = lighting.LightTrack(np.asarray(reader.frames, np.float64), mats)
    except ValueError as exc:
        raise ValueError(f"light {prim.GetPath()} in {reader.path}: {exc}") from None
    return replace(light, track=track)


def _read_dome(reader, prim, emission, world):
    from pxr import UsdLux

    from ._images import read_image

    path = str(prim.GetPath())
    t0 = reader.times[0]
    api = UsdLux.DomeLight_1(prim) if str(prim.GetTypeName()) == "DomeLight_1" else UsdLux.DomeLight(prim)
    fmt = str(api.GetTextureFormatAttr().Get(t0) or "automatic")
    # Rotation only: strip scale from the row-vector matrix, then to column convention.
    u, _, vt = np.linalg.svd(world[:3, :3])
    dome_to_world = (u @ vt).T
    if str(prim.GetTypeName()) == "DomeLight_1":
        pole = str(api.GetPoleAxisAttr().Get() or "scene")
        if pole == "Z" or (pole == "scene" and reader.up_axis == "Z"):
            # UsdLux: the +90 degree rotation about X that takes the dome's +Y pole to +Z,
            # applied to the dome itself before its transform.
            dome_to_world = dome_to_world @ np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    asset = api.GetTextureFileAttr().Get(t0)
    if asset is None or not asset.path:
        return lighting.Environment.constant(emission.astype(np.float32))
    if fmt not in ("automatic", "latlong"):
        raise ValueError(f"dome light {path} in {reader.path}: texture format {fmt!r} is not supported (need latlong)")
    resolved = asset.resolvedPath
    if not resolved or not os.path.isfile(resolved):
        raise ValueError(f"dome light {path} in {reader.path}: texture file {asset.path!r} not found")
    try:
        image = read_image(resolved)
    except (ValueError, OSError) as exc:
        raise ValueError(f"dome light {path} in {reader.path}: cannot read texture {resolved}: {exc}") from exc
    return lighting.Environment.from_usd_dome(image * emission.astype(np.float32), dome_to_world, path=resolved)


def read_camera(reader, prim) -> Camera:
    from pxr import Gf, UsdGeom

    cam = UsdGeom.Camera(prim).GetCamera(reader.times[0])
    frustum = cam.frustum
    position = np.array(frustum.GetPosition(), dtype=np.float64)
    forward = np.array(frustum.ComputeViewDirection(), dtype=np.float64)
    up = np.array(frustum.ComputeUpVector(), dtype=np.float64)
    distance = float(cam.focusDistance) if cam.focusDistance > 0 else 1.0
    positions = None
    if len(reader.times) > 1:  # an animated camera: its eye at every time code
        samples = np.array([UsdGeom.Camera(prim).GetCamera(t).frustum.GetPosition() for t in reader.times], np.float64)
        if not np.all(np.isfinite(samples)):
            raise ValueError(f"camera {prim.GetPath()} in {reader.path}: non-finite position")
        if np.max(np.abs(samples - samples[0])) > 1e-9 * max(1.0, float(np.max(np.abs(samples)))):
            positions = samples
    return Camera(
        position=position,
        target=position + distance * forward / np.linalg.norm(forward),
        up=up / np.linalg.norm(up),
        vertical_fov=float(cam.GetFieldOfView(Gf.Camera.FOVVertical)),
        path=str(prim.GetPath()),
        positions=positions,
    )
