"""Spatially varying surface parameters: image textures and the per-mesh :class:`SurfaceMaps`.

Texture coordinates follow ``UsdUVTexture``: ``st = (u, v)`` with ``(0, 0)`` at the
*bottom-left* corner of the image and ``v`` pointing up, while image arrays are stored with row 0
at the *top* (as image files are read). Texel ``(row r, column c)`` of an ``H x W`` image has its
centre at ``u = (c + 0.5) / W``, ``v = 1 - (r + 0.5) / H``. Sampling is bilinear between the four
nearest texel centres: with ``x = u W - 0.5`` and ``y = (1 - v) H - 0.5`` (continuous column and
row), the value is ``sum (1 - |x - c|)(1 - |y - r|) T[r, c]`` over the texels with
``|x - c| < 1, |y - r| < 1``, the texel indices passed through the wrap mode first.

Wrap modes (per axis, ``wrapS`` for u/columns, ``wrapT`` for v/rows), as ``UsdUVTexture``:

* ``"repeat"`` -- the image tiles the plane (index ``i mod W``);
* ``"clamp"`` -- indices outside the image take the edge texel;
* ``"mirror"`` -- the image is reflected at every edge (period ``2 W``);
* ``"black"`` -- texels outside the image are 0.

Before indexing, ``u`` and ``v`` are reduced to one period (repeat: ``[0, 1)``, mirror:
``[0, 2)``) or clipped to ``[-1, 2]`` (clamp, black: nothing changes beyond one image width), so
very large coordinates never overflow integer texel indices.

Values are linear: colour textures are sRGB-decoded (:func:`srgb_to_linear`) when they are read,
before filtering, as GPUs do. A :class:`Texture` holds 1 to 4 channels; the Warp sampler
:func:`texture_sample` returns RGB by the ``UsdUVTexture`` channel rules (one or two channels:
the first channel repeated; three or more: the first three).

:class:`SurfaceMaps` gathers what a ``UsdPreviewSurface`` says about one mesh -- diffuse colour,
roughness, and either a specular colour (specular workflow) or a metallic factor (metallic
workflow) -- each a :class:`Texture` or a constant, and evaluates the shading parameters the
BRDFs of :mod:`warpshade.scene._materials` take at texture coordinates (see
:meth:`SurfaceMaps.sample`). Roughness is the number :class:`~warpshade.scene._materials.Microfacet`
takes as ``roughness`` (the distribution's alpha, not squared again).

Kernels for tests and batch use: :data:`sample_kernel` (one texture at N coordinates) and
:data:`surface_kernel` (all maps of a :class:`SurfaceMaps` at N coordinates, through
:meth:`SurfaceMaps.to_warp`). The float64 NumPy paths (:meth:`Texture.sample`,
:meth:`SurfaceMaps.sample`) are their oracles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._wp import wp

wp.set_module_options({"enable_backward": False})

__all__ = [
    "WRAP_MODES",
    "DIELECTRIC_IOR",
    "SurfaceMapsArrays",
    "SurfaceSample",
    "srgb_to_linear",
    "linear_to_srgb",
    "dielectric_f0",
    "texture_sample",
    "texture_sample_st",
    "surface_sample",
    "sample_kernel",
    "surface_kernel",
    "sample_texture_warp",
    "sample_surface_warp",
]

#: Wrap modes and their integer codes (the index is the code the Warp functions take).
WRAP_MODES = ("black", "clamp", "repeat", "mirror")
#: UsdPreviewSurface's default index of refraction; its normal-incidence reflectance is 0.04.
DIELECTRIC_IOR = 1.5


def srgb_to_linear(values) -> np.ndarray:
    """The sRGB transfer function inverted (IEC 61966-2-1), float64, same shape as ``values``.

    ``x / 12.92`` for ``x <= 0.04045``, else ``((x + 0.055) / 1.055) ** 2.4``; inputs in [0, 1].
    """
    x = np.asarray(values, np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((np.maximum(x, 0.04045) + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(values) -> np.ndarray:
    """The sRGB encoding, the inverse of :func:`srgb_to_linear`, float64."""
    x = np.asarray(values, np.float64)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.maximum(x, 0.0031308) ** (1.0 / 2.4) - 0.055)


def dielectric_f0(ior: float) -> float:
    """Normal-incidence Fresnel reflectance ``((1 - ior) / (1 + ior))**2`` of a dielectric."""
    if not (math.isfinite(ior) and ior > 0.0):
        raise ValueError(f"ior must be finite and > 0, got {ior!r}")
    return ((1.0 - ior) / (1.0 + ior)) ** 2


def _wrap_code(mode, what: str) -> int:
    if isinstance(mode, (int, np.integer)) and 0 <= int(mode) < len(WRAP_MODES):
        return int(mode)
    if mode not in WRAP_MODES:
        raise ValueError(f"{what}: wrap mode must be one of {', '.join(WRAP_MODES)}, got {mode!r}")
    return WRAP_MODES.index(mode)


def _reduce(coord: np.ndarray, mode: int) -> np.ndarray:
    """A texture coordinate reduced to one period / clipped range (see the module docstring)."""
    if mode == 2:  # repeat
        return coord - np.floor(coord)
    if mode == 3:  # mirror
        return coord - 2.0 * np.floor(0.5 * coord)
    return np.clip(coord, -1.0, 2.0)


def _wrap_index(index: np.ndarray, size: int, mode: int) -> np.ndarray:
    """Texel indices through a wrap mode; -1 marks a black (outside) texel."""
    if mode == 2:
        return np.mod(index, size)
    if mode == 3:
        m = np.mod(index, 2 * size)
        return np.where(m >= size, 2 * size - 1 - m, m)
    if mode == 1:
        return np.clip(index, 0, size - 1)
    return np.where((index >= 0) & (index < size), index, -1)


@dataclass
class Texture:
    """A 2D image texture with bilinear filtering (conventions: module docstring).

    Attributes:
        image: texel values, shape (H, W, C), float32, linear (already decoded from sRGB and
            scaled/biased where the source asked for it), row 0 = top of the image; C in 1..4.
            A (H, W) array is taken as one channel.
        path: the image file it came from (for messages), or None.
        wrap: one wrap mode for both axes, or ``(wrap_s, wrap_t)``; names from :data:`WRAP_MODES`.
    """

    image: np.ndarray
    path: str | None = None
    wrap: str | tuple = "repeat"
    _device_arrays: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self):
        name = f"texture {self.path or '<array>'}"
        img = np.asarray(self.image, dtype=np.float32)
        if img.ndim == 2:
            img = img[..., None]
        if img.ndim != 3 or img.shape[0] < 1 or img.shape[1] < 1:
            raise ValueError(f"{name}: image must be (H, W, C) with H, W >= 1, got shape {img.shape}")
        if not 1 <= img.shape[2] <= 4:
            raise ValueError(f"{name}: image must have 1 to 4 channels, got {img.shape[2]}")
        if not np.all(np.isfinite(img)):
            raise ValueError(f"{name}: image has NaN or infinite texels")
        self.image = np.ascontiguousarray(img)
        modes = (self.wrap, self.wrap) if isinstance(self.wrap, (str, int, np.integer)) else tuple(self.wrap)
        if len(modes) != 2:
            raise ValueError(f"{name}: wrap must be a mode or a (wrap_s, wrap_t) pair, got {self.wrap!r}")
        self._wrap_codes = (_wrap_code(modes[0], f"{name} wrap_s"), _wrap_code(modes[1], f"{name} wrap_t"))

    # ---- properties ---------------------------------------------------------------------
    @property
    def height(self) -> int:
        return int(self.image.shape[0])

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def channels(self) -> int:
        return int(self.image.shape[2])

    @property
    def wrap_s(self) -> str:
        return WRAP_MODES[self._wrap_codes[0]]

    @property
    def wrap_t(self) -> str:
        return WRAP_MODES[self._wrap_codes[1]]

    @property
    def wrap_codes(self) -> tuple[int, int]:
        """Integer codes (index into :data:`WRAP_MODES`) of ``(wrap_s, wrap_t)``."""
        return self._wrap_codes

    @property
    def value_range(self) -> tuple[float, float]:
        """Smallest and largest texel value over all channels (bilinear results stay inside,
        except that ``"black"`` wrapping can blend towards 0)."""
        return float(self.image.min()), float(self.image.max())

    # ---- float64 mirror ----------------------------------------------------------------
    def sample(self, uv) -> np.ndarray:
        """Bilinearly filtered texel values at texture coordinates.

        Args:
            uv: ``(u, v)`` coordinates, shape (N, 2) (or (2,)), v up (module docstring).

        Returns:
            Shape (N, C), float64.

        Raises:
            ValueError: ``uv`` has the wrong shape or non-finite entries.
        """
        st = np.asarray(uv, dtype=np.float64)
        if st.ndim == 1 and st.shape == (2,):
            st = st[None]
        if st.ndim != 2 or st.shape[1] != 2:
            raise ValueError(f"texture {self.path or '<array>'}: uv must have shape (N, 2), got {st.shape}")
        if not np.all(np.isfinite(st)):
            raise ValueError(f"texture {self.path or '<array>'}: uv has NaN or infinite coordinates")
        mode_s, mode_t = self._wrap_codes
        h, w = self.height, self.width
        x = _reduce(st[:, 0], mode_s) * w - 0.5
        y = (1.0 - _reduce(st[:, 1], mode_t)) * h - 0.5
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
        cols = [_wrap_index(x0, w, mode_s), _wrap_index(x0 + 1, w, mode_s)]
        rows = [_wrap_index(y0, h, mode_t), _wrap_index(y0 + 1, h, mode_t)]
        img = self.image.astype(np.float64)

        def texel(r, c):
            ok = ((r >= 0) & (c >= 0))[:, None]
            return np.where(ok, img[np.maximum(r, 0), np.maximum(c, 0)], 0.0)

        top = (1.0 - fx) * texel(rows[0], cols[0]) + fx * texel(rows[0], cols[1])
        bottom = (1.0 - fx) * texel(rows[1], cols[0]) + fx * texel(rows[1], cols[1])
        return (1.0 - fy) * top + fy * bottom

    def sample_rgb(self, uv) -> np.ndarray:
        """:meth:`sample` as RGB by the UsdUVTexture channel rules, shape (N, 3), float64."""
        values = self.sample(uv)
        return np.repeat(values[:, :1], 3, axis=1) if self.channels < 3 else values[:, :3]

    # ---- device ---------------------------------------------------------------------------
    def to_warp(self, device=None):
        """The image as a ``wp.array3d(dtype=float)`` of shape (H, W, C) on ``device`` (cached)."""
        key = str(wp.get_device(device))
        arr = self._device_arrays.get(key)
        if arr is None:
            arr = wp.array(self.image, dtype=wp.float32, device=device)
            self._device_arrays[key] = arr
        return arr

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_device_arrays"] = {}
        return state


# ---- Warp sampling ----------------------------------------------------------------------------
@wp.func
def _reduce_coord(coord: float, mode: int):
    if mode == 2:
        return coord - wp.floor(coord)
    if mode == 3:
        return coord - 2.0 * wp.floor(0.5 * coord)
    return wp.clamp(coord, -1.0, 2.0)


@wp.func
def _wrap_texel(index: int, size: int, mode: int):
    if mode == 2:
        m = index % size
        if m < 0:
            m = m + size
        return m
    if mode == 3:
        period = 2 * size
        m = index % period
        if m < 0:
            m = m + period
        if m >= size:
            m = period - 1 - m
        return m
    if mode == 1:
        return wp.clamp(index, 0, size - 1)
    if index < 0 or index >= size:
        return -1
    return index


@wp.func
def _texel_rgb(image: wp.array3d(dtype=float), row: int, col: int):
    if row < 0 or col < 0:
        return wp.vec3(0.0, 0.0, 0.0)
    if image.shape[2] < 3:
        x = image[row, col, 0]
        return wp.vec3(x, x, x)
    return wp.vec3(image[row, col, 0], image[row, col, 1], image[row, col, 2])


@wp.func
def texture_sample_st(image: wp.array3d(dtype=float), uv: wp.vec2, wrap_s: int, wrap_t: int):
    """Bilinear RGB at ``uv`` with separate wrap modes for u (columns) and v (rows)."""
    h = image.shape[0]
    w = image.shape[1]
    u = uv[0]
    v = uv[1]
    if not (wp.isfinite(u) and wp.isfinite(v)):
        return wp.vec3(0.0, 0.0, 0.0)
    x = _reduce_coord(u, wrap_s) * float(w) - 0.5
    y = (1.0 - _reduce_coord(v, wrap_t)) * float(h) - 0.5
    xf = wp.floor(x)
    yf = wp.floor(y)
    fx = x - xf
    fy = y - yf
    x0 = int(xf)
    y0 = int(yf)
    c0 = _wrap_texel(x0, w, wrap_s)
    c1 = _wrap_texel(x0 + 1, w, wrap_s)
    r0 = _wrap_texel(y0, h, wrap_t)
    r1 = _wrap_texel(y0 + 1, h, wrap_t)
    top = (1.0 - fx) * _texel_rgb(image, r0, c0) + fx * _texel_rgb(image, r0, c1)
    bottom = (1.0 - fx) * _texel_rgb(image, r1, c0) + fx * _texel_rgb(image, r1, c1)
    return (1.0 - fy) * top + fy * bottom


@wp.func
def texture_sample(image: wp.array3d(dtype=float), uv: wp.vec2, wrap: int):
    """Bilinear RGB at ``uv`` (one wrap mode for both axes); C = 1 returns (x, x, x)."""
    return texture_sample_st(image, uv, wrap, wrap)


@wp.kernel
def sample_kernel(
    image: wp.array3d(dtype=float),
    uvs: wp.array(dtype=wp.vec2),
    wrap_s: int,
    wrap_t: int,
    out: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    out[i] = texture_sample_st(image, uvs[i], wrap_s, wrap_t)


def _as_uv_array(uvs, device):
    st = np.asarray(uvs, dtype=np.float32)
    if st.ndim != 2 or st.shape[1] != 2:
        raise ValueError(f"uvs must have shape (N, 2), got {st.shape}")
    return wp.array(st, dtype=wp.vec2, device=device)


def sample_texture_warp(texture: Texture, uvs, device=None) -> np.ndarray:
    """:func:`texture_sample_st` at ``uvs`` (N, 2) on ``device``: RGB, shape (N, 3), float32."""
    st = _as_uv_array(uvs, device)
    out = wp.empty(st.shape[0], dtype=wp.vec3, device=device)
    if st.shape[0]:
        wp.launch(sample_kernel, dim=st.shape[0], inputs=[texture.to_warp(device), st, *texture.wrap_codes, out],
                  device=device)
    return out.numpy()


# ---- surface maps ------------------------------------------------------------------------------
def _as_map(value, channels: int, what: str):
    """A Texture stays a Texture (checked for its channel count); a constant becomes float64."""
    if isinstance(value, Texture):
        if value.channels not in ((1, 3, 4) if channels == 3 else (1,)):
            raise ValueError(f"{what}: texture {value.path or '<array>'} has {value.channels} channels "
                             f"(need {'1 or 3' if channels == 3 else '1'})")
        return value
    const = np.asarray(value, dtype=np.float64)
    if channels == 3:
        const = np.broadcast_to(const.reshape(-1), (3,)).copy() if const.size in (1, 3) else None
    else:
        const = float(const) if const.size == 1 else None
    if const is None or not np.all(np.isfinite(const)):
        raise ValueError(f"{what}: need a Texture or a finite constant of {channels} value(s), got {value!r}")
    return const


@dataclass
class SurfaceMaps:
    """The spatially varying UsdPreviewSurface parameters of one mesh.

    Each map is a :class:`Texture` or a constant. What :meth:`sample` returns at texture
    coordinate ``uv`` (every value clipped to the parameter's valid range, [0, 1]):

    * specular workflow (``use_specular_workflow``): ``diffuse = diffuseColor``,
      ``specular = specularColor`` (normal-incidence reflectance, RGB);
    * metallic workflow: ``diffuse = diffuseColor * (1 - metallic)`` and
      ``specular = lerp(F0_dielectric, diffuseColor, metallic)`` with
      ``F0_dielectric = ((1 - ior) / (1 + ior))**2`` (0.04 for the default ior 1.5), the
      UsdPreviewSurface rule;
    * ``roughness`` as authored: the value :class:`~warpshade.scene._materials.Microfacet`
      takes as ``roughness`` (its alpha). Callers that need ``roughness > 0`` clamp it themselves.

    Attributes:
        diffuse: diffuseColor, a Texture (1 or 3 channels, linear) or RGB (3,) float64.
        roughness: a one-channel Texture or a float.
        specular: specularColor (Texture or RGB), used in the specular workflow.
        metallic: a one-channel Texture or a float, used in the metallic workflow.
        use_specular_workflow: which of the two workflows the material uses.
        ior: index of refraction for the dielectric F0 (metallic workflow).
        uv_primvar: name of the mesh primvar the textures are looked up with (None when all maps
            are constants).
        material: the material's prim path (for messages), or None.
    """

    diffuse: Texture | np.ndarray = field(default_factory=lambda: np.full(3, 0.18))
    roughness: Texture | float = 0.5
    specular: Texture | np.ndarray = field(default_factory=lambda: np.zeros(3))
    metallic: Texture | float = 0.0
    use_specular_workflow: bool = False
    ior: float = DIELECTRIC_IOR
    uv_primvar: str | None = None
    material: str | None = None

    def __post_init__(self):
        where = f"surface maps {self.material or '<arrays>'}"
        self.diffuse = _as_map(self.diffuse, 3, f"{where}: diffuse")
        self.roughness = _as_map(self.roughness, 1, f"{where}: roughness")
        self.specular = _as_map(self.specular, 3, f"{where}: specular")
        self.metallic = _as_map(self.metallic, 1, f"{where}: metallic")
        self.use_specular_workflow = bool(self.use_specular_workflow)
        self.f0_dielectric = dielectric_f0(float(self.ior))

    @property
    def textures(self) -> dict[str, Texture]:
        """The textured maps by name (``diffuse``, ``roughness``, ``specular``, ``metallic``) that
        take part in the material's workflow."""
        names = ("diffuse", "roughness", "specular") if self.use_specular_workflow else ("diffuse", "roughness", "metallic")
        return {n: getattr(self, n) for n in names if isinstance(getattr(self, n), Texture)}

    @property
    def is_textured(self) -> bool:
        return bool(self.textures)

    @staticmethod
    def _eval(value, uv, n: int, rgb: bool) -> np.ndarray:
        if isinstance(value, Texture):
            return value.sample_rgb(uv) if rgb else value.sample(uv)[:, 0]
        return np.broadcast_to(value, (n, 3) if rgb else (n,)).astype(np.float64)

    def sample(self, uv=None, count: int | None = None) -> dict[str, np.ndarray]:
        """Shading parameters at texture coordinates (float64 mirror).

        Args:
            uv: texture coordinates (N, 2); may be None when no map is textured (then
                ``count`` values of the constants are returned).
            count: number of points when ``uv`` is None.

        Returns:
            ``{"diffuse": (N, 3), "roughness": (N,), "specular": (N, 3)}``, float64, linear.

        Raises:
            ValueError: a map is textured but ``uv`` is None, or ``uv`` is malformed.
        """
        if uv is None:
            if self.is_textured:
                raise ValueError(f"surface maps {self.material or '<arrays>'}: textured "
                                 f"({', '.join(self.textures)}) but no texture coordinates were given")
            n = 1 if count is None else int(count)
            st = None
        else:
            st = np.asarray(uv, np.float64).reshape(-1, 2) if np.asarray(uv).size else np.zeros((0, 2))
            n = st.shape[0]
        base = self._eval(self.diffuse, st, n, True)
        rough = np.clip(self._eval(self.roughness, st, n, False), 0.0, 1.0)
        if self.use_specular_workflow:
            diffuse = base
            specular = self._eval(self.specular, st, n, True)
        else:
            metal = np.clip(self._eval(self.metallic, st, n, False), 0.0, 1.0)[:, None]
            diffuse = base * (1.0 - metal)
            specular = (1.0 - metal) * self.f0_dielectric + metal * base
        return {"diffuse": np.clip(diffuse, 0.0, 1.0), "roughness": rough, "specular": np.clip(specular, 0.0, 1.0)}

    def at_vertices(self, uvs=None, vertex_count: int | None = None) -> dict[str, np.ndarray]:
        """:meth:`sample` at per-vertex UVs: ``diffuse`` (V, 3), ``roughness`` (V,),
        ``specular`` (V, 3), float64. ``uvs`` is the mesh's (V, 2) ``Mesh.uvs``; it may be None
        for untextured maps (pass ``vertex_count`` then)."""
        return self.sample(uvs, count=vertex_count)

    # ---- device -----------------------------------------------------------------------------
    def to_warp(self, device=None) -> "SurfaceMapsArrays":
        """The maps as a :class:`SurfaceMapsArrays` struct on ``device``: every map is an image
        array (a constant is a 1 x 1 texture with clamped wrapping, which bilinear sampling
        returns exactly)."""
        s = SurfaceMapsArrays()

        def image(value):
            if isinstance(value, Texture):
                return value.to_warp(device), value.wrap_codes
            const = np.asarray(value, np.float32).reshape(1, 1, -1)
            return wp.array(const, dtype=wp.float32, device=device), (1, 1)

        s.diffuse, (s.diffuse_wrap_s, s.diffuse_wrap_t) = image(self.diffuse)
        s.roughness, (s.roughness_wrap_s, s.roughness_wrap_t) = image(self.roughness)
        second = self.specular if self.use_specular_workflow else self.metallic
        s.second, (s.second_wrap_s, s.second_wrap_t) = image(second)
        s.specular_workflow = int(self.use_specular_workflow)
        s.f0_dielectric = float(self.f0_dielectric)
        return s


@wp.struct
class SurfaceMapsArrays:
    """Device form of :class:`SurfaceMaps` (built by :meth:`SurfaceMaps.to_warp`): ``second`` is
    the specular colour (specular workflow) or the metallic map (metallic workflow)."""

    diffuse: wp.array3d(dtype=float)
    diffuse_wrap_s: int
    diffuse_wrap_t: int
    roughness: wp.array3d(dtype=float)
    roughness_wrap_s: int
    roughness_wrap_t: int
    second: wp.array3d(dtype=float)
    second_wrap_s: int
    second_wrap_t: int
    specular_workflow: int
    f0_dielectric: float


@wp.struct
class SurfaceSample:
    """Shading parameters at one point: linear RGB diffuse albedo and F0, Microfacet roughness."""

    diffuse: wp.vec3
    roughness: float
    specular: wp.vec3


@wp.func
def _clamp01(v: wp.vec3):
    return wp.vec3(wp.clamp(v[0], 0.0, 1.0), wp.clamp(v[1], 0.0, 1.0), wp.clamp(v[2], 0.0, 1.0))


@wp.func
def surface_sample(maps: SurfaceMapsArrays, uv: wp.vec2):
    """:meth:`SurfaceMaps.sample` at one texture coordinate, as a :class:`SurfaceSample`."""
    base = texture_sample_st(maps.diffuse, uv, maps.diffuse_wrap_s, maps.diffuse_wrap_t)
    rough = texture_sample_st(maps.roughness, uv, maps.roughness_wrap_s, maps.roughness_wrap_t)[0]
    second = texture_sample_st(maps.second, uv, maps.second_wrap_s, maps.second_wrap_t)
    out = SurfaceSample()
    out.roughness = wp.clamp(rough, 0.0, 1.0)
    if maps.specular_workflow != 0:
        out.diffuse = _clamp01(base)
        out.specular = _clamp01(second)
    else:
        metal = wp.clamp(second[0], 0.0, 1.0)
        f0 = maps.f0_dielectric
        out.diffuse = _clamp01(base * (1.0 - metal))
        out.specular = _clamp01(wp.vec3(f0, f0, f0) * (1.0 - metal) + base * metal)
    return out


@wp.kernel
def surface_kernel(
    maps: SurfaceMapsArrays,
    uvs: wp.array(dtype=wp.vec2),
    diffuse: wp.array(dtype=wp.vec3),
    roughness: wp.array(dtype=float),
    specular: wp.array(dtype=wp.vec3),
):
    i = wp.tid()
    s = surface_sample(maps, uvs[i])
    diffuse[i] = s.diffuse
    roughness[i] = s.roughness
    specular[i] = s.specular


def sample_surface_warp(maps: SurfaceMaps, uvs, device=None) -> dict[str, np.ndarray]:
    """:func:`surface_sample` at ``uvs`` (N, 2) on ``device``; the keys and shapes of
    :meth:`SurfaceMaps.sample`, float32."""
    st = _as_uv_array(uvs, device)
    n = st.shape[0]
    out = {
        "diffuse": wp.empty(n, dtype=wp.vec3, device=device),
        "roughness": wp.empty(n, dtype=float, device=device),
        "specular": wp.empty(n, dtype=wp.vec3, device=device),
    }
    if n:
        wp.launch(surface_kernel, dim=n, inputs=[maps.to_warp(device), st, out["diffuse"], out["roughness"],
                                                 out["specular"]], device=device)
    return {k: v.numpy() for k, v in out.items()}
