"""Brute-force ray-traced ground truth that every method is measured against.

``shade(scene, frame, lighting, samples)`` returns per-vertex outgoing radiance of the diffuse
scene and its Monte Carlo standard error (:class:`ShadingResult`, NumPy float32, shape
(receiver_count, 3)); see :mod:`warpshade.reference.shading` for the estimators.
"""

from .shading import METHODS, ReferenceShader, ShadingResult, shade, upload_lighting

__all__ = ["METHODS", "ReferenceShader", "ShadingResult", "shade", "upload_lighting"]
