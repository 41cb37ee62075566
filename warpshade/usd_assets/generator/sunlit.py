"""``sunlit.usda`` -- all-frequency lighting of spatially varying glossy materials (48 frames,
0..47, at 24 fps; written only on request, ``--scenes sunlit``, like ``ripples``). A (2, 3)
torus knot (tube radius 0.12 m, 2,613 vertices with exact smooth vertex normals and vertex UVs,
u along the knot repeating 4 times, v around it) resting on a 41 x 41 vertex ground grid (6 m
square, UVs spanning [0, 1] over the plane). UsdPreviewSurface materials: the knot uses the
specular workflow (diffuseColor (0.30, 0.07, 0.05), specularColor (0.75, 0.6, 0.4)) with a
roughness texture ``sunlit_knot_roughness.png`` (128 x 128 grey, raw, repeat) of smooth bands
broken by noise between 0.08 and 0.5; the ground uses the metallic workflow (metallic 0, so
F0 = 0.04) with an sRGB diffuse texture ``sunlit_ground_diffuse.png`` (a 4 x 4 stone / slate
checker) and a raw roughness texture ``sunlit_ground_roughness.png`` (rust-like noise, 0.15 to
0.5). Roughness values are what ``warpshade.scene._materials.Microfacet(roughness=...)`` takes
(its alpha; warpshade does not square UsdPreviewSurface roughness). Lights: a DomeLight with
its own sky ``sunlit_sky.hdr`` (256 x 512 lat-long): a clear sky with a soft aureole plus a
sun disc 1.2 degrees across at 40 degrees elevation (azimuth 70 degrees from +X towards +Y),
painted by exact texel coverage so that its irradiance on the ground is ``SUNLIT_SUN_TO_SKY``
(4) times the rest of the sky's (peak radiance ~3e4 against a sky of ~0.25-1), so the knot casts
a sharp shadow on the plane; and an orange SphereLight (/World/Lamp, radius 0.08 m, intensity
150) that circles the knot once over the clip 1.5 m from its axis, bobbing 0.65-1.15 m above the
ground (time-sampled translate, :func:`sunlit_lamp_position`), always outside the knot's convex
hull. The camera frames the knot and its shadow.
"""

from __future__ import annotations

import os

import numpy as np
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade, Vt

from ...io._images import write_hdr
from ...scene._lighting import sky_radiance, usd_dome_texel_directions
from .shapes import grid, smoothstep, torus_knot
from .writing import define_camera, define_mesh, new_stage, rounded, save_stage


SUNLIT_FRAMES = 48
SUNLIT_SKY_FILE = "sunlit_sky.hdr"
SUNLIT_SKY_SIZE = (256, 512)
SUNLIT_SUN_ELEVATION_DEG = 40.0
SUNLIT_SUN_AZIMUTH_DEG = 70.0  # from +X towards +Y: the shadow falls towards the camera's left
SUNLIT_SUN_DIAMETER_DEG = 1.2
#: The sun's irradiance on the ground plane over the rest of the sky's.
SUNLIT_SUN_TO_SKY = 4.0
SUNLIT_SUN_COLOR = np.array([1.0, 0.94, 0.84])
SUNLIT_TEXTURES = ("sunlit_knot_roughness.png", "sunlit_ground_diffuse.png", "sunlit_ground_roughness.png")
#: The (p, q) torus knot: core radius 2 s, wobble s, tube radius; segments along it, vertices around.
SUNLIT_KNOT = {"p": 2, "q": 3, "scale": 0.28, "tube": 0.12, "segments": 200, "around": 12, "u_repeat": 4}
SUNLIT_KNOT_ROUGHNESS = (0.08, 0.5)
SUNLIT_GROUND_ROUGHNESS = (0.15, 0.5)
SUNLIT_LAMP_RADIUS = 0.08
SUNLIT_LAMP_COLOR = (1.0, 0.55, 0.25)
SUNLIT_LAMP_INTENSITY = 150.0


def sunlit_sun_direction() -> np.ndarray:
    """World direction towards the sun of ``sunlit.usda`` (Z-up), unit (3,)."""
    el, az = np.radians(SUNLIT_SUN_ELEVATION_DEG), np.radians(SUNLIT_SUN_AZIMUTH_DEG)
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def sunlit_lamp_position(frame: int) -> np.ndarray:
    """World position of the moving sphere light at a frame: one turn around the knot per clip,
    1.5 m from the vertical axis, bobbing between 0.65 and 1.15 m above the ground."""
    t = frame / SUNLIT_FRAMES
    angle = 2.0 * np.pi * t - 0.6
    return np.array([1.5 * np.cos(angle), 1.5 * np.sin(angle), 0.9 + 0.25 * np.sin(4.0 * np.pi * t)])


def _periodic_noise(rng, size: int, cells: int) -> np.ndarray:
    """Smooth value noise on a size x size image that tiles: a random cells x cells lattice
    interpolated with smoothstep weights, in [0, 1]."""
    lattice = rng.random((cells, cells))
    x = np.arange(size) * cells / size
    k = np.floor(x).astype(int)
    w = smoothstep(x - k)
    rows = (1 - w)[:, None] * lattice[k % cells] + w[:, None] * lattice[(k + 1) % cells]
    return (1 - w)[None, :] * rows[:, k % cells] + w[None, :] * rows[:, (k + 1) % cells]


