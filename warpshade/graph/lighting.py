"""Per-frame lighting for stage graphs: the scene's lights, optionally rotating over time.

The papers' demos rotate a fixed environment; :class:`LightingSource` does the same: distant
lights (environments and distant lights) are rotated about the scene's up axis by
``degrees_per_frame`` times the frame offset from the first frame. SH projections are computed
once per (order, window) in the unrotated pose (float64) and rotated per frame with
:func:`warpshade.basis.sh.rotate`, which is exact for band-limited coefficients.

Lights with a :class:`~warpshade.scene.LightTrack` (animated USD transforms) are posed at each
frame first (``light.at(frame)``); their SH are rotated by their own track rotation, then by the
graph's rotation.
"""

from __future__ import annotations

from dataclasses import fields, replace
from pathlib import Path

import numpy as np

from ..basis import sh
from ..scene.lighting import DistantLight, Environment, SphereLight, up_rotation

__all__ = ["LightingSource"]


def _axis_rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()


class LightingSource:
    """The lights of each frame.

    Args:
        lights: list of light objects (Environment, DistantLight, SphereLight).
        up_axis: the scene's up axis ("Y" or "Z"), the default rotation axis.
        degrees_per_frame: rotation speed of the distant lights about the up axis.
        frame0: the time code at which the rotation is zero.
    """

    def __init__(self, lights, up_axis: str = "Z", degrees_per_frame: float = 0.0, frame0: float = 0.0):
        if not lights:
            raise ValueError("lighting: no lights (the scene has none and none were given)")
        self.lights = list(lights)
        self.axis = up_rotation(up_axis)[:, 2]
        self.degrees_per_frame = float(degrees_per_frame)
        self.frame0 = float(frame0)
        self._sh_cache: dict = {}

    @classmethod
    def from_spec(cls, spec: dict, scene, base_dir: Path | None = None) -> "LightingSource":
        """Build from a graph's ``[lighting]`` table (see :mod:`warpshade.graph.graph`).

        Keys: ``source`` ("scene" default, "sky", "constant", or an .hdr/.exr path),
        ``rotate_degrees_per_frame`` (0), ``intensity`` (1.0, scales every light),
        ``color`` (for "constant").
        """
        spec = dict(spec or {})
        source = spec.pop("source", "scene")
        speed = float(spec.pop("rotate_degrees_per_frame", 0.0))
        intensity = float(spec.pop("intensity", 1.0))
        color = spec.pop("color", (1.0, 1.0, 1.0))
        if spec:
            raise ValueError(f"[lighting]: unknown key(s) {sorted(spec)}")
        to_world = up_rotation(scene.up_axis)
        if source == "scene":
            lights = list(scene.lights)
            if not lights:
                lights = [Environment.sky(to_world=to_world)]
        elif source == "sky":
            lights = [Environment.sky(to_world=to_world)]
        elif source == "constant":
            lights = [Environment.constant(color)]
        else:
            from ..io.images import read_image

            p = Path(source)
            if not p.is_absolute() and base_dir is not None:
                p = base_dir / p
            lights = [Environment(read_image(p), to_world=to_world, path=str(p))]
        if intensity != 1.0:
            lights = [_scaled(light, intensity) for light in lights]
        return cls(lights, scene.up_axis, speed, float(scene.frames[0]))

    def rotation(self, frame: float) -> np.ndarray:
        """World rotation applied to the distant lights at ``frame``, (3, 3)."""
        return _axis_rotation(self.axis, self.degrees_per_frame * (float(frame) - self.frame0))

    def lights_at(self, frame: float) -> list:
        """The light objects at ``frame``: posed by their tracks, distant lights rotated."""
        r = self.rotation(frame)
        out = []
        for light in self.lights:
            light = light.at(frame) if getattr(light, "track", None) is not None else light
            if isinstance(light, Environment):
                out.append(light.rotated(r))
            elif isinstance(light, DistantLight):
                out.append(DistantLight(r @ light.direction, light.irradiance, light.angle_deg, light.path))
            else:
                out.append(light)
        return out

    def sh(self, order: int, frame: float, window: str | None = None, **window_args) -> np.ndarray:
        """SH of all distant lights at ``frame``, world frame, shape (3, order**2), float64."""
        key = (order, window, tuple(sorted(window_args.items())))
        if key not in self._sh_cache:
            fixed = np.zeros((3, order * order))
            tracked = []  # (track, SH at the track's first time code)
            for light in self.lights:
                if isinstance(light, (Environment, DistantLight)):
                    coeffs = light.to_sh(order)
                    if window is not None:
                        coeffs = sh.window(coeffs, window, **window_args)
                    if light.track is None:
                        fixed += coeffs
                    else:
                        tracked.append((light.track, coeffs))
            self._sh_cache[key] = (fixed, tracked)
        fixed, tracked = self._sh_cache[key]
        total = fixed.copy()
        for track, coeffs in tracked:
            total += sh.rotate(coeffs, track.rotation(frame))
        if self.degrees_per_frame == 0.0:
            return total
        return sh.rotate(total, self.rotation(frame))

    def fingerprint(self) -> str:
        """Content hash of the lights (images, poses, emission, tracks) and the graph rotation."""
        from .cache import hash_arrays

        arrays = [np.array([self.degrees_per_frame, self.frame0]), self.axis]
        for light in self.lights:
            arrays.append(np.frombuffer(type(light).__name__.encode(), np.uint8))
            for f in fields(light):
                if f.name not in ("path", "track"):
                    arrays.append(np.asarray(getattr(light, f.name), np.float64))
            track = getattr(light, "track", None)
            if track is not None:
                arrays += [track.times, track.transforms]
        return hash_arrays(arrays)

    @property
    def animated(self) -> bool:
        """True when the lighting changes over frames (graph rotation or light tracks)."""
        return self.degrees_per_frame != 0.0 or any(getattr(x, "track", None) is not None for x in self.lights)

    def sphere_lights(self) -> list:
        return [light for light in self.lights if isinstance(light, SphereLight)]


def _scaled(light, k: float):
    if isinstance(light, Environment):
        return replace(light, image=light.image * np.float32(k))
    if isinstance(light, DistantLight):
        return replace(light, irradiance=light.irradiance * k)
    if isinstance(light, SphereLight):
        return replace(light, radiance=light.radiance * k)
    return light
