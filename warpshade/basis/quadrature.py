"""Quadrature sample sets on the unit sphere.

Every sample set is a :class:`SphereSamples`: unit directions (N, 3) float64 and weights (N,)
float64 whose sum is 4*pi, so that ``sum(w * f(d))`` approximates ``integral f(s) ds`` over the
sphere. Three families are provided:

* :func:`fibonacci` -- spherical Fibonacci points with equal weights (low discrepancy; the
  default for Monte Carlo style estimates, optionally randomly rotated per receiver);
* :func:`gauss_legendre` -- Gauss-Legendre nodes in ``z = cos(theta)`` times uniform ``phi``:
  integrates every spherical polynomial up to a stated total degree exactly (to rounding), which
  makes it the oracle for SH orthonormality, triple products and projections;
* :func:`latlong` -- the pixel centres of an equirectangular (lat-long) image with their exact
  solid angles, used to project environment maps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "SphereSamples",
    "fibonacci",
    "gauss_legendre",
    "latlong",
    "latlong_directions",
    "random_rotations",
]


@dataclass(frozen=True)
class SphereSamples:
    """A quadrature rule on the unit sphere.

    Attributes:
        directions: unit vectors, shape (N, 3), float64.
        weights: quadrature weights in steradians, shape (N,), float64; they sum to 4*pi.
    """

    directions: np.ndarray
    weights: np.ndarray

    def __len__(self) -> int:
        return int(self.directions.shape[0])

    def integrate(self, values: np.ndarray) -> np.ndarray:
        """Integrate sampled values over the sphere.

        Args:
            values: samples of the integrand, shape (N, ...) matching ``directions``.

        Returns:
            ``sum_i w_i * values[i]`` with the trailing shape of ``values``.
        """
        return np.tensordot(self.weights, np.asarray(values), axes=(0, 0))


def fibonacci(count: int) -> SphereSamples:
    """Spherical Fibonacci points with equal weights ``4*pi/count``.

    Args:
        count: number of points (>= 1).

    Returns:
        :class:`SphereSamples` with nearly uniform, low-discrepancy directions.
    """
    if count < 1:
        raise ValueError(f"fibonacci: count must be >= 1, got {count}")
    i = np.arange(count, dtype=np.float64)
    golden = (1.0 + 5.0**0.5) / 2.0
    z = 1.0 - (2.0 * i + 1.0) / count
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = 2.0 * np.pi * np.mod(i / golden, 1.0)
    dirs = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
    return SphereSamples(dirs, np.full(count, 4.0 * np.pi / count))


def gauss_legendre(degree: int) -> SphereSamples:
    """Product rule exact for spherical polynomials of total degree <= ``degree``.

    Uses ``degree // 2 + 1`` Gauss-Legendre nodes in ``z = cos(theta)`` and ``degree + 1``
    equally spaced azimuths. A product of three SH of bands < n has degree 3(n - 1), so
    ``gauss_legendre(3 * (n - 1))`` integrates triple products of order-n SH exactly.

    Args:
        degree: highest total polynomial degree to integrate exactly (>= 0).

    Returns:
        :class:`SphereSamples` with ``(degree // 2 + 1) * (degree + 1)`` points.
    """
    if degree < 0:
        raise ValueError(f"gauss_legendre: degree must be >= 0, got {degree}")
    n_theta = degree // 2 + 1
    n_phi = degree + 1
    z, wz = np.polynomial.legendre.leggauss(n_theta)
    phi = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    zz, pp = np.meshgrid(z, phi, indexing="ij")
    r = np.sqrt(np.maximum(0.0, 1.0 - zz * zz))
    dirs = np.stack([r * np.cos(pp), r * np.sin(pp), zz], axis=-1).reshape(-1, 3)
    weights = np.repeat(wz * (2.0 * np.pi / n_phi), n_phi)
    return SphereSamples(dirs, weights)


def latlong_directions(height: int, width: int) -> np.ndarray:
    """Pixel-centre directions of an equirectangular image, shape (height, width, 3).

    Convention (z-up, the same as :func:`latlong`): row 0 is the +z pole, ``theta`` runs from 0
    at the top row to pi at the bottom; column ``j`` has azimuth ``phi = 2*pi*(j + 0.5)/width``
    measured from +x towards +y. Scene code that uses another up axis rotates the result.
    """
    theta = (np.arange(height) + 0.5) * (np.pi / height)
    phi = (np.arange(width) + 0.5) * (2.0 * np.pi / width)
    st = np.sin(theta)[:, None]
    return np.stack(
        [st * np.cos(phi)[None, :], st * np.sin(phi)[None, :], np.broadcast_to(np.cos(theta)[:, None], (height, width))],
        axis=-1,
    )


def latlong(height: int, width: int) -> SphereSamples:
    """Pixel centres of a ``height`` x ``width`` lat-long image with exact pixel solid angles.

    The weight of a pixel in row ``i`` is ``(cos(theta_i0) - cos(theta_i1)) * 2*pi/width``, the
    exact solid angle of the pixel, so the weights sum to 4*pi. Directions are flattened in row
    major order, matching ``image.reshape(-1, channels)``.
    """
    if height < 1 or width < 1:
        raise ValueError(f"latlong: image size must be positive, got {height}x{width}")
    edges = np.cos(np.arange(height + 1) * (np.pi / height))
    row_w = (edges[:-1] - edges[1:]) * (2.0 * np.pi / width)
    dirs = latlong_directions(height, width).reshape(-1, 3)
    return SphereSamples(dirs, np.repeat(row_w, width))


def random_rotations(count: int, seed: int = 0) -> np.ndarray:
    """Uniformly distributed random rotation matrices, shape (count, 3, 3), float64.

    Used to decorrelate one spherical point set across receivers (a per-receiver random
    rotation of a Fibonacci set gives stratified, unbiased estimates).
    """
    from scipy.spatial.transform import Rotation

    return Rotation.random(count, random_state=np.random.default_rng(seed)).as_matrix()
