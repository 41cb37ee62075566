"""Writing shading results to USD: a new layer over the input scene, never over the input.

The written layer sublayers the scene's source file (when there is one) and adds per-vertex
``primvars:displayColor`` (vertex interpolation, one time sample per frame) to each shaded
mesh as an ``over``, so it loads in usdview/Omniverse on top of the original animation. A
mesh that is not in the source file as an editable mesh with the same vertex count (a
generated ground plane, an instance proxy, a scene built from arrays) is written in full as a
new Mesh prim under ``/Shaded`` with its world-space points (time-sampled when it moves).
The file is exported to a temporary name and moved into place atomically.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
from pxr import Sdf, Usd, UsdGeom, Vt

from .._fileio import atomic_path, captured_stderr

__all__ = ["write_vertex_colors", "usd_output_name", "USDA_MAX_BYTES"]


def _safe_name(path: str) -> str:
    name = "".join(c if c.isalnum() or c == "_" else "_" for c in path.strip("/"))
    return name if name and not name[0].isdigit() else f"m_{name}"


def write_vertex_colors(path, scene, frames, colors, extra_primvars: dict | None = None) -> Path:
    """Write time-sampled per-vertex colours (and optional extra primvars) as a new USD layer.

    Args:
        path: output file (.usda, .usdc or .usd). Must not be the scene's source file.
        scene: the :class:`~warpshade.scene.Scene` that was shaded.
        frames: time codes, shape (T,).
        colors: per-vertex linear RGB per frame, shape (T, vertex_count, 3).
        extra_primvars: optional name -> array of shape (T, vertex_count) or
            (T, vertex_count, k) written as float / float[k] vertex primvars (e.g. ambient
            occlusion), names prefixed with ``warpshade_``.

    Returns:
        The written path.
    """
    path = Path(path).resolve()
    frames = np.asarray(frames, np.float64).reshape(-1)
    colors = np.asarray(colors, np.float32)
    if colors.shape != (frames.shape[0], scene.vertex_count, 3):
        raise ValueError(
            f"write_vertex_colors: colors must have shape ({frames.shape[0]}, {scene.vertex_count}, 3), got {colors.shape}"
        )
    if not np.all(np.isfinite(colors)):
        raise ValueError("write_vertex_colors: colors contain NaN/inf; refusing to write them")
    source = Path(scene.source).resolve() if scene.source and Path(scene.source).exists() else None
    if source is not None and source == path:
        raise ValueError(f"write_vertex_colors: refusing to write over the input file {source}")
    if path.suffix not in (".usda", ".usdc", ".usd"):
        raise ValueError(f"write_vertex_colors: output must end in .usda, .usdc or .usd, got {path.name}")

    with atomic_path(path, exists=False) as tmp:  # Sdf creates the layer itself, in the same directory
        with captured_stderr() as printed:  # USD reports a failed save with a line per write
            try:
                _author(str(tmp), path, source, scene, frames, colors, extra_primvars)
            except ValueError:
                raise
            except Exception as exc:  # OSError, pxr.Tf.ErrorException (a full disk, a vanished directory)
                detail = f" ({printed[0]})" if printed else ""
                code = getattr(exc, "errno", None) or errno.EIO
                raise OSError(code, f"could not write the USD layer {path}{detail}: {getattr(exc, 'strerror', None) or exc}") from None
    return path


#: Above this many bytes of colour data a layer written as ``format="auto"`` is binary (.usdc):
#: text takes ~3x the bytes and far longer to write and read.
USDA_MAX_BYTES = 32 * 2**20


def usd_output_name(stem: str, scene, frame_count: int, fmt: str = "auto") -> str:
    """The USD file name of a run's layer: ``<stem>.usda`` or ``<stem>.usdc``.

    Args:
        fmt: "usda", "usdc" or "auto" (binary when the time-sampled colours exceed
            :data:`USDA_MAX_BYTES`: vertex_count x frames x 3 floats).
    """
    if fmt not in ("auto", "usda", "usdc"):
        raise ValueError(f"USD format must be 'auto', 'usda' or 'usdc', got {fmt!r}")
    if fmt == "auto":
        fmt = "usdc" if scene.vertex_count * frame_count * 12 > USDA_MAX_BYTES else "usda"
    return f"{stem}.{fmt}"


def _author(tmp, path, source, scene, frames, colors, extra_primvars):
    layer = Sdf.Layer.CreateNew(tmp)
    if layer is None:
        raise OSError(errno.EIO, f"could not create USD layer {tmp}")
    stage = Usd.Stage.Open(layer)
    src_stage = None
    if source is not None:
        try:
            rel = os.path.relpath(source, path.parent)
        except ValueError:  # different drives
            rel = str(source)
        layer.subLayerPaths.append(rel)
        src_stage = Usd.Stage.Open(str(source))
    stage.SetStartTimeCode(float(frames[0]))
    stage.SetEndTimeCode(float(frames[-1]))
    stage.SetTimeCodesPerSecond(scene.fps)
    stage.SetFramesPerSecond(scene.fps)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if scene.up_axis.upper() == "Y" else UsdGeom.Tokens.z)

    for mesh in scene.meshes:
        sl = slice(mesh.vertex_offset, mesh.vertex_offset + mesh.vertex_count)
        prim = _editable_source_mesh(src_stage, mesh) if src_stage is not None else None
        if prim is not None:
            target = stage.OverridePrim(prim.GetPath())
        else:
            target = _define_full_mesh(stage, scene, mesh, frames)
            _hide_source_prim(src_stage, stage, mesh)
        pv_api = UsdGeom.PrimvarsAPI(target)
        pv = pv_api.CreatePrimvar("displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.vertex)
        for t, f in enumerate(frames):
            pv.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(colors[t, sl])), Usd.TimeCode(float(f)))
        for name, values in (extra_primvars or {}).items():
            arr = np.asarray(values, np.float32)
            if arr.shape[:2] != (frames.shape[0], scene.vertex_count):
                raise ValueError(f"write_vertex_colors: primvar {name!r} has shape {arr.shape}")
            if arr.ndim == 2:
                tname, conv = Sdf.ValueTypeNames.FloatArray, Vt.FloatArray.FromNumpy
            elif arr.shape[2] == 3:
                tname, conv = Sdf.ValueTypeNames.Float3Array, Vt.Vec3fArray.FromNumpy
            else:
                raise ValueError(f"write_vertex_colors: primvar {name!r} must be (T, V) or (T, V, 3)")
            epv = pv_api.CreatePrimvar(f"warpshade_{name}", tname, UsdGeom.Tokens.vertex)
            for t, f in enumerate(frames):
                epv.Set(conv(np.ascontiguousarray(arr[t, sl])), Usd.TimeCode(float(f)))

    if not layer.Save():
        raise OSError(errno.EIO, f"could not save USD layer {tmp}")


def _editable_source_mesh(src_stage, mesh):
    if not mesh.path.startswith("/"):
        return None
    try:
        prim = src_stage.GetPrimAtPath(mesh.path)
    except Exception:  # not a valid path
        return None
    if not prim or not prim.IsA(UsdGeom.Mesh) or prim.IsInstanceProxy():
        return None
    pts = UsdGeom.Mesh(prim).GetPointsAttr().Get()
    if pts is None or len(pts) != mesh.vertex_count:
        return None
    return prim


def _hide_source_prim(src_stage, stage, mesh) -> None:
    """A source Mesh the loader expanded into other geometry (a procedural height field's
    preview grid) is made invisible in the written layer: the full mesh under /Shaded replaces it."""
    if src_stage is None or not mesh.path.startswith("/"):
        return
    try:
        prim = src_stage.GetPrimAtPath(mesh.path)
    except Exception:  # not a valid path
        return
    if prim and prim.IsA(UsdGeom.Mesh) and not prim.IsInstanceProxy():
        UsdGeom.Imageable(stage.OverridePrim(prim.GetPath())).MakeInvisible()


def _define_full_mesh(stage, scene, mesh, frames):
    stage.DefinePrim("/Shaded", "Xform")
    usd_mesh = UsdGeom.Mesh.Define(stage, f"/Shaded/{_safe_name(mesh.path)}")
    usd_mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.full(mesh.triangle_count, 3, np.int32)))
    usd_mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(mesh.faces.reshape(-1).astype(np.int32)))
    usd_mesh.GetSubdivisionSchemeAttr().Set(UsdGeom.Tokens.none)
    sl = slice(mesh.vertex_offset, mesh.vertex_offset + mesh.vertex_count)
    pts_attr = usd_mesh.GetPointsAttr()
    if mesh.animation == "static":
        pts_attr.Set(Vt.Vec3fArray.FromNumpy(scene.points_at(frames[0])[sl].astype(np.float32)))
    else:
        for f in frames:
            pts_attr.Set(Vt.Vec3fArray.FromNumpy(scene.points_at(f)[sl].astype(np.float32)), Usd.TimeCode(float(f)))
    return usd_mesh.GetPrim()
