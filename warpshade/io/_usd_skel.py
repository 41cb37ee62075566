"""UsdSkel in a USD stage: skeletons (joint order, hierarchy, bind and rest poses, the animated
joint-local transforms) and the skin bindings of the meshes bound to them.

Part of the stage reader of :mod:`warpshade.io._usd` (whose docstring states the rules): each
function takes the ``_StageReader`` doing the load as ``reader``.
"""

from __future__ import annotations

import warnings

import numpy as np

from ..scene._scene import Skeleton, SkinBinding

__all__ = ["read_skinning", "read_skin_binding"]


def read_skinning(reader):
    """Skeletons, and per skinned mesh path (skeleton index, UsdSkel.SkinningQuery, Skeleton)."""
    from pxr import Usd, UsdSkel

    cache = UsdSkel.Cache()
    skins: dict[str, tuple[int, object]] = {}
    skeletons: list[Skeleton] = []
    index_of: dict[str, int] = {}
    for prim in Usd.PrimRange(reader.stage.GetPseudoRoot(), reader.predicate):
        if not prim.IsA(UsdSkel.Root):
            continue
        root = UsdSkel.Root(prim)
        cache.Populate(root, reader.predicate)
        for binding in cache.ComputeSkelBindings(root, reader.predicate):
            skel = binding.GetSkeleton()
            skel_path = str(skel.GetPrim().GetPath())
            query = cache.GetSkelQuery(skel)
            if not query:
                raise ValueError(f"skeleton {skel_path} in {reader.path}: invalid skeleton (check joints and bindTransforms)")
            if skel_path not in index_of:
                index_of[skel_path] = len(skeletons)
                skeletons.append(_read_skeleton(reader, skel, query))
            for target in binding.GetSkinningTargets():
                skins[str(target.GetPrim().GetPath())] = (index_of[skel_path], target, skeletons[index_of[skel_path]])
    return skins, skeletons


def _read_skeleton(reader, skel, query) -> Skeleton:
    path = str(skel.GetPrim().GetPath())
    joints = [str(j) for j in query.GetJointOrder()]
    if not joints:
        raise ValueError(f"skeleton {path} in {reader.path}: has no joints")
    j = len(joints)
    topology = query.GetTopology()
    valid, why = topology.Validate()
    if not valid:
        raise ValueError(f"skeleton {path} in {reader.path}: invalid joint hierarchy ({why})")
    parents = np.asarray(topology.GetParentIndices(), dtype=np.int64)
    bind = np.array(query.GetJointWorldBindTransforms(), dtype=np.float64).reshape(-1, 4, 4)
    if bind.shape[0] != j:
        raise ValueError(f"skeleton {path} in {reader.path}: {bind.shape[0]} bindTransforms for {j} joints")
    rest_attr = skel.GetRestTransformsAttr().Get()
    if rest_attr is not None and len(rest_attr) == j:
        rest = np.array(rest_attr, dtype=np.float64).reshape(j, 4, 4)
    else:
        rest = np.array(query.ComputeJointLocalTransforms(reader.times[0], True), dtype=np.float64).reshape(j, 4, 4)
    local = np.stack(
        [np.array(query.ComputeJointLocalTransforms(t), dtype=np.float64).reshape(j, 4, 4) for t in reader.times]
    )
    if not (np.all(np.isfinite(local)) and np.all(np.isfinite(bind))):
        raise ValueError(f"skeleton {path} in {reader.path}: joint transforms have NaN or infinite entries")
    if np.all(local == local[:1]):
        local = local[:1]
    return Skeleton(
        path=path,
        joint_names=joints,
        parents=parents,
        bind_transforms=bind,
        rest_transforms=rest,
        local_transforms=local,
        skel_to_world=reader._world_transforms(skel.GetPrim()),
    )


def read_skin_binding(reader, skin_info, path, vertex_count) -> SkinBinding:
    from pxr import UsdGeom

    skel_index, query, skeleton = skin_info
    t0 = reader.times[0]
    idx_pv = query.GetJointIndicesPrimvar()
    w_pv = query.GetJointWeightsPrimvar()
    if not (idx_pv and w_pv and idx_pv.HasAuthoredValue() and w_pv.HasAuthoredValue()):
        raise ValueError(f"mesh {path} in {reader.path}: bound to skeleton {skeleton.path} but has no jointIndices/jointWeights")
    k = int(query.GetNumInfluencesPerComponent())
    idx = np.asarray(idx_pv.Get(t0), dtype=np.int64)
    w = np.asarray(w_pv.Get(t0), dtype=np.float64)
    if idx.size != w.size or k < 1 or idx.size % k:
        raise ValueError(
            f"mesh {path} in {reader.path}: {idx.size} jointIndices and {w.size} jointWeights do not match "
            f"elementSize {k}"
        )
    interp = str(query.GetInterpolation())
    if interp == UsdGeom.Tokens.constant:
        if idx.size != k:
            raise ValueError(f"mesh {path} in {reader.path}: constant skinning needs {k} influences, found {idx.size}")
        idx = np.tile(idx.reshape(1, k), (vertex_count, 1))
        w = np.tile(w.reshape(1, k), (vertex_count, 1))
    elif interp == UsdGeom.Tokens.vertex:
        if idx.size != vertex_count * k:
            raise ValueError(
                f"mesh {path} in {reader.path}: {idx.size} jointIndices for {vertex_count} points x {k} influences"
            )
        idx = idx.reshape(vertex_count, k)
        w = w.reshape(vertex_count, k)
    else:
        raise ValueError(f"mesh {path} in {reader.path}: skinning interpolation {interp!r} (need constant or vertex)")
    skin_order = query.GetJointOrder()
    if skin_order:
        names = [str(n) for n in skin_order]
        lookup = {name: i for i, name in enumerate(skeleton.joint_names)}
        missing = [n for n in names if n not in lookup]
        if missing:
            raise ValueError(
                f"mesh {path} in {reader.path}: skel:joints names {len(missing)} joint(s) not in skeleton "
                f"{skeleton.path}: {', '.join(missing[:5])}"
            )
        remap = np.array([lookup[n] for n in names], dtype=np.int64)
        limit = len(names)
    else:
        remap = None
        limit = skeleton.joint_count
    if idx.size and (idx.min() < 0 or idx.max() >= limit):
        raise ValueError(
            f"mesh {path} in {reader.path}: jointIndices {int(idx.min())}..{int(idx.max())} out of range for "
            f"{limit} joints ({'skel:joints' if remap is not None else 'skeleton ' + skeleton.path})"
        )
    if remap is not None:
        idx = remap[idx]
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"mesh {path} in {reader.path}: jointWeights must be finite and >= 0")
    total = w.sum(axis=1)
    if np.any(total <= 0):
        raise ValueError(f"mesh {path} in {reader.path}: {int(np.sum(total <= 0))} point(s) have all-zero joint weights")
    w = w / total[:, None]
    method = query.GetSkinningMethod() if hasattr(query, "GetSkinningMethod") else "classicLinear"
    if str(method) not in ("", "classicLinear"):
        warnings.warn(f"mesh {path} in {reader.path}: skinning method {method!r} is evaluated as linear blend skinning", stacklevel=3)
    if query.HasBlendShapes():
        warnings.warn(f"mesh {path} in {reader.path}: blend shapes are ignored", stacklevel=3)
    return SkinBinding(
        skeleton=skel_index,
        joint_indices=idx.astype(np.int32),
        joint_weights=w.astype(np.float32),
        geom_bind_transform=np.array(query.GetGeomBindTransform(t0), dtype=np.float64),
    )
