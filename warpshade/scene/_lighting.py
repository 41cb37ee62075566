"""Lights: environment maps (lat-long), distant lights and sphere lights, and their SH projection.

Conventions:

* Radiance is linear RGB.
* An :class:`Environment` stores a lat-long image in its own *map frame*, z-up, with the
  layout of :func:`warpshade.basis.quadrature.latlong_directions` (row 0 = +z pole, azimuth
  from +x towards +y). ``to_world`` is the rotation that takes map-frame directions to world
  directions (``d_world = to_world @ d_map``); rotating an environment over time changes only
  ``to_world``.
* SH lighting coefficients have shape (3, n*n): one row per RGB channel, in the world frame.
* A light may carry a :class:`LightTrack` (its time-sampled world transform, e.g. animated USD
  xformOps). The light's own fields describe it at the track's first time code; ``light.at(t)``
  returns the light posed at time ``t`` (environments and distant lights rotate with the track,
  sphere lights move with it) without a track.

USD dome lights (UsdLux.DomeLight / DomeLight_1) use the OpenEXR lat-long convention in the
dome's local frame: +Y is the top pole (image row 0), latitude 0 / longitude 0 is +Z,
longitude +pi/2 is +X, and longitude runs from +pi at the left image edge to -pi at the right
edge. Seen from inside, that layout is the mirror image of the map frame above, so
:meth:`Environment.from_usd_dome` flips the texture's columns and sets
``to_world = dome_to_world @ USD_DOME_FROM_MAP`` (a proper rotation); see
:func:`usd_dome_texel_directions` for the file layout written out explicitly.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..basis import quadrature, sh

__all__ = [
    "scaled_light",
]

#: Rotation taking map-frame directions of a column-flipped USD dome texture to the dome's local
#: frame: map +x -> dome -Z, map +y -> dome -X, map +z (pole) -> dome +Y. With the columns
#: flipped, map azimuth ``phi`` equals USD longitude ``+ pi``.
USD_DOME_FROM_MAP = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])


def usd_dome_texel_directions(height: int, width: int) -> np.ndarray:
    """Dome-local directions of the pixel centres of a USD lat-long texture, shape (H, W, 3).

    Straight from the OpenEXR convention UsdLux documents: pixel (0, 0) has latitude +pi/2 and
    longitude +pi, the last pixel latitude -pi/2 and longitude -pi; a direction at
    (lat, lon) is ``(cos(lat) sin(lon), sin(lat), cos(lat) cos(lon))`` (+Y up, lon 0 = +Z,
    lon pi/2 = +X). Used to write dome textures and as an independent check of
    :meth:`Environment.from_usd_dome`.
    """
    lat = np.pi / 2.0 - (np.arange(height) + 0.5) * (np.pi / height)
    lon = np.pi - (np.arange(width) + 0.5) * (2.0 * np.pi / width)
    cl = np.cos(lat)[:, None]
    return np.stack(
        [
            cl * np.sin(lon)[None, :],
            np.broadcast_to(np.sin(lat)[:, None], (height, width)),
            cl * np.cos(lon)[None, :],
        ],
        axis=-1,
    )


def sky_radiance(
    directions,
    sun_direction=(0.4, 0.3, 0.866),
    sun_radiance=(40.0, 36.0, 30.0),
    sun_angle_deg: float = 12.0,
    zenith=(0.35, 0.55, 1.0),
    horizon=(1.0, 0.95, 0.85),
    ground=(0.25, 0.22, 0.2),
    up=(0.0, 0.0, 1.0),
) -> np.ndarray:
    """Radiance of a smooth procedural sky with a soft sun disc, shape (..., 3), float64.

    The sky blends from ``horizon`` to ``zenith`` with the square root of the elevation sine,
    is ``ground`` below the horizon, and adds a sun disc of half-angle ``sun_angle_deg`` whose
    radiance falls off smoothly to its edge. Directions and ``up`` share one frame.
    """
    d = np.asarray(directions, np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    u = np.asarray(up, np.float64)
    z = (d @ (u / np.linalg.norm(u)))[..., None]
    t = np.clip(z, 0.0, 1.0) ** 0.5
    img = np.where(z >= 0.0, (1 - t) * np.asarray(horizon) + t * np.asarray(zenith), np.asarray(ground))
    s = np.asarray(sun_direction, np.float64)
    s = s / np.linalg.norm(s)
    cosang = d @ s
    edge = np.cos(np.radians(sun_angle_deg))
    w = np.clip((cosang - edge) / (1.0 - edge), 0.0, 1.0) ** 0.5
    return img + w[..., None] * np.asarray(sun_radiance)


def _check_size(height, width, caller: str) -> None:
    """A lat-long map size: integers >= 1 each, within the texel limit of environment maps."""
    from .._limits import MAX_IMAGE_PIXELS

    for name, value in (("height", height), ("width", width)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ValueError(f"{caller}: {name} must be an integer >= 1, got {value!r}")
    if int(height) * int(width) > MAX_IMAGE_PIXELS:
        raise ValueError(f"{caller}: {height} x {width} texels exceed the {MAX_IMAGE_PIXELS} an environment map "
                         "may have")


def up_rotation(up_axis: str) -> np.ndarray:
    """Rotation taking the z-up map frame to a world whose up axis is ``up_axis`` ("Y" or "Z").

    For "Y" this maps map +z to world +y and map +x to world +x (right-handed).
    """
    if up_axis.upper() == "Z":
        return np.eye(3)
    if up_axis.upper() == "Y":
        # columns are the world images of map x, y, z: x -> x, y -> -z, z -> y
        return np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    raise ValueError(f"up_rotation: up axis must be 'Y' or 'Z', got {up_axis!r}")


@dataclass
class LightTrack:
    """Time-sampled world transform of a light.

    Attributes:
        times: increasing time codes, shape (T,), T >= 2.
        transforms: local-to-world matrices per time code, (T, 4, 4), row-vector convention (as
            USD: translation in the last row). Scale is ignored for directions.

    Between samples rotations are interpolated by slerp and positions linearly; outside the
    sampled range the nearest sample holds.
    """

    times: np.ndarray
    transforms: np.ndarray

    def __post_init__(self):
        from scipy.spatial.transform import Rotation, Slerp

        t = np.asarray(self.times, np.float64).reshape(-1)
        m = np.asarray(self.transforms, np.float64)
        if m.shape != (t.size, 4, 4) or t.size < 2:
            raise ValueError(f"light track: need (T, 4, 4) transforms for T >= 2 times, got {m.shape} for {t.size}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(m))):
            raise ValueError("light track: times and transforms must be finite")
        if np.any(np.diff(t) <= 0):
            raise ValueError("light track: times must increase")
        self.times, self.transforms = t, m
        # column-convention rotations with scale and shear removed (polar decomposition)
        u, _, vt = np.linalg.svd(np.swapaxes(m[:, :3, :3], 1, 2))
        rot = u @ vt
        if np.any(np.linalg.det(rot) < 0):
            raise ValueError("light track: mirrored (negative-determinant) transforms are not supported")
        self._slerp = Slerp(t, Rotation.from_matrix(rot))
        self._r0 = rot[0]

    def rotation(self, time: float) -> np.ndarray:
        """Rotation (3, 3) taking world directions at the first time code to those at ``time``."""
        tc = float(np.clip(time, self.times[0], self.times[-1]))
        return self._slerp([tc]).as_matrix()[0] @ self._r0.T

    def position(self, time: float) -> np.ndarray:
        """World position of the light's origin at ``time``, (3,)."""
        return np.array([np.interp(float(time), self.times, self.transforms[:, 3, k]) for k in range(3)])


