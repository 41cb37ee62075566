"""USD writing helpers of the scene generator: new stages, meshes, the ground grid, the camera, saving.

Every stage is Z-up, in metres (``metersPerUnit = 1``), ``FPS`` (24) frames per second, time codes
``0 .. FRAME_COUNT - 1`` (60 frames) when animated, with ``/World`` as its default prim.
Coordinates are rounded to ``DECIMALS`` (1e-4, 0.1 mm) and camera matrices to 1e-6 before they are
written (:func:`rounded`, :func:`round_matrix`), so the files' bytes change only when the
generator does.
"""

from __future__ import annotations

import os

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

from .shapes import grid


FRAME_COUNT = 60
FPS = 24.0
DECIMALS = 4  # coordinates are rounded to 0.1 mm: small files, stable bytes


def rounded(a) -> np.ndarray:
    return np.round(np.asarray(a, dtype=np.float64), DECIMALS)


def vec3f(a) -> Vt.Vec3fArray:
    return Vt.Vec3fArray.FromNumpy(rounded(a).astype(np.float32).reshape(-1, 3))


def new_stage(animated: bool, frame_count: int = FRAME_COUNT) -> Usd.Stage:
    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(FPS)
    stage.SetFramesPerSecond(FPS)
    if animated:
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(frame_count - 1)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    return stage


def save_stage(stage: Usd.Stage, path: str) -> None:
    """Write the stage's root layer: text for ``.usda``, USD's crate format for ``.usdc``."""
    if path.endswith(".usdc"):
        tmp = path[: -len(".usdc")] + ".tmp.usdc"  # the extension picks the file format
        if not stage.GetRootLayer().Export(tmp):
            raise OSError(f"could not write {tmp}")
    else:
        tmp = path + ".tmp"
        with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(stage.GetRootLayer().ExportToString())
    os.replace(tmp, path)


def define_mesh(stage, path, points, counts, indices, color=None):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(vec3f(points))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([int(c) for c in counts]))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for i in indices]))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*rounded(pts.min(0))), Gf.Vec3f(*rounded(pts.max(0)))]))
    if color is not None:
        mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, color))]))
    return mesh


def define_camera(stage, eye, target, focal=35.0):
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(focal)
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(24.0)
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    cam.CreateFocusDistanceAttr(float(np.linalg.norm(target - eye)))
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.05, 1000.0))
    view = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*target), Gf.Vec3d(0, 0, 1))
    UsdGeom.Xformable(cam).AddTransformOp().Set(round_matrix(view.GetInverse()))


def round_matrix(m, decimals: int = 6) -> Gf.Matrix4d:
    return Gf.Matrix4d(*[float(v) for v in np.round(np.array(m), decimals).ravel()])


def define_ground(stage, path="/World/Ground", size=6.0, material=False):
    pts, counts, idx = grid(40, size)
    mesh = define_mesh(stage, path, pts, counts, idx, color=None if material else (0.8, 0.8, 0.8))
    if material:
        mat = UsdShade.Material.Define(stage, "/World/Looks/Ground")
        shader = UsdShade.Shader.Define(stage, "/World/Looks/Ground/Surface")
        shader.CreateIdAttr("UsdPreviewSurface")
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.7, 0.68, 0.62))
        shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.9)
        mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    return mesh
