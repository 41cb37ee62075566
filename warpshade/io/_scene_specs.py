"""Scene specs: a file path, ``warp-example:NAME`` or ``bundled:NAME``, resolved to a USD file.

The bundled scenes ship inside the installed package, in ``warpshade/usd_assets/``
(:func:`bundled_asset_directory`; written by ``python -m warpshade.usd_assets.generator``).
A prefixed name never leaves its directory (``bundled:../../x`` is refused). Nothing here imports
``pxr`` but :func:`usd_file_dependencies`, when it is called.
"""

from __future__ import annotations

import os
from importlib import resources

__all__: list[str] = []

#: The scene spec prefixes :func:`resolve_scene_path` understands.
SCENE_SPEC_PREFIXES = ("warp-example:", "bundled:")
#: The suffixes of USD files.
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


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
        ValueError: a prefixed NAME that leads out of its directory (``..``, an absolute path, a
            link to elsewhere), naming the spec.
    """
    spec = os.fspath(spec)
    for prefix, directory_fn, extensions, what in (
        ("warp-example:", _warp_asset_directory, (".usd",), "Warp's example assets"),
        ("bundled:", bundled_asset_directory, (".usda", ".usdc"), "the bundled scenes"),
    ):
        if spec.startswith(prefix):
            name = spec[len(prefix) :]
            directory = directory_fn()
            candidates = [os.path.join(directory, name)]
            if not os.path.splitext(name)[1]:
                candidates[:0] = [os.path.join(directory, name + ext) for ext in extensions]
            root = os.path.realpath(directory)
            for cand in candidates:
                if os.path.commonpath([root, os.path.realpath(cand)]) != root:
                    raise ValueError(f"scene spec {spec!r}: {name!r} leads out of the directory of {what} ({directory}); "
                                     f"{prefix}NAME names a file in it: give another file by its path")
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


def usd_file_dependencies(path) -> list[str]:
    """The files a USD file pulls in: the layers it sublayers, references or loads as payloads
    and the assets its attributes name (textures, sky images), as absolute paths, the file itself
    among them; empty when they cannot be worked out (no ``pxr``, a file USD cannot open: the
    loader names those). Imports ``pxr`` on the first call."""
    from .._fileio import captured_stderr

    try:
        with captured_stderr():  # USD's warnings about missing assets: the loader reports them
            from pxr import UsdUtils

            layers, assets, _unresolved = UsdUtils.ComputeAllDependencies(os.fspath(path))
    except Exception:  # ImportError, pxr.Tf.ErrorException
        return []
    files = [layer.realPath for layer in layers] + list(assets)
    return [os.path.abspath(f) for f in files if f]
