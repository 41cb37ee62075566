"""The per-frame state of a scene and the kernels that fill it.

A :class:`~warpshade.scene.Scene` is the static description (rest meshes, skeletons, animation
samples, lights); a :class:`FrameState` is what changes per frame, as device arrays with fixed
addresses; a :class:`FrameEvaluator` owns the static device data and fills one FrameState per
frame with kernels only (the split Newton makes between ``Model`` and ``State``):

* the host writes the frame index into a small input buffer (:meth:`FrameEvaluator.set_frame`);
* :meth:`FrameEvaluator.launch` reads it on the device and evaluates: per-mesh local-to-world
  transforms (table look-ups), skeleton poses and skinning matrices
  (:func:`~warpshade.geometry._skinning.skeleton_pose_kernel`), skinned / rigid / point-cached
  meshes, area-weighted normals of the moving meshes, the frame's lighting
  (:class:`~warpshade.scene._lighting_warp.FrameLighting`) and, when asked for, a BVH refit.
  Meshes that never move are evaluated once, at construction.

Because :meth:`~FrameEvaluator.launch` only launches kernels on fixed buffers, a whole frame
(scene evaluation and every stage after it) is recorded once and replayed
(:func:`warpshade._wp.record_program`). Changes that do not come from the frame -- a new
lighting, an override, a new eye or albedo -- are host writes followed by a :class:`Change`
notification.

The pieces live beside this module: the :class:`Change` flags and :class:`MaterialAssignment` in
:mod:`._state_flags`, :class:`FrameState` in :mod:`._frame_state`, the kernels in :mod:`._state_kernels`
and the scene's static device arrays in :mod:`._static_arrays`; all are importable from here.

Conventions: matrices on the device are Warp column-vector ``mat44`` (the transposes of USD's
row-vector matrices); points and normals are world space, float32.
"""

from __future__ import annotations

import numpy as np

from .._wp import HostFields, resolve_device, wp
from ._frame_state import FrameState
from ._state_flags import Change, MaterialAssignment  # noqa: F401  (Change: imported from here by the stages)
from ._state_kernels import count_nonfinite_kernel, eye_kernel, live_points_kernel, mesh_transforms_kernel
from ._static_arrays import DEVICE_SAMPLE_BYTES, column_matrices, static_data

__all__ = [
    "DEVICE_SAMPLE_BYTES",
    "CPU_REFIT_NOTE",
]

#: Why the BVH refit is a Python call of a recorded CPU frame (on CUDA it is captured).
CPU_REFIT_NOTE = "BVH refit: Warp's CPU graph capture does not record wp.Mesh.refit (measured on Warp 1.19)"

#: The mesh animations whose points a frame loop can feed (:meth:`FrameEvaluator.set_frame`):
#: their normals are recomputed from the points every frame.
LIVE_POINTS = ("deforming", "skinned")


def _checked_host(where: str, value, shape: tuple) -> np.ndarray:
    """Fed host values as float32 C-contiguous of ``shape``, finite."""
    try:
        a = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: expected an array of numbers {shape}: {exc}") from None
    if a.dtype.kind != "f":
        raise ValueError(f"{where}: expected floating-point numbers, got dtype {a.dtype}")
    if a.shape != shape:
        raise ValueError(f"{where}: expected shape {shape}, got {a.shape} (topology never changes)")
    with np.errstate(over="ignore"):  # values past float32's range become infinite: refused below
        a = np.ascontiguousarray(a, np.float32)
    bad = int(np.count_nonzero(~np.isfinite(a)))
    if bad:
        raise ValueError(f"{where}: {bad} value(s) are NaN or infinite (in float32)")
    return a


