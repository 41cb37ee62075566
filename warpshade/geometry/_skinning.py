"""Linear-blend skinning (LBS) and rigid point/normal transforms on Warp, with float64 mirrors.

Matrices follow USD's row-vector convention (``p' = [p, 1] @ M``). A skinned point is

    p_skel = sum_k w_k * ([p, 1] @ geom_bind @ skinning_transform[j_k])

with ``skinning_transform[j] = inverse(bind[j]) @ skel_space[j]`` (see
:meth:`warpshade.scene.Skeleton.skinning_transforms`), which is UsdSkel's linear blend
skinning. The Warp kernel takes the per-joint matrices already composed with whatever comes
after skinning (e.g. the skeleton's local-to-world), so one launch writes world-space points.

A rigid transform is the one-joint case; :func:`launch_transform_points` and
:func:`launch_transform_normals` do it without weights, for static, rigid and deforming meshes.
All launches write into a slice of a scene-wide output array (meshes are concatenated).

The per-frame kernels read everything that changes per frame from device arrays -- matrices
by index, the frame index from a one-element array -- so a frame's launches can be recorded
once and replayed (:mod:`warpshade.scene._state`); :func:`skeleton_pose_kernel` composes joint
hierarchies on the device.
"""

import numpy as np

from .._wp import resolve_device, wp

__all__ = [
    "skin_points_f64",
    "skin_points",
    "launch_skin_points",
    "joint_matrices_for_warp",
    "launch_transform_points",
    "launch_transform_normals",
    "skin_points_kernel",
    "transform_points_kernel",
    "transform_normals_kernel",
    "skeleton_pose_kernel",
]

wp.set_module_options({"enable_backward": False})


@wp.kernel
def skin_points_kernel(
    bound_points: wp.array(dtype=wp.vec3),
    joint_indices: wp.array2d(dtype=wp.int32),
    joint_weights: wp.array2d(dtype=wp.float32),
    joint_matrices: wp.array(dtype=wp.mat44),
    joint_offset: int,
    out_points: wp.array(dtype=wp.vec3),
    out_offset: int,
):
    """``out[out_offset + v] = sum_k w_vk * (M[joint_offset + j_vk] p_v)`` (column-vector mat44)."""
    v = wp.tid()
    p = bound_points[v]
    acc = wp.vec3(0.0, 0.0, 0.0)
    for k in range(joint_indices.shape[1]):
        w = joint_weights[v, k]
        if w != 0.0:
            acc += w * wp.transform_point(joint_matrices[joint_offset + joint_indices[v, k]], p)
    out_points[out_offset + v] = acc


@wp.kernel
def transform_points_kernel(
    points: wp.array(dtype=wp.vec3),
    in_offset: int,
    frame: wp.array(dtype=wp.int32),
    frame_stride: int,
    matrices: wp.array(dtype=wp.mat44),
    matrix_index: int,
    out_points: wp.array(dtype=wp.vec3),
    out_offset: int,
):
    """``out[out_offset + v] = M p`` with ``p = points[in_offset + frame[0] * frame_stride + v]``
    and ``M = matrices[matrix_index]`` (column-vector mat44): rigid meshes (stride 0) and
    per-frame point samples (stride = vertex count) read their frame on the device."""
    v = wp.tid()
    p = points[in_offset + frame[0] * frame_stride + v]
    out_points[out_offset + v] = wp.transform_point(matrices[matrix_index], p)


@wp.kernel
def transform_normals_kernel(
    normals: wp.array(dtype=wp.vec3),
    matrices: wp.array(dtype=wp.mat44),
    matrix_index: int,
    area_sums: int,
    out_normals: wp.array(dtype=wp.vec3),
    out_offset: int,
):
    """Normals under ``M = matrices[matrix_index]``: ``normalize(s * inverse(M3)^T n)``.

    ``s = 1`` for unit normals (authored normals keep their side under a mirror) and
    ``s = sign(det M3)`` for area-weighted normal sums (``area_sums = 1``): the cross products
    they sum transform by the cofactor matrix ``det(M3) inverse(M3)^T``, so a mirroring
    transform flips them exactly as recomputing them from the transformed triangles would.
    Zero-length results become (0, 0, 1).
    """
    v = wp.tid()
    m = matrices[matrix_index]
    m3 = wp.mat33(m[0, 0], m[0, 1], m[0, 2], m[1, 0], m[1, 1], m[1, 2], m[2, 0], m[2, 1], m[2, 2])
    det = wp.determinant(m3)
    n = wp.vec3(0.0)
    if wp.abs(det) > 1.0e-30:  # a transform that flattens the mesh: the fallback normal below
        n = wp.transpose(wp.inverse(m3)) * normals[v]
        if area_sums != 0 and det < 0.0:
            n = -n
    length = wp.length(n)
    if length > 1.0e-30:
        n = n / length
    else:
        n = wp.vec3(0.0, 0.0, 1.0)
    out_normals[out_offset + v] = n


