"""USD and image input/output. Only :mod:`warpshade.io.usd` imports ``pxr`` (loaded on first use).

Public names:

* :func:`load_usd` -- a USD stage as a :class:`warpshade.scene.Scene`;
* :func:`load_scene` -- the same from a scene spec (``PATH``, ``warp-example:NAME``,
  ``bundled:NAME``) with an optional ground plane and sky;
* :func:`resolve_scene_path` -- a scene spec to a file path;
* :func:`read_image`, :func:`read_exr`, :func:`read_hdr`, :func:`write_hdr`,
  :func:`write_exr` -- linear HDR images;
* :func:`read_texture_file` -- a material texture image (PNG, JPEG, ... or EXR/HDR) as stored
  (UsdPreviewSurface networks are read by :mod:`warpshade.io.textures` during :func:`load_usd`).
"""

from __future__ import annotations

from .images import read_exr, read_hdr, read_image, write_exr, write_hdr

__all__ = [
    "load_usd",
    "load_scene",
    "resolve_scene_path",
    "read_image",
    "read_exr",
    "read_hdr",
    "write_hdr",
    "write_exr",
    "read_texture_file",
]

_USD_NAMES = ("load_usd", "load_scene", "resolve_scene_path")
_TEXTURE_NAMES = ("read_texture_file",)


def __getattr__(name):
    # pxr is heavy: import warpshade.io.usd only when one of its functions is asked for.
    if name in _USD_NAMES:
        from . import usd

        return getattr(usd, name)
    if name in _TEXTURE_NAMES:
        from . import textures

        return getattr(textures, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
