"""The sky every bundled scene shares (except ``sunlit``, which has its own).

A ``DomeLight`` (/World/Sky) whose lat-long texture ``sky.hdr`` (``SKY_SIZE`` = 64 x 128, Radiance
RGBE) is :func:`warpshade.scene._lighting.sky_radiance` with a soft sun towards ``SUN_DIRECTION``;
the dome carries USD's ``rotateX:orientToStageUpAxis`` op so its +Y pole points up (+Z).
"""

from __future__ import annotations

import os

import numpy as np
from pxr import Sdf, UsdLux

from ...io._images import write_hdr
from ...scene._lighting import sky_radiance, usd_dome_texel_directions


SKY_FILE = "sky.hdr"
SKY_SIZE = (64, 128)
#: Sun direction (towards the sun), world space, Z-up: in front of the figure (-Y), high.
SUN_DIRECTION = np.array([0.35, -0.6, 0.72]) / np.linalg.norm([0.35, -0.6, 0.72])


def define_sky(stage) -> None:
    dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
    dome.OrientToStageUpAxis()
    dome.CreateTextureFileAttr(Sdf.AssetPath("./" + SKY_FILE))
    dome.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
    dome.CreateIntensityAttr(1.0)


def write_sky(out_dir: str) -> str:
    """The dome texture: sky_radiance at the world directions of the file's texels."""
    height, width = SKY_SIZE
    # Dome frame -> world for a DomeLight with rotateX:orientToStageUpAxis = 90 (column form).
    dome_to_world = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    dirs = usd_dome_texel_directions(height, width) @ dome_to_world.T
    image = sky_radiance(dirs, sun_direction=SUN_DIRECTION, up=(0.0, 0.0, 1.0))
    path = os.path.join(out_dir, SKY_FILE)
    write_hdr(path, image.astype(np.float32))
    return path
