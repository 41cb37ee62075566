"""The static scene description and the per-frame state.

:class:`Scene` holds everything that does not change per frame: meshes (rest pose, topology,
UVs, albedo), skeletons and skin bindings, lights, camera and the time range. It is built by
:func:`warpshade.io.load_usd` (or directly from arrays with :meth:`Scene.from_meshes`, which is
what tests and generators use) and contains only NumPy data, so it never depends on pxr.

:meth:`Scene.evaluate` produces a :class:`~warpshade.scene._state.FrameState`: what changes per
frame (deformed points and normals in world space, per-mesh transforms, joint transforms) as
Warp arrays on the chosen device, filled by the kernels of
:class:`~warpshade.scene._state.FrameEvaluator` (which per-frame loops use directly). Per-frame
animation is stored sampled at ``scene.frames`` (the stage's time codes).

All shaded meshes are concatenated in scene order: mesh ``k`` owns vertices
``mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count`` of every per-vertex array.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

__all__: list[str] = []

#: How a mesh moves: not at all, by a per-frame rigid transform, by per-frame points, by skinning.
ANIMATION_KINDS = ("static", "rigid", "deforming", "skinned")


@dataclass
class SkinBinding:
    """Linear-blend-skinning weights of one mesh.

    Attributes:
        skeleton: index into ``Scene.skeletons``.
        joint_indices: per-vertex influencing joints, shape (vertex_count, K), int32, indices
            into the skeleton's joint order.
        joint_weights: matching weights, shape (vertex_count, K), float32, rows sum to 1.
        geom_bind_transform: the mesh's bind-time local-to-skeleton-space transform (4, 4),
            float64, row-vector convention (``p_skel = [p, 1] @ M``) as in USD.
    """

    skeleton: int
    joint_indices: np.ndarray
    joint_weights: np.ndarray
    geom_bind_transform: np.ndarray = field(default_factory=lambda: np.eye(4))


@dataclass
class Skeleton:
    """A joint hierarchy with its animation sampled at the scene's frames.

    Matrices follow USD's row-vector convention: a point transforms as ``[p, 1] @ M`` and
    ``world = local @ parent_world``.

    Attributes:
        path: prim path of the UsdSkel.Skeleton.
        joint_names: joint paths in skeleton order, length J.
        parents: parent index per joint, shape (J,), int, -1 for roots.
        bind_transforms: skeleton-space bind transforms, shape (J, 4, 4), float64.
        rest_transforms: joint-local rest transforms, shape (J, 4, 4), float64.
        local_transforms: joint-local animated transforms per frame, shape (T, J, 4, 4).
        skel_to_world: the skeleton prim's local-to-world transform per frame, shape (T, 4, 4).
    """

    path: str
    joint_names: list[str]
    parents: np.ndarray
    bind_transforms: np.ndarray
    rest_transforms: np.ndarray
    local_transforms: np.ndarray
    skel_to_world: np.ndarray

    @property
    def joint_count(self) -> int:
        return len(self.joint_names)

    def skel_space_transforms(self, frame_index: int) -> np.ndarray:
        """Joint transforms in skeleton space at a frame, shape (J, 4, 4), float64."""
        local = self.local_transforms[frame_index]
        out = np.empty_like(local)
        for j in range(self.joint_count):  # joints are ordered parents-first (USD requirement)
            p = int(self.parents[j])
            out[j] = local[j] if p < 0 else local[j] @ out[p]
        return out

    def skinning_transforms(self, frame_index: int) -> np.ndarray:
        """``inverse(bind) @ skel_space`` per joint at a frame, shape (J, 4, 4), float64."""
        return np.linalg.inv(self.bind_transforms) @ self.skel_space_transforms(frame_index)

    def joint_angles(self, frame_index: int) -> np.ndarray:
        """Joint rotations relative to the rest pose as rotation vectors, shape (J, 3), radians.

        These are the per-frame pose parameters the data-driven methods learn from.
        """
        from scipy.spatial.transform import Rotation

        rest = self.rest_transforms[:, :3, :3]
        cur = self.local_transforms[frame_index][:, :3, :3]

        def _rot(m):
            # strip scale; row-vector matrices are the transpose of column-vector rotations
            u, _, vt = np.linalg.svd(m)
            return u @ vt

        rel = np.stack([_rot(cur[j]) @ _rot(rest[j]).T for j in range(self.joint_count)])
        return Rotation.from_matrix(np.transpose(rel, (0, 2, 1))).as_rotvec()


@dataclass
class Mesh:
    """One triangulated mesh prim.

    Attributes:
        path: USD prim path (or a name for meshes built from arrays).
        points: rest/authored points in the mesh's local space, shape (V, 3), float64.
        faces: triangles, shape (F, 3), int32, indices into this mesh's points.
        animation: one of :data:`ANIMATION_KINDS`.
        transforms: local-to-world per frame, shape (T, 4, 4) float64 (row-vector convention),
            or (1, 4, 4) when constant.
        point_samples: per-frame local points for ``"deforming"`` meshes, shape (T, V, 3).
        normals: authored normals (V, 3) or None (then area-weighted normals are computed).
        uvs: per-vertex UVs (V, 2) or None.
        albedo: per-vertex diffuse albedo, shape (V, 3), float32, linear RGB.
        skin: the :class:`SkinBinding` of a ``"skinned"`` mesh.
        vertex_offset: index of this mesh's first vertex in the scene's concatenated arrays.
        dropped_face_count: zero-area triangles removed when the mesh was loaded.
        surface: the spatially varying material parameters
            (:class:`~warpshade.scene._textures.SurfaceMaps`: diffuse colour, roughness, specular
            colour or metallic, textures looked up with ``uvs``) from a bound UsdPreviewSurface,
            or None (no such material; ``albedo`` alone describes the surface).
        implicit: the implicit USD prim the mesh was tessellated from, as ``(type, parameters)``:
            the prim type (``"Sphere"``, ``"Cube"``, ``"Cylinder"``, ``"Cone"``, ``"Capsule"``,
            ``"Plane"``, ``"Capsule_1"``, ``"Cylinder_1"``) and its shape attributes in the prim's
            local space (``{"radius": 0.5, "height": 1.0, "axis": "Z"}``; a float, or a (T,)
            float64 array when animated); ``transforms`` place it in the world. None for meshes
            (see :mod:`warpshade.io._usd_implicit`).
    """

    path: str
    points: np.ndarray
    faces: np.ndarray
    animation: str = "static"
    transforms: np.ndarray = field(default_factory=lambda: np.eye(4)[None])
    point_samples: np.ndarray | None = None
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None
    albedo: np.ndarray | None = None
    skin: SkinBinding | None = None
    vertex_offset: int = 0
    dropped_face_count: int = 0
    surface: Any = None
    implicit: tuple | None = None

    def __post_init__(self):
        self.points = np.asarray(self.points, dtype=np.float64).reshape(-1, 3)
        self.faces = np.asarray(self.faces, dtype=np.int32).reshape(-1, 3)
        self.transforms = np.asarray(self.transforms, dtype=np.float64).reshape(-1, 4, 4)
        if self.animation not in ANIMATION_KINDS:
            raise ValueError(f"mesh {self.path}: unknown animation kind {self.animation!r}")
        if self.surface is not None and getattr(self.surface, "is_textured", False):
            if self.uvs is None or np.asarray(self.uvs).shape != (self.vertex_count, 2):
                raise ValueError(f"mesh {self.path}: textured surface maps ({', '.join(self.surface.textures)}) need "
                                 f"uvs of shape ({self.vertex_count}, 2), got "
                                 f"{None if self.uvs is None else np.asarray(self.uvs).shape}")
        if self.albedo is None:
            self.albedo = np.full((self.vertex_count, 3), 0.8, dtype=np.float32)
        else:
            a = np.asarray(self.albedo, dtype=np.float32)
            self.albedo = np.broadcast_to(a.reshape(-1, 3) if a.size != 3 else a.reshape(1, 3), (self.vertex_count, 3)).copy()

    @property
    def vertex_count(self) -> int:
        return int(self.points.shape[0])

    @property
    def triangle_count(self) -> int:
        return int(self.faces.shape[0])


@dataclass
class Camera:
    """A pinhole camera (world space, y-up image).

    Attributes:
        position: eye position (3,).
        target: point looked at (3,).
        up: up vector (3,).
        vertical_fov: vertical field of view in degrees.
        path: USD prim path, or None for a camera framed automatically.
        positions: eye position per time code of the scene, (T, 3), when the camera moves (an
            animated USD camera), else None; ``position``/``target``/``up`` are the first frame's.
    """

    position: np.ndarray
    target: np.ndarray
    up: np.ndarray
    vertical_fov: float = 40.0
    path: str | None = None
    positions: np.ndarray | None = None

    @property
    def moving(self) -> bool:
        return self.positions is not None

    def position_at(self, frame_index: int) -> np.ndarray:
        """The eye at the scene's time code number ``frame_index`` (clamped to the samples)."""
        if self.positions is None:
            return np.asarray(self.position, np.float64)
        return np.asarray(self.positions[min(max(int(frame_index), 0), len(self.positions) - 1)], np.float64)


