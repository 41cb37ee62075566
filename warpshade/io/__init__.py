"""USD and image input/output: the only layer that imports ``pxr`` (loaded on first use).

Modules: :mod:`~warpshade.io._usd` (the stage reader, with :mod:`~warpshade.io._usd_mesh`,
:mod:`~warpshade.io._usd_skel`, :mod:`~warpshade.io._usd_lights`, :mod:`~warpshade.io._textures`
and :mod:`~warpshade.io._heightfield`), :mod:`~warpshade.io._scene_specs` (scene specs and the
bundled scenes, no ``pxr``), :mod:`~warpshade.io._usd_write` (shading results out),
:mod:`~warpshade.io._images` (HDR images).

Public names:

* :func:`load_usd` -- a USD stage as a :class:`warpshade.scene.Scene`;
* :func:`load_scene` -- the same from a scene spec (``PATH``, ``warp-example:NAME``,
  ``bundled:NAME``) with an optional ground plane and sky;
* :func:`resolve_scene_path` -- a scene spec to a file path; :data:`SCENE_SPEC_PREFIXES` -- the
  prefixes it understands;
* :func:`bundled_asset_directory` -- the directory of the bundled scenes (``warpshade/usd_assets/``,
  package data of the installed package);
* :func:`read_image`, :func:`read_exr`, :func:`read_hdr`, :func:`write_hdr`,
  :func:`write_exr` -- linear HDR images;
* :func:`tessellate` -- an implicit shape (a UsdGeom Sphere, Capsule, Cube, Cylinder, Cone or
  Plane, by kind and parameters) as a triangle mesh; :func:`write_vertex_colors` -- per-vertex colours onto a USD mesh;
* :func:`read_texture_file` -- a material texture image (PNG, JPEG, ... or EXR/HDR) as stored
  (UsdPreviewSurface networks are read by :mod:`warpshade.io._textures` during :func:`load_usd`).
"""

from __future__ import annotations

from ._images import read_exr, read_hdr, read_image, write_exr, write_hdr
from ._scene_specs import SCENE_SPEC_PREFIXES, bundled_asset_directory, resolve_scene_path

__all__ = [
    "load_usd",
    "load_scene",
    "resolve_scene_path",
    "SCENE_SPEC_PREFIXES",
    "bundled_asset_directory",
    "read_image",
    "read_exr",
    "read_hdr",
    "write_hdr",
    "write_exr",
    "read_texture_file",
    "tessellate",
    "write_vertex_colors",
]

#: Public names read on first use from their module (``_usd`` imports pxr, which is heavy).
_LAZY = {"load_usd": "_usd", "load_scene": "_usd", "read_texture_file": "_textures",
         "tessellate": "_usd_implicit", "write_vertex_colors": "_usd_write"}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
