"""Sphere sets of a scene's occluders, attached to the animation (private; the public names
are re-exported by :mod:`warpshade.geometry.spheres`)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from .._wp import resolve_device, wp
from . import _spheres_fit as _fit
from . import _spheres_kernels as _k
from . import _spheres_mvc as _mvc
from ._spheres_core import SphereSet, fit_spheres, solid_volume

# ---- scenes and animation -------------------------------------------------------------------
#: Attachment kinds (how a set's centres follow its mesh).
ATTACHMENT_KINDS = ("rigid", "skinned", "vertex_weights", "triangle_frame")


def _mesh_transform(scene, mesh, t: int) -> np.ndarray:
    """Row-vector local-to-world of a mesh at frame index t (skeleton-to-world when skinned)."""
    if mesh.animation == "skinned":
        skel = scene.skeletons[mesh.skin.skeleton]
        return skel.skel_to_world[min(t, skel.skel_to_world.shape[0] - 1)]
    return mesh.transforms[min(t, mesh.transforms.shape[0] - 1)]


def _transform_scale(matrix: np.ndarray) -> float:
    """Largest singular value of the 3x3 part: a sphere of radius r maps inside radius s * r."""
    return float(np.linalg.svd(np.asarray(matrix, np.float64)[:3, :3], compute_uv=False)[0])


def _skinning_matrices(scene, skeleton_index: int, t: int, joint_transforms=None, skel_to_world=None) -> np.ndarray:
    """inverse(bind) @ skel_space @ skel_to_world per joint, (J, 4, 4) row-vector, float64."""
    skel = scene.skeletons[skeleton_index]
    tt = min(t, skel.local_transforms.shape[0] - 1)
    space = skel.skel_space_transforms(tt) if joint_transforms is None else np.asarray(joint_transforms, np.float64)
    world = skel.skel_to_world[min(t, skel.skel_to_world.shape[0] - 1)] if skel_to_world is None else skel_to_world
    return np.linalg.inv(skel.bind_transforms) @ space @ world


@dataclass
class SceneSpheres:
    """Sphere sets of a scene's occluder meshes, attached so they follow the animation.

    Spheres of all sets are concatenated in set order: set ``k`` owns spheres
    ``sphere_offset[k] : sphere_offset[k + 1]``.

    Attributes:
        sets: one :class:`SphereSet` per occluder mesh, fit in world space at ``frame``.
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

    # -- float64 reference of the per-frame animation --
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
                mats = _skinning_matrices(scene, int(att["skeleton"]), t, skel_to_world=_mesh_transform(scene, mesh, t))
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
                    out[sl] = _triangle_frame_points(pts, att["triangle"], att["bary"], att["local_offset"])
        return out

    def mesh_scales_at(self, scene, frame: float) -> np.ndarray:
        """Per set, the largest singular value of its mesh transform at a time code, (M,)."""
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
                    self.rest_radii[lo + j] = dist[i, j] / scales[k] * (1.0 + _fit.RADIUS_PAD_RELATIVE)
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


def _triangle_frames(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Rows (unit edge a->b, normal x edge, unit normal) per triangle, (n, 3, 3) float64."""
    e = b - a
    n = np.cross(e, c - a)
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    le = np.linalg.norm(e, axis=1, keepdims=True)
    ok = (ln[:, 0] > 1e-30) & (le[:, 0] > 1e-30)
    n = np.where(ok[:, None], n / np.maximum(ln, 1e-300), [0.0, 0.0, 1.0])
    e = np.where(ok[:, None], e / np.maximum(le, 1e-300), [1.0, 0.0, 0.0])
    return np.stack([e, np.cross(n, e), n], axis=1)


def _triangle_frame_points(points, triangle, bary, local_offset) -> np.ndarray:
    a, b, c = (points[triangle[:, k]] for k in range(3))
    frames = _triangle_frames(a, b, c)
    base = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:3] * c
    return base + np.einsum("si,sij->sj", local_offset, frames)


def _closest_on_triangles(x: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest point of each triangle to x (Ericson's region test), returns (points, bary)."""
    ab, ac, ap = b - a, c - a, x - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = x - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = x - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    n = x.shape[0]
    bary = np.zeros((n, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = vb / denom
        w = vc / denom
        bary[:] = np.stack([1 - v - w, v, w], axis=1)
        # edge and vertex regions
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        regions = [
            ((d1 <= 0) & (d2 <= 0), np.stack([np.ones(n), np.zeros(n), np.zeros(n)], 1)),
            ((d3 >= 0) & (d4 <= d3), np.stack([np.zeros(n), np.ones(n), np.zeros(n)], 1)),
            ((d6 >= 0) & (d5 <= d6), np.stack([np.zeros(n), np.zeros(n), np.ones(n)], 1)),
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), np.stack([1 - t_ab, t_ab, np.zeros(n)], 1)),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), np.stack([1 - t_ac, np.zeros(n), t_ac], 1)),
            ((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), np.stack([np.zeros(n), 1 - t_bc, t_bc], 1)),
        ]
    done = np.zeros(n, dtype=bool)
    for mask, value in regions:
        m = mask & ~done
        bary[m] = value[m]
        done |= m
    bary = np.nan_to_num(bary, nan=1.0 / 3.0)
    return bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:3] * c, bary


