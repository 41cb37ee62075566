"""``ripples.usda`` -- an animated water surface as a procedural height field (8 m square, 512 x 512
vertices, 48 frames that loop): a swell, three crossing chop waves, two circular ripples and a
static seeded terrain term, described by the ``warpshade:heightField:*`` attributes of one Mesh
prim (:mod:`warpshade.io._heightfield`, expanded by the loader), under the sky, with a camera
looking across the water toward the sun at a glancing angle.
"""

from __future__ import annotations

import os

from pxr import Gf, UsdGeom, Vt

from ...io._heightfield import HeightFieldSpec, author
from .sky import define_sky
from .writing import FPS, define_camera, new_stage, save_stage


RIPPLES_FRAMES = 48
RIPPLES_RESOLUTION = 512


def make_ripples(out_dir: str, resolution: int = RIPPLES_RESOLUTION, frame_count: int = RIPPLES_FRAMES,
                 file_name: str = "ripples.usda") -> str:
    """The water height field (warpshade.io._heightfield): every wave advances a whole number of
    periods over the clip, so frame ``frame_count`` would equal frame 0."""
    duration = frame_count / FPS

    def speed(wavelength, cycles):
        return wavelength * cycles / duration

    planar = [  # amplitude, wavelength, direction, phase speed, phase
        (0.050, 2.6, 0.30, 1.00, speed(2.6, 1), 0.0),
        (0.020, 0.95, 1.00, 0.35, speed(0.95, 2), 1.3),
        (0.014, 0.62, -0.55, 1.00, speed(0.62, 3), 2.1),
        (0.008, 0.37, 0.85, -0.40, speed(0.37, 4), 0.4),
    ]
    circular = [  # amplitude, wavelength, centre, phase speed, phase, decay
        (0.012, 0.30, -1.4, 1.1, speed(0.30, 5), 0.0, 0.35),
        (0.009, 0.22, 1.7, -0.9, speed(0.22, 6), 1.0, 0.45),
    ]
    spec = HeightFieldSpec(resolution, (8.0, 8.0), planar, circular, terrain=(0.012, 1.4, 3, 7))
    stage = new_stage(animated=True, frame_count=frame_count)
    define_sky(stage)
    mesh = UsdGeom.Mesh.Define(stage, "/World/Water")
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(0.1, 0.25, 0.3)]))
    author(mesh, spec)
    define_camera(stage, eye=(-3.0, 5.2, 1.3), target=(0.6, -1.0, 0.0))
    path = os.path.join(out_dir, file_name)
    save_stage(stage, path)
    return path
