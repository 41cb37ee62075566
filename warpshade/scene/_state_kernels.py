"""Kernels of the frame evaluation (:class:`~warpshade.scene._state.FrameEvaluator`): the eye and the
mesh transforms looked up in their per-frame tables, fed points copied in, fed values checked.

Each reads the frame's host inputs (``frame``: the frame index, then flags the host sets) on the
device, so a recorded frame replays them.
"""

from __future__ import annotations

from .._wp import wp

wp.set_module_options({"enable_backward": False})


@wp.kernel
def eye_kernel(frame: wp.array(dtype=wp.int32), table: wp.array(dtype=wp.vec3), eye: wp.array(dtype=wp.vec3)):
    # frame[2] = 1 once the host has set the eye itself (set_eye): the camera path no longer drives it
    if frame[2] == 0:
        eye[0] = table[wp.min(frame[0], table.shape[0] - 1)]


@wp.kernel
def mesh_transforms_kernel(
    frame: wp.array(dtype=wp.int32),
    table: wp.array(dtype=wp.mat44),
    scale_table: wp.array(dtype=wp.float32),
    start: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    transforms: wp.array(dtype=wp.mat44),
    scales: wp.array(dtype=wp.float32),
):
    m = wp.tid()
    k = start[m] + wp.min(frame[0], count[m] - 1)
    transforms[m] = table[k]
    scales[m] = scale_table[k]


@wp.kernel
def live_points_kernel(frame: wp.array(dtype=wp.int32), slot: int, staging: wp.array(dtype=wp.vec3),
                        points: wp.array(dtype=wp.vec3), offset: int):
    # frame[slot] = 1 when the host fed this mesh's points for the frame (FrameEvaluator.set_frame)
    if frame[slot] != 0:
        v = wp.tid()
        points[offset + v] = staging[v]


@wp.kernel
def count_nonfinite_kernel(values: wp.array(dtype=wp.float32), count: wp.array(dtype=wp.int32)):
    if not wp.isfinite(values[wp.tid()]):
        wp.atomic_add(count, 0, 1)