@dataclass
class Environment:
    """A distant environment given as a lat-long radiance image.

    Attributes:
        image: radiance, shape (H, W, 3), float32, linear RGB, lat-long in the map frame.
        to_world: rotation (3, 3) taking map-frame directions to world directions.
        path: file the image came from (None for procedural environments).
        track: time-sampled transform (the fields above are the pose at its first time code).
    """

    image: np.ndarray
    to_world: np.ndarray = field(default_factory=lambda: np.eye(3))
    path: str | None = None
    track: LightTrack | None = None

    def __post_init__(self):
        img = np.asarray(self.image, dtype=np.float32)
        if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 1 or img.shape[1] < 1:
            raise ValueError(f"environment {self.path or '<array>'}: image must be (H, W, 3), got {img.shape}")
        if not np.all(np.isfinite(img)):
            raise ValueError(f"environment {self.path or '<array>'}: image has NaN or infinite texels")
        if np.any(img < 0.0):
            bad = img < 0.0
            first = tuple(int(i) for i in np.unravel_index(int(np.argmax(bad)), img.shape))
            raise ValueError(f"environment {self.path or '<array>'}: image has {int(bad.sum())} negative values (radiance "
                             f"is >= 0), the first at (row, column, channel) = {first}")
        self.image = img
        self.to_world = np.asarray(self.to_world, dtype=np.float64).reshape(3, 3)

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def constant(cls, rgb=(1.0, 1.0, 1.0), height: int = 8, width: int = 16) -> "Environment":
        """A uniform environment of radiance ``rgb``."""
        _check_size(height, width, "Environment.constant")
        img = np.broadcast_to(np.asarray(rgb, np.float32).reshape(1, 1, 3), (height, width, 3)).copy()
        return cls(img)

    @classmethod
    def sky(
        cls,
        height: int = 64,
        width: int = 128,
        sun_direction=(0.4, 0.3, 0.866),
        sun_radiance=(40.0, 36.0, 30.0),
        sun_angle_deg: float = 12.0,
        zenith=(0.35, 0.55, 1.0),
        horizon=(1.0, 0.95, 0.85),
        ground=(0.25, 0.22, 0.2),
        to_world=None,
    ) -> "Environment":
        """A smooth procedural sky with a soft sun disc (map frame z-up), for demos and tests.

        See :func:`sky_radiance`; ``sun_direction`` is given in the map frame.
        """
        _check_size(height, width, "Environment.sky")
        img = sky_radiance(
            quadrature.latlong_directions(height, width),
            sun_direction=sun_direction,
            sun_radiance=sun_radiance,
            sun_angle_deg=sun_angle_deg,
            zenith=zenith,
            horizon=horizon,
            ground=ground,
        )
        return cls(img.astype(np.float32), np.eye(3) if to_world is None else to_world)

    @classmethod
    def from_usd_dome(cls, texture, dome_to_world=None, path: str | None = None) -> "Environment":
        """An environment from a UsdLux dome texture in its file layout (OpenEXR lat-long).

        Args:
            texture: radiance as stored in the file, shape (H, W, 3), row 0 = dome +Y pole,
                left column = longitude +pi (see :func:`usd_dome_texel_directions`).
            dome_to_world: rotation (3, 3) taking dome-local directions to world directions
                (column-vector convention: ``d_world = dome_to_world @ d_dome``); identity when
                None. For a USD prim this is the transpose of the rotation part of its
                row-vector local-to-world matrix, with any DomeLight_1 pole-axis offset.
            path: the texture file, for messages.
        """
        img = np.asarray(texture, np.float32)[:, ::-1]
        rot = np.eye(3) if dome_to_world is None else np.asarray(dome_to_world, np.float64)
        return cls(np.ascontiguousarray(img), rot @ USD_DOME_FROM_MAP, path)

    def rotated(self, rotation) -> "Environment":
        """The same environment rotated in world space by ``rotation`` (3, 3)."""
        return replace(self, to_world=np.asarray(rotation, np.float64) @ self.to_world)

    def at(self, time: float) -> "Environment":
        """The environment posed at ``time`` by its track (itself when it has none)."""
        if self.track is None:
            return self
        return replace(self, to_world=self.track.rotation(time) @ self.to_world, track=None)

    # ---- queries (float64 mirror) -----------------------------------------------
    @property
    def height(self) -> int:
        return int(self.image.shape[0])

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    def radiance(self, directions) -> np.ndarray:
        """Bilinearly filtered radiance in world directions, shape (..., 3), float64.

        Interpolation wraps in azimuth and clamps at the poles (texel centres).
        """
        d = np.asarray(directions, np.float64)
        batch = d.shape[:-1]
        local = d.reshape(-1, 3) @ self.to_world  # = (to_world.T @ d.T).T
        local /= np.maximum(np.linalg.norm(local, axis=1, keepdims=True), 1e-300)
        theta = np.arccos(np.clip(local[:, 2], -1.0, 1.0))
        phi = np.mod(np.arctan2(local[:, 1], local[:, 0]), 2.0 * np.pi)
        h, w = self.height, self.width
        v = theta / np.pi * h - 0.5
        u = phi / (2.0 * np.pi) * w - 0.5
        v0 = np.floor(v)
        u0 = np.floor(u)
        fv = (v - v0)[:, None]
        fu = (u - u0)[:, None]
        r0 = np.clip(v0, 0, h - 1).astype(np.int64)
        r1 = np.clip(v0 + 1, 0, h - 1).astype(np.int64)
        c0 = np.mod(u0, w).astype(np.int64)
        c1 = np.mod(u0 + 1, w).astype(np.int64)
        img = self.image.astype(np.float64)
        out = (
            (1 - fv) * ((1 - fu) * img[r0, c0] + fu * img[r0, c1])
            + fv * ((1 - fu) * img[r1, c0] + fu * img[r1, c1])
        )
        return out.reshape(*batch, 3)

    def to_sh(self, order: int, window: str | None = None, **window_args) -> np.ndarray:
        """Project the environment onto SH in the world frame, shape (3, order**2), float64.

        Each texel is weighted by its exact solid angle (:func:`quadrature.latlong`); the
        texel-centre value is used (the piecewise-constant image), so the DC term of a constant
        map is exact and smooth maps converge quadratically in the texel size. ``window`` optionally applies :func:`warpshade.basis.sh.window` (e.g. to
        reduce ringing of a sharp sun).
        """
        q = quadrature.latlong(self.height, self.width)
        dirs_world = q.directions @ self.to_world.T
        y = sh.basis(dirs_world, order)
        coeffs = (self.image.reshape(-1, 3).astype(np.float64) * q.weights[:, None]).T @ y
        if window is not None:
            coeffs = sh.window(coeffs, window, **window_args)
        return coeffs


