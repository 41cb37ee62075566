"""``dish.usda`` -- a brushed-metal dish like the platter of Wang et al. 2009's Fig. 12 (static,
one frame). A shallow dish (radius ``DISH_RADIUS``: a bowl rising from 0.03 m at the centre to
0.15 m, a rounded lip and an outer wall down to the ground; 25 rings x 97 columns with the seam
duplicated) whose vertex UVs are polar: ``u = azimuth / 2 pi`` (increasing counter-clockwise
about +Z) and ``v`` the arc length along the profile, so the UV tangent (the direction of
increasing u, :mod:`warpshade.geometry._uv_tangents`) runs around the dish, the direction of
circular brush marks; exact vertex normals of the surface of revolution. A ball (radius 0.14 m,
lat-long UVs) rests in the dish off centre and casts a shadow on it; a 31 x 31 vertex ground grid
(5 m, planar UVs) under them. The bundled sky (``sky.hdr``, sun towards
:data:`.sky.SUN_DIRECTION`); the camera looks down at the dish from near the mirror direction of
the sun, so the sun's highlight, fanned out across the brush direction by an anisotropic BRDF,
lies on the dish. Materials come from the stage graph (``stages/dish_sg_aniso.toml``).
"""

from __future__ import annotations

import os

import numpy as np
from pxr import Sdf, UsdGeom, Vt

from .shapes import grid
from .sky import SUN_DIRECTION, define_sky
from .writing import define_camera, define_mesh, new_stage, rounded, save_stage

DISH_RADIUS = 1.0
DISH_AROUND = 96
#: (r, z) of the dish's profile from the centre outwards: the bowl (z = 0.03 + 0.12 (r / R)^2),
#: the lip's round top and the outer wall down to the ground.
DISH_BOWL_RINGS = 20
BALL_RADIUS = 0.14
BALL_CENTRE_RZ = (0.42, 0.35)  # radius from the axis and azimuth (rad) of the ball's contact point
CAMERA_DISTANCE = 2.7


def dish_profile() -> np.ndarray:
    """(r, z) samples of the dish's profile, centre to ground, (N, 2)."""
    r = DISH_RADIUS * np.linspace(0.0, 1.0, DISH_BOWL_RINGS + 1)
    bowl = np.stack([r, 0.03 + 0.12 * (r / DISH_RADIUS) ** 2], 1)
    lip = np.array([[DISH_RADIUS + 0.025, 0.162], [DISH_RADIUS + 0.05, 0.15], [DISH_RADIUS + 0.06, 0.08],
                    [DISH_RADIUS + 0.065, 0.0]])
    return np.concatenate([bowl, lip])


def surface_of_revolution(profile, around: int, up_normals: bool = True):
    """A surface of revolution about +Z with a duplicated seam and polar UVs.

    Args:
        profile: (r, z) samples, (N, 2); r = 0 rows are poles (their quads degenerate into triangles).
        around: segments around the axis.
        up_normals: normals turned to the profile's left, ``(-dz, dr)`` (up for a profile
            running outwards), else to its right.

    Returns:
        points (N (around + 1), 3), polygon counts and indices (CCW seen from the normals' side;
        quads, triangles next to a pole),
        normals (exact for the profile's polyline tangent), UVs (u = azimuth / 2 pi, v = arc length).
    """
    prof = np.asarray(profile, np.float64)
    n = len(prof)
    phi = 2.0 * np.pi * np.arange(around + 1) / around
    d = np.gradient(prof, axis=0)
    nrz = np.stack([-d[:, 1], d[:, 0]], 1) * (1.0 if up_normals else -1.0)
    nrz /= np.linalg.norm(nrz, axis=1, keepdims=True)
    cos, sin = np.cos(phi)[None, :], np.sin(phi)[None, :]
    pts = np.stack([prof[:, :1] * cos, prof[:, :1] * sin, np.broadcast_to(prof[:, 1:], (n, around + 1))], -1)
    nrm = np.stack([nrz[:, :1] * cos, nrz[:, :1] * sin, np.broadcast_to(nrz[:, 1:], (n, around + 1))], -1)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(prof, axis=0), axis=1))])
    uvs = np.stack([np.broadcast_to(phi[None, :] / (2.0 * np.pi), (n, around + 1)),
                    np.broadcast_to(arc[:, None], (n, around + 1))], -1)
    idx = np.arange(n * (around + 1)).reshape(n, around + 1)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, e = idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    quads = np.stack([a, e, c, b], 1)  # outwards along the profile, then around: CCW about the left normal
    ring = np.repeat(np.arange(n - 1), around)
    counts, faces = [], []
    for q, k in zip(quads, ring):
        # next to a pole (r = 0) two corners coincide: a triangle without them both
        face = [q[0], q[1], q[2]] if prof[k, 0] == 0.0 else [q[0], q[1], q[3]] if prof[k + 1, 0] == 0.0 else list(q)
        faces.append(face if up_normals else face[::-1])
        counts.append(len(face))
    return (pts.reshape(-1, 3), np.asarray(counts), np.concatenate(faces), nrm.reshape(-1, 3), uvs.reshape(-1, 2))


def dish_height(r: float) -> float:
    return 0.03 + 0.12 * (r / DISH_RADIUS) ** 2


def ball_centre() -> np.ndarray:
    """World centre of the ball resting on the bowl: along the bowl's normal at its contact point."""
    r, az = BALL_CENTRE_RZ
    slope = 0.24 * r / DISH_RADIUS**2
    n = np.array([-slope, 0.0, 1.0]) / np.hypot(slope, 1.0)  # in the (r, z) plane
    c = np.array([r, 0.0, dish_height(r)]) + BALL_RADIUS * n
    return np.array([c[0] * np.cos(az), c[0] * np.sin(az), c[2]])


def _define(stage, path, pts, counts, idx, normals, uvs):
    mesh = define_mesh(stage, path, pts, counts, idx)
    if normals is not None:
        mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(rounded(normals).astype(np.float32)))
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set(Vt.Vec2fArray.FromNumpy(rounded(uvs).astype(np.float32)))
    return mesh


def make_dish(out_dir: str) -> str:
    stage = new_stage(animated=False)
    define_sky(stage)
    pts, counts, idx = grid(31, 5.0)
    _define(stage, "/World/Ground", pts, counts, idx, None, (pts[:, :2] + 2.5) / 5.0)
    _define(stage, "/World/Dish", *surface_of_revolution(dish_profile(), DISH_AROUND))
    t = np.linspace(0.0, np.pi, 13)
    ball_profile = np.stack([BALL_RADIUS * np.sin(t), -BALL_RADIUS * np.cos(t)], 1)
    ball_profile[[0, -1], 0] = 0.0
    bp, bc, bi, bn, buv = surface_of_revolution(ball_profile, 24, up_normals=False)
    _define(stage, "/World/Ball", bp + ball_centre(), bc, bi, bn, buv)
    mirror = np.array([-SUN_DIRECTION[0], -SUN_DIRECTION[1], SUN_DIRECTION[2]])
    # a little off the sun's mirror direction (towards the zenith): the highlight's fan sits inside the dish
    view = mirror + np.array([0.0, 0.0, 0.35])
    eye = CAMERA_DISTANCE * view / np.linalg.norm(view)
    define_camera(stage, eye=eye, target=(0.0, 0.0, 0.08))
    path = os.path.join(out_dir, "dish.usda")
    save_stage(stage, path)
    return path
