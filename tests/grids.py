"""Small mesh builders shared by the tests."""

import numpy as np


def ground_grid(coords):
    """A z = 0 grid over ``coords`` × ``coords``: (points (N,3), triangles (T,3)), two per cell."""
    gx, gy = np.meshgrid(coords, coords, indexing="ij")
    points = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    idx = np.arange(gx.size).reshape(gx.shape)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return points, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


#: A closed unit-ish cube (+-1) as a one-prim USD stage, Z up: the smallest scene a run can load.
CUBE_USDA = """\
#usda 1.0
(
    upAxis = "Z"
)
def Mesh "Cube"
{
    int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
    int[] faceVertexIndices = [0, 1, 3, 2, 2, 3, 7, 6, 6, 7, 5, 4, 4, 5, 1, 0, 2, 6, 4, 0, 7, 3, 1, 5]
    point3f[] points = [(-1, -1, -1), (1, -1, -1), (-1, 1, -1), (1, 1, -1), (-1, -1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, 1)]
}
"""