class FrameEvaluator:
    """Fills one :class:`FrameState` of a scene per frame, on one device, with kernels only.

    Args:
        scene: the :class:`~warpshade.scene.Scene`.
        device: Warp device (None = Warp's default).
        lighting: a :class:`~warpshade.scene._lighting.LightingSource` (None: no lighting in
            the state).
        eye: viewer position (3,), world (default: the scene camera's position).
        bvh: also keep a BVH over the points, refit every frame (``state.bvh``).

    Attributes:
        state: the :class:`FrameState` (fixed buffers).
        albedo: per-vertex diffuse albedo, wp.array2d(float32), shape (vertex_count, 3),
            linear RGB (static; :meth:`set_albedo` changes it).
        uncaptured: why each Python call of :meth:`launch` is not capturable (empty when the
            whole evaluation is kernels).
    """

    def __init__(self, scene, device=None, lighting=None, eye=None, bvh: bool = False):
        from ._lighting_warp import FrameLighting

        dev = resolve_device(device)
        self.scene = scene
        self.device = dev
        data = static_data(scene, dev)
        self._data = data
        #: the frame's host inputs, written only by this evaluator: the frame index, whether the
        #: SH lighting is overridden (``set_lighting_override``), whether the host set the eye
        #: (``set_eye``); kernels read them as ``frame[0]``, ``frame[1]``, ``frame[2]``. Then one
        #: field per mesh that can take fed points and per skeleton: whether the frame uses the
        #: values fed to :meth:`set_frame` (1) or the time samples (0)
        self._live_fields = {("points", k): f"live_points_{k}" for k, m in enumerate(scene.meshes)
                             if m.animation in LIVE_POINTS}
        self._live_fields.update({("joints", s): f"live_joints_{s}" for s in range(len(scene.skeletons))})
        self.input = HostFields(("frame_index", "sh_override", "eye_from_host", *self._live_fields.values()), dev)
        #: mesh index -> staging buffer of fed points (allocated when a mesh is first fed)
        self._live_points: dict[int, Any] = {}
        #: (kind, index) -> (device staging array, its host side, a NumPy view of the host side)
        self._live_staging: dict[tuple, tuple] = {}
        #: bumped whenever a staging buffer is allocated: a recorded frame older than it must be
        #: recorded again (it does not read the new buffer)
        self.live_version = 0
        self.uncaptured: list[str] = []

        # per-mesh transform tables (skeleton-to-world for skinned meshes), row t = frame index t
        tables, scales, start, count = [], [], [], []
        for mesh in scene.meshes:
            rows = self._mesh_transform_rows(mesh)
            start.append(sum(t.shape[0] for t in tables))
            count.append(rows.shape[0])
            tables.append(rows)
            scales.append(np.linalg.svd(rows[:, :3, :3], compute_uv=False)[:, 0])
        table = np.concatenate(tables)
        self._transform_table = wp.array(column_matrices(table), dtype=wp.mat44, device=dev)
        self._scale_table = wp.array(np.concatenate(scales).astype(np.float32), dtype=wp.float32, device=dev)
        self._transform_start = wp.array(np.array(start, np.int32), dtype=wp.int32, device=dev)
        self._transform_count = wp.array(np.array(count, np.int32), dtype=wp.int32, device=dev)

        # skeletons: joint-local animation, parents, inverse binds, skeleton-to-world
        offsets = [0]
        for skel in scene.skeletons:
            offsets.append(offsets[-1] + skel.joint_count)
        self._skeletons = len(scene.skeletons)
        if self._skeletons:
            local, local_start, local_frames, parents, inv_bind, world, world_start, world_frames = [], [], [], [], [], [], [], []
            lsum = wsum = 0
            for skel in scene.skeletons:
                lt = np.asarray(skel.local_transforms, np.float64)
                local.append(lt.reshape(-1, 4, 4))
                local_start.append(lsum)
                local_frames.append(lt.shape[0])
                lsum += lt.shape[0] * skel.joint_count
                parents.append(np.asarray(skel.parents, np.int32))
                inv_bind.append(np.linalg.inv(np.asarray(skel.bind_transforms, np.float64)))
                w = np.asarray(skel.skel_to_world, np.float64).reshape(-1, 4, 4)
                world.append(w)
                world_start.append(wsum)
                world_frames.append(w.shape[0])
                wsum += w.shape[0]
            ints = lambda x: wp.array(np.asarray(x, np.int32), dtype=wp.int32, device=dev)  # noqa: E731
            mats = lambda x: wp.array(column_matrices(np.concatenate(x)), dtype=wp.mat44, device=dev)  # noqa: E731
            live_slot = [self.input.slot(self._live_fields["joints", s]) for s in range(self._skeletons)]
            #: fed joint-local transforms (USD row-vector matrices), all skeletons concatenated
            self._live_joints = wp.zeros(offsets[-1], dtype=wp.mat44, device=dev)
            self._skel_inputs = [mats(local), ints(local_start), ints(local_frames), ints(offsets), ints(np.concatenate(parents)),
                                 mats(inv_bind), mats(world), ints(world_start), ints(world_frames), ints(live_slot),
                                 self._live_joints]
        joint_count = offsets[-1]

        v = scene.vertex_count
        camera = scene.camera
        has_eye = eye is not None or camera is not None
        eye_pos = np.asarray(eye if eye is not None else (camera.position if camera is not None else (0.0, 0.0, 0.0)), np.float32)
        self.state = FrameState(
            frame=float(scene.frames[0]), frame_index=0, frame_index_device=self.input.array[0:1],
            points=wp.zeros(v, dtype=wp.vec3, device=dev), normals=wp.zeros(v, dtype=wp.vec3, device=dev),
            mesh_transforms=wp.zeros(len(scene.meshes), dtype=wp.mat44, device=dev),
            mesh_scales=wp.zeros(len(scene.meshes), dtype=wp.float32, device=dev),
            joint_transforms=wp.zeros(max(joint_count, 1), dtype=wp.mat44, device=dev),
            skin_matrices=wp.zeros(max(joint_count, 1), dtype=wp.mat44, device=dev),
            joint_offsets=offsets, eye=wp.array([eye_pos.reshape(3)], dtype=wp.vec3, device=dev), has_eye=has_eye,
            device=dev,
        )
        # an animated camera drives the eye per frame (until set_eye)
        self._eye_table = None
        if eye is None and camera is not None and camera.moving:
            self._eye_table = wp.array(np.asarray(camera.positions, np.float32), dtype=wp.vec3, device=dev)
        self.albedo = wp.array(np.asarray(scene.albedo, np.float32).reshape(-1, 3), dtype=wp.float32, device=dev)
        self.state.lighting = FrameLighting(lighting, scene.frames, self.input, dev) if lighting is not None else None
        self.lighting_source = lighting
        for mesh in scene.meshes:
            if mesh.animation == "deforming" and "samples" not in data["meshes"][scene.meshes.index(mesh)]:
                mb = mesh.point_samples.nbytes / 2**20
                self.uncaptured.append(f"deforming mesh {mesh.path}: its point samples ({mb:.0f} MB) exceed the device "
                                       f"budget of {DEVICE_SAMPLE_BYTES / 2**20:.0f} MB and are uploaded per frame")
        # evaluate everything once: meshes that never move keep these points and normals
        self._launch(moving_only=False)
        if bvh:
            from ..geometry._bvh import Visibility

            self.state.bvh = Visibility.over(self.state.points, scene.faces)
        self.launch()

    # ---- host side -----------------------------------------------------------------------
    @staticmethod
    def _moves(mesh) -> bool:
        return not (mesh.animation == "static" or (mesh.animation == "rigid" and mesh.transforms.shape[0] == 1))

    def _mesh_transform_rows(self, mesh) -> np.ndarray:
        if mesh.animation == "skinned":
            return np.asarray(self.scene.skeletons[mesh.skin.skeleton].skel_to_world, np.float64).reshape(-1, 4, 4)
        return np.asarray(mesh.transforms, np.float64).reshape(-1, 4, 4)

    @property
    def moving(self) -> bool:
        """Whether any mesh moves (else the points, normals and BVH never change)."""
        return any(self._moves(m) for m in self.scene.meshes)

    def set_frame(self, frame, points=None, joints=None) -> int:
        """Validate a time code and write its index for the next :meth:`launch`, with the live
        inputs of that frame; every input is checked before anything is written.

        Args:
            frame: a time code of the scene.
            points: {mesh prim path: world-space points (V, 3)} replacing the time-sampled
                points of deforming and skinned meshes for this frame (normals and the BVH
                follow them): NumPy floats, or a wp.array (vec3 (V,) or float32 (V, 3)) on the
                evaluator's device, copied device to device into the mesh's staging buffer.
            joints: {skeleton prim path: joint-local transforms (J, 4, 4)}, USD's row-vector
                matrices as ``UsdSkel`` animation gives them (what ``Skeleton.local_transforms``
                holds per frame), replacing the skeleton's time samples for this frame (its
                skeleton-to-world stays the frame's): NumPy floats, or a wp.array (mat44 (J,)
                or float32 (J, 4, 4)) on the evaluator's device.

            A mesh or skeleton not fed uses its time samples, as does every one at the next
            call without it.

        Raises:
            ValueError: ``frame`` is not a time code of the scene (the valid range is named), or
                a fed array names no deforming or skinned mesh / skeleton of the scene, or has
                the wrong shape, dtype or device, or holds NaN or infinities (the prim is named).
        """
        fed = self._check_live("points", points) + self._check_live("joints", joints)
        t = self.scene.frame_index(frame)
        for kind, index, value in fed:
            self._stage_live(kind, index, value)
        flags = {name: 0 for name in self._live_fields.values()}
        flags.update({self._live_fields[kind, index]: 1 for kind, index, _ in fed})
        self.input.write(frame_index=t, **flags)
        self.state.frame = float(self.scene.frames[t])
        self.state.frame_index = t
        return t

    def _check_live(self, kind: str, fed) -> list:
        """Fed ``points`` or ``joints`` checked: [(kind, mesh or skeleton index, array)], each
        array float32 C-contiguous on the host or a vec3 / mat44 wp.array on the device."""
        if fed is None:
            return []
        if not isinstance(fed, dict):
            raise ValueError(f"{kind}: expected a dict {{prim path: array}}, got {type(fed).__name__}")
        if kind == "points":
            prims = {m.path: k for k, m in enumerate(self.scene.meshes)}
        else:
            prims = {sk.path: k for k, sk in enumerate(self.scene.skeletons)}
        out = []
        for path, value in fed.items():
            if path not in prims:
                noun, nouns = ("mesh", "meshes") if kind == "points" else ("skeleton", "skeletons")
                raise ValueError(f"{kind}: no {noun} prim {path!r} in {self.scene.source or 'the scene'} "
                                 f"({nouns}: {sorted(prims)})")
            index = prims[path]
            if kind == "points":
                mesh = self.scene.meshes[index]
                if mesh.animation not in LIVE_POINTS:
                    raise ValueError(f"points: mesh {path} is {mesh.animation} (its points never deform): only "
                                     "deforming (point-cached) and skinned meshes take fed points")
                rows, item, dtype = mesh.vertex_count, (3,), wp.vec3
            else:
                rows, item, dtype = self.scene.skeletons[index].joint_count, (4, 4), wp.mat44
            where = f"{kind} of {path}"
            value = self._checked_device(where, value, rows, item, dtype) if isinstance(value, wp.array) else \
                _checked_host(where, value, (rows, *item))
            out.append((kind, index, value))
        return out

    def _checked_device(self, where: str, value, rows: int, item: tuple, dtype):
        """A fed wp.array as a contiguous ``dtype`` array of ``rows`` on this device, finite
        (counted on the device: only the count comes back)."""
        if str(value.device) != str(self.device):
            raise ValueError(f"{where}: the array is on {value.device}, the run on {self.device} "
                             "(pass a NumPy array or an array on the run's device)")
        if value.dtype == dtype and value.shape == (rows,):
            pass
        elif value.dtype == wp.float32 and value.shape == (rows, *item):
            value = value.view(dtype) if value.is_contiguous else value
        else:
            raise ValueError(f"{where}: expected a wp.array of {dtype.__name__} ({rows},) or float32 "
                             f"{(rows, *item)}, got {getattr(value.dtype, '__name__', value.dtype)} {value.shape}")
        if not value.is_contiguous:
            raise ValueError(f"{where}: the wp.array is not contiguous (pass a contiguous array or a copy)")
        flat = wp.array(ptr=value.ptr, dtype=wp.float32, shape=(rows * int(np.prod(item)),), device=self.device)
        count = wp.zeros(1, dtype=wp.int32, device=self.device)
        wp.launch(count_nonfinite_kernel, dim=flat.shape[0], inputs=[flat, count], device=self.device)
        bad = int(count.numpy()[0])
        if bad:
            raise ValueError(f"{where}: {bad} value(s) are NaN or infinite")
        return value

    def _stage_live(self, kind: str, index: int, value) -> None:
        """Copy checked fed values into their staging buffer: device arrays device to device,
        host arrays through the buffer's host side (the buffer itself on the CPU, a pinned
        host twin uploaded asynchronously on CUDA)."""
        if (kind, index) not in self._live_staging:
            if kind == "points":
                staging = wp.zeros(self.scene.meshes[index].vertex_count, dtype=wp.vec3, device=self.device)
                self._live_points[index] = staging
                self.live_version += 1  # a recording made before does not read it
            else:
                lo = self.state.joint_offsets[index]
                staging = self._live_joints[lo : lo + self.scene.skeletons[index].joint_count]
            host = staging if self.device.is_cpu else wp.empty_like(staging, device="cpu", pinned=True)
            self._live_staging[kind, index] = (staging, host, host.numpy())
        staging, host, host_view = self._live_staging[kind, index]
        if isinstance(value, wp.array):
            wp.copy(staging, value)
            return
        host_view.reshape(value.shape)[...] = value
        if host is not staging:
            wp.copy(staging, host)

    def set_eye(self, position) -> None:
        """Move the viewer (3,), world (a direct write; notify :data:`Change.VIEW`)."""
        p = np.asarray(position, np.float64).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"eye: expected three finite numbers, got {position!r}")
        self.state.eye.assign(np.asarray([p], np.float32))
        self.state.has_eye = True
        self.input.write(eye_from_host=1)  # the camera path (if any) stops driving the eye
        self._eye_set = p.copy()

    def set_lighting(self, source) -> None:
        """Light the next frames with ``source`` (a :class:`~warpshade.scene.LightingSource`):
        a new ``state.lighting`` (stages bound to the old one must be set up again); no override."""
        from ._lighting_warp import FrameLighting

        self.lighting_source = source
        self.state.lighting = FrameLighting(source, self.scene.frames, self.input, self.device)
        self.input.write(sh_override=0)

    def set_lighting_override(self, coeffs) -> None:
        """Use world-frame SH coefficients (3, n*n) instead of the lights' SH for the next
        frames (:meth:`~warpshade.scene._lighting_warp.FrameLighting.set_override`), or the lights' again when ``coeffs`` is None."""
        if coeffs is not None:
            self.state.lighting.set_override(coeffs)
        self.input.write(sh_override=int(coeffs is not None))

    def eye_at(self, frame) -> np.ndarray:
        """The eye at time code ``frame``: the position set by :meth:`set_eye`, else the
        animated camera's at that frame, else the fixed eye (3,) float64."""
        if getattr(self, "_eye_set", None) is not None or self._eye_table is None:
            return self.state.eye.numpy()[0].astype(np.float64)
        return self.scene.camera.position_at(self.scene.frame_index(frame))

    def set_material(self, brdf, prims=None) -> None:
        """Choose the BRDF of every mesh, or of the meshes ``prims`` (prim paths); ``brdf=None``
        removes the choice (the stages' own BRDFs again). A host write: notify
        :data:`Change.MATERIAL`.

        Raises:
            ValueError: ``brdf`` is not a :class:`~warpshade.scene._materials.BRDF`, or a prim
                path names no mesh of the scene (the known ones are listed).
        """
        from ._materials import BRDF

        if brdf is not None and not isinstance(brdf, BRDF):
            raise ValueError(f"set_material: expected a warpshade.scene._materials BRDF or None, got {type(brdf).__name__}")
        mats = self.state.materials
        if prims is None:
            mats.default = brdf
            mats.prims.clear()
        else:
            paths = [prims] if isinstance(prims, str) else list(prims)
            known = {m.path for m in self.scene.meshes}
            unknown = sorted(set(paths) - known)
            if unknown:
                raise ValueError(f"set_material: no mesh prim {unknown} in {self.scene.source or 'the scene'} "
                                 f"(meshes: {sorted(known)})")
            for p in paths:
                if brdf is None:
                    mats.prims.pop(p, None)
                else:
                    mats.prims[p] = brdf
        mats.version += 1

    def assign_materials(self, default, prims: dict) -> None:
        """Replace the whole assignment (a material track's frame): ``default`` BRDF or None and
        prim path -> BRDF (paths already checked). A host write: notify :data:`Change.MATERIAL`."""
        mats = self.state.materials
        mats.default, mats.prims = default, dict(prims)
        mats.version += 1

    def set_albedo(self, albedo, prims=None) -> None:
        """Replace the diffuse albedo of every vertex, or of the meshes whose prim paths are in
        ``prims`` (one prim path or a list of them; RGB, (3,) or per vertex of those meshes); a
        direct write (notify :data:`Change.MATERIAL`). Everything is checked before anything is
        written.

        Raises:
            ValueError: naming the albedo or prim at fault: no prims, an unknown prim, an albedo
                that is not numbers, not (3,) / (vertices, 3), not finite or negative.
        """
        current = self.albedo.numpy().copy()
        try:
            a = np.asarray(albedo, np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"albedo: expected RGB numbers, got {albedo!r}") from None
        if prims is None:
            meshes = self.scene.meshes
        else:
            paths = [prims] if isinstance(prims, str) else list(prims)
            if not paths or not all(isinstance(p, str) for p in paths):
                raise ValueError(f"albedo: prims must be a mesh prim path or a non-empty list of them, got {prims!r}")
            known = {m.path for m in self.scene.meshes}
            unknown = sorted(set(paths) - known)
            if unknown:
                raise ValueError(f"albedo: no mesh prim {unknown} in {self.scene.source or 'the scene'} "
                                 f"(meshes: {sorted(known)})")
            meshes = [m for m in self.scene.meshes if m.path in set(paths)]
        count = sum(m.vertex_count for m in meshes)
        if a.size == 3 and a.ndim in (1, 2) and a.shape[-1] == 3:
            value = np.broadcast_to(a.reshape(3), (count, 3))
        elif a.shape == (count, 3):
            value = a
        else:
            raise ValueError(f"albedo: expected RGB (3,) or one per vertex ({count}, 3), got shape {a.shape}")
        if not np.all(np.isfinite(value)) or np.any(value < 0):
            raise ValueError("albedo: expected finite non-negative RGB, got "
                             f"{'non-finite values' if not np.all(np.isfinite(value)) else f'minimum {value.min():g}'}")
        start = 0
        for m in meshes:
            current[m.vertex_offset : m.vertex_offset + m.vertex_count] = value[start : start + m.vertex_count]
            start += m.vertex_count
        self.albedo.assign(current.astype(np.float32))

    # ---- device side ---------------------------------------------------------------------
    def launch(self, recorder=None) -> None:
        """Evaluate the frame written by :meth:`set_frame` (kernels on fixed buffers only).

        Args:
            recorder: the :class:`~warpshade._wp.FrameRecorder` when the frame is being
                recorded (host uploads of oversized point samples become its calls).
        """
        self._launch(moving_only=True, recorder=recorder)
        if self.state.lighting is not None:
            self.state.lighting.launch()
        if self.state.bvh is not None and self.moving:
            if recorder is not None and self.device.is_cpu:
                # Warp's CPU capture (1.19) does not record wp.Mesh.refit: a stale BVH would replay
                recorder.call(self.state.bvh.refit, CPU_REFIT_NOTE)
            else:
                self.state.bvh.refit()

    def evaluate(self, frame) -> FrameState:
        """:meth:`set_frame` then :meth:`launch` (uncaptured); returns :attr:`state`."""
        self.set_frame(frame)
        self.launch()
        return self.state

    def _launch(self, moving_only: bool, recorder=None) -> None:
        from ..geometry._normals import compute_vertex_normals
        from ..geometry._skinning import launch_skin_points, launch_transform_normals, launch_transform_points

        dev, st, data, scene = self.device, self.state, self._data, self.scene
        self.input.launch()
        frame = self.input.array
        if self._eye_table is not None:
            wp.launch(eye_kernel, dim=1, inputs=[frame, self._eye_table, st.eye], device=dev)
        if not moving_only or self.moving:
            wp.launch(mesh_transforms_kernel, dim=len(scene.meshes), device=dev, inputs=[
                frame, self._transform_table, self._scale_table, self._transform_start, self._transform_count,
                st.mesh_transforms, st.mesh_scales])
        if self._skeletons:
            from ..geometry._skinning import skeleton_pose_kernel

            wp.launch(skeleton_pose_kernel, dim=self._skeletons, device=dev,
                      inputs=[frame, *self._skel_inputs, st.joint_transforms, st.skin_matrices])
        for k, (mesh, entry) in enumerate(zip(scene.meshes, data["meshes"])):
            if moving_only and not self._moves(mesh):
                continue
            if mesh.animation == "skinned":
                launch_skin_points(entry["points"], entry["joint_indices"], entry["joint_weights"], st.skin_matrices,
                                   st.points, mesh.vertex_offset, joint_offset=st.joint_offsets[mesh.skin.skeleton])
            elif mesh.animation == "deforming":
                if "samples" in entry:
                    launch_transform_points(entry["samples"], 0, mesh.vertex_count, st.mesh_transforms, st.points,
                                            mesh.vertex_offset, matrix_index=k, frame=frame, frame_stride=mesh.vertex_count)
                else:
                    self._upload_samples(mesh, k, recorder)
            else:
                launch_transform_points(entry["points"], 0, mesh.vertex_count, st.mesh_transforms, st.points,
                                        mesh.vertex_offset, matrix_index=k)
                launch_transform_normals(entry["rest_normals"], st.mesh_transforms, st.normals, mesh.vertex_offset,
                                         matrix_index=k, area_sums=entry["area_sums"])
            if k in self._live_points:
                wp.launch(live_points_kernel, dim=mesh.vertex_count, device=dev, inputs=[
                    frame, self.input.slot(self._live_fields["points", k]), self._live_points[k], st.points,
                    mesh.vertex_offset])
            if "vertices" in entry:
                compute_vertex_normals(st.points, entry["faces"], st.normals, entry["vertices"])

    def _upload_samples(self, mesh, k: int, recorder) -> None:
        from ..geometry._skinning import launch_transform_points

        def upload():
            t = self.input["frame_index"]
            src = wp.array(np.asarray(mesh.point_samples[t], np.float32), dtype=wp.vec3, device=self.device)
            launch_transform_points(src, 0, mesh.vertex_count, self.state.mesh_transforms, self.state.points,
                                    mesh.vertex_offset, matrix_index=k)

        if recorder is not None:
            recorder.call(upload, f"deforming mesh {mesh.path}: point samples uploaded per frame")
        else:
            upload()
