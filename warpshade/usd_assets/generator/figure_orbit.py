"""``figure_orbit.usda`` -- ``figure.usda`` seen by a moving camera: a layer over it (a sublayer)
whose camera circles the figure a third of the way round over the clip, rising and falling
(view-dependent shading under a moving view).
"""

from __future__ import annotations

import os

import numpy as np
from pxr import Gf, Sdf

from .writing import FPS, FRAME_COUNT, round_matrix


def make_figure_orbit(out_dir: str) -> str:
    """``figure.usda`` seen by a moving camera: a layer over it (sublayer) whose camera circles the
    figure a third of the way round over the clip, rising and falling (view-dependent shading
    under a moving view). Stage metadata is authored again: USD reads it from the root layer."""
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.subLayerPaths.append("./figure.usda")
    layer.startTimeCode, layer.endTimeCode = 0, FRAME_COUNT - 1
    layer.timeCodesPerSecond = layer.framesPerSecond = FPS
    layer.defaultPrim = "World"
    layer.pseudoRoot.SetInfo("upAxis", "Z")
    layer.pseudoRoot.SetInfo("metersPerUnit", 1.0)
    world = Sdf.PrimSpec(layer.pseudoRoot, "World", Sdf.SpecifierOver)
    cam = Sdf.PrimSpec(world, "Camera", Sdf.SpecifierOver)
    attr = Sdf.AttributeSpec(cam, "xformOp:transform", Sdf.ValueTypeNames.Matrix4d)
    target = np.array([0.0, 0.0, 1.0])
    for f in range(FRAME_COUNT):
        t = f / (FRAME_COUNT - 1)
        angle = np.radians(-72.0 + 120.0 * t)
        eye = target + np.array([3.9 * np.cos(angle), 3.9 * np.sin(angle), 0.6 + 0.5 * np.sin(np.pi * t)])
        view = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*target), Gf.Vec3d(0, 0, 1))
        layer.SetTimeSample(attr.path, float(f), round_matrix(view.GetInverse()))
    path = os.path.join(out_dir, "figure_orbit.usda")
    tmp = path + ".tmp"
    with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(layer.ExportToString())
    os.replace(tmp, path)
    return path
