"""The per-frame state of a scene: :class:`FrameState`, the device arrays with fixed addresses
that the :class:`~warpshade.scene._state.FrameEvaluator` fills every frame and the stages read."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from .._wp import wp
from ._state_flags import MaterialAssignment


@dataclass
class FrameState:
    """What changes per frame, as Warp arrays with fixed addresses on one device.

    Attributes:
        frame: the time code evaluated last (host float).
        frame_index: its index in ``scene.frames`` (host int).
        frame_index_device: the same on the device, wp.array(int32), shape (1,) -- what the
            per-frame kernels read.
        points: world-space vertex positions, wp.array(vec3), shape (vertex_count,).
        normals: world-space unit vertex normals, wp.array(vec3), shape (vertex_count,).
        mesh_transforms: local-to-world per mesh (skeleton-to-world for skinned meshes),
            wp.array(mat44), shape (mesh_count,), column-vector convention.
        mesh_scales: largest singular value of each mesh transform's 3x3 part (a sphere of
            radius r maps inside radius s * r), wp.array(float32), shape (mesh_count,).
        joint_transforms: skeleton-space joint transforms of all skeletons concatenated,
            wp.array(mat44), shape (joint_count,); skeleton ``s`` owns
            ``joint_offsets[s] : joint_offsets[s + 1]``.
        skin_matrices: ``skel_to_world @ joint @ inverse(bind)`` per joint (what linear blend
            skinning applies to bind-space points), wp.array(mat44), shape (joint_count,).
        joint_offsets: first joint of each skeleton, host list of length skeleton_count + 1.
        lighting: the frame's lights (:class:`~warpshade.scene._lighting_warp.FrameLighting`),
            or None when the evaluator has no lighting.
        eye: viewer position, wp.array(vec3), shape (1,) (the scene camera's position, or set).
        has_eye: whether ``eye`` is a real viewer (a camera or set explicitly).
        bvh: :class:`~warpshade.geometry._bvh.Visibility` over ``points``, refit every frame,
            or None when not asked for.
        materials: the :class:`MaterialAssignment` (BRDFs set at run time; host data read by
            stages when notified of :data:`Change.MATERIAL`).
        device: the Warp device.
    """

    frame: float
    frame_index: int
    frame_index_device: Any
    points: Any
    normals: Any
    mesh_transforms: Any
    mesh_scales: Any
    joint_transforms: Any
    skin_matrices: Any
    joint_offsets: list = field(default_factory=list)
    lighting: Any = None
    eye: Any = None
    has_eye: bool = False
    bvh: Any = None
    device: Any = None
    materials: MaterialAssignment = field(default_factory=MaterialAssignment)

    @property
    def vertex_count(self) -> int:
        return int(self.points.shape[0])

    def snapshot(self) -> "FrameState":
        """A copy of the geometry arrays (points, normals, transforms) detached from the
        evaluator's buffers; lighting and BVH are not copied."""
        return FrameState(
            frame=self.frame, frame_index=self.frame_index, frame_index_device=wp.clone(self.frame_index_device),
            points=wp.clone(self.points), normals=wp.clone(self.normals),
            mesh_transforms=wp.clone(self.mesh_transforms), mesh_scales=wp.clone(self.mesh_scales),
            joint_transforms=wp.clone(self.joint_transforms), skin_matrices=wp.clone(self.skin_matrices),
            joint_offsets=list(self.joint_offsets), eye=wp.clone(self.eye), has_eye=self.has_eye, device=self.device,
        )
