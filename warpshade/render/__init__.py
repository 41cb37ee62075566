"""Preview images: a Warp ray-cast pinhole camera over per-vertex or per-pixel shading.

``render(scene, frame, colors=...)`` interpolates per-vertex colours at the primary hits;
``render(scene, frame, shade=callback)`` calls ``callback(gbuffer)`` for per-pixel radiance.
Images are tone-mapped (exposure + sRGB or Reinhard) and written to PNG atomically. Pictures of
a method against ground truth are the measuring layer's (:mod:`warpshade.measure._pictures`).
"""

from ._camera import camera_basis, camera_for, frame_camera
from ._image import GREY_BACKGROUND, TONEMAP_MODES, tonemap, tonemap_f64, write_png
from ._raycast import GBuffer, RenderResult, interpolate_vertex_values, render, render_gbuffer

__all__ = [
    "GBuffer",
    "GREY_BACKGROUND",
    "RenderResult",
    "TONEMAP_MODES",
    "camera_basis",
    "camera_for",
    "frame_camera",
    "interpolate_vertex_values",
    "render",
    "render_gbuffer",
    "tonemap",
    "tonemap_f64",
    "write_png",
]
