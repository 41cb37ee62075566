"""Brute-force ray-traced ground truth that every method is measured against.

``shade(scene, frame, lighting, samples, bounces=0)`` returns per-vertex outgoing radiance of the
diffuse scene, with ``bounces`` diffuse bounces of indirect light, and its Monte Carlo standard
error (:class:`ShadingResult`, NumPy float32, shape (receiver_count, 3)); see
:mod:`warpshade.reference._shading` for the estimators.
``shade_glossy(scene, frame, brdf, eye, ...)`` is the same for a BRDF of
:mod:`warpshade.scene._materials` or a tabulated one (MERL layout, a colour table per channel)
seen from a viewer (:mod:`warpshade.reference._glossy`). Both are
one Monte Carlo estimator with the BRDF as a parameter (:mod:`warpshade.reference._estimator`;
the diffuse reference is its Lambert case).
``reference_image(scene, frame, brdf, camera, ...)`` evaluates both at a camera's primary hits,
with per-pixel roughness, specular colour and albedo for textured materials
(:class:`PixelReference`, (height, width, 3) images; :mod:`warpshade.reference._pixels`).
"""

from ._glossy import GLOSSY_METHODS, GlossyReferenceShader, shade_glossy
from ._pixels import PixelHits, PixelReference, pixel_hits, reference_image
from ._shading import METHODS, ReferenceShader, ShadingResult, shade, upload_lighting

__all__ = [
    "GLOSSY_METHODS",
    "METHODS",
    "GlossyReferenceShader",
    "PixelHits",
    "PixelReference",
    "ReferenceShader",
    "ShadingResult",
    "pixel_hits",
    "reference_image",
    "shade",
    "shade_glossy",
    "upload_lighting",
]
