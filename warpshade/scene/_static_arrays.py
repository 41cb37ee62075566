"""The static device arrays of a scene that the frame evaluation reads (rest or bind-pose points,
skinning weights, point samples, faces), built once per device and cached on the scene."""

from __future__ import annotations

import numpy as np

from .._wp import wp

#: Deforming meshes whose point samples (all frames) fit in this many bytes are kept on the
#: device; larger ones are uploaded one frame at a time (a Python call in the frame program).
DEVICE_SAMPLE_BYTES = 256 * 1024 * 1024


def column_matrices(row_matrices) -> np.ndarray:
    m = np.asarray(row_matrices, np.float64).reshape(-1, 4, 4)
    return np.ascontiguousarray(np.transpose(m, (0, 2, 1))).astype(np.float32)


def static_data(scene, dev) -> dict:
    """Static arrays of ``scene`` on one device, built on first use and cached on the scene."""
    key = str(dev)
    cache = scene._device_cache
    if key in cache:
        return cache[key]
    from ..geometry._normals import vertex_normal_sums_f64

    data = {"faces": wp.array(scene.faces, dtype=wp.int32, device=dev), "meshes": []}
    for mesh in scene.meshes:
        entry = {}
        if mesh.animation == "skinned":
            bind = np.asarray(mesh.skin.geom_bind_transform, np.float64)
            bound = mesh.points @ bind[:3, :3] + bind[3, :3]
            entry["points"] = wp.array(bound.astype(np.float32), dtype=wp.vec3, device=dev)
            entry["joint_indices"] = wp.array(np.asarray(mesh.skin.joint_indices, np.int32), dtype=wp.int32, device=dev)
            entry["joint_weights"] = wp.array(np.asarray(mesh.skin.joint_weights, np.float32), dtype=wp.float32, device=dev)
        elif mesh.animation == "deforming":
            samples = np.asarray(mesh.point_samples, np.float32).reshape(-1, 3)
            if samples.nbytes <= DEVICE_SAMPLE_BYTES:
                entry["samples"] = wp.array(samples, dtype=wp.vec3, device=dev)
        else:
            entry["points"] = wp.array(mesh.points.astype(np.float32), dtype=wp.vec3, device=dev)
            if mesh.normals is not None:
                entry["rest_normals"] = wp.array(np.asarray(mesh.normals, np.float32), dtype=wp.vec3, device=dev)
                entry["area_sums"] = False
            else:  # area-weighted sums of the rest pose; transformed by the cofactor they stay exact
                sums = vertex_normal_sums_f64(mesh.points, mesh.faces)
                scale = np.maximum(np.linalg.norm(sums, axis=1, keepdims=True), 1e-300)
                degenerate = np.linalg.norm(sums, axis=1) <= 1e-30
                unit = np.where(degenerate[:, None], 0.0, sums / scale)  # direction is what the cofactor keeps
                entry["rest_normals"] = wp.array(unit.astype(np.float32), dtype=wp.vec3, device=dev)
                entry["area_sums"] = True
        if mesh.animation in ("deforming", "skinned"):
            entry["faces"] = wp.array(mesh.faces + mesh.vertex_offset, dtype=wp.int32, device=dev)
            entry["vertices"] = wp.array(np.arange(mesh.vertex_offset, mesh.vertex_offset + mesh.vertex_count, dtype=np.int32),
                                         dtype=wp.int32, device=dev)
        data["meshes"].append(entry)
    cache[key] = data
    return data
