"""Float64 mirrors of the data-driven kernels and the paper's lighting-independent error."""

from __future__ import annotations

import numpy as np

from ...basis import quadrature, sh

__all__: list[str] = []


def transfer_f64(model, poses) -> np.ndarray:
    """The model's transfer at raw pose vectors (n, a) (or one (a,)), float64 (n, V, M): the
    mirror of :mod:`._kernels` (pose projection, maps, basis)."""
    return model.predict(np.atleast_2d(np.asarray(poses, np.float64)))


def hemisphere_transfer_error(generated, simulated, normals, directions: int = 2048) -> np.ndarray:
    """Per-vertex ``E = integral over the hemisphere about n of (T_g(w) - T_s(w))^2 dw`` (the
    paper's section 6), by quadrature on a spherical Fibonacci set (float64).

    Args:
        generated, simulated: SH transfer vectors (V, n*n) (world frame).
        normals: unit normals (V, 3).
        directions: quadrature points over the sphere.

    Returns:
        (V,) float64.
    """
    diff = np.asarray(generated, np.float64) - np.asarray(simulated, np.float64)
    order = int(round(np.sqrt(diff.shape[1])))
    q = quadrature.fibonacci(int(directions))
    y = sh.basis(q.directions, order)  # (S, C)
    values = diff @ y.T  # (V, S)
    upper = (np.asarray(normals, np.float64) @ q.directions.T) > 0.0
    return np.sum(values ** 2 * upper * q.weights[None, :], axis=1)
