"""SHEXP's blocker spheres of a scene: sphere sets of the occluder meshes, attached to the
animation, and their per-frame centres and radii on a Warp device.

The sphere geometry (fitting, attachment coordinates, hierarchy) is
:mod:`warpshade.geometry.spheres`; this module decides which scene mesh gets which spheres
and how they follow it, reading the scene only through its public interface
(``scene.meshes``, ``scene.skeletons``, ``scene.points_at``, ``scene.frames``,
``scene.frame_index``, ``mesh.transforms``, ``Skeleton.skinning_transforms``):

* :func:`spheres_for_scene` fits every closed occluder mesh (world space, at one frame) and
  attaches its centres (:data:`ATTACHMENT_KINDS`): static/rigid meshes by the mesh transform;
  skinned meshes by mean value coordinates pushed through the bone weights, or by linear blend
  skinning of the centre with its cluster's mean skin weights; deforming closed meshes by
  dense MVC over the vertices; deforming open (shell) meshes by a triangle frame. Radii stay
  fixed in mesh-local units (times a safety factor, times the mesh transform's scale,
  optionally grown until they bound every frame of the scene's own animation:
  :meth:`SceneSpheres.calibrate_radii`).
* :class:`SceneSpheres` holds the sets and attachments (artifact form ``to_arrays``) and the
  float64 mirror of the animation (:meth:`SceneSpheres.centres_at`,
  :meth:`SceneSpheres.radii_at`).
* :class:`SphereAnimator` evaluates centres and radii per frame with kernels only, reading a
  :class:`~warpshade.scene._state.FrameState` (``mesh_transforms``, ``mesh_scales``,
  ``skin_matrices``, ``points``): a recorded frame (:func:`warpshade._wp.record_program`)
  replays it.
* :func:`scene_receiver_clusters` clusters the scene's vertices for the hierarchy cut.

Matrices on the host are USD row-vector (``[p, 1] @ M``); on the device, Warp column-vector.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np

from ..._wp import resolve_device, wp
from ...geometry.spheres import ReceiverClusters, SphereSet, cluster_receivers, fit_spheres, make_solid, solid_volume
from ...geometry.spheres import _attach as _attach
from ...geometry.spheres import _kernels as _k
from ...geometry.spheres._fit import RADIUS_PAD_RELATIVE

__all__ = ["ATTACHMENT_KINDS", "RADIUS_EXCESS", "SceneSpheres", "SphereAnimator", "implicit_spheres", "scene_receiver_clusters",
           "spheres_for_scene"]

#: Attachment kinds (how a set's centres follow its mesh).
ATTACHMENT_KINDS = ("rigid", "skinned", "vertex_weights", "triangle_frame")


# ---- float64 transforms of the reference path ------------------------------------------------
def _mesh_transform(scene, mesh, t: int) -> np.ndarray:
    """Row-vector local-to-world of a mesh at frame index t, (4, 4) float64: skeleton-to-world
    for skinned meshes (what ``FrameState.mesh_transforms`` holds on the device)."""
    if mesh.animation == "skinned":
        world = scene.skeletons[mesh.skin.skeleton].skel_to_world
        return world[min(t, world.shape[0] - 1)]
    return mesh.transforms[min(t, mesh.transforms.shape[0] - 1)]


def _transform_scale(matrix: np.ndarray) -> float:
    """Largest singular value of the 3x3 part: a sphere of radius r maps inside radius s * r."""
    return float(np.linalg.svd(np.asarray(matrix, np.float64)[:3, :3], compute_uv=False)[0])


def _skinning_matrices(scene, mesh, t: int) -> np.ndarray:
    """Bind space to world per joint of a skinned mesh's skeleton at frame index t:
    ``inverse(bind) @ skel_space @ skel_to_world``, (J, 4, 4) row-vector float64 (the
    transposes of ``FrameState.skin_matrices``)."""
    skel = scene.skeletons[mesh.skin.skeleton]
    return skel.skinning_transforms(min(t, skel.local_transforms.shape[0] - 1)) @ _mesh_transform(scene, mesh, t)


# ---- the blocker model of a scene --------------------------------------------------------------
@dataclass
class SceneSpheres:
    """Sphere sets of a scene's occluder meshes, attached so they follow the animation.

    Spheres of all sets are concatenated in set order: set ``k`` owns spheres
    ``sphere_offset[k] : sphere_offset[k + 1]``.

    Attributes:
        sets: one :class:`~warpshade.geometry.spheres.SphereSet` per occluder mesh, fit in world
            space at ``frame``.
        mesh_index: scene mesh index of each set, (M,) int64.
        mesh_path: prim path of each set's mesh.
        frame: the time code the spheres were fit at.
        kinds: attachment kind per set (:data:`ATTACHMENT_KINDS`).
        attachments: per set, the arrays of its attachment (see :func:`spheres_for_scene`).
        rest_radii: per sphere radius in mesh-local units (fit radius / mesh scale at the fit
            frame, times ``radius_scale``, grown by calibration), (S,) float64; the radius at a
            frame is this times the mesh transform's largest singular value.
        radius_scale: the safety factor applied to the fit radii.
        skipped: (mesh path, reason) for every mesh that got no spheres.
        budget: the requested total sphere count; ``split``: how it was divided.
    """

    sets: list
    mesh_index: np.ndarray
    mesh_path: list
    frame: float
    kinds: list
    attachments: list
    rest_radii: np.ndarray
    radius_scale: float = 1.0
    skipped: list = field(default_factory=list)
    budget: int = 0
    split: str = "volume"

    @property
    def sphere_count(self) -> int:
        return int(sum(s.sphere_count for s in self.sets))

    @property
    def sphere_offset(self) -> np.ndarray:
        """First sphere of each set, plus the total, (M + 1,) int64."""
        return np.concatenate([[0], np.cumsum([s.sphere_count for s in self.sets])]).astype(np.int64)

    @property
    def sphere_mesh(self) -> np.ndarray:
        """Scene mesh index of every sphere, (S,) int32."""
        return np.concatenate([np.full(s.sphere_count, m, np.int32) for s, m in zip(self.sets, self.mesh_index)] or [np.zeros(0, np.int32)])

    @property
    def sphere_set(self) -> np.ndarray:
        """Set index of every sphere, (S,) int32."""
        return np.concatenate([np.full(s.sphere_count, k, np.int32) for k, s in enumerate(self.sets)] or [np.zeros(0, np.int32)])

    @property
    def centres(self) -> np.ndarray:
        """World-space centres at the fit frame, (S, 3) float64."""
        return np.concatenate([s.centres for s in self.sets]) if self.sets else np.zeros((0, 3))

    @property
    def radii(self) -> np.ndarray:
        """Fit radii (world units at the fit frame, before safety factor), (S,) float64."""
        return np.concatenate([s.radii for s in self.sets]) if self.sets else np.zeros(0)

    # -- float64 mirror of the per-frame animation --
    def centres_at(self, scene, frame: float) -> np.ndarray:
        """World-space sphere centres at a time code, (S, 3) float64 (reference path)."""
        t = scene.frame_index(frame)
        out = np.zeros((self.sphere_count, 3))
        world = None
        off = self.sphere_offset
        for k, (kind, att) in enumerate(zip(self.kinds, self.attachments)):
            mesh = scene.meshes[int(self.mesh_index[k])]
            sl = slice(int(off[k]), int(off[k + 1]))
            if kind == "rigid":
                m = _mesh_transform(scene, mesh, t)
                out[sl] = att["local_centres"] @ m[:3, :3] + m[3, :3]
            elif kind == "skinned":
                mats = _skinning_matrices(scene, mesh, t)
                idx = att["joint_index"]
                valid = idx >= 0
                m = mats[np.where(valid, idx, 0)]  # (S_k, B, 4, 4)
                contrib = np.einsum("sbi,sbij->sbj", att["joint_point"], m[..., :3, :3]) + att["joint_weight"][..., None] * m[..., 3, :3]
                out[sl] = np.sum(np.where(valid[..., None], contrib, 0.0), axis=1)
            else:
                if world is None:
                    world = scene.points_at(frame)
                pts = world[mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count]
                if kind == "vertex_weights":
                    out[sl] = att["weights"] @ pts
                else:
                    out[sl] = _attach.triangle_frame_points(pts, att["triangle"], att["bary"], att["local_offset"])
        return out

    def mesh_scales_at(self, scene, frame: float) -> np.ndarray:
        """Per set, the largest singular value of its mesh transform at a time code, (M,) float64."""
        t = scene.frame_index(frame)
        return np.array([_transform_scale(_mesh_transform(scene, scene.meshes[int(m)], t)) for m in self.mesh_index])

    def radii_at(self, scene, frame: float) -> np.ndarray:
        """Sphere radii at a time code, (S,) float64 (reference path)."""
        return self.rest_radii * self.mesh_scales_at(scene, frame)[self.sphere_set]

    def surface_samples_at(self, scene, frame: float) -> tuple[np.ndarray, np.ndarray]:
        """Every set's surface samples on the deformed meshes at a time code.

        Returns:
            (points (N, 3) float64 world space, owning sphere (N,) int64 in the concatenated
            sphere indexing).
        """
        world = scene.points_at(frame)
        pts, owner = [], []
        for k, s in enumerate(self.sets):
            mesh = scene.meshes[int(self.mesh_index[k])]
            p = world[mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count]
            pts.append(s.surface_samples(p, mesh.faces))
            owner.append(s.sample_sphere + int(self.sphere_offset[k]))
        if not pts:
            return np.zeros((0, 3)), np.zeros(0, np.int64)
        return np.concatenate(pts), np.concatenate(owner)

    def calibrate_radii(self, scene, frames=None) -> np.ndarray:
        """Grow ``rest_radii`` until the spheres bound every set's surface samples on every frame.

        A skinned or deforming mesh stretches, and fixed radii can leave deformed samples
        outside every sphere. Frame by frame, each uncovered sample grows the sphere of its own
        mesh that needs the least growth to contain it (in mesh-local units, so later frames
        see the grown radii); afterwards the union of spheres bounds every sample on every given
        frame. Interior samples have no deformed position and are not checked.

        Returns:
            the per-sphere growth factor, (S,).
        """
        frames = scene.frames if frames is None else np.asarray(frames, np.float64).reshape(-1)
        old = self.rest_radii.copy()
        off = self.sphere_offset
        for f in frames:
            centres = self.centres_at(scene, f)
            scales = self.mesh_scales_at(scene, f)
            world = scene.points_at(f)
            for k, s in enumerate(self.sets):
                mesh = scene.meshes[int(self.mesh_index[k])]
                pts = s.surface_samples(world[mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count], mesh.faces)
                lo, hi = int(off[k]), int(off[k + 1])
                dist = np.linalg.norm(pts[:, None, :] - centres[None, lo:hi], axis=2)  # (N, S_k)
                radii = self.rest_radii[lo:hi] * scales[k]
                outside = np.all(dist > radii[None], axis=1)
                if not np.any(outside):
                    continue
                for i in np.nonzero(outside)[0]:  # few; radii change as they are processed
                    radii = self.rest_radii[lo:hi] * scales[k]
                    if np.any(dist[i] <= radii):
                        continue
                    j = int(np.argmin(dist[i] - radii))
                    self.rest_radii[lo + j] = dist[i, j] / scales[k] * (1.0 + RADIUS_PAD_RELATIVE)
        return self.rest_radii / np.maximum(old, 1e-300)

    # -- artifact form --
    def to_arrays(self) -> dict:
        """Plain NumPy arrays (for the artifact cache); invert with :meth:`from_arrays`."""
        out = {"rest_radii": self.rest_radii, "mesh_index": np.asarray(self.mesh_index, np.int64)}
        for k, s in enumerate(self.sets):
            for name, arr in s.to_arrays().items():
                out[f"set{k}/{name}"] = arr
            for name, arr in self.attachments[k].items():
                out[f"att{k}/{name}"] = np.asarray(arr)
        meta = {
            "mesh_path": list(self.mesh_path),
            "frame": float(self.frame),
            "kinds": list(self.kinds),
            "radius_scale": float(self.radius_scale),
            "skipped": [list(x) for x in self.skipped],
            "budget": int(self.budget),
            "split": self.split,
            "set_count": len(self.sets),
        }
        out["meta_json"] = np.array(json.dumps(meta))
        return out

    @classmethod
    def from_arrays(cls, arrays: dict) -> SceneSpheres:
        meta = json.loads(str(np.asarray(arrays["meta_json"])))
        sets, atts = [], []
        for k in range(meta["set_count"]):
            sets.append(SphereSet.from_arrays({n.split("/", 1)[1]: a for n, a in arrays.items() if n.startswith(f"set{k}/")}))
            att = {n.split("/", 1)[1]: np.array(a) for n, a in arrays.items() if n.startswith(f"att{k}/")}
            atts.append(att)
        return cls(
            sets=sets,
            mesh_index=np.array(arrays["mesh_index"]),
            mesh_path=meta["mesh_path"],
            frame=meta["frame"],
            kinds=meta["kinds"],
            attachments=atts,
            rest_radii=np.array(arrays["rest_radii"]),
            radius_scale=meta["radius_scale"],
            skipped=[tuple(x) for x in meta["skipped"]],
            budget=meta["budget"],
            split=meta["split"],
        )


def _attach_skinned(scene, mesh, solid, sphere_set: SphereSet, t: int, method: str, max_bones: int) -> dict:
    """Attachment arrays of a skinned mesh's spheres (see :func:`spheres_for_scene`)."""
    skin = mesh.skin
    skel = scene.skeletons[skin.skeleton]
    if method == "mvc":
        bind = np.asarray(skin.geom_bind_transform, np.float64)
        bind_points = mesh.points @ bind[:3, :3] + bind[3, :3]
        weights, err = _attach.mvc_weights(solid, sphere_set.centres, sphere_set)
        att = _attach.bone_coordinates(weights, skin.joint_indices, skin.joint_weights, bind_points, skel.joint_count, max_bones)
        att.update({"skeleton": np.int64(skin.skeleton), "method": np.array("mvc"), "mvc_error": err})
    elif method == "skin_weights":
        att = _attach.skin_weight_coordinates(sphere_set.centres, sphere_set, mesh.faces, skin.joint_indices, skin.joint_weights,
                                              _skinning_matrices(scene, mesh, t), max_bones)
        att.update({"skeleton": np.int64(skin.skeleton), "method": np.array("skin_weights")})
    else:
        raise ValueError(f"mesh {mesh.path}: skinned attachment must be 'mvc' or 'skin_weights', got {method!r}")
    return att


