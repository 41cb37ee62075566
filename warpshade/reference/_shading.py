"""Monte Carlo ground truth: outgoing radiance of diffuse receivers under distant and area light.

For a receiver at ``p`` with unit normal ``n`` and albedo ``rho`` (per RGB channel) the
outgoing radiance (the same in every direction for a Lambertian surface) is::

    L_o = rho / pi * integral L_i(s) V(s) max(0, n . s) ds

and with ``bounces = k`` diffuse bounces of indirect light (every surface Lambertian with the
scene's per-vertex albedo, reflecting from its front faces only)::

    L^(0)(p) = the direct radiance above
    L^(b)(p) = L^(0)(p) + rho / pi * integral_{occluded s} L^(b-1)(q(s)) max(0, n . s) ds

with ``q(s)`` the closest hit toward ``s`` (a back face sends nothing) -- the radiance the
interreflected transfer of :mod:`warpshade.transfer._interreflection` reproduces. This is the
estimator of :mod:`._estimator` with the Lambert BRDF ``b = 1 / pi``, the per-vertex tint
``t = rho`` and no viewer; the bounces are paths with next-event estimation at every vertex
(described there). Estimators of the environment term (per sample point):

* ``"cosine"``: one direction from the cosine-weighted hemisphere of ``n`` -- the Lambert
  BRDF's lobe, so this is the BRDF-sampling strategy (``"brdf"`` of :mod:`._glossy`); estimate
  ``rho * L(s) V(s)`` (pdf ``cos / pi``). Exact (zero variance) under a constant, unoccluded sky.
* ``"light"``: one direction from the environment's luminance distribution (pdf ``p_env``);
  estimate ``rho / pi * L V max(0, n.s) / p_env``.
* ``"mis"``: one direction from each, combined with the balance heuristic
  (``f / (p_cos + p_env)`` for each), i.e. two rays per sample point.

Analytic lights: a delta :class:`~..scene.lighting.DistantLight` gives
``rho / pi * E max(0, n.l) V(l)`` (no variance); disc distant lights and
:class:`~..scene.lighting.SphereLight` s are sampled uniformly in the cone they subtend; a
receiver inside a sphere light gets ``rho * L_e`` unshadowed (by cosine sampling, whose
weight ``b cos / p_cos`` is 1). Sampling (randomised-QMC R2
replicates, :data:`REPLICATES` of them) and the reported standard error are described in
:mod:`._estimator`.
"""

from __future__ import annotations

from ..scene._materials import Lambert
from ._estimator import (
    ESTIMATOR_VERSION,
    REPLICATES,
    AnalyticLights,
    DeviceLighting,
    MonteCarloShader,
    ShadingResult,
    upload_lighting,
)

__all__: list[str] = []

#: Environment estimators: BRDF (cosine), light and MIS sampling, in the order of the kernel's ``method``.
METHODS = ("cosine", "light", "mis")


class ReferenceShader(MonteCarloShader):
    """Per-frame diffuse reference shading with an in-place BVH refit and uploaded lighting.

    Build once (scene, lighting, samples, method), then call :meth:`shade` (a time code) or
    :meth:`shade_state` (device points and normals) every frame; :meth:`shade_points` shades
    arbitrary receivers such as camera hit points against the current BVH (its ``tint``
    argument is their albedo).

    Args:
        scene: :class:`~warpshade.scene.Scene`; albedo is ``scene.albedo``.
        lighting, samples, device, seed, vertices, workers, bounces: as :func:`shade`.
        method: "cosine", "light" or "mis".
        offset: shadow-ray origin offset along the normal, world units (default: the BVH's).

    Attributes:
        bvh: :class:`~warpshade.geometry._bvh.Visibility` of the scene (refit per frame).
        lighting: :class:`DeviceLighting`.
        albedo: per-vertex albedo, wp.array(vec3), shape (vertex_count,).
        radiance, stderr: per-vertex outputs, wp.array(vec3), shape (receiver_count,).
    """

    def __init__(self, scene, lighting=None, samples: int = 256, method: str = "mis", device=None, seed: int = 0,
                 vertices=None, workers=None, offset=None, bounces: int = 0):
        super().__init__(scene, Lambert(1.0), scene.albedo, method, METHODS, "reference.shade", eye=None,
                         lighting=lighting, samples=samples, device=device, seed=seed, vertices=vertices,
                         workers=workers, offset=offset, bounces=bounces)
        self.albedo = self.tint


def shade(scene, frame, lighting=None, samples: int = 256, device=None, method: str = "mis", seed: int = 0, vertices=None, workers=None,
          bounces: int = 0) -> ShadingResult:
    """Ray-traced ground-truth radiance of every (or the selected) vertex at one frame.

    Args:
        scene: :class:`~warpshade.scene.Scene`; albedo is ``scene.albedo``.
        frame: time code (one of ``scene.frames``).
        lighting: a list of lights (at most one :class:`Environment`, any number of
            :class:`DistantLight` / :class:`SphereLight`), a single light, or None for ``scene.lights``.
        samples: environment rays per receiver (see module docstring), >= 2 (>= 4 for "mis").
        device: Warp device (None = Warp's default).
        method: "cosine", "light" (environment importance sampling) or "mis".
        seed: random seed.
        vertices: receiver vertex indices (default every vertex).
        workers: CPU launch threads (default: every core on the CPU device).
        bounces: diffuse bounces of indirect light, 0..MAX_BOUNCES (module docstring); 0 is
            the direct light only, bit-identical to the reference without bounces.

    Returns:
        :class:`ShadingResult`: ``radiance`` and ``stderr``, shape (receiver_count, 3), float32,
        linear RGB; ``numpy.asarray(result)`` is the radiance.
    """
    return ReferenceShader(scene, lighting, samples, method, device, seed, vertices, workers, bounces=bounces).shade(frame)
