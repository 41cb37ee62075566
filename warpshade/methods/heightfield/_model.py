"""The height field's set-up: the grid it runs on and the tables built once per set-up.

A height field has no precomputed artifact that outlives a run: what its stages build at set-up
is the checked grid layout (:class:`GridLayout`, :func:`grid_layout`), the max pyramid's levels
and the horizon march (:func:`pyramid_levels`, :func:`march_plan`), the canonical SH wedge table
(:func:`wedge_table`) and, per BRDF, the ``F(wo)`` table over the view's elevation
(:func:`view_table`). Float64 NumPy; the kernels read them as float32.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...basis import sh

__all__ = [
    "GRID_TOLERANCE",
    "WEDGE_ENTRIES",
    "WEDGE_NODES",
]

#: Entries of the canonical wedge table over z0 = sin(horizon elevation) in [-1, 1].
WEDGE_ENTRIES = 257
#: Gauss-Legendre nodes in cos(theta) of the wedge table.
WEDGE_NODES = 64
#: Relative tolerance of the regular-grid check (of the grid spacing).
GRID_TOLERANCE = 1e-3


@dataclass(frozen=True)
class GridLayout:
    """A regular height-field grid: vertex ``r * size + c`` at ``(x0 + c dx, y0 + r dy)``."""

    size: int
    x0: float
    y0: float
    dx: float
    dy: float


def grid_layout(scene, where: str = "height field") -> GridLayout:
    """Check that the scene is one regular G x G grid whose vertices only move along z.

    Raises:
        ValueError: naming ``where`` and what is wrong.
    """
    v = scene.vertex_count
    g = int(round(math.sqrt(v)))
    if g * g != v or g < 2:
        raise ValueError(f"{where}: needs a regular G x G height-field grid; the scene has {v} vertices, not a square count")
    if scene.up_axis != "Z":
        raise ValueError(f"{where}: height fields are Z-up; the scene is {scene.up_axis}-up")
    for mesh in scene.meshes:
        if mesh.animation in ("skinned",) or (mesh.animation == "rigid" and mesh.transforms.shape[0] > 1):
            raise ValueError(f"{where}: mesh {mesh.path} moves as a whole ({mesh.animation}); a height field only moves "
                             "its heights")
    p = scene.points_at(scene.frames[0])
    x0, y0 = p[0, 0], p[0, 1]
    dx = (p[g - 1, 0] - x0) / (g - 1)
    dy = (p[(g - 1) * g, 1] - y0) / (g - 1)
    if not (dx > 0 and dy > 0):
        raise ValueError(f"{where}: the grid must be row-major with columns along +x and rows along +y "
                         f"(vertex r * G + c at (x0 + c dx, y0 + r dy)); got spacings dx = {dx:g}, dy = {dy:g}")
    r, c = np.divmod(np.arange(v), g)
    tol = GRID_TOLERANCE * min(dx, dy)
    ex = np.abs(p[:, 0] - (x0 + c * dx)).max()
    ey = np.abs(p[:, 1] - (y0 + r * dy)).max()
    if ex > tol or ey > tol:
        raise ValueError(f"{where}: the vertices are not a regular {g} x {g} grid (row-major, x along columns, y along "
                         f"rows): off by up to {max(ex, ey):.3g} (tolerance {tol:.3g})")
    for mesh in scene.meshes:
        if mesh.animation == "deforming":
            xy = np.asarray(mesh.point_samples[:, :, :2], np.float64)
            drift = float(np.abs(xy - xy[:1]).max())
            if drift > tol:
                raise ValueError(f"{where}: mesh {mesh.path} moves its vertices sideways by up to {drift:.3g} over the "
                                 "frames; a height field only moves them along z")
    return GridLayout(g, float(x0), float(y0), float(dx), float(dy))


def pyramid_levels(size: int) -> list[int]:
    """Side length of each max-pyramid level: G, ceil(G / 2), ... down to 1."""
    sizes = [int(size)]
    while sizes[-1] > 1:
        sizes.append((sizes[-1] + 1) // 2)
    return sizes


def march_plan(layout: GridLayout, samples_per_octave: int, footprint: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Distances (world units) and pyramid levels of the horizon march, (J,) float64 and int32.

    ``d_j = s 2^(j / q)`` (s the smaller grid spacing) up to the grid's diagonal; sample j reads
    the finest level whose cell side ``2^k s`` is at least ``footprint (d_{j+1} - d_j)``: with
    ``footprint = 1`` consecutive cells meet (conservative: no blocker is skipped, but the cell's
    maximum over its whole side, across the march too, raises the horizon); smaller footprints
    read finer cells (less bias, gaps between the samples).
    """
    q = int(samples_per_octave)
    s = min(layout.dx, layout.dy)
    diag = math.hypot(layout.dx, layout.dy) * (layout.size - 1)
    count = int(math.ceil(q * math.log2(max(diag / s, 1.0)))) + 1
    j = np.arange(count, dtype=np.float64)
    d = s * 2.0 ** (j / q)
    gap = float(footprint) * d * (2.0 ** (1.0 / q) - 1.0) / s
    top = len(pyramid_levels(layout.size)) - 1
    levels = np.clip(np.ceil(np.log2(np.maximum(gap, 1.0)) - 1e-9), 0, top).astype(np.int32)
    return d, levels