def _split_budget(volumes: np.ndarray, budget: int) -> np.ndarray:
    """Integer counts >= 1 proportional to volume, summing to at most max(budget, len)."""
    n = volumes.size
    if budget < n:
        raise ValueError(f"spheres_for_scene: budget {budget} is smaller than the {n} occluder meshes (one sphere each at least)")
    share = volumes / volumes.sum() * budget
    counts = np.maximum(1, np.floor(share).astype(int))
    while counts.sum() > budget:
        counts[np.argmax(counts)] -= 1
    remainder = share - counts
    for i in np.argsort(-remainder):
        if counts.sum() >= budget:
            break
        counts[i] += 1
    return counts


#: Capsules block with spheres along their spine whose radius exceeds the capsule's by at most
#: this fraction (spacing ``d`` with ``sqrt(1 + (d / 2r)^2) <= 1 + RADIUS_EXCESS``).
RADIUS_EXCESS = 0.03
#: Quasi-random points of the outside-volume estimate of a capsule's spheres.
_EXACT_SAMPLES = 1 << 14


def implicit_spheres(mesh, xf: np.ndarray, frame: float) -> SphereSet | None:
    """The blocker spheres of a tessellated UsdGeom Sphere or Capsule (``mesh.implicit``) whose shape
    does not change over time, in world space at the frame of ``xf`` (its local-to-world, row
    vectors): the sphere itself, or spheres along the capsule's spine (:data:`RADIUS_EXCESS`).
    None for any other mesh (fitted instead). A non-uniform scale bounds by its largest factor."""
    implicit = getattr(mesh, "implicit", None)
    if implicit is None or mesh.animation not in ("static", "rigid"):
        return None
    kind, params = implicit
    if kind not in ("Sphere", "Capsule") or any(isinstance(v, np.ndarray) for v in params.values()):
        return None
    r = float(params["radius"])
    if kind == "Sphere":
        local, radii, h = np.zeros((1, 3)), np.array([r]), 0.0
    else:
        h = float(params["height"])
        step = 2.0 * r * math.sqrt((1.0 + RADIUS_EXCESS) ** 2 - 1.0)
        n = max(2, math.ceil(h / step) + 1) if h > 0 else 1
        d = h / (n - 1) if n > 1 else 0.0
        axis = np.eye(3)[{"X": 0, "Y": 1, "Z": 2}[str(params.get("axis", "Z"))]]
        local = np.linspace(-0.5 * h, 0.5 * h, n)[:, None] * axis[None, :]
        radii = np.full(n, math.sqrt(r * r + 0.25 * d * d))
    scale = _transform_scale(xf)
    centres = local @ xf[:3, :3] + xf[3, :3]
    error, error_union = _capsule_outside(r, h, local, radii)
    volume = (math.pi * r * r * h + 4.0 / 3.0 * math.pi * r ** 3) * scale ** 3
    return SphereSet(centres=centres, radii=radii * scale, source=mesh.path, error=error, error_union=error_union,
                     grid_error=error, volume=volume, closed=True,
                     parameters={"implicit": kind, "exact": True, "frame": float(frame), "radius_excess": RADIUS_EXCESS})


