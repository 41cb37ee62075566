"""The translucent thin-membrane model (Sloan et al. 2005, Sec. 4.2, eq. 22-23).

Transfer about the surface normal zeta: ``g(s) = s.zeta`` on the front and ``-alpha s.zeta``
behind (``alpha <= 1`` the translucency), a single lobe about the normal with convolution
coefficients::

    g*_l = A_l (1 + (-1)^l alpha),  A_l = pi, 2pi/3, pi/4, 0, -pi/24, ...  (clamped cosine)

i.e. eq. 23 times pi: this project's transfer is shaded as ``albedo / pi * dot(L, t)`` (the 1/pi
of eq. 23 is in the shading). ``alpha = 0`` is plain unshadowed diffuse transfer.

Per-vertex translucency: a constant, or from the local thickness of the mesh, ``alpha =
translucency * exp(-thickness / thickness_scale)`` with the thickness ray cast from each vertex
along ``-n`` at the bake frame (a ray that leaves the mesh -- an open sheet -- counts as thin).
"""

from __future__ import annotations

import numpy as np

from ...basis import sh
from ._model import LDPRTModel

__all__ = ["membrane_coefficients", "membrane_model", "thickness"]


def membrane_coefficients(translucency, order: int) -> np.ndarray:
    """``g*_l = A_l (1 + (-1)^l alpha)`` for translucency alpha (scalar or (V,)), shape (..., n)."""
    alpha = np.asarray(translucency, dtype=np.float64)
    if np.any(alpha < 0.0) or np.any(alpha > 1.0) or not np.all(np.isfinite(alpha)):
        raise ValueError("membrane: translucency must lie in [0, 1]")
    a = sh.clamped_cosine_zh(order, "convolution")
    sign = np.where(np.arange(order) % 2 == 0, 1.0, -1.0)
    return a * (1.0 + sign * alpha[..., None])


def membrane_model(translucency, order: int) -> LDPRTModel:
    """One lobe per vertex about the local normal (+z of the tangent frame), nothing stored."""
    alpha = np.atleast_1d(np.asarray(translucency, dtype=np.float64))
    count = alpha.shape[0]
    axes = np.zeros((count, 1, 3), np.float32)
    axes[:, 0, 2] = 1.0
    return LDPRTModel(axes=axes, coeffs=membrane_coefficients(alpha, order)[:, None, :].astype(np.float32),
                      counts=np.ones(count, np.int32), stored=np.zeros((count, 4), np.float32),
                      fit_error=np.zeros(count, np.float32), scale=1.0, total_error=0.0,
                      restarted=np.zeros(count, bool), seconds=0.0)


def thickness(scene, frame, device=None) -> np.ndarray:
    """Distance from each vertex along ``-n`` to the mesh (inf where the ray leaves it), (V,)."""
    from ...geometry._bvh import Visibility

    state = scene.evaluate(frame, device=device)
    bvh = Visibility.from_scene(scene, frame=frame, device=device)
    p = state.points.numpy().astype(np.float64)
    n = state.normals.numpy().astype(np.float64)
    hits = bvh.closest_hits(p - bvh.offset * n, -n)
    d = hits["distance"].astype(np.float64)
    return np.where(d >= 0.0, d + bvh.offset, np.inf)