@dataclass
class DistantLight:
    """A distant (directional) light.

    Attributes:
        direction: unit vector from the scene *towards* the light, world space (3,).
        irradiance: RGB irradiance on a surface facing the light (radiance times solid angle).
        angle_deg: angular diameter in degrees (0 = a delta light).
        path: USD prim path or None.
        track: time-sampled transform (the fields above are the pose at its first time code).
    """

    direction: np.ndarray
    irradiance: np.ndarray
    angle_deg: float = 0.53
    path: str | None = None
    track: LightTrack | None = None

    def __post_init__(self):
        d = np.asarray(self.direction, np.float64).reshape(3)
        self.direction = d / np.linalg.norm(d)
        self.irradiance = np.asarray(self.irradiance, np.float64).reshape(3)

    def at(self, time: float) -> "DistantLight":
        """The light posed at ``time`` by its track (itself when it has none)."""
        if self.track is None:
            return self
        return replace(self, direction=self.track.rotation(time) @ self.direction, track=None)

    def to_sh(self, order: int) -> np.ndarray:
        """SH of the light's radiance (a delta, or a uniform disc when ``angle_deg`` > 0), (3, n*n)."""
        half = np.radians(self.angle_deg) / 2.0
        if half <= 0.0:
            zh = np.array([np.sqrt((2 * l + 1) / (4 * np.pi)) for l in range(order)])
        else:
            solid = 2.0 * np.pi * (1.0 - np.cos(half))
            zh = sh.cap_zh(half, order) / solid
        coeffs = sh.zh_to_sh(self.direction, zh)
        return self.irradiance[:, None] * coeffs[None, :]