@wp.kernel
def skeleton_pose_kernel(
    frame: wp.array(dtype=wp.int32),
    local: wp.array(dtype=wp.mat44),
    local_start: wp.array(dtype=wp.int32),
    local_frames: wp.array(dtype=wp.int32),
    joint_start: wp.array(dtype=wp.int32),
    parents: wp.array(dtype=wp.int32),
    inverse_bind: wp.array(dtype=wp.mat44),
    skel_to_world: wp.array(dtype=wp.mat44),
    world_start: wp.array(dtype=wp.int32),
    world_frames: wp.array(dtype=wp.int32),
    live_slot: wp.array(dtype=wp.int32),
    live_local: wp.array(dtype=wp.mat44),
    joint_transforms: wp.array(dtype=wp.mat44),
    skin_matrices: wp.array(dtype=wp.mat44),
):
    """Pose every skeleton of a scene at frame ``frame[0]``, one thread per skeleton.

    All matrices are Warp column-vector mat44 (the transposes of USD's row-vector matrices).
    Skeleton ``s`` owns joints ``joint_start[s] .. joint_start[s + 1]`` (parents first, as USD
    requires); its joint-local transforms are ``local_frames[s]`` frames of that many joints
    from ``local_start[s]`` (frame-major), its skeleton-to-world ``world_frames[s]`` matrices
    from ``world_start[s]``; a frame past the last sample holds the last one. When
    ``frame[live_slot[s]]`` is non-zero (``live_slot[s] >= 0``) the skeleton's joint-local
    transforms are read from ``live_local`` instead (joints ``joint_start[s] ..``, USD's
    row-vector matrices as fed from Python, transposed here). Writes the
    skeleton-space joint transforms ``X_j = X_parent L_j`` and the skinning matrices
    ``skel_to_world X_j inverse(bind_j)``.
    """
    s = wp.tid()
    t = frame[0]
    j0 = joint_start[s]
    count = joint_start[s + 1] - j0
    lt = wp.min(t, local_frames[s] - 1)
    world = skel_to_world[world_start[s] + wp.min(t, world_frames[s] - 1)]
    live = False
    if live_slot[s] >= 0:
        live = frame[live_slot[s]] != 0
    for j in range(count):
        x = local[local_start[s] + lt * count + j]
        if live:
            x = wp.transpose(live_local[j0 + j])
        p = parents[j0 + j]
        if p >= 0:
            x = joint_transforms[j0 + p] * x
        joint_transforms[j0 + j] = x
        skin_matrices[j0 + j] = world * x * inverse_bind[j0 + j]


def _matrix_array(matrices, device):
    """Row-vector (4, 4) or (K, 4, 4) NumPy matrices, or a wp.array(mat44), as a device array."""
    if isinstance(matrices, wp.array):
        return matrices
    return wp.array(joint_matrices_for_warp(matrices), dtype=wp.mat44, device=device)


def launch_transform_points(points, in_offset: int, count: int, matrices, out_points, out_offset: int = 0,
                            matrix_index: int = 0, frame=None, frame_stride: int = 0) -> None:
    """``out[out_offset + v] = [points[in_offset + v], 1] @ M`` for v < count, on Warp.

    Args:
        points: wp.array(vec3) holding the source points (e.g. all frames of a deforming mesh).
        in_offset: index of the first source point (plus ``frame[0] * frame_stride``).
        count: number of points.
        matrices: a (4, 4) row-vector matrix (USD convention, float64; uploaded), or a device
            wp.array(mat44) in Warp's column-vector layout read at ``matrix_index``.
        out_points: wp.array(vec3) on the same device.
        out_offset: first output index.
        frame, frame_stride: optional device wp.array(int32) whose first entry selects the frame
            of per-frame point samples (``frame_stride`` points per frame).
    """
    if count == 0:
        return
    dev = points.device
    frame = wp.zeros(1, dtype=wp.int32, device=dev) if frame is None else frame
    wp.launch(
        transform_points_kernel,
        dim=int(count),
        inputs=[points, int(in_offset), frame, int(frame_stride), _matrix_array(matrices, dev), int(matrix_index),
                out_points, int(out_offset)],
        device=dev,
    )


def launch_transform_normals(normals, matrices, out_normals, out_offset: int = 0, matrix_index: int = 0,
                             area_sums: bool = False) -> None:
    """Transform normals by the inverse transpose of ``M``'s 3x3 part and renormalise.

    In row-vector form ``n' = n @ inverse(M3).T``; zero-length results become (0, 0, 1).
    ``matrices`` is a (4, 4) row-vector matrix or a device wp.array(mat44) read at
    ``matrix_index``; ``area_sums`` marks unnormalised area-weighted sums (see
    :func:`transform_normals_kernel`).
    """
    count = normals.shape[0]
    if count == 0:
        return
    dev = normals.device
    wp.launch(
        transform_normals_kernel,
        dim=count,
        inputs=[normals, _matrix_array(matrices, dev), int(matrix_index), int(bool(area_sums)), out_normals, int(out_offset)],
        device=dev,
    )


