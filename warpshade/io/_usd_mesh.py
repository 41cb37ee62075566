"""Mesh prims of a USD stage as :class:`~warpshade.scene.Mesh`: polygons to triangles, normals,
UVs, albedo, point instancers (whose prototypes may hold implicit prims, tessellated by
:mod:`warpshade.io._usd_implicit`).

Part of the stage reader of :mod:`warpshade.io._usd` (whose docstring states what is read and
the errors): each function takes the ``_StageReader`` doing the load as ``reader``.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..scene._scene import Mesh
from ._usd_appearance import read_appearance
from ._usd_implicit import is_implicit, read_implicit
from ._usd_skel import read_skin_binding

__all__ = ["ZERO_AREA_RELATIVE", "read_mesh", "read_point_instancer"]

#: A triangle counts as zero-area when its area is below this fraction of the squared diagonal
#: of its mesh's bounding box: far below anything float32 coordinates can resolve (their
#: relative spacing is 6e-8, so a genuine sliver has relative area >= ~1e-14 only when its
#: vertices are collinear to the last bit), and exactly 0 for repeated vertices.
ZERO_AREA_RELATIVE = 1e-12



def read_mesh(reader, prim, skin_info=None, transforms=None, name=None) -> Mesh | None:
    """Read one Mesh prim; ``transforms`` overrides its world transform (point instancing)."""
    from pxr import UsdGeom

    mesh = UsdGeom.Mesh(prim)
    path = name or str(prim.GetPath())
    # -- height fields: procedural grids expanded by warpshade.io._heightfield ---------------
    from . import _heightfield as heightfield

    if skin_info is None and transforms is None and heightfield.is_height_field(prim):
        return heightfield.read_mesh(reader, prim, path)
    # ----------------------------------------------------------------------------------------
    t0 = reader.times[0]
    counts_attr = mesh.GetFaceVertexCountsAttr()
    indices_attr = mesh.GetFaceVertexIndicesAttr()
    for attr in (counts_attr, indices_attr):
        if attr.GetNumTimeSamples() > 1:
            values = [np.asarray(attr.Get(t)) for t in reader.times]
            if any(v.shape != values[0].shape or np.any(v != values[0]) for v in values):
                raise ValueError(f"mesh {path} in {reader.path}: topology ({attr.GetName()}) changes over time, which is not supported")
    counts = np.asarray(counts_attr.Get(t0) or [], dtype=np.int64)
    indices = np.asarray(indices_attr.Get(t0) or [], dtype=np.int64)
    points_attr = mesh.GetPointsAttr()
    rest = points_attr.Get(t0)
    if rest is None or len(rest) == 0 or counts.size == 0:
        reader.skipped.append((path, "empty mesh (no points or no faces)"))
        return None
    rest = np.asarray(rest, dtype=np.float64).reshape(-1, 3)
    vertex_count = rest.shape[0]

    # Time-sampled points (deforming) -- skinned meshes use the first frame as rest pose.
    samples = None
    if points_attr.GetNumTimeSamples() > 1 and skin_info is None:
        samples = np.stack([reader._points_at(points_attr, t, vertex_count, path) for t in reader.times])
        if np.all(samples == samples[:1]):
            samples = None
    reader._check_finite(rest, path, float(reader.frames[0]))

    # Topology checks and fan triangulation.
    if np.any(counts < 3):
        bad = int(np.flatnonzero(counts < 3)[0])
        raise ValueError(f"mesh {path} in {reader.path}: face {bad} has {int(counts[bad])} vertices (need >= 3)")
    if int(counts.sum()) != indices.size:
        raise ValueError(
            f"mesh {path} in {reader.path}: faceVertexCounts sum to {int(counts.sum())} but there are "
            f"{indices.size} faceVertexIndices"
        )
    if indices.size and (indices.min() < 0 or indices.max() >= vertex_count):
        raise ValueError(
            f"mesh {path} in {reader.path}: faceVertexIndices range {int(indices.min())}..{int(indices.max())} "
            f"is out of range for {vertex_count} points"
        )
    holes = np.asarray(mesh.GetHoleIndicesAttr().Get(t0) or [], dtype=np.int64)
    left_handed = mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
    corners, face_of_tri = _fan_corners(counts)
    keep = np.ones(face_of_tri.shape[0], dtype=bool)
    if holes.size:
        keep &= ~np.isin(face_of_tri, holes)
    corners = _retriangulate_concave(corners, counts, indices, rest)
    if left_handed:
        corners = corners[:, [0, 2, 1]]
    tris = indices[corners]
    # Polygon areas (for faceVarying/uniform averaging) from the rest points.
    tri_area = 0.5 * np.linalg.norm(
        np.cross(rest[tris[:, 1]] - rest[tris[:, 0]], rest[tris[:, 2]] - rest[tris[:, 0]]), axis=1
    )
    poly_area = np.bincount(face_of_tri, weights=tri_area, minlength=counts.size)
    diag2 = float(np.sum((rest.max(axis=0) - rest.min(axis=0)) ** 2))
    zero = keep & (tri_area <= ZERO_AREA_RELATIVE * max(diag2, 1e-300))
    dropped = int(zero.sum())
    keep &= ~zero
    if not keep.any():
        raise ValueError(f"mesh {path} in {reader.path}: all {tris.shape[0]} triangles have zero area (or are holes)")
    if dropped:
        warnings.warn(
            f"mesh {path} in {reader.path}: dropped {dropped} zero-area triangle(s) of {tris.shape[0]}",
            stacklevel=3,
        )
    faces = tris[keep]

    # Animation kind and transforms.
    if skin_info is not None:
        animation = "skinned"
        xfs = np.eye(4)[None]
    else:
        xfs = reader._world_transforms(prim) if transforms is None else transforms
        if samples is not None:
            animation = "deforming"
        elif xfs.shape[0] > 1:
            animation = "rigid"
        else:
            animation = "static"

    normals = None
    if animation in ("static", "rigid"):
        normals = _read_normals(reader, mesh, path, vertex_count, indices, counts, poly_area)
    uvs = _read_uvs(reader, mesh, path, vertex_count, indices, counts)
    surface, uvs, albedo = read_appearance(reader, prim, path, vertex_count, indices, counts, poly_area, uvs)
    skin = None
    if skin_info is not None:
        skin = read_skin_binding(reader, skin_info, path, vertex_count)
    return Mesh(
        path=path,
        points=rest,
        faces=faces.astype(np.int32),
        animation=animation,
        transforms=xfs,
        point_samples=samples,
        normals=normals,
        uvs=uvs,
        albedo=albedo,
        skin=skin,
        dropped_face_count=dropped,
        surface=surface,
    )


def _read_normals(reader, mesh, path, vertex_count, indices, counts, poly_area):
    pv = reader._primvar(mesh.GetPrim(), "normals")
    if pv is not None:
        values, interp = pv.ComputeFlattened(reader.times[0]), pv.GetInterpolation()
    else:
        attr = mesh.GetNormalsAttr()
        if not attr.HasAuthoredValue():
            return None
        values, interp = attr.Get(reader.times[0]), mesh.GetNormalsInterpolation()
    if values is None or len(values) == 0:
        return None
    corner_w = np.repeat(poly_area, counts)
    n = reader._to_vertex(values, str(interp), path, "normals", vertex_count, indices, counts, corner_w)
    if n is None:
        return None
    length = np.linalg.norm(n, axis=1)
    referenced = np.zeros(vertex_count, dtype=bool)
    referenced[indices] = True
    if not np.all(np.isfinite(n)) or np.any(length[referenced] < 1e-6):
        warnings.warn(
            f"mesh {path} in {reader.path}: authored normals have NaN/zero-length entries; "
            "area-weighted normals are computed instead",
            stacklevel=3,
        )
        return None
    return n / np.maximum(length, 1e-30)[:, None]


def _read_uvs(reader, mesh, path, vertex_count, indices, counts):
    from pxr import Sdf, UsdGeom

    prim = mesh.GetPrim()
    pv = reader._primvar(prim, "st")
    if pv is None:
        for cand in UsdGeom.PrimvarsAPI(prim).GetPrimvarsWithAuthoredValues():
            if cand.GetTypeName().role == Sdf.ValueTypeNames.TexCoord2f.role:
                pv = cand
                break
    if pv is None:
        return None
    values = pv.ComputeFlattened(reader.times[0])
    if values is None or len(values) == 0:
        return None
    uv = reader._to_vertex(values, str(pv.GetInterpolation()), path, pv.GetName(), vertex_count, indices, counts)
    return None if uv is None or uv.shape[1] != 2 else uv


def read_point_instancer(reader, prim) -> list[Mesh]:
    """One mesh per visible instance and prototype Mesh or implicit prim (module docstring of
    :mod:`warpshade.io._usd`); instances hidden at any frame are counted in ``skipped``."""
    from pxr import UsdGeom

    inst = UsdGeom.PointInstancer(prim)
    base = str(prim.GetPath())
    protos = inst.GetPrototypesRel().GetTargets()
    per_frame = []
    masks = []
    for t in reader.times:
        xf = inst.ComputeInstanceTransformsAtTime(t, t)
        per_frame.append(np.array(xf, dtype=np.float64).reshape(-1, 4, 4))
        mask = inst.ComputeMaskAtTime(t)
        masks.append(np.ones(per_frame[-1].shape[0], bool) if not mask else np.asarray(mask, bool))
    counts = {a.shape[0] for a in per_frame}
    if len(counts) != 1:
        raise ValueError(f"point instancer {base} in {reader.path}: instance count changes over time, which is not supported")
    proto_indices = np.asarray(inst.GetProtoIndicesAttr().Get(reader.times[0]) or [], dtype=np.int64)
    inst_xf = np.stack(per_frame, axis=1)  # (N, T, 4, 4)
    visible = np.all(np.stack(masks), axis=0)
    hidden = int(np.count_nonzero(~visible))
    if hidden:
        reader.skipped.append((base, f"{hidden} of {visible.size} instance(s) hidden by invisibleIds or inactiveIds "
                                     "at some frame"))
    instancer_world = reader._world_transforms(prim)
    meshes = []
    for i, p in enumerate(proto_indices):
        if not visible[i]:
            continue
        if not 0 <= p < len(protos):
            raise ValueError(f"point instancer {base} in {reader.path}: protoIndices[{i}] = {p} but there are {len(protos)} prototypes")
        proto = reader.stage.GetPrimAtPath(protos[p])
        if not proto:
            raise ValueError(f"point instancer {base} in {reader.path}: prototype {protos[p]} does not exist")
        for sub in _prototype_prims(reader, proto):
            # mesh -> prototype-root space, per frame; the instance transforms computed by
            # USD already include the prototype root's own ops (IncludeProtoXform).
            to_proto = reader._world_transforms(sub) @ np.linalg.inv(reader._world_transforms(proto))
            frames = max(to_proto.shape[0], inst_xf.shape[1], instancer_world.shape[0])
            xf = np.stack(
                [
                    to_proto[min(k, to_proto.shape[0] - 1)]
                    @ inst_xf[i, min(k, inst_xf.shape[1] - 1)]
                    @ instancer_world[min(k, instancer_world.shape[0] - 1)]
                    for k in range(frames)
                ]
            )
            if np.all(xf == xf[:1]):
                xf = xf[:1]
            rel = str(sub.GetPath())[len(str(proto.GetPath())) :]
            if sub.IsA(UsdGeom.Mesh):
                m = read_mesh(reader, sub, transforms=xf, name=f"{base}/instance_{i}{rel}")
            else:
                m = read_implicit(reader, sub, transforms=xf, name=f"{base}/instance_{i}{rel}")
            if m is not None:
                meshes.append(m)
    return meshes


def _prototype_prims(reader, proto) -> list:
    """The Mesh and implicit prims of a point instancer's prototype, in traversal order; guide /
    proxy / invisible prims and unsupported gprims are left out and recorded once in ``skipped``."""
    from pxr import Usd, UsdGeom

    cache = reader._prototype_cache
    key = str(proto.GetPath())
    if key in cache:
        return cache[key]
    found = []
    it = iter(Usd.PrimRange(proto, reader.predicate))
    for sub in it:
        if sub.IsA(UsdGeom.Imageable):
            why = reader._hidden_reason(sub, prototype=True)
            if why is not None:
                reader.skipped.append((str(sub.GetPath()), why))
                it.PruneChildren()
                continue
        if sub.IsA(UsdGeom.Mesh) or is_implicit(sub):
            found.append(sub)
        elif sub.IsA(UsdGeom.Gprim):
            reader.skipped.append((str(sub.GetPath()), reader._unsupported_gprim(sub)))
    cache[key] = found
    return found


def _retriangulate_concave(corners: np.ndarray, counts: np.ndarray, indices: np.ndarray, points: np.ndarray):
    """Replace the fan triangles of concave polygons by an ear-clipping triangulation.

    A polygon is concave when one of its corners turns against its Newell normal. Each such
    polygon is projected onto its plane and triangulated with mapbox-earcut; the triangles keep
    the polygon's winding and its ``count - 2`` slots in ``corners`` (corner indices into
    ``faceVertexIndices``). Polygons that ear clipping cannot split into ``count - 2``
    triangles (self-intersecting outlines) keep their fan.
    """
    counts = np.asarray(counts, np.int64)
    big = np.flatnonzero(counts > 3)
    if big.size == 0:
        return corners
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    first_tri = np.cumsum(counts - 2) - (counts - 2)
    # per corner of the big polygons: previous, this and next point
    face = np.repeat(big, counts[big])
    local = np.arange(face.size) - np.repeat(np.cumsum(counts[big]) - counts[big], counts[big])
    n = counts[face]
    at = lambda k: points[indices[starts[face] + (local + k) % n]]  # noqa: E731
    prev, here, nxt = at(-1), at(0), at(1)
    # Newell normal per polygon (sum of cross products of consecutive corners)
    newell = np.zeros((counts.size, 3))
    np.add.at(newell, face, np.cross(here, nxt))
    turn = np.einsum("ij,ij->i", np.cross(here - prev, nxt - here), newell[face])
    scale = np.linalg.norm(newell[face], axis=1) * np.linalg.norm(here - prev, axis=1) * np.linalg.norm(nxt - here, axis=1)
    reflex = turn < -1e-9 * np.maximum(scale, 1e-300)
    concave = np.unique(face[reflex])
    if concave.size == 0:
        return corners
    import mapbox_earcut

    corners = corners.copy()
    for f in concave:
        k = int(counts[f])
        nrm = newell[f] / max(np.linalg.norm(newell[f]), 1e-300)
        u = np.cross(nrm, [1.0, 0.0, 0.0] if abs(nrm[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(nrm, u)  # (u, v, nrm) right-handed: the outline stays counter-clockwise
        poly = points[indices[starts[f]:starts[f] + k]]
        flat = np.stack([poly @ u, poly @ v], axis=1)
        tri = np.asarray(mapbox_earcut.triangulate_float64(flat, np.array([k], dtype=np.uint32)), np.int64)
        if tri.size != 3 * (k - 2):
            continue
        tri = tri.reshape(-1, 3)
        e1, e2 = flat[tri[:, 1]] - flat[tri[:, 0]], flat[tri[:, 2]] - flat[tri[:, 0]]
        flip = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
        tri[flip] = tri[flip][:, [0, 2, 1]]
        corners[first_tri[f]:first_tri[f] + k - 2] = starts[f] + tri
    return corners


def _fan_corners(counts: np.ndarray):
    """Fan triangulation of polygons: corner indices (T, 3) into faceVertexIndices, face per tri."""
    counts = np.asarray(counts, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tri_per_face = counts - 2
    face_of_tri = np.repeat(np.arange(counts.size), tri_per_face)
    first_tri = np.cumsum(tri_per_face) - tri_per_face
    k = np.arange(face_of_tri.size) - first_tri[face_of_tri]
    s = starts[face_of_tri]
    return np.stack([s, s + k + 1, s + k + 2], axis=1), face_of_tri