def _capsule_outside(r: float, h: float, centres: np.ndarray, radii: np.ndarray) -> tuple[float, float]:
    """(sum of the spheres' volumes outside the capsule, the union's) over the capsule's volume, by
    Halton points in each sphere (0, 0 for a sphere's own sphere)."""
    if centres.shape[0] == 1 and h == 0.0:
        return 0.0, 0.0
    from scipy.stats import qmc

    u = qmc.Halton(d=3, scramble=False).random(_EXACT_SAMPLES + 1)[1:]
    axis = centres[-1] - centres[0]
    axis = axis / np.linalg.norm(axis)

    def outside(p):  # outside the capsule: farther than r from the spine segment
        z = np.clip(p @ axis, -0.5 * h, 0.5 * h)
        return np.linalg.norm(p - z[:, None] * axis[None, :], axis=1) > r

    cube = 2.0 * u - 1.0
    ball = cube[np.einsum("ij,ij->i", cube, cube) <= 1.0]
    v_ball = 4.0 / 3.0 * math.pi
    total, union_out = 0.0, 0.0
    for k, (c, rad) in enumerate(zip(centres, radii)):
        p = c + rad * ball
        out = outside(p)
        total += out.mean() * v_ball * rad ** 3
        # the union's outside part, each point counted by its first sphere
        if k:
            first = np.all(np.linalg.norm(p[:, None, :] - centres[None, :k, :], axis=2) > radii[None, :k], axis=1)
        else:
            first = np.ones(p.shape[0], bool)
        union_out += (out & first).mean() * v_ball * rad ** 3
    v = math.pi * r * r * h + 4.0 / 3.0 * math.pi * r ** 3
    return float(total / v), float(union_out / v)


