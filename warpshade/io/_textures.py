"""UsdPreviewSurface networks in: the :class:`~warpshade.scene._textures.SurfaceMaps` of a mesh.

Used by :mod:`warpshade.io._usd_mesh` for every mesh it reads (this module imports ``pxr`` too; it is
part of the USD reader). For a mesh bound to a material (``UsdShade.MaterialBindingAPI``,
``ComputeBoundMaterial``) whose surface shader is a ``UsdPreviewSurface``, the inputs
``diffuseColor``, ``roughness``, ``specularColor``, ``useSpecularWorkflow``, ``metallic`` and
``ior`` are read, each as:

* a constant -- the authored value, else the spec's fallback (diffuseColor 0.18, roughness 0.5,
  specularColor 0, useSpecularWorkflow 0, metallic 0, ior 1.5);
* a connected ``UsdUVTexture`` (through node-graph interface connections too):
  ``inputs:file`` (an asset path, resolved by USD relative to the layer that authors it),
  ``inputs:st`` (connected to a ``UsdPrimvarReader_float2`` whose ``inputs:varname`` names the
  mesh's UV primvar, optionally through a ``UsdTransform2d``: scale, then rotation in degrees
  counter-clockwise, then translation; unconnected: the mesh's default UVs, ``primvars:st`` or the
  first ``texCoord2f`` primvar), ``inputs:wrapS`` / ``inputs:wrapT`` (black, clamp, repeat,
  mirror; ``useMetadata``, the default, falls back to black as the spec says, since the image
  files read here carry no wrap metadata), ``inputs:scale`` / ``inputs:bias`` (float4, applied
  after decoding: ``value * scale + bias``), ``inputs:sourceColorSpace`` and the output it is
  connected through (``r``, ``g``, ``b``, ``a`` or ``rgb``).

Texture files: 8- and 16-bit PNG, JPEG, TIFF, ... through Pillow (integer values divided by
255 or 65535), and linear float ``.exr`` / ``.hdr`` through :mod:`warpshade.io._images`.
Channels follow the UsdUVTexture rules: one channel (grey) gives r = g = b = grey and a = 1, two
(grey, alpha) r = g = b = grey and a = alpha, three a = 1; the single outputs ``g`` and ``b``
need a file with at least three channels. ``sourceColorSpace = "sRGB"`` decodes the RGB channels
with the sRGB curve (alpha stays linear), ``"raw"`` does not; ``"auto"`` (the default) decodes
8-bit integer files connected to colour inputs (diffuseColor, specularColor) and leaves scalar
inputs (roughness, metallic) and float files raw.

What a mesh gets (``Mesh.surface``): None when it has no UsdPreviewSurface; otherwise a
:class:`SurfaceMaps` -- with constants only, when nothing is textured. All textures of one
material must use the same texture coordinates (one primvar, one transform); the per-vertex UVs
they use become ``Mesh.uvs``.

Roughness is passed on as authored: warpshade reads it as the number
:class:`~warpshade.scene._materials.Microfacet` takes as ``roughness`` (its GGX/Beckmann alpha).

Errors (ValueError naming the USD file, the mesh, the shader prim and the texture file): a
texture file that is missing, empty, unreadable, of zero size or without the channel an output
needs; an ``rgb`` output connected to a scalar input; a textured material on a mesh without the
UV primvar it names (or without any UVs); textures of one material on different UV sets.
Connections to other node types (e.g. primvar readers driving diffuseColor) are not evaluated:
a warning names them and the input's fallback is used.
"""

from __future__ import annotations

import math
import os
import warnings

import numpy as np

from ..scene._textures import SurfaceMaps, Texture, srgb_to_linear

__all__ = [
    "SurfaceReader",
    "TEXTURE_FILE_EXTENSIONS_FLOAT",
]

#: Files read as linear float images by :mod:`warpshade.io._images`.
TEXTURE_FILE_EXTENSIONS_FLOAT = (".exr", ".hdr", ".pic", ".rgbe")

