"""Precomputed per-vertex quantities: ray-traced SH visibility, diffuse transfer, ambient occlusion,
and interreflected (multi-bounce) diffuse transfer.

``compute(scene, frame, order, samples, space="world" | "local")`` returns a
:class:`TransferResult` of NumPy float32 arrays (``visibility`` and ``transfer`` of shape
(receiver_count, order**2), ``ambient_occlusion`` of shape (receiver_count,)); the definitions,
the estimator and the frames are documented in :mod:`warpshade.transfer.raytrace` (``compute``
itself is :mod:`warpshade.transfer.bake`).
:class:`TransferTracer` is the per-frame, allocation-free form (device outputs, BVH refit).

``compute(..., bounces=k, albedo=None)`` adds ``transfer_rgb``, the transfer after k diffuse
bounces per RGB channel, shape (receiver_count, 3, order**2), world frame
(:mod:`warpshade.transfer.interreflection`; :class:`InterreflectionTracer` per frame).
"""

from .bake import compute
from .interreflection import MAX_BOUNCES, InterreflectionTracer
from .raytrace import SPACES, TransferResult, TransferTracer, sample_rays

__all__ = ["MAX_BOUNCES", "SPACES", "InterreflectionTracer", "TransferResult", "TransferTracer", "compute", "sample_rays"]
