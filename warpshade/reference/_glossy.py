"""Monte Carlo ground truth for glossy receivers: outgoing radiance towards a viewer.

For a receiver at ``p`` with unit normal ``n``, seen from ``eye`` (``v = normalize(eye - p)``)
and a BRDF ``b`` of :mod:`warpshade.scene._materials` or a tabulated one
(:class:`~warpshade.scene._tabulated.TabulatedBRDF`; the same for every receiver), the
reference is::

    L_o(p, v) = c * integral b(v, s) L_i(s) V(s) max(0, n . s) ds

with ``c`` an RGB colour (the ``specular`` colour of the glossy stages), ``L_i`` the environment
plus analytic lights and ``V`` ray-traced visibility: the estimator of :mod:`._estimator` with
the tint ``t = c``. A colour table (``channel = "rgb"``) has its own ``b`` per channel: channel
``k`` of ``L_o`` is ``c_k`` times the integral with table channel ``k`` (one estimator pass per
channel, as ``rpo.shade`` shades one set of operators per channel). A spatially varying material gives ``c`` per vertex (``color`` of shape
(vertex_count, 3)) and a microfacet BRDF's roughness per vertex (``roughness``, shape
(vertex_count,)); per-pixel receivers (camera hits) are :mod:`._pixels`'. ``L_o = 0`` where the viewer is below the receiver's horizon (also
for a Lambert BRDF, whose radiance is otherwise that of :func:`warpshade.reference.shade`).

Environment estimators: ``"brdf"`` samples the BRDF lobe (:func:`~warpshade.scene._materials_warp.brdf_sample`),
``"light"`` the environment's luminance distribution, ``"mis"`` one direction from each, combined
with the balance heuristic (two rays per sample point). Analytic lights: delta distant lights
are evaluated exactly (one shadow ray); disc distant lights and sphere lights are sampled
uniformly in the cone they subtend (estimate ``b L cos V Omega``); a receiver inside a sphere
light sees it everywhere (estimated by BRDF sampling, no rays). Randomised QMC replicates and
standard errors exactly as :func:`warpshade.reference.shade`.
"""

from __future__ import annotations

import numpy as np

from .._wp import wp
from ._estimator import MonteCarloShader, ShadingResult, _vec3, strategy_index

__all__: list[str] = []

#: Environment estimators: BRDF, light and MIS sampling, in the order of the kernel's ``method``.
GLOSSY_METHODS = ("brdf", "light", "mis")

_CALLER = "reference.shade_glossy"


class GlossyReferenceShader(MonteCarloShader):
    """Per-frame glossy reference shading (BVH refit in place, lighting and BRDF uploaded once).

    Args:
        scene: the :class:`~warpshade.scene.Scene`.
        brdf: a :class:`~warpshade.scene._materials.BRDF` applied to every receiver.
        eye: viewer position, 3 floats, world (default: the scene camera's position).
        lighting: lights (default ``scene.lights``); samples, method, seed, vertices, workers:
            as :class:`~warpshade.reference.ReferenceShader` (method: "brdf", "light", "mis").
        color: RGB factor of the result: 3 floats, or one RGB row per vertex, shape
            (vertex_count, 3), finite and >= 0 (a specular colour texture sampled at the vertices).
        roughness: per-vertex microfacet alpha overriding ``brdf.roughness`` (GGX / Beckmann),
            shape (vertex_count,), in (0, 2]; None (default): ``brdf``'s own everywhere.
        tangents: the tangent direction of an anisotropic BRDF (``ward``, ``ashikhmin-shirley``,
            ``beckmann-anisotropic``): ``"uv"``, one world direction or one per vertex
            (:class:`~warpshade.reference._estimator.MonteCarloShader`).

    Attributes:
        color: the RGB factor, wp.vec3 (None when it is given per vertex: see ``tint``); eye:
            the viewer, wp.vec3; and those of :class:`~warpshade.reference._estimator.MonteCarloShader`.

    Raises:
        ValueError: naming the parameter: a bad ``color`` or ``roughness`` shape or value, a
            roughness for a BRDF without one, a bad method, or no ``eye`` and no scene camera.
    """

    def __init__(self, scene, brdf, eye=None, lighting=None, samples: int = 256, method: str = "mis", color=(1.0, 1.0, 1.0),
                 device=None, seed: int = 0, vertices=None, workers=None, roughness=None, tangents=None):
        strategy_index(method, GLOSSY_METHODS, _CALLER)  # a bad method is reported before a missing camera
        if eye is None:
            if scene.camera is None:
                raise ValueError(f"{_CALLER}: scene {scene.source or '<arrays>'} has no camera; pass eye=")
            eye = scene.camera.position
        rows = _color_rows(color, scene.vertex_count)
        self.color = rows if isinstance(rows, wp.vec3) else None
        tint = np.asarray(rows, np.float32)
        super().__init__(scene, brdf, tint, method, GLOSSY_METHODS, _CALLER, eye=eye, lighting=lighting, samples=samples,
                         device=device, seed=seed, vertices=vertices, workers=workers, roughness=roughness,
                         tangents=tangents)


def _color_rows(color, vertex_count: int):
    """``color`` as a uniform wp.vec3 (3 numbers) or per-vertex rows (vertex_count, 3) float32,
    finite and >= 0; ValueError naming ``color`` otherwise."""
    arr = np.asarray(color, dtype=np.float64)
    if arr.ndim < 2 or arr.shape[0] == 1:
        return _vec3(color, "color", _CALLER)
    if arr.shape != (vertex_count, 3):
        raise ValueError(f"{_CALLER}: color must be 3 floats or have shape ({vertex_count}, 3), got shape {arr.shape}")
    if not np.all(np.isfinite(arr) & (arr >= 0.0)):
        raise ValueError(f"{_CALLER}: per-vertex color must be finite and >= 0")
    return arr.astype(np.float32)


def shade_glossy(scene, frame, brdf, eye=None, lighting=None, samples: int = 256, color=(1.0, 1.0, 1.0), device=None,
                 method: str = "mis", seed: int = 0, vertices=None, workers=None, roughness=None,
                 tangents=None) -> ShadingResult:
    """Ray-traced glossy radiance towards ``eye`` of every (or the selected) vertex at one frame.

    See the module docstring for the integral and the estimators; arguments as
    :class:`GlossyReferenceShader` (``color`` and ``roughness`` may be per vertex). Returns a
    :class:`~warpshade.reference.ShadingResult` (``radiance`` and ``stderr``, shape
    (receiver_count, 3), float32, linear RGB).
    """
    return GlossyReferenceShader(scene, brdf, eye, lighting, samples, method, color, device, seed, vertices,
                                 workers, roughness, tangents).shade(frame)
