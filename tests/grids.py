"""Small mesh builders shared by the tests."""

import numpy as np


def ground_grid(coords):
    """A z = 0 grid over ``coords`` × ``coords``: (points (N,3), triangles (T,3)), two per cell."""
    gx, gy = np.meshgrid(coords, coords, indexing="ij")
    points = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    idx = np.arange(gx.size).reshape(gx.shape)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return points, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
