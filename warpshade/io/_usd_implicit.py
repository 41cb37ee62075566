"""Implicit UsdGeom prims tessellated into triangle meshes: Sphere, Cube, Cylinder, Cone, Capsule,
Plane and, where the installed USD has them, the USD 24 ``Capsule_1`` and ``Cylinder_1`` (radii
``radiusTop`` / ``radiusBottom``).

Part of the stage reader of :mod:`warpshade.io._usd` (whose docstring states what is read): each
function that reads a prim takes the ``_StageReader`` doing the load as ``reader``. The shapes
follow the UsdGeom schemas: centred at the prim's origin, the spine along ``axis`` (X, Y or Z,
default Z), ``height`` the length of the straight part (a Capsule's caps add ``radius`` at each
end), a Cone's base at ``-height/2`` and its apex at ``+height/2``, a Cube's edges ``size`` long,
a Plane ``width`` x ``length`` in the plane across ``axis`` (width along Z for axis X, else X;
length along Z for axis Y, else Y). ``Capsule_1`` is the convex hull of two spheres of radii
``radiusBottom`` / ``radiusTop`` centred at ``-height/2`` / ``+height/2`` (the caps are cut where
the cone tangent to both meets them, as in USD's own tessellation); ``Cylinder_1`` is a capped
cone frustum (a radius of 0 makes a cone).

Tessellation density (fixed counts, so a prim's mesh depends on the prim alone, never on the rest
of the scene):

* :data:`SEGMENTS` = 32 segments around every circle (11.25 degrees each): the polygon's sagitta
  is ``1 - cos(5.6 deg)`` = 0.48 % of the radius, and per-vertex diffuse shading interpolated
  linearly over a segment is within ``(2 pi / 32)**2 / 8`` = 0.5 % of the peak radiance;
* curved profiles in the same 11.25 degree steps: a Sphere has 16 latitude bands (482 vertices,
  960 triangles), each Capsule cap 8;
* straight parts (a cylinder's side, a cap's disc, a cone's side) in rows about as long as a
  segment is wide (``2 pi radius / SEGMENTS``), at most :data:`MAX_ROWS`, so per-vertex shading and
  shadows are sampled evenly over the surface;
* a Cube face is a :data:`CUBE_CELLS` x :data:`CUBE_CELLS` grid (12 x 12); a Plane has
  :data:`PLANE_CELLS` (40) cells along its longer side and as many of about the same size along
  the other.

Every vertex lies on the analytic surface (to float64 rounding); area and volume approach the
analytic values as ``SEGMENTS**-2`` (a Sphere's area is 0.8 % and its volume 1.6 % under them at
32 segments, a quarter of that at 64). Newton's humanoid (16 visual capsules, 3 spheres) becomes
24,742 vertices.
Normals are the analytic ones, per vertex: vertices are shared over smooth parts and duplicated
along the sharp edges (a cylinder's rims, a cone's base, a cube's edges), so shading never averages
across an edge; a cone's apex is a ring of coincident vertices, each with its triangle's normal.
A Plane is shaded on its ``+axis`` side (``doubleSided`` is not used).

Animated parameters (time-sampled ``radius``, ``height``, ...) make a ``"deforming"`` mesh with
the same topology at every frame (counts chosen at the first frame); an animated transform makes
a ``"rigid"`` one. ``Mesh.implicit`` records the shape as ``(type, parameters)`` in the prim's
local space: each shape attribute a float, or a (T,) array over the scene's frames when animated,
and ``axis`` for shapes with a spine (:func:`shape_parameters`).
"""

from __future__ import annotations

import math

import numpy as np

from ..scene._scene import Mesh
from ._usd_appearance import read_appearance

__all__ = ["IMPLICIT_TYPES", "SEGMENTS", "MAX_ROWS", "CUBE_CELLS", "PLANE_CELLS", "is_implicit", "read_implicit",
           "shape_attributes", "shape_parameters", "tessellate"]

#: Segments around every circle of a tessellated implicit prim (11.25 degrees each).
SEGMENTS = 32
#: Most rows along one straight part (a very long cylinder's side): 4 x SEGMENTS.
MAX_ROWS = 4 * SEGMENTS
#: Cells per side of each face of a tessellated Cube.
CUBE_CELLS = 12
#: Cells along the longer side of a tessellated Plane.
PLANE_CELLS = 40

