"""Precomputed per-vertex quantities: ray-traced SH visibility, diffuse transfer, ambient occlusion.

``compute(scene, frame, order, samples, space="world" | "local")`` returns a
:class:`TransferResult` of NumPy float32 arrays (``visibility`` and ``transfer`` of shape
(receiver_count, order**2), ``ambient_occlusion`` of shape (receiver_count,)); the definitions,
the estimator and the frames are documented in :mod:`warpshade.transfer.raytrace`.
:class:`TransferTracer` is the per-frame, allocation-free form (device outputs, BVH refit).
"""

from .raytrace import SPACES, TransferResult, TransferTracer, compute, sample_rays

__all__ = ["SPACES", "TransferResult", "TransferTracer", "compute", "sample_rays"]