_FALLBACKS = {
    "diffuseColor": (0.18, 0.18, 0.18),
    "roughness": 0.5,
    "specularColor": (0.0, 0.0, 0.0),
    "metallic": 0.0,
}
_COLOUR_INPUTS = ("diffuseColor", "specularColor")
_WRAP_TOKENS = {"black": "black", "clamp": "clamp", "repeat": "repeat", "mirror": "mirror", "useMetadata": "black"}


def read_texture_file(path) -> tuple[np.ndarray, bool]:
    """Read a texture image as stored: values, and whether they came from 8-bit integers.

    Returns:
        ``(image, eight_bit)``: image of shape (H, W, C), float32, C in 1..4, integer formats
        scaled to [0, 1] (not colour-decoded); row 0 = top of the image.

    Raises:
        ValueError: the file is missing, empty, unreadable or has zero size (the message names it
            and says why).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ValueError(f"texture file {path} not found")
    if os.path.getsize(path) == 0:
        raise ValueError(f"texture file {path} is empty (0 bytes)")
    ext = os.path.splitext(path)[1].lower()
    if ext in TEXTURE_FILE_EXTENSIONS_FLOAT:
        from ._images import read_image

        try:
            img = read_image(path)
        except (ValueError, OSError) as exc:
            raise ValueError(f"texture file {path} cannot be read: {exc}") from exc
        return _checked(img, path), False
    from PIL import Image

    try:
        with Image.open(path) as im:
            im.load()
            mode = im.mode
            if mode == "P":
                im = im.convert("RGBA" if "transparency" in im.info else "RGB")
                mode = im.mode
            elif mode in ("1", "CMYK", "YCbCr", "LAB", "HSV"):
                im = im.convert("L" if mode == "1" else "RGB")
                mode = im.mode
            elif mode == "PA":
                im = im.convert("RGBA")
                mode = im.mode
            data = np.asarray(im)
    except Exception as exc:  # Pillow raises UnidentifiedImageError, OSError, SyntaxError, ...
        raise ValueError(f"texture file {path} cannot be read as an image ({type(exc).__name__}: {exc})") from exc
    if mode in ("L", "LA", "RGB", "RGBA"):
        img, eight_bit = data.astype(np.float32) / 255.0, True
    elif mode.startswith("I;16"):
        img, eight_bit = data.astype(np.float32) / 65535.0, False
    elif mode == "F":
        img, eight_bit = data.astype(np.float32), False
    else:
        raise ValueError(f"texture file {path}: unsupported pixel format {mode!r}")
    return _checked(img, path), eight_bit


def _checked(img: np.ndarray, path: str) -> np.ndarray:
    img = np.asarray(img, np.float32)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[0] == 0 or img.shape[1] == 0:
        raise ValueError(f"texture file {path} has zero size (pixel array {img.shape})")
    if not 1 <= img.shape[2] <= 4:
        raise ValueError(f"texture file {path} has {img.shape[2]} channels (need 1 to 4)")
    if not np.all(np.isfinite(img)):
        raise ValueError(f"texture file {path} has NaN or infinite pixels")
    return img


def _rgba(img: np.ndarray) -> np.ndarray:
    """(H, W, C) -> (H, W, 4) by the UsdUVTexture channel rules."""
    h, w, c = img.shape
    out = np.ones((h, w, 4), np.float32)
    if c <= 2:
        out[..., :3] = img[..., :1]
        if c == 2:
            out[..., 3] = img[..., 1]
    else:
        out[..., :c] = img
    return out


class SurfaceReader:
    """Reads the SurfaceMaps of the meshes of one stage; caches decoded texture files.

    The stage reader is passed to :meth:`read` rather than kept, so that no reference cycle
    keeps the stage (and USD's cached layers) alive after a load.
    """

    def __init__(self):
        self._files: dict[str, tuple[np.ndarray, bool]] = {}
        self._textures: dict[tuple, Texture] = {}

    # ---- entry -----------------------------------------------------------------------------
    def read(self, stage_reader, prim, mesh_path: str, vertex_count: int, indices, counts, default_uvs):
        """The mesh's :class:`SurfaceMaps` (or None) and the per-vertex UVs its textures use.

        Args:
            stage_reader: the :class:`warpshade.io._usd._StageReader` doing the load (the file
                name, the first time code and its primvar helpers).

        Returns:
            ``(surface, uvs)``: ``uvs`` is ``default_uvs`` unless the textures name another
            primvar or a UsdTransform2d; (V, 2) float64 or None.
        """
        from pxr import UsdShade

        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        if not material:
            return None, default_uvs
        shader = material.ComputeSurfaceSource()[0]
        if not shader or shader.GetIdAttr().Get() != "UsdPreviewSurface":
            return None, default_uvs
        ctx = _Context(self, stage_reader, prim, mesh_path, str(material.GetPath()), vertex_count, indices, counts, default_uvs)
        values = {name: ctx.input(shader, name) for name in _FALLBACKS}
        workflow = ctx.constant(shader, "useSpecularWorkflow", 0)
        ior = float(ctx.constant(shader, "ior", 1.5))
        if not (math.isfinite(ior) and ior > 0):
            raise ValueError(f"{ctx.where(shader)}: ior must be finite and > 0, got {ior}")
        surface = SurfaceMaps(
            diffuse=values["diffuseColor"],
            roughness=values["roughness"],
            specular=values["specularColor"],
            metallic=values["metallic"],
            use_specular_workflow=bool(int(workflow)),
            ior=ior,
            uv_primvar=ctx.uv_key[0] if ctx.uv_key is not None else None,
            material=ctx.material,
        )
        return surface, (ctx.uvs if ctx.uv_key is not None else default_uvs)

    def texture(self, key, build) -> Texture:
        tex = self._textures.get(key)
        if tex is None:
            tex = self._textures[key] = build()
        return tex

    def file(self, resolved: str):
        if resolved not in self._files:
            self._files[resolved] = read_texture_file(resolved)
        return self._files[resolved]


class _Context:
    """One mesh's material being read: error messages, the UV set its textures share."""

    def __init__(self, owner, reader, prim, mesh_path, material, vertex_count, indices, counts, default_uvs):
        self.owner = owner
        self.reader = reader
        self.prim = prim
        self.mesh_path = mesh_path
        self.material = material
        self.vertex_count = vertex_count
        self.indices = indices
        self.counts = counts
        self.default_uvs = default_uvs
        self.uv_key = None  # (primvar name, transform) shared by every texture
        self.uvs = None

    def where(self, shader, name: str | None = None) -> str:
        what = f"mesh {self.mesh_path} in {self.reader.path}: material {self.material}, shader {shader.GetPath()}"
        return what + (f" input {name}" if name else "")

    # ---- values ---------------------------------------------------------------------------
    def constant(self, shader, name, fallback):
        from pxr import UsdShade

        inp = shader.GetInput(name)
        if not inp:
            return fallback
        for attr in inp.GetValueProducingAttributes():
            if UsdShade.Utils.GetBaseNameAndType(attr.GetName())[1] == UsdShade.AttributeType.Output:
                warnings.warn(f"{self.where(shader, name)} is connected; only a constant is read, using {fallback}",
                              stacklevel=5)
                return fallback
            value = attr.Get(self.reader.times[0])
            if value is not None:
                return value
        return fallback

    def input(self, shader, name):
        """A constant (float or (3,) float64) or a Texture for one UsdPreviewSurface input."""
        from pxr import UsdShade

        fallback = _FALLBACKS[name]
        inp = shader.GetInput(name)
        if not inp:
            return fallback
        for attr in inp.GetValueProducingAttributes():
            if UsdShade.Utils.GetBaseNameAndType(attr.GetName())[1] == UsdShade.AttributeType.Output:
                source = UsdShade.Shader(attr.GetPrim())
                output = UsdShade.Utils.GetBaseNameAndType(attr.GetName())[0]
                kind = source.GetIdAttr().Get() if source else None
                if kind != "UsdUVTexture":
                    warnings.warn(f"{self.where(shader, name)} is connected to {attr.GetPath()} ({kind or 'not a shader'}), "
                                  f"which is not evaluated; using the fallback {fallback}", stacklevel=5)
                    return fallback
                return self.texture(source, str(output), name)
            value = attr.Get(self.reader.times[0])
            if value is None:
                continue
            if name in _COLOUR_INPUTS:
                rgb = np.asarray(value, np.float64).reshape(-1)
                if rgb.size != 3 or not np.all(np.isfinite(rgb)):
                    raise ValueError(f"{self.where(shader, name)}: need a finite colour, got {value!r}")
                return rgb
            number = float(value)
            if not math.isfinite(number):
                raise ValueError(f"{self.where(shader, name)}: need a finite value, got {value!r}")
            return number
        return fallback

    # ---- textures -------------------------------------------------------------------------
    def _tex_value(self, tex, name, fallback):
        inp = tex.GetInput(name)
        if not inp:
            return fallback
        for attr in inp.GetValueProducingAttributes():
            value = attr.Get(self.reader.times[0])
            if value is not None:
                return value
        return fallback

    def texture(self, tex, output: str, name: str) -> Texture:
        where = self.where(tex, name)
        colour = name in _COLOUR_INPUTS
        if output not in ("r", "g", "b", "a", "rgb"):
            raise ValueError(f"{where}: connected through output {output!r} (need r, g, b, a or rgb)")
        if output == "rgb" and not colour:
            raise ValueError(f"{where}: {name} takes one channel but is connected to output rgb (3 channels); "
                             "connect outputs:r, g, b or a")
        asset = self._tex_value(tex, "file", None)
        if asset is None or not getattr(asset, "path", ""):
            raise ValueError(f"{where}: UsdUVTexture has no inputs:file")
        resolved = asset.resolvedPath
        if not resolved:
            resolved = self._expected_path(tex, asset.path)
        try:
            image, eight_bit = self.owner.file(resolved)
        except ValueError as exc:
            raise ValueError(f"{where}: texture {asset.path!r}: {exc}") from None
        space = str(self._tex_value(tex, "sourceColorSpace", "auto") or "auto")
        if space not in ("auto", "raw", "sRGB"):
            raise ValueError(f"{where}: sourceColorSpace {space!r} (need auto, raw or sRGB)")
        decode = space == "sRGB" or (space == "auto" and colour and eight_bit)
        if output in ("g", "b") and image.shape[2] < 3:
            raise ValueError(f"{where}: texture file {resolved} has {image.shape[2]} channel(s); output {output} needs 3 or 4")
        scale = np.asarray(self._tex_value(tex, "scale", (1.0, 1.0, 1.0, 1.0)), np.float64).reshape(-1)
        bias = np.asarray(self._tex_value(tex, "bias", (0.0, 0.0, 0.0, 0.0)), np.float64).reshape(-1)
        if scale.size != 4 or bias.size != 4 or not (np.all(np.isfinite(scale)) and np.all(np.isfinite(bias))):
            raise ValueError(f"{where}: inputs:scale and inputs:bias must be finite float4 values")
        wrap = tuple(self._wrap(tex, axis, where) for axis in ("wrapS", "wrapT"))
        key = (resolved, output, decode, tuple(scale), tuple(bias), wrap)

        def build():
            rgba = _rgba(image).astype(np.float64)
            if decode:
                rgba[..., :3] = srgb_to_linear(np.clip(rgba[..., :3], 0.0, 1.0))
            rgba = rgba * scale + bias
            channel = {"r": [0], "g": [1], "b": [2], "a": [3], "rgb": [0, 1, 2]}[output]
            return Texture(rgba[..., channel].astype(np.float32), path=resolved, wrap=wrap)

        texture = self.owner.texture(key, build)
        self._use_uvs(tex, where, resolved)
        return texture

    def _wrap(self, tex, axis: str, where: str) -> str:
        token = str(self._tex_value(tex, axis, "useMetadata") or "useMetadata")
        if token not in _WRAP_TOKENS:
            raise ValueError(f"{where}: inputs:{axis} {token!r} (need black, clamp, repeat, mirror or useMetadata)")
        return _WRAP_TOKENS[token]

    def _expected_path(self, tex, asset_path: str) -> str:
        """Where a relative asset path points from the layer that authors it (for messages)."""
        from pxr import Sdf

        attr = tex.GetInput("file").GetAttr()
        for spec in attr.GetPropertyStack(self.reader.times[0]):
            if spec.default is not None or spec.layer.ListTimeSamplesForPath(spec.path):
                return Sdf.ComputeAssetPathRelativeToLayer(spec.layer, asset_path)
        return asset_path

    def _use_uvs(self, tex, where: str, resolved: str) -> None:
        """Find the UVs the texture is looked up with and check all textures share them."""
        from pxr import UsdShade

        varname, transform = None, None
        inp = tex.GetInput("st")
        if inp:
            for attr in inp.GetValueProducingAttributes():
                if UsdShade.Utils.GetBaseNameAndType(attr.GetName())[1] != UsdShade.AttributeType.Output:
                    continue
                node = UsdShade.Shader(attr.GetPrim())
                kind = node.GetIdAttr().Get() if node else None
                if kind == "UsdTransform2d":
                    transform = (
                        tuple(float(x) for x in self._tex_value(node, "scale", (1.0, 1.0))),
                        float(self._tex_value(node, "rotation", 0.0)),
                        tuple(float(x) for x in self._tex_value(node, "translation", (0.0, 0.0))),
                    )
                    inner = node.GetInput("in")
                    node = None
                    for src in inner.GetValueProducingAttributes() if inner else []:
                        if UsdShade.Utils.GetBaseNameAndType(src.GetName())[1] == UsdShade.AttributeType.Output:
                            node = UsdShade.Shader(src.GetPrim())
                    kind = node.GetIdAttr().Get() if node else None
                if node is not None and kind is not None and kind.startswith("UsdPrimvarReader_float2"):
                    varname = str(self._tex_value(node, "varname", "") or "")
                    if not varname:
                        raise ValueError(f"{where}: primvar reader {node.GetPath()} has no inputs:varname")
                elif node is not None:
                    raise ValueError(f"{where}: inputs:st is connected to {node.GetPath()} ({kind}); need a "
                                     "UsdPrimvarReader_float2, optionally through a UsdTransform2d")
        key = (varname, transform)
        if self.uv_key is not None:
            if key != self.uv_key:
                raise ValueError(f"{where}: textures of one material must share their texture coordinates; "
                                 f"this one uses {self._describe(key)}, another {self._describe(self.uv_key)}")
            return
        uvs = self._primvar_uvs(varname, where, resolved)
        if transform is not None:
            (sx, sy), degrees, (tx, ty) = transform
            c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
            scaled = uvs * np.array([sx, sy])
            uvs = np.stack([c * scaled[:, 0] - s * scaled[:, 1] + tx, s * scaled[:, 0] + c * scaled[:, 1] + ty], axis=1)
        self.uv_key, self.uvs = key, uvs

    @staticmethod
    def _describe(key) -> str:
        name, transform = key
        text = f"primvar {name!r}" if name else "the mesh's default UVs"
        return text + (f" through UsdTransform2d {transform}" if transform else "")

    def _primvar_uvs(self, varname, where: str, resolved: str) -> np.ndarray:
        if not varname:
            if self.default_uvs is None:
                raise ValueError(f"{where}: texture file {resolved} is applied, but the mesh has no texture coordinates "
                                 "(no primvars:st or texCoord2f primvar)")
            return np.asarray(self.default_uvs, np.float64)
        pv = self.reader._primvar(self.prim, varname)
        if pv is None:
            raise ValueError(f"{where}: texture file {resolved} is looked up with primvar {varname!r}, which the mesh "
                             "does not have (or has no value)")
        values = pv.ComputeFlattened(self.reader.times[0])
        uvs = None
        if values is not None and len(values):
            uvs = self.reader._to_vertex(values, str(pv.GetInterpolation()), self.mesh_path, pv.GetName(),
                                         self.vertex_count, self.indices, self.counts)
        if uvs is None or uvs.shape[1] != 2 or not np.all(np.isfinite(uvs)):
            raise ValueError(f"{where}: primvar {varname!r} (for texture file {resolved}) does not give finite 2D "
                             "texture coordinates per vertex")
        return uvs