#: The implicit prim types read, with their shape attributes (time-sampled ones are followed).
IMPLICIT_TYPES = {
    "Sphere": ("radius",),
    "Cube": ("size",),
    "Cylinder": ("radius", "height"),
    "Cone": ("radius", "height"),
    "Capsule": ("radius", "height"),
    "Capsule_1": ("radiusTop", "radiusBottom", "height"),
    "Cylinder_1": ("radiusTop", "radiusBottom", "height"),
    "Plane": ("width", "length"),
}
#: The schemas' fallback values (what an unauthored attribute reads as).
_FALLBACKS = {
    "Sphere": {"radius": 1.0},
    "Cube": {"size": 2.0},
    "Cylinder": {"radius": 1.0, "height": 2.0},
    "Cone": {"radius": 1.0, "height": 2.0},
    "Capsule": {"radius": 0.5, "height": 1.0},
    "Capsule_1": {"radiusTop": 0.5, "radiusBottom": 0.5, "height": 1.0},
    "Cylinder_1": {"radiusTop": 1.0, "radiusBottom": 1.0, "height": 2.0},
    "Plane": {"width": 2.0, "length": 2.0},
}
_HAS_AXIS = {"Cylinder", "Cone", "Capsule", "Capsule_1", "Cylinder_1", "Plane"}


def is_implicit(prim) -> bool:
    """True for the implicit gprims this module tessellates (see :data:`IMPLICIT_TYPES`)."""
    return str(prim.GetTypeName()) in IMPLICIT_TYPES


def shape_attributes(prim) -> list:
    """The prim's shape attributes (``radius``, ``height``, ...): what animates its shape."""
    return [prim.GetAttribute(name) for name in IMPLICIT_TYPES.get(str(prim.GetTypeName()), ())]


# ---- tessellation (pure NumPy, float64) -----------------------------------------------------------
def _check(kind: str, params: dict, where: str) -> None:
    """Refuse parameters that make no surface, naming the attribute."""
    positive = {"Sphere": ("radius",), "Cube": ("size",), "Cylinder": ("radius", "height"), "Cone": ("radius", "height"),
                "Capsule": ("radius",), "Capsule_1": ("radiusTop", "radiusBottom"), "Cylinder_1": ("height",),
                "Plane": ("width", "length")}[kind]
    for name, value in params.items():
        if name == "axis":
            continue
        if not math.isfinite(value) or value < 0 or (name in positive and value == 0):
            need = "> 0" if name in positive else ">= 0"
            raise ValueError(f"{where}: {name} must be finite and {need}, got {value!r}")
    if kind == "Cylinder_1" and params["radiusTop"] == 0 and params["radiusBottom"] == 0:
        raise ValueError(f"{where}: radiusTop and radiusBottom are both 0 (need one > 0)")


def _rows(length: float, radius: float, segments: int) -> int:
    """Rows along a straight part of ``length``: about as long as a segment of a circle of ``radius`` is wide."""
    edge = 2.0 * math.pi * radius / segments
    if not length > 0 or not edge > 0:
        return 1
    return int(min(max(math.ceil(length / edge - 1e-9), 1), MAX_ROWS))


def _bands(angle: float, segments: int) -> int:
    """Bands over an arc of ``angle`` radians, in steps of at most ``2 pi / segments``."""
    return int(max(math.ceil(angle / (2.0 * math.pi / segments) - 1e-9), 1))


def _line(a, b, n: int, normal) -> np.ndarray:
    """``n`` + 1 profile points (rho, z, n_rho, n_z) from ``a`` to ``b`` (rho, z), one normal."""
    t = np.linspace(0.0, 1.0, n + 1)[:, None]
    pts = (1.0 - t) * np.asarray(a, np.float64) + t * np.asarray(b, np.float64)
    return np.hstack([pts, np.broadcast_to(np.asarray(normal, np.float64), (n + 1, 2))])


def _arc(centre_z: float, radius: float, lat0: float, lat1: float, n: int) -> np.ndarray:
    """``n`` + 1 profile points on a circle of ``radius`` centred on the spine at ``centre_z``,
    latitudes ``lat0`` .. ``lat1`` (radians; -pi/2 is the bottom pole)."""
    lat = np.linspace(lat0, lat1, n + 1)
    c, s = np.cos(lat), np.sin(lat)
    c[np.isclose(np.abs(lat), 0.5 * np.pi, rtol=0.0, atol=1e-15)] = 0.0  # exact poles
    return np.stack([radius * c, centre_z + radius * s, c, s], axis=1)


