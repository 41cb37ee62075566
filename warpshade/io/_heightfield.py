"""Procedural animated height fields: a few attributes on a USD Mesh prim, expanded on load.

A 512 x 512 grid with 48 frames of animated points is over 100 MB as USD point samples; the
height field is instead described by a handful of numbers on a ``UsdGeom.Mesh`` prim and
expanded by the loader (:mod:`warpshade.io._usd_mesh` calls :func:`read_mesh` for every Mesh prim
that :func:`is_height_field`) into a regular grid mesh whose points are animated per time code
(``animation = "deforming"``).

Attributes (all in the ``warpshade:heightField:`` namespace, stage units, Z-up only):

============== =========== ===========================================================
name            type        meaning
============== =========== ===========================================================
resolution      int         vertices per side G (>= 2); the grid is G x G
size            double2     extent (sx, sy), centred on the prim's origin
planarWaves     double[]    6 numbers per travelling wave: amplitude, wavelength,
                            direction x, direction y, phase speed, phase (radians)
circularWaves   double[]    7 per circular ripple: amplitude, wavelength, centre x,
                            centre y, phase speed, phase, decay (1 / length)
terrain         double4     static seeded term: amplitude, wavelength, octaves, seed
base            double      constant height offset (default 0)
============== =========== ===========================================================

Heights at time ``t = time code / timeCodesPerSecond`` (seconds)::

    h(x, t) = base + terrain(x)
              + sum_planar a sin(2 pi (d . x - c t) / lambda + phi)              (|d| = 1)
              + sum_circ   a exp(-decay r) sin(2 pi (r - c t) / lambda + phi)     r = |x - centre|

``terrain`` sums ``octaves`` octaves of 6 sinusoids each (octave o: wavelength
``lambda / 2^o``, amplitude ``a / 2^o``, directions and phases drawn by
``numpy.random.default_rng(seed)``), so the same attributes give the same floats everywhere.

Grid layout (what :func:`warpshade.methods.heightfield.grid_layout` checks): vertex ``r * G + c`` (row r
along +y, column c along +x) at ``(-sx/2 + c sx/(G-1), -sy/2 + r sy/(G-1), h)``; two triangles
per cell, ``(v00, v10, v11)`` and ``(v00, v11, v01)`` (counter-clockwise seen from +z, so a flat
field's normals are +z). Points are computed in float64 and stored as float32 samples.

The prim may also carry ordinary (coarse) points and faces for other USD tools; the loader
ignores them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "ATTRIBUTE_PREFIX",
    "HeightFieldSpec",
    "MAX_SAMPLE_BYTES",
    "author",
    "grid_faces",
    "grid_xy",
    "heights",
    "is_height_field",
    "mesh_from_spec",
    "read_mesh",
    "read_spec",
]

ATTRIBUTE_PREFIX = "warpshade:heightField:"
#: Largest expansion (T frames x G^2 points x 12 bytes of float32 samples) the loader accepts.
MAX_SAMPLE_BYTES = 2 * 1024**3
#: Sinusoids per terrain octave.
TERRAIN_TERMS = 6


@dataclass
class HeightFieldSpec:
    """A procedural height field (see the module docstring).

    Attributes:
        resolution: vertices per side G.
        size: extent (sx, sy).
        planar: (P, 6) travelling waves.
        circular: (Q, 7) circular ripples.
        terrain: (amplitude, wavelength, octaves, seed).
        base: constant height.
    """

    resolution: int
    size: tuple = (8.0, 8.0)
    planar: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    circular: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))
    terrain: tuple = (0.0, 1.0, 0, 0)
    base: float = 0.0

    def __post_init__(self):
        self.resolution = int(self.resolution)
        self.size = tuple(float(s) for s in np.asarray(self.size, np.float64).reshape(-1))
        self.planar = np.asarray(self.planar, np.float64).reshape(-1, 6)
        self.circular = np.asarray(self.circular, np.float64).reshape(-1, 7)
        self.terrain = tuple(float(x) for x in np.asarray(self.terrain, np.float64).reshape(-1))
        self.base = float(self.base)

    def check(self, where: str = "height field") -> "HeightFieldSpec":
        """Raise ValueError (naming ``where``) for anything the expansion cannot use."""
        if self.resolution < 2:
            raise ValueError(f"{where}: resolution must be >= 2, got {self.resolution}")
        if len(self.size) != 2 or not all(np.isfinite(s) and s > 0 for s in self.size):
            raise ValueError(f"{where}: size must be two positive numbers, got {self.size}")
        for name, arr in (("planarWaves", self.planar), ("circularWaves", self.circular)):
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{where}: {name} has NaN or infinite values")
            if arr.size and np.any(arr[:, 1] <= 0):
                raise ValueError(f"{where}: {name} wavelengths must be > 0")
        if self.planar.size and np.any(np.hypot(self.planar[:, 2], self.planar[:, 3]) <= 0):
            raise ValueError(f"{where}: planarWaves directions must be non-zero")
        if len(self.terrain) != 4 or not all(np.isfinite(self.terrain)) or self.terrain[1] <= 0 or self.terrain[2] < 0:
            raise ValueError(f"{where}: terrain must be (amplitude, wavelength > 0, octaves >= 0, seed), got {self.terrain}")
        if not np.isfinite(self.base):
            raise ValueError(f"{where}: base must be finite")
        return self


def grid_xy(resolution: int, size) -> tuple[np.ndarray, np.ndarray]:
    """x and y of the grid vertices in row-major order, each (G*G,) float64."""
    g = int(resolution)
    sx, sy = (float(s) for s in size)
    xs = np.linspace(-sx / 2, sx / 2, g)
    ys = np.linspace(-sy / 2, sy / 2, g)
    y, x = np.meshgrid(ys, xs, indexing="ij")  # row r = y index, column c = x index
    return x.ravel(), y.ravel()


def grid_faces(resolution: int) -> np.ndarray:
    """Two counter-clockwise (seen from +z) triangles per cell, (2 (G-1)^2, 3) int32."""
    g = int(resolution)
    r, c = np.meshgrid(np.arange(g - 1), np.arange(g - 1), indexing="ij")
    v00 = (r * g + c).ravel()
    v10, v01 = v00 + 1, v00 + g
    v11 = v01 + 1
    tris = np.stack([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)], 1)
    return tris.reshape(-1, 3).astype(np.int32)


def _terrain(spec: HeightFieldSpec, x, y) -> np.ndarray:
    amp, wl, octaves, seed = spec.terrain
    out = np.zeros_like(x)
    if amp == 0.0 or int(octaves) == 0:
        return out
    rng = np.random.default_rng(int(seed))
    for o in range(int(octaves)):
        ang = rng.uniform(0.0, 2.0 * np.pi, TERRAIN_TERMS)
        phase = rng.uniform(0.0, 2.0 * np.pi, TERRAIN_TERMS)
        k = 2.0 * np.pi / (wl / 2.0**o)
        a = amp / 2.0**o / np.sqrt(TERRAIN_TERMS)
        for t in range(TERRAIN_TERMS):
            out += a * np.sin(k * (np.cos(ang[t]) * x + np.sin(ang[t]) * y) + phase[t])
    return out


def heights(spec: HeightFieldSpec, times) -> np.ndarray:
    """Heights at the grid vertices for each time (seconds), (T, G*G) float64.

    Every wave is ``A(x) sin(k s(x) - w t + phi) = A sin(k s + phi) cos(w t) - A cos(k s + phi) sin(w t)``:
    the spatial parts are computed once and each frame is one matrix product.
    """
    spec.check()
    x, y = grid_xy(spec.resolution, spec.size)
    t = np.asarray(times, np.float64).reshape(-1)
    static = spec.base + _terrain(spec, x, y)
    rows, cols = [], []
    for a, wl, dx, dy, c, phi in spec.planar:
        d = np.hypot(dx, dy)
        k = 2.0 * np.pi / wl
        arg = k * (dx * x + dy * y) / d + phi
        rows += [a * np.sin(arg), -a * np.cos(arg)]
        cols += [np.cos(k * c * t), np.sin(k * c * t)]
    for a, wl, cx, cy, c, phi, decay in spec.circular:
        r = np.hypot(x - cx, y - cy)
        k = 2.0 * np.pi / wl
        env = a * np.exp(-decay * r)
        arg = k * r + phi
        rows += [env * np.sin(arg), -env * np.cos(arg)]
        cols += [np.cos(k * c * t), np.sin(k * c * t)]
    out = np.broadcast_to(static, (t.size, static.size)).copy()
    if rows:
        out += np.stack(cols, 1) @ np.stack(rows, 0)
    return out


def mesh_from_spec(spec: HeightFieldSpec, times, path: str = "/HeightField", transforms=None, albedo=None):
    """The :class:`~warpshade.scene.Mesh` of a height field at ``times`` (seconds): static for
    one time, else ``"deforming"`` with float32 point samples (T, G*G, 3)."""
    from ..scene._scene import Mesh

    spec.check(f"mesh {path}")
    g = spec.resolution
    t = np.asarray(times, np.float64).reshape(-1)
    nbytes = t.size * g * g * 12
    if nbytes > MAX_SAMPLE_BYTES:
        raise ValueError(f"mesh {path}: the height field ({g} x {g}, {t.size} frames) expands to {nbytes / 2**20:,.0f} MB "
                         f"of point samples, over the loader's {MAX_SAMPLE_BYTES / 2**20:,.0f} MB "
                         "(warpshade.io._heightfield.MAX_SAMPLE_BYTES); lower its resolution or the frame count")
    x, y = grid_xy(g, spec.size)
    h = heights(spec, t)
    rest = np.stack([x, y, h[0]], 1)
    kwargs = {}
    if transforms is not None:
        kwargs["transforms"] = transforms
    if albedo is not None:
        kwargs["albedo"] = albedo
    if t.size > 1:
        samples = np.empty((t.size, g * g, 3), np.float32)
        samples[:, :, 0] = x.astype(np.float32)
        samples[:, :, 1] = y.astype(np.float32)
        samples[:, :, 2] = h.astype(np.float32)
        return Mesh(path=path, points=rest, faces=grid_faces(g), animation="deforming", point_samples=samples, **kwargs)
    animation = "rigid" if transforms is not None and np.asarray(transforms).reshape(-1, 4, 4).shape[0] > 1 else "static"
    return Mesh(path=path, points=rest, faces=grid_faces(g), animation=animation, **kwargs)


# ---- USD ---------------------------------------------------------------------------------------
def is_height_field(prim) -> bool:
    """Whether a prim carries ``warpshade:heightField:resolution``."""
    return prim.HasAttribute(ATTRIBUTE_PREFIX + "resolution")


def _get(prim, name, default=None):
    attr = prim.GetAttribute(ATTRIBUTE_PREFIX + name)
    if not attr or not attr.HasAuthoredValue():
        return default
    return attr.Get()


def read_spec(prim, where: str | None = None) -> HeightFieldSpec:
    """The :class:`HeightFieldSpec` authored on a prim (ValueError naming it when malformed)."""
    where = where or f"mesh {prim.GetPath()}"
    res = _get(prim, "resolution")
    if res is None or isinstance(res, bool) or not float(res).is_integer():
        raise ValueError(f"{where}: {ATTRIBUTE_PREFIX}resolution must be an int, got {res!r}")
    size = _get(prim, "size", (8.0, 8.0))
    planar = np.asarray(_get(prim, "planarWaves", []) or [], np.float64)
    circular = np.asarray(_get(prim, "circularWaves", []) or [], np.float64)
    for name, arr, n in (("planarWaves", planar, 6), ("circularWaves", circular, 7)):
        if arr.size % n:
            raise ValueError(f"{where}: {ATTRIBUTE_PREFIX}{name} needs {n} numbers per wave, got {arr.size}")
    terrain = _get(prim, "terrain", (0.0, 1.0, 0.0, 0.0))
    base = _get(prim, "base", 0.0)
    return HeightFieldSpec(int(res), tuple(size), planar, circular, tuple(terrain), float(base)).check(where)


def author(mesh, spec: HeightFieldSpec, preview: int = 9) -> None:
    """Write ``spec`` onto a ``UsdGeom.Mesh`` (with a coarse static preview grid of ``preview``
    vertices per side for other USD tools)."""
    from pxr import Gf, Sdf, Vt

    spec.check(f"mesh {mesh.GetPath()}")
    prim = mesh.GetPrim()
    prim.CreateAttribute(ATTRIBUTE_PREFIX + "resolution", Sdf.ValueTypeNames.Int, custom=True).Set(int(spec.resolution))
    prim.CreateAttribute(ATTRIBUTE_PREFIX + "size", Sdf.ValueTypeNames.Double2, custom=True).Set(Gf.Vec2d(*spec.size))
    prim.CreateAttribute(ATTRIBUTE_PREFIX + "planarWaves", Sdf.ValueTypeNames.DoubleArray, custom=True).Set(
        Vt.DoubleArray([float(v) for v in spec.planar.ravel()]))
    prim.CreateAttribute(ATTRIBUTE_PREFIX + "circularWaves", Sdf.ValueTypeNames.DoubleArray, custom=True).Set(
        Vt.DoubleArray([float(v) for v in spec.circular.ravel()]))
    prim.CreateAttribute(ATTRIBUTE_PREFIX + "terrain", Sdf.ValueTypeNames.Double4, custom=True).Set(Gf.Vec4d(*spec.terrain))
    prim.CreateAttribute(ATTRIBUTE_PREFIX + "base", Sdf.ValueTypeNames.Double, custom=True).Set(float(spec.base))
    coarse = HeightFieldSpec(preview, spec.size, spec.planar, spec.circular, spec.terrain, spec.base)
    x, y = grid_xy(preview, spec.size)
    h = heights(coarse, [0.0])[0]
    pts = np.round(np.stack([x, y, h], 1), 4).astype(np.float32)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    faces = grid_faces(preview)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(faces)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for i in faces.ravel()]))
    half = np.array(spec.size) / 2
    amp = float(np.abs(spec.planar[:, 0]).sum() + np.abs(spec.circular[:, 0]).sum() + 2 * abs(spec.terrain[0]))
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(-half[0], -half[1], spec.base - amp),
                                         Gf.Vec3f(half[0], half[1], spec.base + amp)]))


def read_mesh(reader, prim, path: str):
    """The loader's hook (:class:`warpshade.io._usd._StageReader`): the expanded grid mesh of a
    height-field prim, points at every time code of the stage, its world transform and constant
    ``displayColor`` (else the loader's default albedo)."""
    from pxr import UsdGeom

    where = f"mesh {path} in {reader.path}"
    if reader.up_axis != "Z":
        raise ValueError(f"{where}: height fields are read in Z-up stages only (this stage is {reader.up_axis}-up)")
    spec = read_spec(prim, where)
    fps = float(reader.stage.GetTimeCodesPerSecond()) or 24.0
    times = np.asarray(reader.frames, np.float64) / fps
    albedo = None
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
    if pv and pv.HasAuthoredValue():
        vals = np.asarray(pv.Get(), np.float64).reshape(-1, 3)
        if vals.shape[0] == 1 and np.all(np.isfinite(vals)):
            albedo = vals[0].astype(np.float32)
    return mesh_from_spec(spec, times, path=path, transforms=reader._world_transforms(prim), albedo=albedo)