def wedge_table(order: int, azimuths: int, entries: int = WEDGE_ENTRIES, nodes: int = WEDGE_NODES) -> np.ndarray:
    """SH of the canonical wedge ``|phi| <= pi / A``, open above ``z > z0``, for ``z0`` on
    ``linspace(-1, 1, entries)``: (entries, n*n) float64.

    The azimuthal integral is closed form (``int cos(m phi) = 2 sin(m pi / A) / m``; the sine
    terms vanish by symmetry), the polar one Gauss-Legendre over ``[z0, 1]`` with ``nodes``.
    """
    n = int(order)
    half = math.pi / int(azimuths)
    z0 = np.linspace(-1.0, 1.0, int(entries))
    x, w = np.polynomial.legendre.leggauss(int(nodes))
    z = z0[:, None] + (1.0 - z0[:, None]) * 0.5 * (x[None] + 1.0)  # (E, Q)
    wz = 0.5 * (1.0 - z0[:, None]) * w[None]
    dirs = np.stack([np.sqrt(np.maximum(1.0 - z * z, 0.0)), np.zeros_like(z), z], -1)
    y = sh.basis(dirs.reshape(-1, 3), n).reshape(z.shape + (n * n,))  # at phi = 0: the cos(m phi) parts
    phi_int = np.zeros(n * n)
    for l in range(n):
        for m in range(-l, l + 1):
            if m == 0:
                phi_int[l * l + l] = 2.0 * half
            elif m > 0:
                phi_int[l * l + l + m] = 2.0 * math.sin(m * half) / m
    return np.einsum("eq,eqi->ei", wz, y) * phi_int[None]


def rotated_wedge_tables(table: np.ndarray, azimuths: int) -> tuple[np.ndarray, np.ndarray]:
    """The canonical wedge table z-rotated to every azimuth ``phi_i = 2 pi i / A``.

    Args:
        table: (E, n*n) from :func:`wedge_table`.

    Returns:
        ``(rotated (A * E, n*n), full (n*n,))``: row ``i * E + e`` is ``table[e]`` turned by
        ``Rz(phi_i)``; ``full`` is the sum of the turned whole wedges (``z0 = -1``, row 0).
    """
    t = np.asarray(table, np.float64)
    n = math.isqrt(t.shape[1])
    out = []
    for i in range(int(azimuths)):
        phi = 2.0 * math.pi * i / int(azimuths)
        r = t.copy()
        for l in range(n):
            for m in range(1, l + 1):
                c, s = math.cos(m * phi), math.sin(m * phi)
                a, b = t[:, l * l + l + m], t[:, l * l + l - m]
                r[:, l * l + l + m] = c * a - s * b
                r[:, l * l + l - m] = s * a + c * b
        out.append(r)
    rotated = np.concatenate(out)
    full = np.sum([o[0] for o in out], axis=0)
    return rotated, full


def view_table(operator, entries: int, factors: str = "rpo", brdf=None) -> np.ndarray:
    """``F(wo)`` at local views ``(sin t, 0, cos t)`` for ``cos t`` on ``linspace(0, 1, entries)``,
    (entries, n*n) float64: the operators' ``sum_b (w_b . y(wo)) u_b`` (``factors = "rpo"``) or
    the cosine-weighted BRDF's own SH projection (``"exact"``, needs ``brdf``)."""
    mu = np.linspace(0.0, 1.0, int(entries))
    views = np.stack([np.sqrt(np.maximum(1.0 - mu * mu, 0.0)), np.zeros_like(mu), mu], 1)
    views[0] = (1.0, 0.0, 1e-6)  # grazing: keep the view a unit vector just above the plane
    views /= np.linalg.norm(views, axis=1, keepdims=True)
    if factors == "exact":
        from ...scene import _materials as materials
        from ..rpo._model import PHI_NODES, Z_NODES

        return materials.brdf_matrix(brdf, operator.order, views, Z_NODES, PHI_NODES, cosine=True)
    return operator.view_weights(views) @ operator.light_sh
