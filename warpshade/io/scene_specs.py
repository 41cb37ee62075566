"""Scene specs: a file path, ``warp-example:NAME`` or ``bundled:NAME``, resolved to a USD file.

The bundled scenes ship inside the installed package, in ``warpshade/usd_assets/``
(:func:`bundled_asset_directory`; written by ``python -m warpshade.usd_assets.generator``).
Nothing here imports ``pxr``.
"""

from __future__ import annotations

import os
from importlib import resources

__all__: list[str] = []

#: The scene spec prefixes :func:`resolve_scene_path` understands.
SCENE_SPEC_PREFIXES = ("warp-example:", "bundled:")


def bundled_asset_directory() -> str:
    """The directory of the bundled scenes, ``usd_assets/`` inside the installed ``warpshade``
    package (package data: ``*.usda``, ``*.usdc``, their ``*.hdr`` skies and ``*.png`` textures)."""
    return os.fspath(resources.files("warpshade") / "usd_assets")


def resolve_scene_path(spec) -> str:
    """Turn a scene spec into an existing file path.

    Spec grammar::

        spec := PATH                    a .usd/.usda/.usdc/.usdz file
              | "warp-example:" NAME     NAME[.usd] in warp.examples.get_asset_directory()
                                         (e.g. warp-example:bunny, warp-example:bear)
              | "bundled:" NAME          NAME[.usda or .usdc, in that order] in the
                                         package's usd_assets/ (e.g. bundled:figure)

    Raises:
        FileNotFoundError: naming the file (and, for the prefixed forms, what is available).
    """
    spec = os.fspath(spec)
    for prefix, directory_fn, extensions in (
        ("warp-example:", _warp_asset_directory, (".usd",)),
        ("bundled:", bundled_asset_directory, (".usda", ".usdc")),
    ):
        if spec.startswith(prefix):
            name = spec[len(prefix) :]
            directory = directory_fn()
            candidates = [os.path.join(directory, name)]
            if not os.path.splitext(name)[1]:
                candidates[:0] = [os.path.join(directory, name + ext) for ext in extensions]
            for cand in candidates:
                if os.path.isfile(cand):
                    return cand
            available = sorted(
                {os.path.splitext(f)[0] for f in (os.listdir(directory) if os.path.isdir(directory) else []) if f.endswith(extensions)}
            )
            raise FileNotFoundError(
                f"scene spec {spec!r}: no file {candidates[0]} (available: {', '.join(available) or 'none'})"
            )
    path = os.path.expanduser(spec)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"USD file not found: {path}")
    return path


def _warp_asset_directory() -> str:
    import warp.examples

    return warp.examples.get_asset_directory()
