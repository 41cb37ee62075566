"""``blockers.usda`` -- a 40 x 40 vertex ground grid (6 m square, UsdPreviewSurface material)
and three rigid blockers animated over it with time-sampled transforms: two UV spheres of
radius 0.5 and 0.3 (quads with triangle fans at the poles) and a 0.7 m box (a 4 x 4 quad
grid per face) that spins while it travels.
"""

from __future__ import annotations

import os

import numpy as np
from pxr import Gf, UsdGeom

from .shapes import box, uv_sphere
from .sky import define_sky
from .writing import FRAME_COUNT, define_camera, define_ground, define_mesh, new_stage, rounded, save_stage


def blocker_paths(frame: int):
    """World translations of the blockers and the box's spin angle (degrees) at a frame."""
    t = frame / (FRAME_COUNT - 1)
    big = np.array([-2.0 + 4.0 * t, 0.6 * np.sin(2 * np.pi * t), 0.5 + 0.25 + 0.3 * np.sin(np.pi * t)])
    small = np.array([1.5 * np.cos(2 * np.pi * t), 1.5 * np.sin(2 * np.pi * t), 0.3 + 0.5])
    cube = np.array([1.8 - 3.6 * t, -1.0 + 0.8 * t, 0.35 + 0.15 + 0.4 * np.sin(np.pi * t) ** 2])
    return big, small, cube, 360.0 * t


def make_blockers(out_dir: str) -> str:
    stage = new_stage(animated=True)
    define_sky(stage)
    define_ground(stage, material=True)
    specs = [("BigSphere", uv_sphere(0.5), (0.85, 0.3, 0.25)), ("SmallSphere", uv_sphere(0.3, 16, 8), (0.25, 0.45, 0.85))]
    xforms = []
    for name, (pts, counts, idx), color in specs:
        xf = UsdGeom.Xform.Define(stage, f"/World/Blockers/{name}")
        define_mesh(stage, f"/World/Blockers/{name}/Mesh", pts, counts, idx, color)
        xforms.append(xf.AddTranslateOp())
    cube_xf = UsdGeom.Xform.Define(stage, "/World/Blockers/Box")
    pts, counts, idx = box(0.7)
    define_mesh(stage, "/World/Blockers/Box/Mesh", pts, counts, idx, (0.3, 0.75, 0.35))
    cube_t = cube_xf.AddTranslateOp()
    cube_r = cube_xf.AddRotateZOp()
    for f in range(FRAME_COUNT):
        big, small, cube, spin = blocker_paths(f)
        xforms[0].Set(Gf.Vec3d(*rounded(big)), f)
        xforms[1].Set(Gf.Vec3d(*rounded(small)), f)
        cube_t.Set(Gf.Vec3d(*rounded(cube)), f)
        cube_r.Set(float(rounded(spin)), f)
    define_camera(stage, eye=(4.5, -5.5, 3.8), target=(0.0, 0.0, 0.4))
    path = os.path.join(out_dir, "blockers.usda")
    save_stage(stage, path)
    return path