def _profile(kind: str, p: dict, segments: int, layout):
    """The profile of a shape of revolution about +Z: pieces of (K, 4) arrays (rho, z, n_rho, n_z)
    from the bottom to the top; points within a piece are connected, pieces meet at sharp edges.
    ``layout`` (the counts per piece) is chosen from ``p`` when None and returned."""
    if kind == "Sphere":
        r = p["radius"]
        layout = layout or (segments // 2,)
        return [_arc(0.0, r, -0.5 * math.pi, 0.5 * math.pi, layout[0])], layout
    if kind in ("Capsule", "Capsule_1"):
        rb, rt = (p["radius"], p["radius"]) if kind == "Capsule" else (p["radiusBottom"], p["radiusTop"])
        h = p["height"]
        cb, ct = -0.5 * h, 0.5 * h  # the spheres' centres on the spine
        # sine of the latitude where the cone tangent to both spheres touches them
        s = max(-1.0, min(1.0, (rb - rt) / h)) if h > 0 else (1.0 if rb > rt else -1.0 if rb < rt else 0.0)
        if s >= 1.0:  # the bottom sphere holds the top one: that cap shrinks to the bottom's pole
            rt, ct = 0.0, cb + rb
        elif s <= -1.0:
            rb, cb = 0.0, ct - rt
        lam, c = math.asin(s), math.sqrt(max(0.0, 1.0 - s * s))
        zb, zt = cb + rb * s, ct + rt * s
        side = math.hypot((rb - rt) * c, zt - zb)
        if layout is None:  # 0 side rows: the two caps share their rim (a capsule of height 0)
            layout = (_bands(lam + 0.5 * math.pi, segments), _rows(side, max(rb, rt), segments) if side > 0 else 0,
                      _bands(0.5 * math.pi - lam, segments))
        nb, ns, nt = layout
        bottom = _arc(cb, rb, -0.5 * math.pi, lam, nb)
        top = _arc(ct, rt, lam, 0.5 * math.pi, nt)
        if ns == 0:
            return [np.vstack([bottom, top[1:]])], layout
        middle = _line((rb * c, zb), (rt * c, zt), ns, (c, s))
        return [np.vstack([bottom, middle[1:-1], top])], layout
    if kind in ("Cylinder", "Cone", "Cylinder_1"):
        h = p["height"]
        rb = p["radius"] if kind != "Cylinder_1" else p["radiusBottom"]
        rt = p["radius"] if kind == "Cylinder" else 0.0 if kind == "Cone" else p["radiusTop"]
        biggest = max(rb, rt)
        if layout is None:  # a radius of 0 has no cap (0 rows)
            layout = (_rows(rb, biggest, segments) if rb > 0 else 0, _rows(math.hypot(h, rb - rt), biggest, segments),
                      _rows(rt, biggest, segments) if rt > 0 else 0)
        nb, ns, nt = layout
        slope = np.array([h, rb - rt]) / math.hypot(h, rb - rt)  # outward side normal (n_rho, n_z)
        pieces = []
        if nb:
            pieces.append(_line((0.0, -0.5 * h), (rb, -0.5 * h), nb, (0.0, -1.0)))
        pieces.append(_line((rb, -0.5 * h), (rt, 0.5 * h), ns, slope))
        if nt:
            pieces.append(_line((rt, 0.5 * h), (0.0, 0.5 * h), nt, (0.0, 1.0)))
        return pieces, layout
    raise ValueError(f"{kind} is not a shape of revolution")


def _revolve(pieces, segments: int):
    """Points, analytic normals and counter-clockwise (outward) triangles of a profile revolved
    about +Z. A profile point on the spine with a normal along it is one vertex (a pole); one on
    the spine with a slanted normal (a cone's apex) a ring of coincident vertices."""
    phi = 2.0 * np.pi * np.arange(segments) / segments
    c, s = np.cos(phi), np.sin(phi)
    points, normals, faces = [], [], []
    count = 0
    for piece in pieces:
        rings = []
        for rho, z, nr, nz in piece:
            norm = math.hypot(nr, nz)
            nr, nz = nr / norm, nz / norm
            if rho == 0.0 and abs(nr) < 1e-12:
                points.append([[0.0, 0.0, z]])
                normals.append([[0.0, 0.0, math.copysign(1.0, nz)]])
                rings.append((np.full(segments, count), True))
                count += 1
            else:
                points.append(np.stack([rho * c, rho * s, np.full(segments, z)], axis=1))
                normals.append(np.stack([nr * c, nr * s, np.full(segments, nz)], axis=1))
                rings.append((count + np.arange(segments), rho == 0.0))
                count += segments
        for (a, a_on_spine), (b, b_on_spine) in zip(rings[:-1], rings[1:]):
            a1, b1 = np.roll(a, -1), np.roll(b, -1)
            if not a_on_spine:
                faces.append(np.stack([a, a1, b1], axis=1))
            if not b_on_spine:
                faces.append(np.stack([a, b1, b], axis=1))
    return np.vstack(points), np.vstack(normals), np.vstack(faces).astype(np.int64)


def _grid(origin, du, dv, nu: int, nv: int):
    """A grid of (nu + 1) x (nv + 1) points ``origin + i du + j dv``; triangles counter-clockwise
    around ``du x dv``."""
    i, j = np.meshgrid(np.arange(nu + 1), np.arange(nv + 1), indexing="ij")
    pts = np.asarray(origin, np.float64) + i.reshape(-1, 1) * np.asarray(du) + j.reshape(-1, 1) * np.asarray(dv)
    ii, jj = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    v00 = (ii * (nv + 1) + jj).ravel()
    v10, v01 = v00 + nv + 1, v00 + 1
    v11 = v10 + 1
    return pts, np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])