def sunlit_texture_images() -> dict[str, np.ndarray]:
    """The sunlit textures as the 8-bit arrays written to PNG (row 0 = top = v 1), by file name.

    * knot roughness (128 x 128, grey, raw): three smooth glossy/rough bands per tile along the
      knot (u), broken up by tiling noise, between SUNLIT_KNOT_ROUGHNESS;
    * ground diffuse colour (128 x 128, RGB, sRGB): a 4 x 4 checker of warm stone and slate tiles
      with a little mottling;
    * ground roughness (128 x 128, grey, raw): rust-like noise between SUNLIT_GROUND_ROUGHNESS.
    """
    rng = np.random.default_rng(2009)
    size = 128
    u = (np.arange(size) + 0.5) / size
    bands = smoothstep(0.5 + 1.6 * np.sin(2 * np.pi * 3 * u))[None, :]  # along u (columns)
    knot = np.clip(bands + 0.35 * (_periodic_noise(rng, size, 8) - 0.5), 0.0, 1.0)
    lo, hi = SUNLIT_KNOT_ROUGHNESS
    knot_rough = lo + (hi - lo) * knot
    cells = ((np.arange(size) * 4 // size)[:, None] + (np.arange(size) * 4 // size)[None, :]) % 2
    stone, slate = np.array([0.78, 0.70, 0.58]), np.array([0.36, 0.40, 0.44])  # sRGB-encoded
    mottle = 0.9 + 0.2 * _periodic_noise(rng, size, 16)
    diffuse = np.where(cells[..., None] == 1, slate, stone) * mottle[..., None]
    rust = _periodic_noise(rng, size, 6) * 0.65 + _periodic_noise(rng, size, 24) * 0.35
    rust = (rust - rust.min()) / (rust.max() - rust.min())
    lo, hi = SUNLIT_GROUND_ROUGHNESS
    ground_rough = lo + (hi - lo) * rust

    def to8(x):
        return np.clip(np.round(255.0 * x), 0, 255).astype(np.uint8)

    return dict(zip(SUNLIT_TEXTURES, (to8(knot_rough), to8(diffuse), to8(ground_rough))))


def _write_png(path: str, pixels: np.ndarray) -> str:
    from PIL import Image

    tmp = path[: -len(".png")] + ".tmp.png"
    Image.fromarray(pixels).save(tmp, format="PNG", compress_level=9)
    os.replace(tmp, path)
    return path


def _sunlit_sun_texels(height: int, width: int, dome_to_world: np.ndarray, sun: np.ndarray, sub: int = 16):
    """Fraction of each lat-long texel covered by the sun disc (H, W), by sub x sub samples."""
    half = np.radians(SUNLIT_SUN_DIAMETER_DEG) / 2.0
    centres = usd_dome_texel_directions(height, width) @ dome_to_world.T
    near = np.argwhere(centres @ sun > np.cos(half + 4.0 * np.pi / height))
    coverage = np.zeros((height, width))
    offsets = (np.arange(sub) + 0.5) / sub
    for r, c in near:
        lat = np.pi / 2.0 - (r + offsets) * (np.pi / height)
        lon = np.pi - (c + offsets) * (2.0 * np.pi / width)
        la, lo = np.meshgrid(lat, lon, indexing="ij")
        local = np.stack([np.cos(la) * np.sin(lo), np.sin(la), np.cos(la) * np.cos(lo)], -1)
        # sub-samples weighted by cos(lat): equal solid angle per weight
        inside = (local @ dome_to_world.T) @ sun > np.cos(half)
        coverage[r, c] = np.sum(inside * np.cos(la)) / np.sum(np.cos(la))
    return coverage


def write_sunlit_sky(out_dir: str) -> str:
    """The sunlit dome texture: a clear sky with a soft aureole, plus a sun disc of
    SUNLIT_SUN_DIAMETER_DEG whose irradiance on the ground is SUNLIT_SUN_TO_SKY times the sky's."""
    height, width = SUNLIT_SKY_SIZE
    dome_to_world = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    dirs = usd_dome_texel_directions(height, width) @ dome_to_world.T
    sun = sunlit_sun_direction()
    sky = sky_radiance(dirs, sun_direction=sun, sun_radiance=(3.0, 2.6, 2.0), sun_angle_deg=6.0,
                       zenith=(0.25, 0.45, 1.0), horizon=(0.95, 0.92, 0.85), up=(0.0, 0.0, 1.0))
    lat_edges = np.pi / 2.0 - np.arange(height + 1) * (np.pi / height)
    solid = (np.sin(lat_edges[:-1]) - np.sin(lat_edges[1:]))[:, None] * (2.0 * np.pi / width)  # (H, 1)
    cos_up = np.maximum(dirs[..., 2], 0.0)
    luminance = sky @ np.array([0.2126, 0.7152, 0.0722])
    sky_irradiance = np.sum(luminance * cos_up * solid)
    coverage = _sunlit_sun_texels(height, width, dome_to_world, sun)
    colour = SUNLIT_SUN_COLOR / (SUNLIT_SUN_COLOR @ np.array([0.2126, 0.7152, 0.0722]))
    sun_radiance = SUNLIT_SUN_TO_SKY * sky_irradiance / np.sum(coverage * cos_up * solid)
    image = sky + (sun_radiance * coverage)[..., None] * colour
    path = os.path.join(out_dir, SUNLIT_SKY_FILE)
    write_hdr(path, image.astype(np.float32))
    return path


def _texture_node(stage, material_path, name, file_name, reader, color_space, output, output_type):
    tex = UsdShade.Shader.Define(stage, f"{material_path}/{name}")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath("./" + file_name))
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(color_space)
    tex.CreateOutput(output, output_type)
    return tex


def _preview_material(stage, mesh, path, textures, constants):
    """A UsdPreviewSurface material at ``path`` bound to ``mesh``: ``textures`` maps an input
    (name, type) to (node name, file, colour space, output); ``constants`` input (name, type) -> value."""
    mat = UsdShade.Material.Define(stage, path)
    surface = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    reader = UsdShade.Shader.Define(stage, f"{path}/UVs")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    for (name, value_type), value in constants.items():
        surface.CreateInput(name, value_type).Set(value)
    for (name, value_type), (node, file_name, color_space, output) in textures.items():
        out_type = Sdf.ValueTypeNames.Float3 if output == "rgb" else Sdf.ValueTypeNames.Float
        tex = _texture_node(stage, path, node, file_name, reader, color_space, output, out_type)
        surface.CreateInput(name, value_type).ConnectToSource(tex.ConnectableAPI(), output)
    mat.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    return mat


def _vertex_uvs(mesh, uvs) -> None:
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set(Vt.Vec2fArray.FromNumpy(rounded(uvs).astype(np.float32)))


def make_sunlit(out_dir: str) -> list[str]:
    """``sunlit.usda`` with its sky (``sunlit_sky.hdr``) and textures (``SUNLIT_TEXTURES``)."""
    written = [write_sunlit_sky(out_dir)]
    for name, pixels in sunlit_texture_images().items():
        written.append(_write_png(os.path.join(out_dir, name), pixels))
    stage = new_stage(animated=True, frame_count=SUNLIT_FRAMES)
    dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
    dome.OrientToStageUpAxis()
    dome.CreateTextureFileAttr(Sdf.AssetPath("./" + SUNLIT_SKY_FILE))
    dome.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
    dome.CreateIntensityAttr(1.0)
    # ground: 41 x 41 vertices over 6 m, one texture tile over the whole plane
    pts, counts, idx = grid(41, 6.0)
    ground = define_mesh(stage, "/World/Ground", pts, counts, idx)
    _vertex_uvs(ground, (pts[:, :2] + 3.0) / 6.0)
    C3, F = Sdf.ValueTypeNames.Color3f, Sdf.ValueTypeNames.Float
    _preview_material(
        stage, ground, "/World/Looks/Ground",
        {("diffuseColor", C3): ("DiffuseTexture", SUNLIT_TEXTURES[1], "sRGB", "rgb"),
         ("roughness", F): ("RoughnessTexture", SUNLIT_TEXTURES[2], "raw", "r")},
        {("metallic", F): 0.0, ("useSpecularWorkflow", Sdf.ValueTypeNames.Int): 0},
    )
    # the glossy knot: specular workflow, coloured specular, banded roughness
    pts, counts, idx, normals, uvs = torus_knot(**SUNLIT_KNOT)
    knot = define_mesh(stage, "/World/Knot", pts, counts, idx)
    knot.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(rounded(normals).astype(np.float32)))
    knot.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    _vertex_uvs(knot, uvs)
    _preview_material(
        stage, knot, "/World/Looks/Knot",
        {("roughness", F): ("RoughnessTexture", SUNLIT_TEXTURES[0], "raw", "r")},
        {("diffuseColor", C3): Gf.Vec3f(0.30, 0.07, 0.05), ("specularColor", C3): Gf.Vec3f(0.75, 0.6, 0.4),
         ("useSpecularWorkflow", Sdf.ValueTypeNames.Int): 1},
    )
    # the moving, tinted sphere light
    lamp = UsdLux.SphereLight.Define(stage, "/World/Lamp")
    lamp.CreateRadiusAttr(SUNLIT_LAMP_RADIUS)
    lamp.CreateColorAttr(Gf.Vec3f(*SUNLIT_LAMP_COLOR))
    lamp.CreateIntensityAttr(SUNLIT_LAMP_INTENSITY)
    move = UsdGeom.Xformable(lamp).AddTranslateOp()
    for f in range(SUNLIT_FRAMES):
        move.Set(Gf.Vec3d(*rounded(sunlit_lamp_position(f))), f)
    define_camera(stage, eye=(3.3, -3.7, 2.4), target=(-0.2, -0.45, 0.25))
    path = os.path.join(out_dir, "sunlit.usda")
    save_stage(stage, path)
    return [path] + written
