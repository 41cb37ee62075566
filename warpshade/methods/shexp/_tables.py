"""Host-side tables of SHEXP shading (float64, cached per order).

* :func:`sphere_light_lobes` -- analytic spherical lights (Ren et al. 2006, sec. 7): the
  2-parameter family ``L_H(theta, phi) = H(z) * L(theta, phi)`` (SH product of the clamped
  cosine about the normal +z and a uniform cap light of angular radius theta whose centre is at
  angle phi from the normal, in the xz-plane) fitted per (theta, phi) with a single ZH lobe:
  an axis in the xz-plane at angle psi from +z and per-band coefficients ``z_l``, chosen to
  minimise ``||L_H - zh_to_sh(axis(psi), z)||``. For a fixed axis the best ``z`` is the
  orthogonal projection onto the zonal functions about it (:func:`sh.zh_from_sh_about_axis`),
  so only psi is searched (dense grid, then bounded Brent refinement). At run time the lobe is
  rotated into place with the ZH rule, the same rule that rotates blocker logs.
* :func:`window_alpha` -- per-band window weights (or ones).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ...basis import sh

__all__ = ["SphereLightLobes", "sphere_light_lobes", "window_alpha", "LOBE_THETA_SAMPLES", "LOBE_PHI_SAMPLES"]

#: Table resolution over the light's angular radius theta in [0, pi/2] and its angle phi from
#: the normal in [0, pi]: 1.4 and 1.4 degrees per step.
LOBE_THETA_SAMPLES = 65
LOBE_PHI_SAMPLES = 129
#: Candidate lobe angles of the coarse search (1 degree apart, then refined).
_PSI_GRID = 181


@dataclass(frozen=True)
class SphereLightLobes:
    """Single-ZH-lobe fit of ``L_H(theta, phi)`` (see module docstring).

    Attributes:
        order: SH order n.
        theta: light angular radii, (T,), radians, uniform over [0, pi/2].
        phi: angle of the light's centre from the normal, (P,), radians, uniform over [0, pi].
        axis_angle: fitted lobe axis angle psi from the normal towards the light, (T, P).
        zh: fitted ZH coefficients, (T, P, n).
        relative_residual: ``||L_H - fit|| / ||L_H||`` per entry, (T, P) (0 where L_H = 0).
    """

    order: int
    theta: np.ndarray
    phi: np.ndarray
    axis_angle: np.ndarray
    zh: np.ndarray
    relative_residual: np.ndarray


def _lh(order: int, theta, phi) -> np.ndarray:
    """``H(z) * L(theta, phi)`` for broadcast theta, phi, shape (..., n*n)."""
    theta, phi = np.broadcast_arrays(np.asarray(theta, np.float64), np.asarray(phi, np.float64))
    d = np.stack([np.sin(phi), np.zeros_like(phi), np.cos(phi)], axis=-1)
    light = sh.zh_to_sh(d, sh.cap_zh(theta, order))
    h = sh.zh_to_sh(np.array([0.0, 0.0, 1.0]), sh.clamped_cosine_zh(order, "zh"))
    return sh.product(light, h)


def _axes(psi) -> np.ndarray:
    psi = np.asarray(psi, np.float64)
    return np.stack([np.sin(psi), np.zeros_like(psi), np.cos(psi)], axis=-1)


def _energy(lh: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """``sum_l z_l^2`` of the projection of each lh row onto the zonal functions about psi."""
    return (sh.zh_from_sh_about_axis(lh, _axes(psi)) ** 2).sum(axis=-1)


#: Golden-section iterations refining psi inside one coarse grid step (pi/180 * 0.618^40 ~ 1e-10).
_GOLDEN_ITERATIONS = 40


@functools.lru_cache(maxsize=None)
def sphere_light_lobes(order: int, theta_samples: int = LOBE_THETA_SAMPLES, phi_samples: int = LOBE_PHI_SAMPLES) -> SphereLightLobes:
    """Fit the single-lobe table of one order (built once per process, vectorised over phi).

    psi maximises the projected energy ``sum_l z_l(psi)^2`` (equivalently minimises the
    residual): a coarse search on a 1-degree grid over [0, pi], then golden-section refinement
    inside the bracketing grid steps.
    """
    thetas = np.linspace(0.0, 0.5 * np.pi, theta_samples)
    phis = np.linspace(0.0, np.pi, phi_samples)
    psi_grid = np.linspace(0.0, np.pi, _PSI_GRID)
    step = psi_grid[1] - psi_grid[0]
    axis_angle = np.zeros((theta_samples, phi_samples))
    zh = np.zeros((theta_samples, phi_samples, order))
    residual = np.zeros((theta_samples, phi_samples))
    for i, theta in enumerate(thetas):
        lh = _lh(order, theta, phis)  # (P, n*n)
        total = np.einsum("pi,pi->p", lh, lh)
        energy = _energy(lh[:, None, :], psi_grid[None, :])  # (P, G)
        k = np.argmax(energy, axis=1)
        lo = np.maximum(psi_grid[k] - step, 0.0)
        hi = np.minimum(psi_grid[k] + step, np.pi)
        ratio = 0.5 * (np.sqrt(5.0) - 1.0)
        a = hi - ratio * (hi - lo)
        b = lo + ratio * (hi - lo)
        ea, eb = _energy(lh, a), _energy(lh, b)
        for _ in range(_GOLDEN_ITERATIONS):
            left = ea > eb  # maximum in [lo, b]
            hi = np.where(left, b, hi)
            lo = np.where(left, lo, a)
            a_new = hi - ratio * (hi - lo)
            b_new = lo + ratio * (hi - lo)
            a, b = a_new, b_new
            ea, eb = _energy(lh, a), _energy(lh, b)
        psi = 0.5 * (lo + hi)
        best_grid = psi_grid[k]
        psi = np.where(_energy(lh, psi) >= energy[np.arange(len(k)), k], psi, best_grid)
        psi = np.where(total > 1e-30, psi, phis)
        z = sh.zh_from_sh_about_axis(lh, _axes(psi))
        fit = sh.zh_to_sh(_axes(psi), z)
        axis_angle[i] = psi
        zh[i] = z
        residual[i] = np.where(total > 1e-30, np.linalg.norm(lh - fit, axis=1) / np.sqrt(np.maximum(total, 1e-300)), 0.0)
    for arr in (thetas, phis, axis_angle, zh, residual):
        arr.setflags(write=False)
    return SphereLightLobes(order, thetas, phis, axis_angle, zh, residual)


def window_alpha(order: int, kind: str | None, size: float | None = None) -> np.ndarray:
    """Per-band window weights alpha_l (float32, (n,)); all ones when ``kind`` is None."""
    if kind is None:
        return np.ones(order, np.float32)
    return sh.window_weights(kind, order, size=size).astype(np.float32)
