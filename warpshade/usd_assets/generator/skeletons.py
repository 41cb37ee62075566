"""UsdSkel rigs and skinning of the scene generator.

A joint table lists ``(name, parent, rest offset from the parent)``; :func:`define_skeleton` writes a
Skeleton and its Animation (rotation vectors per frame as quaternions), :func:`bind_skin` binds a
mesh with per-vertex (or constant) joint indices and weights, :func:`chain_weights` and
:func:`strongest_influences` build smooth weights along a joint chain, and
:func:`write_character` writes one clip of a skinned character with the ground, sky and camera.
"""

from __future__ import annotations

import os

import numpy as np
from pxr import Gf, UsdSkel, Vt
from scipy.spatial.transform import Rotation

from .shapes import smoothstep
from .sky import define_sky
from .writing import define_camera, define_ground, new_stage, rounded, save_stage


def joint_paths(joints):
    names = {}
    for name, parent, _ in joints:
        names[name] = name if parent is None else f"{names[parent]}/{name}"
    return [names[n] for n, _, _ in joints]


def _quat_array(rotvecs) -> Vt.QuatfArray:
    q = Rotation.from_rotvec(rotvecs).as_quat()  # (x, y, z, w)
    q = rounded(q)
    return Vt.QuatfArray([Gf.Quatf(float(w), Gf.Vec3f(float(x), float(y), float(z))) for x, y, z, w in q])


def define_skeleton(stage, root_path, joints, rotations, frame_count):
    """A Skeleton and its Animation under ``root_path``: rest/bind poses from ``joints`` offsets.

    ``joints`` lists (name, parent, rest offset from the parent); rest rotations are identity, so
    the authored rotations ``rotations(frame)`` (rotation vectors, (J, 3)) are the joint angles
    relative to the rest pose. Returns the Skeleton and the joint paths.
    """
    paths = joint_paths(joints)
    skel = UsdSkel.Skeleton.Define(stage, f"{root_path}/Skel")
    skel.CreateJointsAttr(Vt.TokenArray(paths))
    world = {}
    local_rest, bind = [], []
    for name, par, off in joints:
        world[name] = np.asarray(off, float) + (world[par] if par else 0.0)
        local_rest.append(Gf.Matrix4d().SetTranslate(Gf.Vec3d(*rounded(off))))
        bind.append(Gf.Matrix4d().SetTranslate(Gf.Vec3d(*rounded(world[name]))))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray(local_rest))
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray(bind))
    anim = UsdSkel.Animation.Define(stage, f"{root_path}/Anim")
    anim.CreateJointsAttr(Vt.TokenArray(paths))
    anim.CreateTranslationsAttr(Vt.Vec3fArray([Gf.Vec3f(*rounded(off)) for _, _, off in joints]))
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1.0, 1.0, 1.0)] * len(paths)))
    attr = anim.CreateRotationsAttr()
    for f in range(frame_count):
        attr.Set(_quat_array(rotations(f)), f)
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    return skel, paths


def bind_skin(mesh, skel, indices, weights, element_size, geom_bind, joints=None, constant=False):
    """Bind a mesh to a skeleton: per-vertex (or ``constant``) joint indices and weights."""
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    if joints is not None:  # the mesh's own joint order, which its indices refer to
        binding.CreateJointsAttr(Vt.TokenArray(joints))
    binding.CreateJointIndicesPrimvar(constant, element_size).Set(Vt.IntArray([int(v) for v in np.ravel(indices)]))
    binding.CreateJointWeightsPrimvar(constant, element_size).Set(Vt.FloatArray([float(v) for v in rounded(weights).ravel()]))
    binding.CreateGeomBindTransformAttr(geom_bind)
    return binding


def write_character(out_dir, file_name, root_path, joints, rotations, frame_count, dress, camera, place=None) -> str:
    """One clip of a skinned character over the ground grid, under the sky, with a camera.

    Args:
        root_path: the SkelRoot, which ``place(root)`` (optional) may move; the skeleton and its
            animation (:func:`define_skeleton`: ``joints``, ``rotations(frame)``) go below it.
        dress: ``dress(stage, skeleton, joint paths)`` adds the character's skinned meshes.
        camera: (eye, target).
    """
    stage = new_stage(animated=True, frame_count=frame_count)
    define_sky(stage)
    define_ground(stage)
    root = UsdSkel.Root.Define(stage, root_path)
    if place is not None:
        place(root)
    skel, paths = define_skeleton(stage, root_path, joints, rotations, frame_count)
    dress(stage, skel, paths)
    define_camera(stage, *camera)
    path = os.path.join(out_dir, file_name)
    save_stage(stage, path)
    return path


def chain_weights(s, chain) -> np.ndarray:
    """Smooth skinning weights along a tube that follows a chain of joints, (N, len(chain)).

    Args:
        s: the points' axis parameters (N,).
        chain: (joint, s where its bone begins, blend half-width) rows in order along the
            tube; the first joint owns everything before the second's start, the last
            everything after its own. Across each bone start the weight passes from the previous
            joint to the next by a smoothstep over +-half-width (0.5 each at the start), so a
            point near a bone shorter than its two half-widths takes three joints.

    Returns:
        weights per chain joint, rows sum to 1.
    """
    w = np.ones((len(s), len(chain)))
    for k in range(1, len(chain)):
        _, start, half = chain[k]
        rise = smoothstep((s - start + half) / (2.0 * half))
        w[:, k] *= rise
        w[:, k - 1] *= 1.0 - rise
    return w / w.sum(1, keepdims=True)


def strongest_influences(joints, weights, count: int):
    """The ``count`` largest weights per row (strongest first) and their joints, renormalised.

    ``joints`` (N, M) or (M,) joint indices, ``weights`` (N, M); with fewer than ``count``
    columns, each row is padded with its strongest joint at weight 0.
    """
    joints = np.broadcast_to(np.asarray(joints), weights.shape)
    order = np.argsort(-weights, axis=1, kind="stable")[:, :count]
    if order.shape[1] < count:
        order = np.concatenate([order, np.repeat(order[:, :1], count - order.shape[1], 1)], 1)
    w = np.take_along_axis(weights, order, 1)
    w = np.where(np.arange(count) < weights.shape[1], w, 0.0)
    return np.take_along_axis(joints, order, 1), w / w.sum(1, keepdims=True)
