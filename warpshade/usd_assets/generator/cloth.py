"""``cloth.usda`` -- a 30 x 30 sheet (faceVarying ``st`` UVs) with time-sampled points:
travelling waves plus finer wrinkles, sagging at the free edge, over a ground grid.
"""

from __future__ import annotations

import os

import numpy as np
from pxr import Sdf, UsdGeom, Vt

from .shapes import grid
from .sky import define_sky
from .writing import FRAME_COUNT, define_camera, define_ground, define_mesh, new_stage, rounded, save_stage, vec3f


CLOTH_RESOLUTION = 30


def cloth_points(frame: int) -> np.ndarray:
    """The sheet's points at a frame (world space), shape (900, 3)."""
    n = CLOTH_RESOLUTION
    s = np.linspace(-1.0, 1.0, n)
    x, y = np.meshgrid(s, s, indexing="ij")
    t = frame / FRAME_COUNT
    phase = 2 * np.pi * t
    # Pinned along y = -1 (amplitude grows with distance), travelling waves and wrinkles.
    reach = (y + 1.0) / 2.0
    wave = 0.18 * reach * np.sin(2.2 * x + 3.0 * y - phase)
    wrinkles = 0.025 * reach * np.sin(9.0 * x + 1.5 * phase) * np.cos(7.0 * y - phase)
    sag = -0.35 * reach**2 * (0.8 + 0.2 * np.cos(phase))
    z = 1.1 + wave + wrinkles + sag
    # The free edge drifts in x a little as the wave passes.
    xs = x + 0.05 * reach * np.sin(phase + y)
    return np.stack([xs.ravel(), y.ravel(), z.ravel()], 1)


def make_cloth(out_dir: str) -> str:
    stage = new_stage(animated=True)
    define_sky(stage)
    define_ground(stage)
    n = CLOTH_RESOLUTION
    pts0 = cloth_points(0)
    _, counts, idx = grid(n, 2.0)
    mesh = define_mesh(stage, "/World/Cloth", pts0, counts, idx, (0.35, 0.55, 0.75))
    mesh.CreateDoubleSidedAttr(True)
    attr = mesh.GetPointsAttr()
    for f in range(FRAME_COUNT):
        attr.Set(vec3f(cloth_points(f)), f)
    s = np.linspace(0.0, 1.0, n)
    u, v = np.meshgrid(s, s, indexing="ij")
    st_vertex = np.stack([u.ravel(), v.ravel()], 1)
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set(Vt.Vec2fArray.FromNumpy(rounded(st_vertex[idx]).astype(np.float32)))
    define_camera(stage, eye=(2.6, -3.2, 2.4), target=(0.0, 0.0, 0.8))
    path = os.path.join(out_dir, "cloth.usda")
    save_stage(stage, path)
    return path