def _cube(size: float, cells: int):
    half = 0.5 * size
    points, normals, faces = [], [], []
    count = 0
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            u = np.zeros(3)
            u[(axis + 1) % 3] = 1.0
            v = np.cross(n, u)  # (u, v, n) right-handed: counter-clockwise seen from outside
            pts, tri = _grid(half * (n - u - v), size * u / cells, size * v / cells, cells, cells)
            points.append(pts)
            normals.append(np.broadcast_to(n, pts.shape))
            faces.append(tri + count)
            count += pts.shape[0]
    return np.vstack(points), np.vstack(normals), np.vstack(faces)


#: The spine axis as a cyclic permutation of +Z (a rotation, so windings stay outward):
#: world coordinates from canonical (x, y, z).
_AXIS_ORDER = {"Z": (0, 1, 2), "X": (2, 0, 1), "Y": (1, 2, 0)}


def _to_axis(v: np.ndarray, axis: str) -> np.ndarray:
    return np.ascontiguousarray(v[:, _AXIS_ORDER[axis]])


def _plane(p: dict, axis: str, cells: int, layout):
    w, l = p["width"], p["length"]
    if layout is None:
        longer = max(w, l)
        layout = tuple(max(1, round(cells * side / longer)) for side in (w, l))
    nw, nl = layout
    normal = np.eye(3)[{"X": 0, "Y": 1, "Z": 2}[axis]]
    wdir = np.eye(3)[2 if axis == "X" else 0]
    ldir = np.eye(3)[2 if axis == "Y" else 1]
    if np.dot(np.cross(wdir, ldir), normal) > 0:
        pts, tri = _grid(-0.5 * (w * wdir + l * ldir), w * wdir / nw, l * ldir / nl, nw, nl)
    else:  # keep the winding counter-clockwise around +axis
        pts, tri = _grid(-0.5 * (w * wdir + l * ldir), l * ldir / nl, w * wdir / nw, nl, nw)
    return pts, np.broadcast_to(normal, pts.shape).copy(), tri, layout


def tessellate(kind: str, params: dict, segments: int = SEGMENTS, layout=None, where: str | None = None):
    """A triangle mesh of an implicit shape in its local space (see the module docstring).

    Args:
        kind: a key of :data:`IMPLICIT_TYPES`.
        params: its shape attributes (``{"radius": 1.0}``, ...) and ``"axis"`` ("X", "Y" or "Z",
            default "Z") for shapes with a spine.
        segments: segments around each circle (:data:`SEGMENTS`); cube and plane cells scale with it.
        layout: counts per part from an earlier call (the first frame's), so that every frame of an
            animated shape has the same topology; None chooses them from ``params``.
        where: what to name in errors (the prim); default ``kind``.

    Returns:
        ``(points, normals, faces, layout)``: points and unit outward normals (V, 3) float64,
        counter-clockwise triangles (F, 3) int64, the counts used.

    Raises:
        ValueError: a parameter that makes no surface (a radius <= 0, ...), naming it.
    """
    if kind not in IMPLICIT_TYPES:
        raise ValueError(f"{where or kind}: {kind!r} is not an implicit prim type ({', '.join(IMPLICIT_TYPES)})")
    p = {name: float(params.get(name, _FALLBACKS[kind][name])) for name in IMPLICIT_TYPES[kind]}
    axis = str(params.get("axis", "Z"))
    if axis not in _AXIS_ORDER:
        raise ValueError(f"{where or kind}: axis must be 'X', 'Y' or 'Z', got {axis!r}")
    _check(kind, p, where or kind)
    if kind == "Cube":
        cells = max(1, round(CUBE_CELLS * segments / SEGMENTS))
        points, normals, faces = _cube(p["size"], cells)
        return points, normals, faces, (cells,)
    if kind == "Plane":
        points, normals, faces, layout = _plane(p, axis, max(1, round(PLANE_CELLS * segments / SEGMENTS)), layout)
        return points, normals, faces, layout
    pieces, layout = _profile(kind, p, segments, layout)
    points, normals, faces = _revolve(pieces, segments)
    return _to_axis(points, axis), _to_axis(normals, axis), faces, layout