class Scene:
    """Static description of an animated scene (see module docstring).

    A scene is treated as immutable once built: its static device arrays (faces, rest points,
    skin weights, authored normals) are cached per device on first use.

    Attributes:
        meshes: the shaded meshes, in scene order.
        skeletons: UsdSkel skeletons referenced by skinned meshes.
        lights: light objects from :mod:`warpshade.scene._lighting`.
        camera: a :class:`Camera` or None.
        frames: time codes, shape (T,), float64.
        fps: time codes per second.
        up_axis: "Y" or "Z".
        source: path of the file the scene was loaded from, or None.
        skipped: ``(prim path, reason)`` for every prim the loader saw but did not turn into a
            mesh or light (guide/proxy purpose, invisible, unsupported light type, ...).
    """

    def __init__(
        self,
        meshes: Sequence[Mesh],
        frames: Sequence[float] = (0.0,),
        fps: float = 24.0,
        skeletons: Sequence[Skeleton] = (),
        lights: Sequence[Any] = (),
        camera: Camera | None = None,
        up_axis: str = "Z",
        source: str | None = None,
        skipped: Sequence[tuple[str, str]] = (),
    ):
        if len(meshes) == 0:
            raise ValueError(f"scene {source or '<arrays>'}: contains no meshes")
        self.meshes = list(meshes)
        self.skeletons = list(skeletons)
        self.lights = list(lights)
        self.camera = camera
        self.frames = np.asarray(frames, dtype=np.float64).reshape(-1)
        self.fps = float(fps)
        self.up_axis = up_axis
        self.source = source
        self.skipped = list(skipped)
        if self.frames.shape[0] == 0:
            raise ValueError(f"scene {source or '<arrays>'}: needs at least one frame")
        t = self.frames.shape[0]
        if not np.all(np.isfinite(self.frames)) or np.any(np.diff(self.frames) <= 0):
            raise ValueError(f"scene {source or '<arrays>'}: frames must be finite and increasing")
        for skel in self.skeletons:
            j = skel.joint_count
            parents = np.asarray(skel.parents).reshape(-1)
            if parents.shape != (j,) or np.any(parents >= np.arange(j)) or np.any(parents < -1):
                raise ValueError(f"skeleton {skel.path}: parents must list each joint's parent before it (USD joint "
                                 f"order), -1 for roots; got {parents.tolist()[:16]}")
            bind = np.asarray(skel.bind_transforms, np.float64)
            if bind.shape != (j, 4, 4) or not np.all(np.isfinite(bind)) or np.any(np.abs(np.linalg.det(bind[:, :3, :3])) < 1e-12):
                raise ValueError(f"skeleton {skel.path}: bind transforms must be ({j}, 4, 4), finite and invertible")
            if skel.local_transforms.shape[1:] != (j, 4, 4) or skel.local_transforms.shape[0] not in (1, t):
                raise ValueError(
                    f"skeleton {skel.path}: local_transforms must be ({t}, {j}, 4, 4), got {skel.local_transforms.shape}"
                )
        for skel in self.skeletons:
            if not (np.all(np.isfinite(skel.local_transforms)) and np.all(np.isfinite(skel.skel_to_world))):
                raise ValueError(f"skeleton {skel.path}: joint or skeleton transforms have NaN or infinite entries")
        offset = 0
        for mesh in self.meshes:
            for what, values in (("points", mesh.points), ("transforms", mesh.transforms), ("point samples", mesh.point_samples),
                                 ("normals", mesh.normals)):
                if values is not None and not np.all(np.isfinite(values)):
                    raise ValueError(f"mesh {mesh.path}: {what} have NaN or infinite values")
            mesh.vertex_offset = offset
            offset += mesh.vertex_count
            if mesh.transforms.shape[0] not in (1, t):
                raise ValueError(
                    f"mesh {mesh.path}: {mesh.transforms.shape[0]} transforms for {t} frames"
                )
            if mesh.animation == "deforming":
                if mesh.point_samples is None or mesh.point_samples.shape[:2] != (t, mesh.vertex_count):
                    raise ValueError(f"mesh {mesh.path}: deforming mesh needs point_samples of shape ({t}, {mesh.vertex_count}, 3)")
            if mesh.animation == "skinned":
                if mesh.skin is None:
                    raise ValueError(f"mesh {mesh.path}: skinned mesh without a skin binding")
                self._check_skin(mesh)
            if mesh.faces.size and (mesh.faces.min() < 0 or mesh.faces.max() >= mesh.vertex_count):
                raise ValueError(
                    f"mesh {mesh.path}: face indices must lie in 0..{mesh.vertex_count - 1}, "
                    f"found {int(mesh.faces.min())}..{int(mesh.faces.max())}"
                )
        self._faces = np.concatenate([m.faces + m.vertex_offset for m in self.meshes]).astype(np.int32)
        self._device_cache: dict = {}  # static device arrays per device (warpshade.scene._static_arrays)
        self._evaluators: dict = {}  # FrameEvaluator per device, for evaluate()

    def __getstate__(self):
        """Pickle the description only: device caches and evaluators stay with their process
        (a scene is sent to worker processes and cluster workers as a task argument)."""
        state = dict(self.__dict__)
        state["_device_cache"] = {}
        state["_evaluators"] = {}
        return state

    def _check_skin(self, mesh: Mesh) -> None:
        skin = mesh.skin
        if not 0 <= skin.skeleton < len(self.skeletons):
            raise ValueError(f"mesh {mesh.path}: skin refers to skeleton {skin.skeleton}, scene has {len(self.skeletons)}")
        skel = self.skeletons[skin.skeleton]
        idx = np.asarray(skin.joint_indices)
        w = np.asarray(skin.joint_weights)
        if idx.shape != w.shape or idx.ndim != 2 or idx.shape[0] != mesh.vertex_count:
            raise ValueError(
                f"mesh {mesh.path}: joint_indices {idx.shape} and joint_weights {w.shape} must both be "
                f"({mesh.vertex_count}, K)"
            )
        bind = np.asarray(skin.geom_bind_transform, np.float64)
        if bind.shape != (4, 4) or not np.all(np.isfinite(bind)) or abs(np.linalg.det(bind[:3, :3])) < 1e-12:
            raise ValueError(f"mesh {mesh.path}: geom bind transform must be a finite, invertible (4, 4) matrix")
        if not (np.all(np.isfinite(w)) and np.all(w >= 0)):
            raise ValueError(f"mesh {mesh.path}: joint weights must be finite and >= 0")
        if idx.size and (idx.min() < 0 or idx.max() >= skel.joint_count):
            raise ValueError(
                f"mesh {mesh.path}: joint indices {int(idx.min())}..{int(idx.max())} do not match skeleton "
                f"{skel.path} with {skel.joint_count} joints"
            )

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def from_meshes(cls, meshes: Sequence[Mesh], **kwargs) -> "Scene":
        """Build a scene directly from :class:`Mesh` objects (no USD involved)."""
        return cls(meshes, **kwargs)

    def with_ground_plane(
        self,
        resolution: int = 40,
        size_factor: float = 3.0,
        albedo=(0.8, 0.8, 0.8),
        path: str = "/ground_plane",
    ) -> "Scene":
        """A new scene with a static square grid under everything, normal along the up axis.

        The plane lies at the lowest point of the scene over all frames (along ``up_axis``),
        is centred under the scene's horizontal centre and is ``size_factor`` times the
        largest horizontal extent wide; it has ``resolution`` x ``resolution`` vertices so
        per-vertex shadows on it are resolved. Meshes are shared with this scene, not copied.
        """
        lo, hi = self.bounds_over_frames()
        plane = ground_plane(lo, hi, self.up_axis, resolution=resolution, size_factor=size_factor, albedo=albedo, path=path)
        return Scene(
            self.meshes + [plane],
            frames=self.frames,
            fps=self.fps,
            skeletons=self.skeletons,
            lights=self.lights,
            camera=self.camera,
            up_axis=self.up_axis,
            source=self.source,
            skipped=self.skipped,
        )

    # ---- static queries -----------------------------------------------------------------
    @property
    def vertex_count(self) -> int:
        """Number of vertices of all shaded meshes, concatenated in scene order."""
        return int(sum(m.vertex_count for m in self.meshes))

    @property
    def triangle_count(self) -> int:
        return int(self._faces.shape[0])

    @property
    def faces(self) -> np.ndarray:
        """All triangles with scene-global vertex indices, shape (F, 3), int32."""
        return self._faces

    @property
    def albedo(self) -> np.ndarray:
        """Per-vertex diffuse albedo, shape (vertex_count, 3), float32."""
        return np.concatenate([m.albedo for m in self.meshes]).astype(np.float32)

    @property
    def dropped_face_count(self) -> int:
        """Zero-area triangles removed from all meshes at load time."""
        return int(sum(m.dropped_face_count for m in self.meshes))

    @property
    def is_static(self) -> bool:
        """True when no mesh moves (static PRT applies)."""
        return all(m.animation == "static" or (m.animation == "rigid" and m.transforms.shape[0] == 1) for m in self.meshes)

    def frame_index(self, frame: float) -> int:
        """Index of a time code in ``frames``.

        Raises:
            TypeError: ``frame`` is not a number (a string, a bool).
            ValueError: it is not finite, or not one of the sampled time codes (the message
                names the valid range).
        """
        if isinstance(frame, (bool, np.bool_)) or not isinstance(frame, (int, float, np.integer, np.floating)):
            raise TypeError(f"frame must be a number (a time code), got {frame!r}")
        if not np.isfinite(frame):
            raise ValueError(f"frame must be a finite time code, got {frame!r}")
        f = float(frame)
        i = int(np.searchsorted(self.frames, f))  # frames increase: the nearest is at i - 1 or i
        idx = i - 1 if i == len(self.frames) or (i > 0 and f - self.frames[i - 1] < self.frames[i] - f) else i
        if abs(self.frames[idx] - f) > 1e-6:
            raise ValueError(
                f"scene {self.source or '<arrays>'}: frame {frame} is not one of the sampled time codes "
                f"({self.frames[0]:g}..{self.frames[-1]:g}, {len(self.frames)} frames)"
            )
        return idx

    def _mesh_transform(self, mesh: Mesh, t: int) -> np.ndarray:
        """Row-vector matrix taking the mesh's (skinned, if skinned) local points to world."""
        if mesh.animation == "skinned":
            skel = self.skeletons[mesh.skin.skeleton]
            return skel.skel_to_world[min(t, skel.skel_to_world.shape[0] - 1)]
        return mesh.transforms[min(t, mesh.transforms.shape[0] - 1)]

    def points_at(self, frame: float) -> np.ndarray:
        """World-space points at a time code, shape (vertex_count, 3), float64 (reference path)."""
        t = self.frame_index(frame)
        parts = []
        for mesh in self.meshes:
            xf = self._mesh_transform(mesh, t)
            if mesh.animation == "deforming":
                local = mesh.point_samples[t]
            elif mesh.animation == "skinned":
                from ..geometry._skinning import skin_points_f64

                skel = self.skeletons[mesh.skin.skeleton]
                local = skin_points_f64(
                    mesh.points, mesh.skin, skel.skinning_transforms(min(t, skel.local_transforms.shape[0] - 1))
                )
            else:
                local = mesh.points
            parts.append(local @ xf[:3, :3] + xf[3, :3])
        return np.concatenate(parts)

    def normals_at(self, frame: float) -> np.ndarray:
        """World-space unit normals at a time code, shape (vertex_count, 3), float64 (reference).

        Area-weighted normals of :meth:`points_at`, except static/rigid meshes with authored
        normals, whose normals are transformed by the inverse transpose of their transform.
        """
        from ..geometry._normals import vertex_normals_f64

        t = self.frame_index(frame)
        normals = vertex_normals_f64(self.points_at(frame), self._faces)
        for mesh in self.meshes:
            if mesh.normals is not None and mesh.animation in ("static", "rigid"):
                xf = self._mesh_transform(mesh, t)
                n = np.asarray(mesh.normals, np.float64) @ np.linalg.inv(xf[:3, :3]).T
                n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
                normals[mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count] = n
        return normals

    def bounds(self, frame: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (lo, hi) of all points at a frame (default: first frame)."""
        pts = self.points_at(self.frames[0] if frame is None else frame)
        return pts.min(axis=0), pts.max(axis=0)

    def bounds_over_frames(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (lo, hi) of all points over every frame, float64 (3,) each."""
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        frames = self.frames[:1] if self.is_static else self.frames
        for f in frames:
            a, b = self.bounds(f)
            lo, hi = np.minimum(lo, a), np.maximum(hi, b)
        return lo, hi

    # ---- per-frame evaluation -----------------------------------------------------------
    def evaluate(self, frame: float, device=None):
        """World-space points, normals and transforms at a time code, evaluated on a Warp device.

        A convenience over :class:`~warpshade.scene._state.FrameEvaluator` (one is kept per
        device, with the static device arrays): returns a
        :class:`~warpshade.scene._state.FrameState` snapshot that later calls do not overwrite.
        Per-frame loops use a FrameEvaluator directly (fixed buffers, capture-safe launches).

        Args:
            frame: a time code of ``frames``.
            device: Warp device (None = Warp's default).

        Returns:
            FrameState with ``points`` and ``normals`` of shape (vertex_count,) vec3, world space,
            float32 (no lighting, no BVH).
        """
        from .._wp import resolve_device
        from ._state import FrameEvaluator

        dev = resolve_device(device)
        evaluator = self._evaluators.get(str(dev))
        if evaluator is None:
            evaluator = self._evaluators[str(dev)] = FrameEvaluator(self, dev)
        return evaluator.evaluate(frame).snapshot()

    def fingerprint(self) -> str:
        """Content hash of everything in the scene that precomputed artifacts can depend on."""
        from .._hashing import hash_arrays

        arrays = [self.frames]
        for m in self.meshes:
            arrays += [m.points, m.faces, m.transforms, m.point_samples, m.albedo, m.normals]
            if m.skin is not None:
                arrays += [m.skin.joint_indices, m.skin.joint_weights, m.skin.geom_bind_transform]
        for s in self.skeletons:
            arrays += [s.parents, s.bind_transforms, s.rest_transforms, s.local_transforms, s.skel_to_world]
        return hash_arrays(arrays)

    def __repr__(self) -> str:
        return (
            f"Scene(source={self.source!r}, meshes={len(self.meshes)}, vertices={self.vertex_count}, "
            f"triangles={self.triangle_count}, frames={len(self.frames)}, lights={len(self.lights)})"
        )


def ground_plane(
    lo,
    hi,
    up_axis: str = "Z",
    resolution: int = 40,
    size_factor: float = 3.0,
    albedo=(0.8, 0.8, 0.8),
    path: str = "/ground_plane",
) -> Mesh:
    """A static square grid mesh under the box ``lo``..``hi``, facing +``up_axis``.

    Args:
        lo, hi: world-space bounds of what stands on the plane, (3,) each.
        up_axis: "Y" or "Z"; the plane lies at ``lo[up]`` with normals along +up.
        resolution: vertices per side (>= 2); the grid has ``2 * (resolution - 1)**2`` triangles.
        size_factor: side length as a multiple of the largest horizontal extent of the box.
        albedo: RGB diffuse albedo of the plane.
        path: name of the mesh.

    Returns:
        A static :class:`Mesh` (world-space points, identity transform).
    """
    if resolution < 2:
        raise ValueError(f"ground_plane: resolution must be >= 2, got {resolution}")
    up = {"Y": 1, "Z": 2}.get(str(up_axis).upper())
    if up is None:
        raise ValueError(f"ground_plane: up axis must be 'Y' or 'Z', got {up_axis!r}")
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    # Horizontal axes in right-handed order so that (a, b, up) is positively oriented.
    a, b = (2, 0) if up == 1 else (0, 1)
    centre = 0.5 * (lo + hi)
    extent = max(hi[a] - lo[a], hi[b] - lo[b], 1e-6) * size_factor
    s = np.linspace(-0.5, 0.5, resolution) * extent
    ga, gb = np.meshgrid(s + centre[a], s + centre[b], indexing="ij")
    pts = np.zeros((resolution * resolution, 3))
    pts[:, a] = ga.ravel()
    pts[:, b] = gb.ravel()
    pts[:, up] = lo[up]
    i, j = np.meshgrid(np.arange(resolution - 1), np.arange(resolution - 1), indexing="ij")
    v00 = (i * resolution + j).ravel()
    v10 = v00 + resolution  # +a
    v01 = v00 + 1  # +b
    v11 = v10 + 1
    # (a, b) counter-clockwise seen from +up: cross(+a, +b) = +up.
    faces = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])
    return Mesh(path=path, points=pts, faces=faces, albedo=np.asarray(albedo, np.float32))
