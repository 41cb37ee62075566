"""SG lighting (Wang et al. 2009, sec. 6), local lights as single SG lobes (float64). The kernels'
mirror is in :mod:`._lighting_warp`.

**Local lights** (eq. 32-33): :func:`point_light_lobe` (sphere lights) and
:func:`directional_light_lobe`, normalised so that a lobe integrates to the light's radiance times
its solid angle (the ray-traced reference's emission); :func:`inside_hull` detects a point light
inside an object's convex hull (precomputed visibility covers distant light only).
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ...basis import sg
from ...scene._lighting import DistantLight, SphereLight

__all__ = [
    "MIN_DISTANT_ANGLE_DEG",
    "directional_light_lobe",
    "inside_hull",
]

#: Angular diameter (degrees) a DistantLight of ``angle_deg`` below it is given: a delta light has
#: no finite SG. 0.53 deg is the sun's (and DistantLight's default); its sharpness ~1.2e5 keeps the
#: float32 exponent of an SG product within 1e-2 (lambda * float32 epsilon).
MIN_DISTANT_ANGLE_DEG = 0.53




def point_light_lobe(light: SphereLight, x, return_inside: bool = False):
    """The SG of a sphere light seen from receivers ``x`` (eq. 32), float64.

    Axis: unit vector from ``x`` to the centre (world). Sharpness ``f_a^-1(2 pi r^2 / d^2)``
    (eq. 3 inverse, epsilon 0.1). Amplitude (RGB): ``radiance * Omega / integral(G)`` with
    ``Omega = 2 pi (1 - cos alpha)``, ``sin alpha = r / d``, the sphere's solid angle, so that the
    lobe carries the sphere's emission as the ray-traced reference integrates it. A receiver
    inside the sphere (``d <= r``) sees the light in every direction: it gets the constant lobe
    (sharpness 0, amplitude ``radiance``, integral ``4 pi radiance``, exact), and a
    ``RuntimeWarning`` says how many receivers are inside.

    Args:
        light: the sphere light (world frame).
        x: receiver positions (N, 3), world frame.
        return_inside: also return the (N,) bool mask of receivers inside the sphere.

    Returns:
        ``(axis (N, 3), sharpness (N,), amplitude (N, 3))`` float64 [, ``inside (N,)``].
    """
    if not isinstance(light, SphereLight):
        raise ValueError(f"point_light_lobe: light must be a SphereLight, got {type(light).__name__}")
    x = np.asarray(x, np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or not np.all(np.isfinite(x)):
        raise ValueError(f"point_light_lobe: x must be finite (N, 3) positions, got shape {x.shape}")
    offset = light.position[None] - x
    d = np.linalg.norm(offset, axis=1)
    inside = d <= light.radius
    axis = np.where(d[:, None] > 1e-300, offset / np.maximum(d, 1e-300)[:, None], np.array([0.0, 0.0, 1.0]))
    sin2 = np.where(inside, 1.0, (light.radius / np.where(inside, 1.0, d)) ** 2)
    solid = 2.0 * math.pi * sin2 / (1.0 + np.sqrt(np.maximum(0.0, 1.0 - sin2)))
    lam = np.where(inside, 0.0, sg.sharpness_for_area(2.0 * math.pi * sin2))
    amp = np.where(inside[:, None], light.radiance[None], light.radiance[None] * (solid / sg.integral(lam))[:, None])
    if inside.any():
        warnings.warn(f"point_light_lobe: {int(inside.sum())} of {x.shape[0]} receivers are inside sphere light "
                      f"{light.path or '<array>'} (radius {light.radius}); they get its radiance from every direction",
                      RuntimeWarning, stacklevel=2)
    return (axis, lam, amp, inside) if return_inside else (axis, lam, amp)


def directional_light_lobe(light: DistantLight):
    """The SG of a distant light (eq. 33), float64.

    Sharpness ``f_a^-1(2 pi r^2)`` with ``r`` the angular radius in radians (half of
    ``angle_deg``, raised to half of :data:`MIN_DISTANT_ANGLE_DEG` for narrower and delta
    lights); amplitude ``irradiance / integral(G)`` so that the lobe integrates to the light's
    irradiance (its radiance times its solid angle).

    Returns:
        ``(axis (3,), sharpness float, amplitude (3,))``, axis towards the light, world frame.
    """
    if not isinstance(light, DistantLight):
        raise ValueError(f"directional_light_lobe: light must be a DistantLight, got {type(light).__name__}")
    if not np.isfinite(light.angle_deg) or light.angle_deg < 0.0 or light.angle_deg >= 180.0:
        raise ValueError(f"directional_light_lobe: angle_deg must be in [0, 180), got {light.angle_deg!r}")
    if not np.all(np.isfinite(light.irradiance)) or not np.all(np.isfinite(light.direction)):
        raise ValueError("directional_light_lobe: direction and irradiance must be finite")
    radius = math.radians(max(float(light.angle_deg), MIN_DISTANT_ANGLE_DEG)) / 2.0
    lam = float(sg.sharpness_for_area(2.0 * math.pi * radius * radius))
    return light.direction.copy(), lam, light.irradiance / float(sg.integral(lam))


def inside_hull(points_of_mesh, light_position):
    """Whether point lights lie inside the convex hull of a mesh's points (then precomputed
    visibility, which describes distant light, does not apply; sec. 7).

    The hull is triangulated once (over its own vertices) for all the positions asked about, so
    a light's whole path over a clip costs one triangulation.

    Args:
        points_of_mesh: (M, 3) world positions.
        light_position: (3,) world position, or (K, 3) positions.

    Returns:
        For one position, True when inside (or on) the hull; for (K, 3), a (K,) bool array. False
        for a flat or degenerate point set (no volume).
    """
    from scipy.spatial import ConvexHull, Delaunay, QhullError

    pts = np.asarray(points_of_mesh, np.float64)
    q = np.asarray(light_position, np.float64)
    one = q.ndim == 1
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.all(np.isfinite(pts)):
        raise ValueError(f"inside_hull: points_of_mesh must be finite (M, 3), got shape {pts.shape}")
    if q.shape[-1:] != (3,) or q.ndim > 2 or not np.all(np.isfinite(q)):
        raise ValueError(f"inside_hull: light_position must be finite (3,) or (K, 3) points, got {light_position!r}")
    q = q.reshape(-1, 3)
    inside = np.zeros(len(q), bool)
    if pts.shape[0] >= 4:
        try:
            tri = Delaunay(pts[ConvexHull(pts).vertices])
            inside = tri.find_simplex(q) >= 0
        except QhullError:
            pass
    return bool(inside[0]) if one else inside