@dataclass
class SphereLight:
    """A spherical area light of uniform radiance.

    Attributes:
        position: centre, world space (3,).
        radius: radius in scene units.
        radiance: RGB radiance emitted from its surface.
        path: USD prim path or None.
        track: time-sampled transform; the centre follows its origin (radius fixed).
    """

    position: np.ndarray
    radius: float
    radiance: np.ndarray
    path: str | None = None
    track: LightTrack | None = None

    def __post_init__(self):
        self.position = np.asarray(self.position, np.float64).reshape(3)
        self.radiance = np.asarray(self.radiance, np.float64).reshape(3)
        if not self.radius > 0.0:
            raise ValueError(f"sphere light {self.path or '<array>'}: radius must be > 0, got {self.radius}")

    def at(self, time: float) -> "SphereLight":
        """The light posed at ``time`` by its track (itself when it has none)."""
        if self.track is None:
            return self
        return replace(self, position=self.track.position(time), track=None)

    def to_sh_at(self, point, order: int) -> np.ndarray:
        """SH of the light's radiance as seen from ``point`` (a cap), shape (3, n*n)."""
        offset = self.position - np.asarray(point, np.float64)
        dist = np.linalg.norm(offset)
        half = np.pi if dist <= self.radius else np.arcsin(self.radius / dist)
        coeffs = sh.zh_to_sh(offset / max(dist, 1e-300), sh.cap_zh(half, order))
        return self.radiance[:, None] * coeffs[None, :]