def joint_matrices_for_warp(row_matrices: np.ndarray) -> np.ndarray:
    """Convert row-vector (USD) matrices (J, 4, 4) to Warp's column-vector mat44 layout (float32)."""
    m = np.asarray(row_matrices, dtype=np.float64).reshape(-1, 4, 4)
    return np.ascontiguousarray(np.transpose(m, (0, 2, 1))).astype(np.float32)


def launch_skin_points(
    bound_points: wp.array,
    joint_indices: wp.array,
    joint_weights: wp.array,
    joint_matrices: wp.array,
    out_points: wp.array,
    out_offset: int = 0,
    joint_offset: int = 0,
) -> None:
    """Skin points on the arrays' device, writing ``out_points[out_offset : out_offset + V]``.

    Args:
        bound_points: points already in bind space (``[p, 1] @ geom_bind``),
            wp.array(vec3), shape (V,).
        joint_indices: influencing joints per point, wp.array2d(int32), shape (V, K).
        joint_weights: matching weights, wp.array2d(float32), shape (V, K).
        joint_matrices: per-joint transforms in Warp's column-vector layout
            (:func:`joint_matrices_for_warp`), wp.array(mat44); joint ``j`` of this mesh is
            entry ``joint_offset + j``.
        out_points: output, wp.array(vec3), at least ``out_offset + V`` long.
        out_offset: first output index (meshes are concatenated in scene order).
        joint_offset: index of the mesh's skeleton's first joint in ``joint_matrices``.
    """
    count = bound_points.shape[0]
    if count == 0:
        return
    wp.launch(
        skin_points_kernel,
        dim=count,
        inputs=[bound_points, joint_indices, joint_weights, joint_matrices, int(joint_offset), out_points, int(out_offset)],
        device=bound_points.device,
    )


def skin_points_f64(points, skin, skinning_transforms) -> np.ndarray:
    """Float64 linear-blend skinning of one mesh (the oracle for the Warp kernel).

    Args:
        points: rest points in the mesh's local space, shape (V, 3).
        skin: a :class:`warpshade.scene.SkinBinding` (joint_indices/joint_weights (V, K),
            geom_bind_transform (4, 4)).
        skinning_transforms: ``inverse(bind) @ skel_space`` per joint, shape (J, 4, 4), float64,
            row-vector convention.

    Returns:
        Skinned points in skeleton space, shape (V, 3), float64.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    bind = np.asarray(skin.geom_bind_transform, dtype=np.float64)
    bound = p @ bind[:3, :3] + bind[3, :3]
    xf = np.asarray(skinning_transforms, dtype=np.float64)
    idx = np.asarray(skin.joint_indices, dtype=np.int64)
    w = np.asarray(skin.joint_weights, dtype=np.float64)
    # (V, K, 3): every influence's transformed point, then the weighted sum over K.
    per_influence = np.einsum("vi,vkij->vkj", bound, xf[idx, :3, :3]) + xf[idx, 3, :3]
    return np.einsum("vk,vkj->vj", w, per_influence)


def skin_points(points, skin, skinning_transforms, post_transform=None, device=None) -> np.ndarray:
    """Skin one mesh with the Warp kernel (float32); returns (V, 3) float32 in skeleton space.

    ``post_transform`` (4, 4, row-vector) is applied after skinning (e.g. skeleton-to-world).
    This host wrapper uploads everything per call; :meth:`warpshade.scene.Scene.evaluate`
    keeps the static arrays on the device instead.
    """
    dev = resolve_device(device)
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    bind = np.asarray(skin.geom_bind_transform, dtype=np.float64)
    bound = (p @ bind[:3, :3] + bind[3, :3]).astype(np.float32)
    xf = np.asarray(skinning_transforms, dtype=np.float64)
    if post_transform is not None:
        xf = xf @ np.asarray(post_transform, dtype=np.float64)
    pts = wp.array(bound, dtype=wp.vec3, device=dev)
    idx = wp.array(np.asarray(skin.joint_indices, dtype=np.int32), dtype=wp.int32, device=dev)
    wgt = wp.array(np.asarray(skin.joint_weights, dtype=np.float32), dtype=wp.float32, device=dev)
    mats = wp.array(joint_matrices_for_warp(xf), dtype=wp.mat44, device=dev)
    out = wp.empty(p.shape[0], dtype=wp.vec3, device=dev)
    launch_skin_points(pts, idx, wgt, mats, out)
    return out.numpy()
