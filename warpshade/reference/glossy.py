"""Monte Carlo ground truth for glossy receivers: outgoing radiance towards a viewer.

For a receiver at ``p`` with unit normal ``n``, seen from ``eye`` (``v = normalize(eye - p)``)
and a BRDF ``b`` of :mod:`warpshade.scene.materials` (the same for every receiver), the
reference is::

    L_o(p, v) = c * integral b(v, s) L_i(s) V(s) max(0, n . s) ds

with ``c`` an RGB colour (the ``specular`` colour of the glossy stages), ``L_i`` the environment
plus analytic lights and ``V`` ray-traced visibility: the estimator of :mod:`.estimator` with
the uniform tint ``t = c``. ``L_o = 0`` where the viewer is below the receiver's horizon (also
for a Lambert BRDF, whose radiance is otherwise that of :func:`warpshade.reference.shade`).

Environment estimators: ``"brdf"`` samples the BRDF lobe (:func:`~warpshade.scene.materials_warp.brdf_sample`),
``"light"`` the environment's luminance distribution, ``"mis"`` one direction from each, combined
with the balance heuristic (two rays per sample point). Analytic lights: delta distant lights
are evaluated exactly (one shadow ray); disc distant lights and sphere lights are sampled
uniformly in the cone they subtend (estimate ``b L cos V Omega``); a receiver inside a sphere
light sees it everywhere (estimated by BRDF sampling, no rays). Randomised QMC replicates and
standard errors exactly as :func:`warpshade.reference.shade`.
"""

from __future__ import annotations

import numpy as np

from .estimator import MonteCarloShader, ShadingResult, _vec3, strategy_index

__all__ = ["GLOSSY_METHODS", "GlossyReferenceShader", "shade_glossy"]

#: Environment estimators: BRDF, light and MIS sampling, in the order of the kernel's ``method``.
GLOSSY_METHODS = ("brdf", "light", "mis")

_CALLER = "reference.shade_glossy"


class GlossyReferenceShader(MonteCarloShader):
    """Per-frame glossy reference shading (BVH refit in place, lighting and BRDF uploaded once).

    Args:
        scene: the :class:`~warpshade.scene.Scene`.
        brdf: a :class:`~warpshade.scene.materials.BRDF` applied to every receiver.
        eye: viewer position, 3 floats, world (default: the scene camera's position).
        lighting: lights (default ``scene.lights``); samples, method, seed, vertices, workers:
            as :class:`~warpshade.reference.ReferenceShader` (method: "brdf", "light", "mis").
        color: RGB factor of the result, 3 floats.

    Attributes:
        color: the RGB factor, wp.vec3; eye: the viewer, wp.vec3; and those of
            :class:`~warpshade.reference.estimator.MonteCarloShader`.
    """

    def __init__(self, scene, brdf, eye=None, lighting=None, samples: int = 256, method: str = "mis", color=(1.0, 1.0, 1.0),
                 device=None, seed: int = 0, vertices=None, workers=None):
        strategy_index(method, GLOSSY_METHODS, _CALLER)  # a bad method is reported before a missing camera
        if eye is None:
            if scene.camera is None:
                raise ValueError(f"{_CALLER}: scene {scene.source or '<arrays>'} has no camera; pass eye=")
            eye = scene.camera.position
        self.color = _vec3(color, "color", _CALLER)
        super().__init__(scene, brdf, np.asarray(self.color, np.float32), method, GLOSSY_METHODS, _CALLER, eye=eye,
                         lighting=lighting, samples=samples, device=device, seed=seed, vertices=vertices, workers=workers)


def shade_glossy(scene, frame, brdf, eye=None, lighting=None, samples: int = 256, color=(1.0, 1.0, 1.0), device=None,
                 method: str = "mis", seed: int = 0, vertices=None, workers=None) -> ShadingResult:
    """Ray-traced glossy radiance towards ``eye`` of every (or the selected) vertex at one frame.

    See the module docstring for the integral and the estimators; arguments as
    :class:`GlossyReferenceShader`. Returns a :class:`~warpshade.reference.ShadingResult`
    (``radiance`` and ``stderr``, shape (receiver_count, 3), float32, linear RGB).
    """
    return GlossyReferenceShader(scene, brdf, eye, lighting, samples, method, color, device, seed, vertices,
                                 workers).shade(frame)