def lights_to_sh(lights, order: int) -> np.ndarray:
    """Sum the SH of all distant lights (environments and distant lights), shape (3, n*n).

    Sphere lights are local (their SH depends on the receiver) and are skipped here.
    """
    total = np.zeros((3, order * order))
    for light in lights:
        if isinstance(light, Environment):
            total += light.to_sh(order)
        elif isinstance(light, DistantLight):
            total += light.to_sh(order)
    return total


def _axis_rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()


class LightingSource:
    """The lights of every frame: a set of lights, optionally turning about the up axis.

    The papers' demos rotate a fixed environment; so can this: distant lights (environments
    and distant lights) are rotated about the scene's up axis by ``degrees_per_frame`` times
    the frame offset from ``frame0``. Lights with a :class:`LightTrack` (animated USD
    transforms) are posed at each frame first (``light.at(frame)``), then rotated. This is the
    float64 host description; :class:`warpshade.scene._lighting_warp.FrameLighting` evaluates it
    per frame on the device from the tables of :meth:`rotation_table` and
    :meth:`sphere_position_table`.

    Args:
        lights: list of light objects (Environment, DistantLight, SphereLight).
        up_axis: the scene's up axis ("Y" or "Z"), the rotation axis.
        degrees_per_frame: rotation speed of the distant lights about the up axis.
        frame0: the time code at which the rotation is zero.
    """

    def __init__(self, lights, up_axis: str = "Z", degrees_per_frame: float = 0.0, frame0: float = 0.0):
        if not lights:
            raise ValueError("lighting: no lights (the scene has none and none were given)")
        for light in lights:
            if not isinstance(light, (Environment, DistantLight, SphereLight)):
                raise ValueError(f"lighting: unsupported light of type {type(light).__name__}")
        if not np.isfinite(degrees_per_frame) or not np.isfinite(frame0):
            raise ValueError(f"lighting: rotation speed and start must be finite, got {degrees_per_frame!r}, {frame0!r}")
        self.lights = list(lights)
        self.up_axis = up_axis
        self.axis = up_rotation(up_axis)[:, 2]
        self.degrees_per_frame = float(degrees_per_frame)
        self.frame0 = float(frame0)
        self._sh_cache: dict = {}

    @classmethod
    def fixed(cls, lights, up_axis: str = "Z") -> "LightingSource":
        """Lights that do not turn (their own tracks still animate them)."""
        return cls(lights, up_axis, 0.0, 0.0)

    # ---- the lights by kind -------------------------------------------------------------
    @property
    def distant_lights(self) -> list:
        """Environments and distant lights, in order (the ones the SH lighting sums)."""
        return [light for light in self.lights if isinstance(light, (Environment, DistantLight))]

    @property
    def environments(self) -> list:
        return [light for light in self.lights if isinstance(light, Environment)]

    def sphere_lights(self) -> list:
        return [light for light in self.lights if isinstance(light, SphereLight)]

    @property
    def animated(self) -> bool:
        """True when the lighting changes over frames (graph rotation or light tracks)."""
        return self.degrees_per_frame != 0.0 or any(getattr(x, "track", None) is not None for x in self.lights)

    # ---- per frame (float64) ------------------------------------------------------------
    def rotation(self, frame: float) -> np.ndarray:
        """World rotation applied to the distant lights at ``frame``, (3, 3)."""
        return _axis_rotation(self.axis, self.degrees_per_frame * (float(frame) - self.frame0))

    def light_rotation(self, light, frame: float) -> np.ndarray:
        """Total world rotation of one distant light at ``frame`` (its track, then the turn)."""
        r = self.rotation(frame)
        track = getattr(light, "track", None)
        return r if track is None else r @ track.rotation(frame)

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

    def base_sh(self, order: int) -> np.ndarray:
        """SH of each distant light at its first pose, world frame, (K, 3, order**2), float64."""
        if order not in self._sh_cache:
            coeffs = [light.to_sh(order) for light in self.distant_lights]
            self._sh_cache[order] = np.stack(coeffs) if coeffs else np.zeros((0, 3, order * order))
        return self._sh_cache[order]

    def sh(self, order: int, frame: float, window: str | None = None, **window_args) -> np.ndarray:
        """SH of all distant lights at ``frame``, world frame, shape (3, order**2), float64.

        Each light's projection at its first pose is rotated exactly (Ivanic-Ruedenberg, the
        float64 oracle of the device evaluation) by :meth:`light_rotation`.
        """
        total = np.zeros((3, order * order))
        for light, coeffs in zip(self.distant_lights, self.base_sh(order)):
            total += sh.rotate(coeffs, self.light_rotation(light, frame))
        if window is not None:
            total = sh.window(total, window, **window_args)
        return total

    # ---- tables for the device ----------------------------------------------------------
    def rotation_table(self, frames) -> np.ndarray:
        """:meth:`light_rotation` of every distant light at every frame, (T', K, 3, 3) float64;
        T' = 1 when the lighting does not change over frames, else ``len(frames)``."""
        frames = np.asarray(frames, np.float64).reshape(-1)
        lights = self.distant_lights
        if not self.animated:
            frames = frames[:1]
        table = np.zeros((frames.shape[0], len(lights), 3, 3))
        for t, f in enumerate(frames):
            for k, light in enumerate(lights):
                table[t, k] = self.light_rotation(light, f)
        return table

    def sphere_position_table(self, frames) -> np.ndarray:
        """Sphere-light centres at every frame, (T', S, 3) float64 (T' = 1 without tracks)."""
        frames = np.asarray(frames, np.float64).reshape(-1)
        spheres = self.sphere_lights()
        if not any(s.track is not None for s in spheres):
            frames = frames[:1]
        return np.array([[s.at(f).position for s in spheres] for f in frames], np.float64).reshape(frames.shape[0], -1, 3)

    def fingerprint(self) -> str:
        """Content hash of the lights (images, poses, emission, tracks) and the rotation."""
        from dataclasses import fields

        from .._hashing import hash_arrays

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

    def scaled(self, factor: float) -> "LightingSource":
        """The same lighting with every light's emission times ``factor``."""
        return LightingSource([scaled_light(light, factor) for light in self.lights], self.up_axis,
                              self.degrees_per_frame, self.frame0)


def scaled_light(light, k: float):
    """A copy of ``light`` with its emission (image, irradiance or radiance) times ``k``."""
    if isinstance(light, Environment):
        return replace(light, image=light.image * np.float32(k))
    if isinstance(light, DistantLight):
        return replace(light, irradiance=light.irradiance * k)
    if isinstance(light, SphereLight):
        return replace(light, radiance=light.radiance * k)
    raise ValueError(f"lighting: unsupported light of type {type(light).__name__}")