def _attach_triangle_frame(points: np.ndarray, faces: np.ndarray, centres: np.ndarray) -> dict:
    """Each centre as a point of its nearest triangle plus an offset in that triangle's frame."""
    tri = np.zeros((centres.shape[0], 3), np.int32)
    bary = np.zeros((centres.shape[0], 3))
    offset = np.zeros((centres.shape[0], 3))
    a, b, c = (points[faces[:, k]] for k in range(3))
    for i, x in enumerate(centres):
        q, w = _closest_on_triangles(np.broadcast_to(x, a.shape), a, b, c)
        f = int(np.argmin(np.linalg.norm(q - x, axis=1)))
        frame = _triangle_frames(a[f : f + 1], b[f : f + 1], c[f : f + 1])[0]
        tri[i], bary[i], offset[i] = faces[f], w[f], frame @ (x - q[f])
    return {"triangle": tri, "bary": bary, "local_offset": offset}


def _representatives(solid) -> np.ndarray:
    """For each merged vertex, the first original vertex that maps to it."""
    _, first = np.unique(solid.merged_index, return_index=True)
    return first


def _mvc_weights(solid, centres: np.ndarray, sphere_set: SphereSet | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mean value coordinates of each centre over the caller's vertices, (S, V), and the
    linear-precision error ``|sum_v w_v p_v - centre|`` per centre.

    On a mesh of several closed components each centre uses the component that holds most of
    its cluster's surface samples (``sphere_set`` given), so it moves with what it bounds.
    """
    vlabel = _mvc.vertex_components(solid.merged_faces, solid.merged_points.shape[0])
    comps = vlabel[solid.merged_faces[:, 0]]
    rep = _representatives(solid)
    dominant = [None] * centres.shape[0]
    if sphere_set is not None and np.unique(comps).size > 1:
        sample_comp = vlabel[solid.merged_index[solid.faces[sphere_set.sample_face, 0]]]
        for i in range(centres.shape[0]):
            own = sample_comp[sphere_set.sample_sphere == i]
            if own.size:
                dominant[i] = int(np.bincount(own).argmax())
    w = np.zeros((centres.shape[0], solid.points.shape[0]))
    err = np.zeros(centres.shape[0])
    for i, x in enumerate(centres):
        lam = _mvc.component_mvc(solid.merged_points, solid.merged_faces, x, comps, component=dominant[i])
        w[i, rep] = lam
        err[i] = float(np.linalg.norm(lam @ solid.merged_points - x))
    return w, err


def _bone_coordinates(weights: np.ndarray, skin, bind_points: np.ndarray, joint_count: int, max_bones: int) -> dict:
    """Pre-multiply per-vertex coordinates by skin weights: per sphere (bone, q_j, b_j).

    ``centre = sum_j [q_j, b_j] @ M_j`` with ``b_j = sum_v w_v W_vj`` and ``q_j = sum_v w_v W_vj
    p_v`` (bind-space points), exact for any joint matrices when every bone is kept. Only the
    ``max_bones`` bones of largest |b_j| are stored; each dropped bone's (q_j, b_j) is folded
    into the strongest kept bone, which keeps the fit-pose centre and the weight sum exact.
    """
    idx = np.asarray(skin.joint_indices, np.int64)
    wts = np.asarray(skin.joint_weights, np.float64)
    s_count = weights.shape[0]
    b = np.zeros((s_count, joint_count))
    q = np.zeros((s_count, joint_count, 3))
    for k in range(idx.shape[1]):
        vw = weights * wts[None, :, k]  # (S, V)
        for j in np.unique(idx[:, k]):
            sel = idx[:, k] == j
            b[:, j] += vw[:, sel].sum(axis=1)
            q[:, j] += vw[:, sel] @ bind_points[sel]
    bones = min(max_bones, joint_count)
    order = np.argsort(-np.abs(b), axis=1)
    keep = order[:, :bones]
    rows = np.arange(s_count)[:, None]
    jb = b[rows, keep].copy()
    jq = q[rows, keep].copy()
    dropped = order[:, bones:]
    if dropped.shape[1]:
        jb[:, 0] += b[rows, dropped].sum(axis=1)
        jq[:, 0] += q[rows, dropped].sum(axis=1)
    used = (np.abs(jb) > 0) | np.any(jq != 0, axis=2)
    used[:, 0] = True
    return {
        "joint_index": np.where(used, keep, -1).astype(np.int32),
        "joint_point": np.where(used[..., None], jq, 0.0),
        "joint_weight": np.where(used, jb, 0.0),
    }


def _attach_skinned(scene, mesh, solid, sphere_set: SphereSet, t: int, method: str, max_bones: int) -> dict:
    centres = sphere_set.centres
    skin = mesh.skin
    skel = scene.skeletons[skin.skeleton]
    bind = np.asarray(skin.geom_bind_transform, np.float64)
    bind_points = mesh.points @ bind[:3, :3] + bind[3, :3]
    if method == "mvc":
        weights, err = _mvc_weights(solid, centres, sphere_set)
    elif method == "skin_weights":
        # linear blend skinning of the centre itself, with the mean skin weights of the surface
        # samples its sphere bounds (barycentric blends of their triangle's vertex weights)
        idx = np.asarray(skin.joint_indices, np.int64)
        wts = np.asarray(skin.joint_weights, np.float64)
        vertex_bones = np.zeros((mesh.vertex_count, skel.joint_count))
        for kk in range(idx.shape[1]):
            np.add.at(vertex_bones, (np.arange(mesh.vertex_count), idx[:, kk]), wts[:, kk])
        tri = np.asarray(mesh.faces, np.int64)[sphere_set.sample_face]
        sample_bones = np.einsum("nk,nkj->nj", sphere_set.sample_bary, vertex_bones[tri])
        bone = np.zeros((centres.shape[0], skel.joint_count))
        np.add.at(bone, sphere_set.sample_sphere, sample_bones)
        bone /= np.maximum(bone.sum(axis=1, keepdims=True), 1e-300)
        mats = _skinning_matrices(scene, skin.skeleton, t, skel_to_world=_mesh_transform(scene, mesh, t))
        bones = min(max_bones, skel.joint_count)
        order = np.argsort(-bone, axis=1)[:, :bones]
        rows = np.arange(bone.shape[0])[:, None]
        jb = bone[rows, order]
        jb = jb / jb.sum(axis=1, keepdims=True)
        # the centre carried back to bind space through the blended fit-frame transform
        blended = np.einsum("sk,skab->sab", jb, mats[order])
        homo = np.concatenate([centres, np.ones((centres.shape[0], 1))], axis=1)
        bind_centre = np.einsum("sa,sab->sb", homo, np.linalg.inv(blended))[:, :3]
        att = {"joint_index": order.astype(np.int32), "joint_point": jb[..., None] * bind_centre[:, None, :], "joint_weight": jb}
        att.update({"skeleton": np.int64(skin.skeleton), "method": np.array("skin_weights")})
        return att
    else:
        raise ValueError(f"mesh {mesh.path}: skinned attachment must be 'mvc' or 'skin_weights', got {method!r}")
    att = _bone_coordinates(weights, skin, bind_points, skel.joint_count, max_bones)
    att.update({"skeleton": np.int64(skin.skeleton), "method": np.array("mvc"), "mvc_error": err})
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
        **fit_options: passed to :func:`fit_spheres` (grid_cells, teleports, seed, ...).

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
    solids, skipped = [], []
    for i in candidates:
        mesh = scene.meshes[i]
        pts = world[mesh.vertex_offset : mesh.vertex_offset + mesh.vertex_count]
        try:
            solid = _fit.make_solid(
                pts, mesh.faces, mesh.path, open_mesh="shell" if open_meshes == "shell" else "error", shell_thickness=shell_thickness, device=device
            )
        except ValueError as exc:
            skipped.append((mesh.path, str(exc)))
            continue
        solids.append((i, solid))
    if not solids:
        raise ValueError(f"scene {scene.source or '<arrays>'}: no closed mesh to bound with spheres ({len(skipped)} skipped)")
    volumes = np.array([solid_volume(solid=s, samples=4096)[0] for _, s in solids])
    counts = _split_budget(volumes, int(budget))
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

    if split == "volume" or len(solids) == 1:
        sets = [fit(k, int(c)) for k, c in enumerate(counts)]
    else:
        counts = np.ones(len(solids), dtype=int)
        sets = [fit(k, 1) for k in range(len(solids))]
        while counts.sum() < budget:
            k = int(np.argmax([s.error * s.volume for s in sets]))  # most outside volume
            counts[k] += min(counts[k], int(budget) - int(counts.sum()))  # double, or what is left
            sets[k] = fit(k, int(counts[k]))

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
            weights, err = _mvc_weights(solid, s.centres, s)
            attachments.append({"weights": weights, "mvc_error": err})
        else:
            kinds.append("triangle_frame")
            attachments.append(_attach_triangle_frame(solid.points, solid.faces, s.centres))
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


class SphereAnimator:
    """Per-frame world-space sphere centres and radii on a Warp device.

    Fixed device buffers are allocated once; :meth:`prepare` uploads the frame's matrices
    (host work) and :meth:`launch` only launches kernels on fixed buffers, so a frame graph can
    capture it. :meth:`update` does both from a :class:`warpshade.scene.FrameState`.

    Attributes:
        centres: wp.array(vec3), (S,), world space, in :class:`SceneSpheres` order.
        radii: wp.array(float32), (S,), world units.
    """

    def __init__(self, scene, spheres: SceneSpheres, device=None):
        dev = resolve_device(device)
        self.device = dev
        self.scene = scene
        self.spheres = spheres
        s_count = spheres.sphere_count
        self.centres = wp.zeros(max(s_count, 1), dtype=wp.vec3, device=dev)
        self.radii = wp.zeros(max(s_count, 1), dtype=wp.float32, device=dev)
        self._rest_radii = wp.array(spheres.rest_radii.astype(np.float32), dtype=wp.float32, device=dev)
        self._sphere_set = wp.array(spheres.sphere_set, dtype=wp.int32, device=dev)
        set_count = len(spheres.sets)
        self._mesh_scale = wp.ones(max(set_count, 1), dtype=wp.float32, device=dev)
        self._set_matrices = wp.zeros(max(set_count, 1), dtype=wp.mat44, device=dev)
        off = spheres.sphere_offset
        rigid_c, rigid_m, rigid_s = [], [], []
        skin_i, skin_p, skin_w, skin_s = [], [], [], []
        self._skeletons = sorted({int(a["skeleton"]) for k, a in zip(spheres.kinds, spheres.attachments) if k == "skinned"})
        joint_base, base = {}, 0
        for sk in self._skeletons:
            joint_base[sk] = base
            base += scene.skeletons[sk].joint_count
        self._joint_base = joint_base
        self._joint_matrices = wp.zeros(max(base, 1), dtype=wp.mat44, device=dev)
        self._per_mesh = []  # (kernel, inputs) of vertex-weight / triangle-frame sets
        bones = max([a["joint_index"].shape[1] for k, a in zip(spheres.kinds, spheres.attachments) if k == "skinned"] or [1])
        for k, (kind, att) in enumerate(zip(spheres.kinds, spheres.attachments)):
            ids = np.arange(off[k], off[k + 1], dtype=np.int32)
            mesh = scene.meshes[int(spheres.mesh_index[k])]
            if kind == "rigid":
                rigid_c.append(att["local_centres"])
                rigid_m.append(np.full(ids.size, k, np.int32))
                rigid_s.append(ids)
            elif kind == "skinned":
                ji = att["joint_index"].astype(np.int64)
                pad = bones - ji.shape[1]
                ji = np.where(ji >= 0, ji + joint_base[int(att["skeleton"])], -1)
                skin_i.append(np.pad(ji, ((0, 0), (0, pad)), constant_values=-1))
                skin_p.append(np.pad(att["joint_point"], ((0, 0), (0, pad), (0, 0))))
                skin_w.append(np.pad(att["joint_weight"], ((0, 0), (0, pad))))
                skin_s.append(ids)
            elif kind == "vertex_weights":
                self._per_mesh.append(
                    (
                        _k.vertex_weight_centres_kernel,
                        ids.size,
                        [
                            wp.array(att["weights"].astype(np.float32), dtype=wp.float32, device=dev),
                            None,
                            int(mesh.vertex_offset),
                            wp.array(ids, dtype=wp.int32, device=dev),
                        ],
                    )
                )
            else:
                self._per_mesh.append(
                    (
                        _k.triangle_frame_centres_kernel,
                        ids.size,
                        [
                            wp.array(att["triangle"].astype(np.int32), dtype=wp.int32, device=dev),
                            wp.array(att["bary"].astype(np.float32), dtype=wp.vec3, device=dev),
                            wp.array(att["local_offset"].astype(np.float32), dtype=wp.vec3, device=dev),
                            None,
                            int(mesh.vertex_offset),
                            wp.array(ids, dtype=wp.int32, device=dev),
                        ],
                    )
                )
        self._rigid = None
        if rigid_s:
            self._rigid = [
                wp.array(np.concatenate(rigid_c).astype(np.float32), dtype=wp.vec3, device=dev),
                wp.array(np.concatenate(rigid_m), dtype=wp.int32, device=dev),
                self._set_matrices,
                wp.array(np.concatenate(rigid_s), dtype=wp.int32, device=dev),
            ]
        self._skinned = None
        if skin_s:
            self._skinned = [
                wp.array(np.concatenate(skin_i).astype(np.int32), dtype=wp.int32, device=dev),
                wp.array(np.concatenate(skin_p).astype(np.float32), dtype=wp.vec3, device=dev),
                wp.array(np.concatenate(skin_w).astype(np.float32), dtype=wp.float32, device=dev),
                self._joint_matrices,
                wp.array(np.concatenate(skin_s), dtype=wp.int32, device=dev),
            ]

    def prepare(self, frame_state) -> None:
        """Upload the frame's mesh transforms, joint matrices and radius scales (host work)."""
        from .skinning import joint_matrices_for_warp

        sp, scene = self.spheres, self.scene
        t = int(frame_state.frame_index)
        mats = np.stack([np.asarray(frame_state.mesh_transforms[int(m)], np.float64) for m in sp.mesh_index])
        self._set_matrices.assign(joint_matrices_for_warp(mats))
        self._mesh_scale.assign(np.array([_transform_scale(m) for m in mats], np.float32))
        if self._skeletons:
            blocks = []
            for sk in self._skeletons:
                # the skeleton's world transform is the skinned mesh's transform in the frame state
                mesh_k = next(k for k, (kind, a) in enumerate(zip(sp.kinds, sp.attachments)) if kind == "skinned" and int(a["skeleton"]) == sk)
                blocks.append(
                    _skinning_matrices(scene, sk, t, joint_transforms=frame_state.joint_transforms[sk], skel_to_world=mats[mesh_k])
                )
            self._joint_matrices.assign(joint_matrices_for_warp(np.concatenate(blocks)))

    def launch(self, points) -> None:
        """Compute centres and radii on the device (kernels on fixed buffers only).

        Args:
            points: the frame's world-space scene points, wp.array(vec3) (vertex_count,) (used by
                deforming meshes).
        """
        dev = self.device
        if self._rigid is not None:
            wp.launch(_k.rigid_centres_kernel, dim=self._rigid[0].shape[0], inputs=self._rigid + [self.centres], device=dev)
        if self._skinned is not None:
            wp.launch(_k.skinned_centres_kernel, dim=self._skinned[0].shape[0], inputs=self._skinned + [self.centres], device=dev)
        for kernel, count, inputs in self._per_mesh:
            args = [points if a is None else a for a in inputs]
            wp.launch(kernel, dim=count, inputs=args + [self.centres], device=dev)
        if self.spheres.sphere_count:
            wp.launch(
                _k.scale_radii_kernel,
                dim=self.spheres.sphere_count,
                inputs=[self._rest_radii, self._sphere_set, self._mesh_scale, self.radii],
                device=dev,
            )

    def update(self, frame_state) -> None:
        """:meth:`prepare` then :meth:`launch` with ``frame_state.points``."""
        self.prepare(frame_state)
        self.launch(frame_state.points)