def spheres_for_scene(
    scene,
    frame: float | None = None,
    budget: int = 64,
    *,
    split: str = "error",
    target_error: float | None = None,
    meshes=None,
    open_meshes: str = "skip",
    shell_thickness: float | None = None,
    skinned_attachment: str = "mvc",
    max_bones: int = 4,
    radius_scale: float = 1.0,
    calibrate: bool = False,
    progress: bool = False,
    device=None,
    **fit_options,
) -> SceneSpheres:
    """Sphere sets for the occluder meshes of a scene, attached to their animation.

    Args:
        scene: a :class:`warpshade.scene.Scene`.
        frame: time code to fit at (default: the first frame); spheres are fit to the world-space
            points of that frame and attached to the mesh from there.
        budget: total number of spheres over all meshes (an upper bound after pruning).
        split: "error" (default: start every mesh at 1 sphere, then repeatedly double the
            count of the mesh with the largest absolute outside volume, or give it what is left
            of the budget; on the blocker scene with 16 spheres this leaves 0.38 units^3 outside
            against 0.71 for "volume") or "volume" (counts proportional to
            mesh volume, at least 1 each; one fit per mesh, so faster).
        target_error: per-mesh E target: each mesh gets the fewest spheres (1, 2, 4, ..., up to
            its share of the budget) that meet it.
        meshes: scene mesh indices or prim paths to consider (default: all).
        open_meshes: "skip" (default; open meshes such as ground planes and cloth get no
            spheres and are listed in ``skipped``) or "shell" (bound their thickened shells).
        shell_thickness: half-thickness of shells (default 1% of each mesh's diagonal).
        skinned_attachment: "mvc" (mean value coordinates pre-multiplied by bone weights, the
            paper's) or "skin_weights" (linear blend skinning of the centre with the mean skin
            weights of the surface samples its sphere bounds).
        max_bones: bones kept per sphere for skinned meshes.
        radius_scale: safety factor on the fit radii.
        calibrate: grow radii so each sphere keeps bounding its cluster on every scene frame
            (:meth:`SceneSpheres.calibrate_radii`).
        progress: tqdm bars.
        device: Warp device.
        **fit_options: passed to :func:`~warpshade.geometry.spheres.fit_spheres` (grid_cells,
            teleports, seed, ...).

    Returns:
        :class:`SceneSpheres`. Attachment arrays per kind: "rigid" ``local_centres`` (S_k, 3);
        "skinned" ``skeleton``, ``joint_index`` (S_k, B) int32 (-1 unused), ``joint_point``
        (S_k, B, 3), ``joint_weight`` (S_k, B); "vertex_weights" ``weights`` (S_k, V_mesh);
        "triangle_frame" ``triangle`` (S_k, 3), ``bary`` (S_k, 3), ``local_offset`` (S_k, 3).
    """
    if split not in ("volume", "error"):
        raise ValueError(f"spheres_for_scene: split must be 'volume' or 'error', got {split!r}")
    if open_meshes not in ("skip", "shell"):
        raise ValueError(f"spheres_for_scene: open_meshes must be 'skip' or 'shell', got {open_meshes!r}")
    if not radius_scale >= 1.0:
        raise ValueError(f"spheres_for_scene: radius_scale must be >= 1 (the fit radii are already tight), got {radius_scale!r}")
    frame = float(scene.frames[0]) if frame is None else float(frame)
    t = scene.frame_index(frame)
    world = scene.points_at(frame)
    if meshes is None:
        candidates = list(range(len(scene.meshes)))
    else:
        paths = {m.path: i for i, m in enumerate(scene.meshes)}
        candidates = []
        for m in meshes:
            if isinstance(m, str):
                if m not in paths:
                    raise ValueError(f"spheres_for_scene: scene has no mesh {m!r}")
                candidates.append(paths[m])
            else:
                candidates.append(int(m))
    solids, skipped, exact = [], [], {}
    for i in candidates:
        mesh = scene.meshes[i]
        own = implicit_spheres(mesh, _mesh_transform(scene, mesh, t), frame)
        if own is not None:  # a UsdGeom Sphere or Capsule blocks with its own spheres (not from the budget)
            exact[i] = own
            continue
        pts = world[mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count]
        try:
            solid = make_solid(
                pts, mesh.faces, mesh.path, open_mesh="shell" if open_meshes == "shell" else "error", shell_thickness=shell_thickness, device=device
            )
        except ValueError as exc:
            skipped.append((mesh.path, str(exc)))
            continue
        solids.append((i, solid))
    if not solids and not exact:
        named = "; ".join(f"{path}: {why.splitlines()[0]}" for path, why in skipped[:3])
        more = f" (and {len(skipped) - 3} more)" if len(skipped) > 3 else ""
        hint = ("" if open_meshes == "shell" else
                "; open or thin meshes can be bounded as a thickened shell (shexp.blockers open_meshes = 'shell', "
                "with shell_thickness)")
        raise ValueError(f"scene {scene.source or '<arrays>'}: no closed mesh to bound with spheres; skipped "
                         f"{len(skipped)}: {named}{more}{hint}")
    volumes = np.array([solid_volume(solid=s, samples=4096)[0] for _, s in solids])
    counts = _split_budget(volumes, int(budget)) if solids else np.zeros(0, int)
    opts = dict(fit_options)
    opts.setdefault("progress", progress)

    def fit(k: int, count: int) -> SphereSet:
        i, solid = solids[k]
        mesh = scene.meshes[i]
        pts = world[mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count]
        return fit_spheres(
            pts,
            mesh.faces,
            count,
            target_error=target_error,
            name=mesh.path,
            open_mesh="shell" if not solid.closed else "error",
            shell_thickness=solid.shell_thickness if not solid.closed else None,
            device=device,
            **opts,
        )

    if not solids:
        sets = []
    elif split == "volume" or len(solids) == 1:
        sets = [fit(k, int(c)) for k, c in enumerate(counts)]
    else:
        counts = np.ones(len(solids), dtype=int)
        sets = [fit(k, 1) for k in range(len(solids))]
        while counts.sum() < budget:
            k = int(np.argmax([s.error * s.volume for s in sets]))  # most outside volume
            counts[k] += min(counts[k], int(budget) - int(counts.sum()))  # double, or what is left
            sets[k] = fit(k, int(counts[k]))

    entries = sorted([(i, solid, st) for (i, solid), st in zip(solids, sets)] +
                     [(i, None, st) for i, st in exact.items()], key=lambda e: e[0])
    solids, sets = [(i, solid) for i, solid, _ in entries], [st for _, _, st in entries]
    kinds, attachments, rest = [], [], []
    for (i, solid), s in zip(solids, sets):
        mesh = scene.meshes[i]
        xf = _mesh_transform(scene, mesh, t)
        scale = _transform_scale(xf)
        rest.append(s.radii / scale * radius_scale)
        if mesh.animation in ("static", "rigid"):
            inv = np.linalg.inv(xf)
            kinds.append("rigid")
            attachments.append({"local_centres": s.centres @ inv[:3, :3] + inv[3, :3]})
        elif mesh.animation == "skinned":
            kinds.append("skinned")
            attachments.append(_attach_skinned(scene, mesh, solid, s, t, skinned_attachment, max_bones))
        elif solid.closed:
            kinds.append("vertex_weights")
            weights, err = _attach.mvc_weights(solid, s.centres, s)
            attachments.append({"weights": weights, "mvc_error": err})
        else:
            kinds.append("triangle_frame")
            attachments.append(_attach.triangle_frame_attachment(solid.points, solid.faces, s.centres))
    result = SceneSpheres(
        sets=sets,
        mesh_index=np.array([i for i, _ in solids], dtype=np.int64),
        mesh_path=[scene.meshes[i].path for i, _ in solids],
        frame=frame,
        kinds=kinds,
        attachments=attachments,
        rest_radii=np.concatenate(rest),
        radius_scale=float(radius_scale),
        skipped=skipped,
        budget=int(budget),
        split=split,
    )
    if calibrate:
        result.calibrate_radii(scene)
    return result


