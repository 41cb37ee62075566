"""The appearance of a mesh or tessellated implicit prim: its bound UsdPreviewSurface (textures,
:mod:`warpshade.io._textures`), its diffuse albedo from the material, ``displayColor`` or the
default (module docstring of :mod:`warpshade.io._usd`). Read by :mod:`._usd_mesh` and
:mod:`._usd_implicit` alike."""

from __future__ import annotations

import warnings

import numpy as np

from ..scene._textures import Texture

__all__ = ["read_appearance"]

_PREVIEW_SURFACE_DEFAULT_DIFFUSE = (0.18, 0.18, 0.18)  # UsdPreviewSurface spec fallback
_DEFAULT_ALBEDO = (0.8, 0.8, 0.8)


def read_appearance(reader, prim, path, vertex_count, indices, counts, poly_area, uvs):
    """The surface of a mesh (or tessellated implicit) prim: ``(surface, uvs, albedo)``.

    ``surface`` is the bound UsdPreviewSurface's :class:`~warpshade.scene._textures.SurfaceMaps`
    or None, ``uvs`` the per-vertex UVs its textures use (``uvs`` unless they name another
    primvar), ``albedo`` the per-vertex diffuse albedo (module docstring of
    :mod:`warpshade.io._usd`). ``indices`` / ``counts`` / ``poly_area`` describe the polygons
    (faceVertexIndices, faceVertexCounts, polygon areas) for primvars of any interpolation.
    """
    surface, uvs = reader._surfaces.read(reader, prim, path, vertex_count, indices, counts, uvs)
    albedo = _read_albedo(reader, prim, path, vertex_count, indices, counts, poly_area)
    if surface is not None and (isinstance(surface.diffuse, Texture) or isinstance(surface.metallic, Texture)
                                or (not surface.use_specular_workflow and surface.metallic > 0.0)):
        # textured (or metallic-darkened) diffuse: the effective albedo at the vertices' UVs
        albedo = surface.at_vertices(uvs, vertex_count)["diffuse"].astype(np.float32)
    return surface, uvs, albedo


def _read_albedo(reader, prim, path, vertex_count, indices, counts, poly_area):
    rgb = _material_diffuse(reader, prim, path)
    if rgb is not None:
        return np.asarray(rgb, np.float32)
    pv = reader._primvar(prim, "displayColor")
    if pv is not None:
        values = pv.ComputeFlattened(reader.times[0])
        if values is not None and not hasattr(values, "__len__"):
            raise ValueError(f"mesh {path} in {reader.path}: primvars:displayColor has a value of unknown type "
                             f"({pv.GetTypeName()})")
        if values is not None and len(values):
            corner_w = np.repeat(poly_area, counts)
            col = reader._to_vertex(values, str(pv.GetInterpolation()), path, "displayColor", vertex_count, indices, counts, corner_w)
            if col is not None and col.shape[1] == 3 and np.all(np.isfinite(col)):
                return col.astype(np.float32)
    return np.asarray(_DEFAULT_ALBEDO, np.float32)


def _material_diffuse(reader, prim, path):
    from pxr import UsdShade

    material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
    if not material:
        return None
    shader = material.ComputeSurfaceSource()[0]
    if not shader or shader.GetIdAttr().Get() != "UsdPreviewSurface":
        return None
    inp = shader.GetInput("diffuseColor")
    if not inp:
        return _PREVIEW_SURFACE_DEFAULT_DIFFUSE
    for attr in inp.GetValueProducingAttributes():
        if UsdShade.Utils.GetBaseNameAndType(attr.GetName())[1] == UsdShade.AttributeType.Output:
            source = UsdShade.Shader(attr.GetPrim())
            if source and source.GetIdAttr().Get() == "UsdUVTexture":
                return None  # sampled at the vertices from Mesh.surface (warpshade.io._textures)
            warnings.warn(
                f"mesh {path} in {reader.path}: material {material.GetPath()} has a connected (textured) "
                "diffuseColor, which is not sampled; using displayColor or the default albedo",
                stacklevel=4,
            )
            return None
        value = attr.Get(reader.times[0])
        if value is not None:
            return tuple(float(c) for c in value)
    return _PREVIEW_SURFACE_DEFAULT_DIFFUSE
