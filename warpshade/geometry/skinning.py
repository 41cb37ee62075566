"""Linear-blend skinning (LBS) and rigid point/normal transforms on Warp, with float64 references.

Matrices follow USD's row-vector convention (``p' = [p, 1] @ M``). A skinned point is

    p_skel = sum_k w_k * ([p, 1] @ geom_bind @ skinning_transform[j_k])

with ``skinning_transform[j] = inverse(bind[j]) @ skel_space[j]`` (see
:meth:`warpshade.scene.Skeleton.skinning_transforms`), which is UsdSkel's linear blend
skinning. The Warp kernel takes the per-joint matrices already composed with whatever comes
after skinning (e.g. the skeleton's local-to-world), so one launch writes world-space points.

A rigid transform is the one-joint case; :func:`launch_transform_points` and
:func:`launch_transform_normals` do it without weights, for static, rigid and deforming meshes.
All launches write into a slice of a scene-wide output array (meshes are concatenated).
"""

import numpy as np

from .._wp import resolve_device, wp

__all__ = [
    "skin_points_reference",
    "skin_points",
    "launch_skin_points",
    "joint_matrices_for_warp",
    "launch_transform_points",
    "launch_transform_normals",
]

wp.set_module_options({"enable_backward": False})


@wp.kernel
def _skin_points_kernel(
    bound_points: wp.array(dtype=wp.vec3),
    joint_indices: wp.array2d(dtype=wp.int32),
    joint_weights: wp.array2d(dtype=wp.float32),
    joint_matrices: wp.array(dtype=wp.mat44),
    out_points: wp.array(dtype=wp.vec3),
    out_offset: int,
):
    v = wp.tid()
    p = bound_points[v]
    acc = wp.vec3(0.0, 0.0, 0.0)
    for k in range(joint_indices.shape[1]):
        w = joint_weights[v, k]
        if w != 0.0:
            acc += w * wp.transform_point(joint_matrices[joint_indices[v, k]], p)
    out_points[out_offset + v] = acc


@wp.kernel
def _transform_points_kernel(
    points: wp.array(dtype=wp.vec3),
    in_offset: int,
    matrix: wp.mat44,
    out_points: wp.array(dtype=wp.vec3),
    out_offset: int,
):
    v = wp.tid()
    out_points[out_offset + v] = wp.transform_point(matrix, points[in_offset + v])


@wp.kernel
def _transform_normals_kernel(
    normals: wp.array(dtype=wp.vec3),
    normal_matrix: wp.mat33,
    out_normals: wp.array(dtype=wp.vec3),
    out_offset: int,
):
    v = wp.tid()
    n = normal_matrix * normals[v]
    length = wp.length(n)
    if length > 1.0e-30:
        n = n / length
    else:
        n = wp.vec3(0.0, 0.0, 1.0)
    out_normals[out_offset + v] = n


def launch_transform_points(points, in_offset: int, count: int, row_matrix, out_points, out_offset: int = 0) -> None:
    """``out[out_offset + v] = [points[in_offset + v], 1] @ row_matrix`` for v < count, on Warp.

    Args:
        points: wp.array(vec3) holding the source points (e.g. all frames of a deforming mesh).
        in_offset: index of the first source point.
        count: number of points.
        row_matrix: (4, 4) local-to-world, row-vector convention (USD), float64.
        out_points: wp.array(vec3) on the same device.
        out_offset: first output index.
    """
    if count == 0:
        return
    m = np.asarray(row_matrix, np.float64).reshape(4, 4).T.astype(np.float32)
    wp.launch(
        _transform_points_kernel,
        dim=int(count),
        inputs=[points, int(in_offset), wp.mat44(*m.ravel()), out_points, int(out_offset)],
        device=points.device,
    )


def launch_transform_normals(normals, row_matrix, out_normals, out_offset: int = 0) -> None:
    """Transform unit normals by the inverse transpose of ``row_matrix``'s 3x3 part and renormalise.

    In row-vector form ``n' = n @ inverse(M3).T``; zero-length results become (0, 0, 1).
    """
    count = normals.shape[0]
    if count == 0:
        return
    m3 = np.asarray(row_matrix, np.float64).reshape(4, 4)[:3, :3]
    # Row form n @ inv(M3).T is column form inv(M3) @ n.
    c = np.linalg.inv(m3).astype(np.float32)
    wp.launch(
        _transform_normals_kernel,
        dim=count,
        inputs=[normals, wp.mat33(*c.ravel()), out_normals, int(out_offset)],
        device=normals.device,
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
) -> None:
    """Skin points on the arrays' device, writing ``out_points[out_offset : out_offset + V]``.

    Args:
        bound_points: points already in bind space (``[p, 1] @ geom_bind``),
            wp.array(vec3), shape (V,).
        joint_indices: influencing joints per point, wp.array2d(int32), shape (V, K).
        joint_weights: matching weights, wp.array2d(float32), shape (V, K).
        joint_matrices: per-joint transforms in Warp's column-vector layout
            (:func:`joint_matrices_for_warp`), wp.array(mat44), shape (J,).
        out_points: output, wp.array(vec3), at least ``out_offset + V`` long.
        out_offset: first output index (meshes are concatenated in scene order).
    """
    count = bound_points.shape[0]
    if count == 0:
        return
    wp.launch(
        _skin_points_kernel,
        dim=count,
        inputs=[bound_points, joint_indices, joint_weights, joint_matrices, out_points, int(out_offset)],
        device=bound_points.device,
    )


def skin_points_reference(points, skin, skinning_transforms) -> np.ndarray:
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