def scene_receiver_clusters(scene, frame: float | None = None, vertices_per_cluster: int = 300, meshes=None,
                            iterations: int = 30, seed: int = 0) -> ReceiverClusters:
    """Lloyd clusters of each scene mesh's vertices at a frame
    (:func:`~warpshade.geometry.spheres.cluster_receivers` on ``scene.points_at(frame)``).

    Args:
        scene: the scene; frame: time code of the positions clustered (default first frame).
        vertices_per_cluster, iterations, seed: see ``cluster_receivers``.
        meshes: scene mesh indices to cluster (default: all).

    Returns:
        :class:`~warpshade.geometry.spheres.ReceiverClusters` in scene vertex indexing, with
        ``cluster_mesh`` the scene mesh index.
    """
    frame = float(scene.frames[0]) if frame is None else float(frame)
    offsets = [m.vertex_offset for m in scene.meshes] + [scene.vertex_count]
    return cluster_receivers(scene.points_at(frame), offsets, vertices_per_cluster, meshes=meshes, iterations=iterations, seed=seed,
                             names=[f"mesh {m.path} at frame {frame:g}" for m in scene.meshes])


class SphereAnimator:
    """Per-frame world-space sphere centres and radii on a Warp device, kernels only.

    Everything static (attachment arrays, rest radii, index tables) is uploaded once;
    :meth:`launch` only launches kernels that gather from the frame's
    :class:`~warpshade.scene._state.FrameState` arrays by index, so it can be recorded and
    replayed (:func:`warpshade._wp.record_program`):

    * rigid / static sets: ``state.mesh_transforms[mesh]`` applied to mesh-local centres;
    * skinned sets: ``state.skin_matrices[state.joint_offsets[skeleton] + joint]`` applied to
      the bone coordinates;
    * deforming sets: dense vertex weights or triangle frames over ``state.points``;
    * radii: rest radius times ``state.mesh_scales[mesh]``.

    Args:
        scene: the :class:`~warpshade.scene.Scene` the spheres were fit to (mesh vertex ranges).
        spheres: its :class:`SceneSpheres`.
        device: Warp device (None = Warp's default).

    Attributes:
        centres: wp.array(vec3), shape (max(S, 1),), world space, in :class:`SceneSpheres` order.
        radii: wp.array(float32), shape (max(S, 1),), world units.
        sphere_count: S.
    """

    def __init__(self, scene, spheres: SceneSpheres, device=None):
        dev = resolve_device(device)
        self.device = dev
        self.scene = scene
        self.spheres = spheres
        self.sphere_count = s_count = spheres.sphere_count
        self._mesh_count = len(scene.meshes)
        self.centres = wp.zeros(max(s_count, 1), dtype=wp.vec3, device=dev)
        self.radii = wp.zeros(max(s_count, 1), dtype=wp.float32, device=dev)

        def i32(a):
            return wp.array(np.asarray(a, np.int32), dtype=wp.int32, device=dev)

        def f32(a, dtype=wp.float32):
            return wp.array(np.asarray(a, np.float32), dtype=dtype, device=dev)

        self._rest_radii = f32(spheres.rest_radii)
        self._sphere_mesh = i32(spheres.sphere_mesh)
        off = spheres.sphere_offset
        rigid_c, rigid_m, rigid_s = [], [], []
        skinned: dict[int, list] = {}  # skeleton -> per set (joint_index, joint_point, joint_weight, sphere ids)
        self._deforming = []  # (kernel, count, inputs before the points, inputs after them)
        for k, (kind, att) in enumerate(zip(spheres.kinds, spheres.attachments)):
            ids = np.arange(off[k], off[k + 1], dtype=np.int32)
            mesh_index = int(spheres.mesh_index[k])
            mesh = scene.meshes[mesh_index]
            if kind == "rigid":
                rigid_c.append(att["local_centres"])
                rigid_m.append(np.full(ids.size, mesh_index, np.int32))
                rigid_s.append(ids)
            elif kind == "skinned":
                skinned.setdefault(int(att["skeleton"]), []).append((att["joint_index"], att["joint_point"], att["joint_weight"], ids))
            elif kind == "vertex_weights":
                self._deforming.append((_k.vertex_weight_centres_kernel, ids.size, [f32(att["weights"])], [int(mesh.vertex_offset), i32(ids)]))
            else:
                self._deforming.append((_k.triangle_frame_centres_kernel, ids.size,
                                        [i32(att["triangle"]), f32(att["bary"], wp.vec3), f32(att["local_offset"], wp.vec3)],
                                        [int(mesh.vertex_offset), i32(ids)]))
        self._rigid = None
        if rigid_s:
            self._rigid = (f32(np.concatenate(rigid_c), wp.vec3), i32(np.concatenate(rigid_m)), i32(np.concatenate(rigid_s)))
        self._skinned = []  # (skeleton, joint_index, joint_point, joint_weight, sphere ids): one launch per skeleton
        for skeleton, parts in sorted(skinned.items()):
            bones = max(p[0].shape[1] for p in parts)
            pad = [bones - p[0].shape[1] for p in parts]
            ji = np.concatenate([np.pad(p[0], ((0, 0), (0, n)), constant_values=-1) for p, n in zip(parts, pad)])
            jp = np.concatenate([np.pad(p[1], ((0, 0), (0, n), (0, 0))) for p, n in zip(parts, pad)])
            jw = np.concatenate([np.pad(p[2], ((0, 0), (0, n))) for p, n in zip(parts, pad)])
            self._skinned.append((skeleton, i32(ji), f32(jp, wp.vec3), f32(jw),
                                  i32(np.concatenate([p[3] for p in parts]))))

    def _check(self, state) -> None:
        """Refuse a frame state of another device or scene (host attribute reads only)."""
        if str(state.points.device) != str(self.device):
            raise ValueError(f"SphereAnimator: frame state on {state.points.device}, animator on {self.device}")
        if state.mesh_transforms.shape[0] != self._mesh_count or state.mesh_scales.shape[0] != self._mesh_count:
            raise ValueError(f"SphereAnimator: frame state has {state.mesh_transforms.shape[0]} mesh transforms, "
                             f"the scene {self._mesh_count} meshes")

    def launch(self, state) -> None:
        """Centres and radii of the frame held by ``state`` (kernels on fixed buffers only).

        Args:
            state: the frame's :class:`~warpshade.scene._state.FrameState` on this device
                (``mesh_transforms``, ``mesh_scales``, ``skin_matrices``, ``joint_offsets``,
                ``points`` are read; its arrays' addresses are what a recording captures).
        """
        self._check(state)
        dev = self.device
        if self._rigid is not None:
            local, mesh, ids = self._rigid
            wp.launch(_k.rigid_centres_kernel, dim=ids.shape[0], inputs=[local, mesh, state.mesh_transforms, ids, self.centres], device=dev)
        for skeleton, ji, jp, jw, ids in self._skinned:
            wp.launch(_k.skinned_centres_kernel, dim=ids.shape[0], device=dev,
                      inputs=[ji, jp, jw, state.skin_matrices, int(state.joint_offsets[skeleton]), ids, self.centres])
        for kernel, count, head, tail in self._deforming:
            wp.launch(kernel, dim=count, inputs=[*head, state.points, *tail, self.centres], device=dev)
        if self.sphere_count:
            wp.launch(_k.scale_radii_kernel, dim=self.sphere_count, device=dev,
                      inputs=[self._rest_radii, self._sphere_mesh, state.mesh_scales, self.radii])

    def update(self, state) -> None:
        """The same as :meth:`launch`."""
        self.launch(state)