def _drop_degenerate(points, normals, faces):
    """Triangles of zero area removed (a capsule whose larger sphere holds the smaller), and the
    vertices no triangle uses."""
    e = np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]])
    scale = float(np.max(np.ptp(points, axis=0))) ** 2
    faces = faces[np.linalg.norm(e, axis=1) > 1e-24 * max(scale, 1e-300)]
    used = np.unique(faces)
    remap = np.full(points.shape[0], -1, np.int64)
    remap[used] = np.arange(used.size)
    return points[used], normals[used], remap[faces]


# ---- reading a prim -------------------------------------------------------------------------------
def shape_parameters(reader, prim, path: str):
    """The shape attributes per frame: ``({name: (T,) float64 or float}, axis)``; a float where
    the value does not change over the reader's frames."""
    kind = str(prim.GetTypeName())
    values = {}
    for name, attr in zip(IMPLICIT_TYPES[kind], shape_attributes(prim)):
        if attr.GetNumTimeSamples() > 1:
            series = np.array([_number(attr.Get(t), path, name, reader) for t in reader.times], np.float64)
            values[name] = float(series[0]) if np.all(series == series[0]) else series
        else:
            values[name] = _number(attr.Get(reader.times[0]), path, name, reader)
    axis = str(prim.GetAttribute("axis").Get() or "Z") if kind in _HAS_AXIS else "Z"
    return values, axis


def _number(value, path, name, reader) -> float:
    if value is None:
        raise ValueError(f"prim {path} in {reader.path}: {name} has no value")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"prim {path} in {reader.path}: {name} must be a number, got {value!r}") from None


def read_implicit(reader, prim, transforms=None, name=None) -> Mesh:
    """Tessellate one implicit prim (see the module docstring); ``transforms`` overrides its world
    transform (point instancing), ``name`` its mesh path."""
    kind = str(prim.GetTypeName())
    path = name or str(prim.GetPath())
    where = f"{kind} {path} in {reader.path}"
    values, axis = shape_parameters(reader, prim, path)
    animated = {k: v for k, v in values.items() if isinstance(v, np.ndarray)}
    first = {k: (float(v[0]) if k in animated else v) for k, v in values.items()}
    points, normals, faces, layout = tessellate(kind, {**first, "axis": axis}, where=where)
    samples = None
    if animated:
        frames = []
        for k, t in enumerate(reader.times):
            at = {name: (float(v[k]) if name in animated else v) for name, v in values.items()}
            frames.append(tessellate(kind, {**at, "axis": axis}, layout=layout, where=f"{where} at time {t.GetValue():g}")[0])
        samples = np.stack(frames)
        normals = None  # area-weighted from the deformed points at evaluation time
    else:
        points, normals, faces = _drop_degenerate(points, normals, faces)
    xfs = reader._world_transforms(prim) if transforms is None else transforms
    animation = "deforming" if samples is not None else "rigid" if xfs.shape[0] > 1 else "static"
    tri_area = 0.5 * np.linalg.norm(np.cross(points[faces[:, 1]] - points[faces[:, 0]],
                                             points[faces[:, 2]] - points[faces[:, 0]]), axis=1)
    surface, uvs, albedo = read_appearance(reader, prim, path, points.shape[0], faces.reshape(-1),
                                           np.full(faces.shape[0], 3, np.int64), tri_area, None)
    shape = {k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in values.items()}
    if kind in _HAS_AXIS:
        shape["axis"] = axis
    return Mesh(
        path=path,
        points=points,
        faces=faces.astype(np.int32),
        animation=animation,
        transforms=xfs,
        point_samples=samples,
        normals=normals,
        uvs=uvs,
        albedo=albedo,
        surface=surface,
        implicit=(kind, shape),
    )
