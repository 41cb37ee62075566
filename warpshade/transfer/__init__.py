"""Precomputed per-vertex quantities: ray-traced SH visibility, diffuse transfer, ambient occlusion,
and interreflected (multi-bounce) diffuse transfer.

``compute(scene, frame, order, samples, space="world" | "local")`` returns a
:class:`TransferResult` of NumPy float32 arrays (``visibility`` and ``transfer`` of shape
(receiver_count, order**2), ``ambient_occlusion`` of shape (receiver_count,)); the definitions,
the estimator and the frames are documented in :mod:`warpshade.transfer._raytrace` (``compute``
itself is :mod:`warpshade.transfer._bake`).
:class:`TransferTracer` is the per-frame, allocation-free form (device outputs, BVH refit).

``compute(..., bounces=k, albedo=None)`` adds ``transfer_rgb``, the transfer after k diffuse
bounces per RGB channel, shape (receiver_count, 3, order**2), world frame
(:mod:`warpshade.transfer._interreflection`; :class:`InterreflectionTracer` per frame).

Spherical signed distance functions of visibility (Wang et al. 2009, sec. 5):
:func:`bake_ssdf` (hemisphere visibility per vertex in its tangent frame, signed angular
distance to the nearest visibility boundary), :func:`compress_ssdf` (PCA to an error budget, an
:class:`SSDFModel`, :mod:`warpshade.transfer._ssdf_pca`) and the look-ups and SG products of
:mod:`warpshade.transfer._ssdf_products`.
"""

from ._bake import compute
from ._interreflection import MAX_BOUNCES, InterreflectionTracer
from ._raytrace import SPACES, TransferResult, TransferTracer, sample_rays
from ._ssdf import SSDF_LIMIT, bake_ssdf, bake_visibility, signed_distance, trace_lobe_visibility
from ._ssdf_pca import SSDFModel, compress_ssdf
from ._ssdf_products import evaluate_ssdf_warp, product_warp, sample_maps, ssdf_integral, ssdf_lookup, ssdf_product

__all__ = ["MAX_BOUNCES", "SPACES", "SSDF_LIMIT", "InterreflectionTracer", "SSDFModel", "TransferResult", "TransferTracer",
           "bake_ssdf", "bake_visibility", "compress_ssdf", "compute", "evaluate_ssdf_warp", "product_warp", "sample_maps",
           "sample_rays", "signed_distance", "ssdf_integral", "ssdf_lookup", "ssdf_product", "trace_lobe_visibility"]
