"""``bend.usda`` -- a capped cylinder (24-gon caps) skinned to a 4-joint chain that bends and
twists over 60 frames (smooth two-joint weights), for local deformable PRT.
"""

from __future__ import annotations

import os

import numpy as np
from pxr import Gf, UsdSkel
from scipy.spatial.transform import Rotation

from .shapes import revolution
from .skeletons import bind_skin, define_skeleton
from .sky import define_sky
from .writing import FRAME_COUNT, define_camera, define_mesh, new_stage, save_stage


BEND_JOINTS = [("Base", None, (0.0, 0.0, 0.0)), ("Mid1", "Base", (0.0, 0.0, 0.5)), ("Mid2", "Mid1", (0.0, 0.0, 0.5)), ("Tip", "Mid2", (0.0, 0.0, 0.5))]
BEND_HEIGHT = 2.0
BEND_RADIUS = 0.22


def bend_joint_rotations(frame: int) -> np.ndarray:
    """Joint-local rotation vectors of the bending cylinder at a frame, shape (4, 3)."""
    t = frame / (FRAME_COUNT - 1)
    bend = 0.55 * np.sin(np.pi * t)  # per joint, about x: the tube curls over
    twist = 0.6 * np.sin(2 * np.pi * t)  # per joint, about the local z axis
    rot = [np.zeros(3)]
    for _ in range(3):
        r = Rotation.from_rotvec([bend, 0.0, 0.0]) * Rotation.from_rotvec([0.0, 0.0, twist])
        rot.append(r.as_rotvec())
    return np.stack(rot)


def make_bend(out_dir: str) -> str:
    stage = new_stage(animated=True)
    define_sky(stage)
    UsdSkel.Root.Define(stage, "/World/Bend")
    skel, _ = define_skeleton(stage, "/World/Bend", BEND_JOINTS, bend_joint_rotations, FRAME_COUNT)

    rings = 33
    profile = [(BEND_HEIGHT * k / (rings - 1), BEND_RADIUS) for k in range(rings)]
    pts, counts, idx, _ = revolution(profile, 24, cap_polygons=True)
    # Smooth two-joint weights: joint spacing 0.5, blend over the middle of each segment.
    seg = np.clip(pts[:, 2] / 0.5, 0.0, 3.0)
    lower = np.minimum(np.floor(seg), 2).astype(int)
    frac = seg - lower
    w_upper = np.clip((frac - 0.25) / 0.5, 0.0, 1.0)
    w_upper = w_upper * w_upper * (3 - 2 * w_upper)  # smoothstep
    infl = np.stack([lower, lower + 1], 1)
    w = np.stack([1.0 - w_upper, w_upper], 1)
    mesh = define_mesh(stage, "/World/Bend/Tube", pts, counts, idx, (0.7, 0.7, 0.72))
    bind_skin(mesh, skel, infl, w, 2, Gf.Matrix4d(1.0))
    define_camera(stage, eye=(3.5, -3.5, 2.2), target=(0.0, 0.0, 1.0))
    path = os.path.join(out_dir, "bend.usda")
    save_stage(stage, path)
    return path
