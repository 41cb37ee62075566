"""USD stages in: meshes, animation, skinning, lights and camera as a :class:`~warpshade.scene.Scene`.

This is the only module of warpshade that imports ``pxr``. What :func:`load_usd` reads:

Meshes
    Every ``UsdGeom.Mesh`` reached by a traversal of active, defined, non-abstract prims,
    *including instance proxies* (scene-graph instancing is flattened: each instance becomes its
    own :class:`~warpshade.scene.Mesh`, named by its proxy path) and the mesh prototypes of
    ``UsdGeom.PointInstancer`` prims (one mesh per instance and prototype mesh, named
    ``<instancer>/instance_<i>/<path below the prototype>``; the prototype root's own transform
    is applied before the instance transform; instances hidden by ``invisibleIds`` or inactive
    are left out). Skipped (and listed in ``Scene.skipped``): prims whose computed purpose is
    ``guide`` or ``proxy``, prims that are invisible at the first frame, implicit gprims (Sphere,
    Cube, Capsule, ...), and unsupported lights.

    Convex polygons are triangulated as fans from their first vertex; concave ones (a reflex
    corner in the rest pose) are re-triangulated by ear clipping (mapbox-earcut) in their
    best-fit plane, keeping their winding. Holes (``holeIndices``) are removed; ``orientation = "leftHanded"`` flips
    the winding so every triangle is counter-clockwise around its outward normal. Topology must
    not change over time.

Normals
    Authored normals (``primvars:normals`` before ``normals``) are kept for static and rigid
    meshes and converted to per-vertex: ``vertex``/``varying`` as they are, ``faceVarying``
    and ``uniform`` as the polygon-area-weighted average over the polygons around each vertex
    (which reproduces smooth normals exactly and averages hard edges, the only option for
    per-vertex shading). Meshes without usable normals, and every deforming or skinned mesh, get
    area-weighted vertex normals from the (deformed) points at evaluation time.

UVs
    ``primvars:st`` (else the first ``texCoord2f`` primvar): ``vertex``/``varying`` as they are,
    ``faceVarying`` averaged over each vertex's corners (best effort: UV seams are averaged),
    others ignored.

Materials
    A bound ``UsdPreviewSurface`` becomes ``Mesh.surface``, a
    :class:`~warpshade.scene.textures.SurfaceMaps` (diffuse colour, roughness, specular colour
    or metallic, each a constant or a ``UsdUVTexture``; read by :mod:`warpshade.io.textures`,
    which documents the rules and errors). Textures whose ``st`` names another primvar than the
    default UVs make that primvar ``Mesh.uvs``.

Albedo
    A bound ``UsdPreviewSurface`` with a textured ``diffuseColor`` or a non-zero ``metallic``:
    the surface's effective diffuse albedo (``diffuseColor * (1 - metallic)``) sampled at the
    vertices' UVs; with a constant ``diffuseColor`` (its spec default 0.18 when unauthored) that
    colour; else ``primvars:displayColor`` (constant, vertex, or averaged from uniform /
    faceVarying), else 0.8 grey. Diffuse colours driven by other nodes are not evaluated (a
    warning says so).

Animation
    Frames are every integer time code from the stage's start to end time code (a stage
    without an authored range is one frame at time code 0). Per mesh: time-sampled points ->
    ``"deforming"``; a world transform that differs between frames -> ``"rigid"``; bound to a
    UsdSkel skeleton through a SkelRoot -> ``"skinned"``; else ``"static"``. Skinned meshes:
    joint-local transforms sampled per frame with ``UsdSkel.SkeletonQuery``, bind transforms
    from the skeleton, weights from ``primvars:skel:jointIndices`` / ``jointWeights``
    (constant or vertex interpolation), remapped through the mesh's ``skel:joints`` to
    skeleton order, rows renormalised; ``primvars:skel:geomBindTransform``.

Lights
    ``DomeLight`` / ``DomeLight_1`` (lat-long ``inputs:texture:file`` as .exr or .hdr, OpenEXR
    orientation in the dome's frame, ``poleAxis`` honoured for DomeLight_1; no texture -> a
    constant environment) -> :class:`~warpshade.scene.Environment`; ``DistantLight`` ->
    :class:`~warpshade.scene.DistantLight`; ``SphereLight`` ->
    :class:`~warpshade.scene.SphereLight`. Emission is ``color * intensity * 2**exposure``
    (times the blackbody colour when ``enableColorTemperature``); see :func:`_read_light`
    for ``normalize``. Animated light transforms are followed (a
    :class:`~warpshade.scene.LightTrack` per light: domes and distant lights rotate, sphere
    lights move); emission and radius are read at the first frame.

Camera
    The first ``UsdGeom.Camera`` in traversal order, at the first frame.

Errors name the file or prim: missing file (FileNotFoundError), unreadable stage, no meshes,
NaN/inf points, face indices out of range, inconsistent face counts, a skin that does not match
its skeleton, a missing or unreadable dome texture, a missing, unreadable or unusable material
texture or the UVs it needs (ValueError; see :mod:`warpshade.io.textures`). Zero-area triangles are
dropped with a ``warnings.warn`` naming the prim and the count, which is also kept in
``Mesh.dropped_face_count``. The stage is opened read-only; nothing is ever written.
"""

from __future__ import annotations

import math
import os
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .._fileio import captured_stderr
from .._limits import MAX_TIME_CODES
from ..scene import lighting
from ..scene.scene import Camera, Mesh, Scene, Skeleton, SkinBinding
from ..scene.textures import Texture
from .textures import SurfaceReader

__all__ = [
    "load_usd",
    "load_scene",
    "resolve_scene_path",
    "bundled_asset_directory",
    "ZERO_AREA_RELATIVE",
    "SCENE_SPEC_PREFIXES",
]

#: A triangle counts as zero-area when its area is below this fraction of the squared diagonal
#: of its mesh's bounding box: far below anything float32 coordinates can resolve (their
#: relative spacing is 6e-8, so a genuine sliver has relative area >= ~1e-14 only when its
#: vertices are collinear to the last bit), and exactly 0 for repeated vertices.
ZERO_AREA_RELATIVE = 1e-12

#: The scene spec prefixes :func:`resolve_scene_path` understands.
SCENE_SPEC_PREFIXES = ("warp-example:", "bundled:")

_PREVIEW_SURFACE_DEFAULT_DIFFUSE = (0.18, 0.18, 0.18)  # UsdPreviewSurface spec fallback
_DEFAULT_ALBEDO = (0.8, 0.8, 0.8)


# ---- scene specs ------------------------------------------------------------------------------
def bundled_asset_directory() -> str:
    """The repository's ``usd_assets/`` directory (present in a source checkout)."""
    return os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "usd_assets")


def resolve_scene_path(spec) -> str:
    """Turn a scene spec into an existing file path.

    Spec grammar::

        spec := PATH                    a .usd/.usda/.usdc/.usdz file
              | "warp-example:" NAME     NAME[.usd] in warp.examples.get_asset_directory()
                                         (e.g. warp-example:bunny, warp-example:bear)
              | "bundled:" NAME          NAME[.usda or .usdc, in that order] in the
                                         repository's usd_assets/ (e.g. bundled:figure)

    Raises:
        FileNotFoundError: naming the file (and, for the prefixed forms, what is available).
    """
    spec = os.fspath(spec)
    for prefix, directory_fn, extensions in (
        ("warp-example:", _warp_asset_directory, (".usd",)),
        ("bundled:", bundled_asset_directory, (".usda", ".usdc")),
    ):
        if spec.startswith(prefix):
            name = spec[len(prefix) :]
            directory = directory_fn()
            candidates = [os.path.join(directory, name)]
            if not os.path.splitext(name)[1]:
                candidates[:0] = [os.path.join(directory, name + ext) for ext in extensions]
            for cand in candidates:
                if os.path.isfile(cand):
                    return cand
            available = sorted(
                {os.path.splitext(f)[0] for f in (os.listdir(directory) if os.path.isdir(directory) else []) if f.endswith(extensions)}
            )
            raise FileNotFoundError(
                f"scene spec {spec!r}: no file {candidates[0]} (available: {', '.join(available) or 'none'})"
            )
    path = os.path.expanduser(spec)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"USD file not found: {path}")
    return path


def _warp_asset_directory() -> str:
    import warp.examples

    return warp.examples.get_asset_directory()


def load_scene(spec, ground_plane: bool = False, sky: bool = True, ground_resolution: int = 40) -> Scene:
    """Load a scene from a spec (see :func:`resolve_scene_path`) with optional additions.

    Args:
        spec: a file path, ``"warp-example:NAME"`` or ``"bundled:NAME"``.
        ground_plane: add a static ``ground_resolution``-squared grid under the scene
            (:meth:`Scene.with_ground_plane`), e.g. to see the shadow of a Warp example model.
        sky: when the stage has no lights, add the procedural sky
            (:meth:`Environment.sky`, turned to the stage's up axis) so the scene can be shaded.
        ground_resolution: vertices per side of the ground plane.

    Returns:
        The :class:`Scene`.
    """
    scene = load_usd(resolve_scene_path(spec))
    if ground_plane:
        scene = scene.with_ground_plane(resolution=ground_resolution)
    if sky and not scene.lights:
        scene.lights.append(lighting.Environment.sky(to_world=lighting.up_rotation(scene.up_axis)))
    return scene


# ---- entry point ------------------------------------------------------------------------------
def load_usd(path) -> Scene:
    """Load a USD stage as a :class:`Scene` (see the module docstring for what is read).

    Args:
        path: a .usd/.usda/.usdc/.usdz file, or a scene spec (:func:`resolve_scene_path`).

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: the stage cannot be opened or its content is invalid (names the prim).
    """
    from pxr import Usd

    path = resolve_scene_path(path)
    if Path(path).is_dir():
        raise ValueError(f"USD file {path}: is a directory")
    with captured_stderr() as printed:
        try:
            stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
        except Exception as exc:  # pxr.Tf.ErrorException
            raise ValueError(f"USD file {path}: cannot be opened as a USD stage ({_first_line(exc)})") from exc
    if stage is None:
        raise ValueError(f"USD file {path}: cannot be opened as a USD stage" + (f" ({printed[0]})" if printed else ""))
    errors = [str(e).strip() for e in stage.GetCompositionErrors()]
    if errors:
        more = f" (and {len(errors) - 1} more composition error(s))" if len(errors) > 1 else ""
        raise ValueError(f"USD file {path}: {errors[0]}{more}")
    return _StageReader(stage, path).read()




def _value_or(value, fallback: float) -> float:
    """A scalar attribute value, or the schema's documented fallback when the attribute is absent."""
    return float(fallback if value is None else value)


def _first_line(exc) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


class _StageReader:
    """One pass over a stage; holds the per-frame transform caches."""

    def __init__(self, stage, path: str):
        from pxr import Usd, UsdGeom

        self.stage = stage
        self.path = path
        self.up_axis = str(UsdGeom.GetStageUpAxis(stage)).upper()
        self.frames, self.range_authored = self._frames()
        self.times = [Usd.TimeCode(float(f)) for f in self.frames]
        self.xform_caches = [UsdGeom.XformCache(t) for t in self.times]
        self.predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        self.skipped: list[tuple[str, str]] = []
        self._warned_unranged = False
        self._surfaces = SurfaceReader()

    # -- time ------------------------------------------------------------------------------
    def _frames(self):
        st = self.stage
        if not st.HasAuthoredTimeCodeRange():
            return np.array([0.0]), False
        start, end = float(st.GetStartTimeCode()), float(st.GetEndTimeCode())
        if not (math.isfinite(start) and math.isfinite(end)) or end < start:
            raise ValueError(f"USD file {self.path}: invalid time code range {start}..{end}")
        count = math.floor(end) - math.ceil(start) + 1
        if count > MAX_TIME_CODES:
            raise ValueError(f"USD file {self.path}: startTimeCode {start:g} .. endTimeCode {end:g} spans {count:,} time codes; "
                             f"at most {MAX_TIME_CODES:,} are sampled (warpshade._limits.MAX_TIME_CODES)")
        frames = np.arange(math.ceil(start), math.floor(end) + 1, dtype=np.float64)
        if frames.size == 0:
            frames = np.array([start])
        return frames, True

    def _world_transforms(self, prim) -> np.ndarray:
        """Local-to-world per frame, (T, 4, 4), or (1, 4, 4) when constant; row-vector."""
        mats = np.stack([np.array(c.GetLocalToWorldTransform(prim)) for c in self.xform_caches])
        if not np.all(np.isfinite(mats)):
            raise ValueError(f"prim {prim.GetPath()} in {self.path}: transform has NaN or infinite entries")
        if np.all(mats == mats[:1]):
            return mats[:1]
        return mats

    # -- main ------------------------------------------------------------------------------
    @contextmanager
    def _reading(self, prim):
        """Turn what malformed data makes the USD bindings or NumPy raise (TypeError,
        IndexError, ...) into a ValueError naming the prim; ValueErrors pass as they are."""
        try:
            yield
        except (ValueError, FileNotFoundError):
            raise
        except Exception as exc:
            raise ValueError(f"prim {prim.GetPath()} in {self.path}: cannot be read ({type(exc).__name__}: "
                             f"{_first_line(exc)})") from exc

    def read(self) -> Scene:
        from pxr import Usd, UsdGeom, UsdLux

        with self._reading(self.stage.GetPseudoRoot()):
            skins, skeletons = self._read_skinning()
        meshes: list[Mesh] = []
        lights = []
        camera = None
        it = iter(Usd.PrimRange(self.stage.GetPseudoRoot(), self.predicate))
        for prim in it:
            if prim.IsPseudoRoot():
                continue
            if prim.IsA(UsdGeom.Imageable):
                purpose = UsdGeom.Imageable(prim).ComputePurpose()
                if purpose in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
                    self.skipped.append((str(prim.GetPath()), f"purpose {purpose}"))
                    it.PruneChildren()
                    continue
                if UsdGeom.Imageable(prim).ComputeVisibility(self.times[0]) == UsdGeom.Tokens.invisible:
                    self.skipped.append((str(prim.GetPath()), "invisible"))
                    it.PruneChildren()
                    continue
            with self._reading(prim):
                if prim.IsA(UsdGeom.PointInstancer):
                    meshes.extend(self._read_point_instancer(prim))
                    it.PruneChildren()
                    continue
                if prim.IsA(UsdGeom.Mesh):
                    mesh = self._read_mesh(prim, skins.get(str(prim.GetPath())))
                    if mesh is not None:
                        meshes.append(mesh)
                elif prim.IsA(UsdGeom.Gprim):
                    self.skipped.append((str(prim.GetPath()), f"implicit {prim.GetTypeName()} (only Mesh prims are read)"))
                elif prim.HasAPI(UsdLux.LightAPI):
                    light = self._read_light(prim)
                    if light is not None:
                        lights.append(self._with_track(prim, light))
                elif prim.IsA(UsdGeom.Camera) and camera is None:
                    camera = self._read_camera(prim)
        if not meshes:
            raise ValueError(f"USD file {self.path}: contains no (visible, renderable) UsdGeom.Mesh prims")
        return Scene(
            meshes,
            frames=self.frames,
            fps=float(self.stage.GetTimeCodesPerSecond()),
            skeletons=skeletons,
            lights=lights,
            camera=camera,
            up_axis=self.up_axis,
            source=self.path,
            skipped=self.skipped,
        )

    # -- meshes ----------------------------------------------------------------------------
    def _read_mesh(self, prim, skin_info=None, transforms=None, name=None) -> Mesh | None:
        """Read one Mesh prim; ``transforms`` overrides its world transform (point instancing)."""
        from pxr import UsdGeom

        mesh = UsdGeom.Mesh(prim)
        path = name or str(prim.GetPath())
        # -- height fields: procedural grids expanded by warpshade.io.heightfield ---------------
        from . import heightfield

        if skin_info is None and transforms is None and heightfield.is_height_field(prim):
            return heightfield.read_mesh(self, prim, path)
        # ----------------------------------------------------------------------------------------
        t0 = self.times[0]
        counts_attr = mesh.GetFaceVertexCountsAttr()
        indices_attr = mesh.GetFaceVertexIndicesAttr()
        for attr in (counts_attr, indices_attr):
            if attr.GetNumTimeSamples() > 1:
                values = [np.asarray(attr.Get(t)) for t in self.times]
                if any(v.shape != values[0].shape or np.any(v != values[0]) for v in values):
                    raise ValueError(f"mesh {path} in {self.path}: topology ({attr.GetName()}) changes over time, which is not supported")
        counts = np.asarray(counts_attr.Get(t0) or [], dtype=np.int64)
        indices = np.asarray(indices_attr.Get(t0) or [], dtype=np.int64)
        points_attr = mesh.GetPointsAttr()
        rest = points_attr.Get(t0)
        if rest is None or len(rest) == 0 or counts.size == 0:
            self.skipped.append((path, "empty mesh (no points or no faces)"))
            return None
        rest = np.asarray(rest, dtype=np.float64).reshape(-1, 3)
        vertex_count = rest.shape[0]

        # Time-sampled points (deforming) -- skinned meshes use the first frame as rest pose.
        samples = None
        if points_attr.GetNumTimeSamples() > 1 and skin_info is None:
            if not self.range_authored:
                self._warn_unranged(path)
            else:
                samples = np.stack([self._points_at(points_attr, t, vertex_count, path) for t in self.times])
                if np.all(samples == samples[:1]):
                    samples = None
        self._check_finite(rest, path, float(self.frames[0]))

        # Topology checks and fan triangulation.
        if np.any(counts < 3):
            bad = int(np.flatnonzero(counts < 3)[0])
            raise ValueError(f"mesh {path} in {self.path}: face {bad} has {int(counts[bad])} vertices (need >= 3)")
        if int(counts.sum()) != indices.size:
            raise ValueError(
                f"mesh {path} in {self.path}: faceVertexCounts sum to {int(counts.sum())} but there are "
                f"{indices.size} faceVertexIndices"
            )
        if indices.size and (indices.min() < 0 or indices.max() >= vertex_count):
            raise ValueError(
                f"mesh {path} in {self.path}: faceVertexIndices range {int(indices.min())}..{int(indices.max())} "
                f"is out of range for {vertex_count} points"
            )
        holes = np.asarray(mesh.GetHoleIndicesAttr().Get(t0) or [], dtype=np.int64)
        left_handed = mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
        corners, face_of_tri = _fan_corners(counts)
        keep = np.ones(face_of_tri.shape[0], dtype=bool)
        if holes.size:
            keep &= ~np.isin(face_of_tri, holes)
        corners = _retriangulate_concave(corners, counts, indices, rest)
        if left_handed:
            corners = corners[:, [0, 2, 1]]
        tris = indices[corners]
        # Polygon areas (for faceVarying/uniform averaging) from the rest points.
        tri_area = 0.5 * np.linalg.norm(
            np.cross(rest[tris[:, 1]] - rest[tris[:, 0]], rest[tris[:, 2]] - rest[tris[:, 0]]), axis=1
        )
        poly_area = np.bincount(face_of_tri, weights=tri_area, minlength=counts.size)
        diag2 = float(np.sum((rest.max(axis=0) - rest.min(axis=0)) ** 2))
        zero = keep & (tri_area <= ZERO_AREA_RELATIVE * max(diag2, 1e-300))
        dropped = int(zero.sum())
        keep &= ~zero
        if not keep.any():
            raise ValueError(f"mesh {path} in {self.path}: all {tris.shape[0]} triangles have zero area (or are holes)")
        if dropped:
            warnings.warn(
                f"mesh {path} in {self.path}: dropped {dropped} zero-area triangle(s) of {tris.shape[0]}",
                stacklevel=3,
            )
        faces = tris[keep]

        # Animation kind and transforms.
        if skin_info is not None:
            animation = "skinned"
            xfs = np.eye(4)[None]
        else:
            xfs = self._world_transforms(prim) if transforms is None else transforms
            if samples is not None:
                animation = "deforming"
            elif xfs.shape[0] > 1:
                animation = "rigid"
            else:
                animation = "static"

        normals = None
        if animation in ("static", "rigid"):
            normals = self._read_normals(mesh, path, vertex_count, indices, counts, poly_area)
        uvs = self._read_uvs(mesh, path, vertex_count, indices, counts)
        surface, uvs = self._surfaces.read(self, prim, path, vertex_count, indices, counts, uvs)
        albedo = self._read_albedo(prim, mesh, path, vertex_count, indices, counts, poly_area)
        if surface is not None and (isinstance(surface.diffuse, Texture) or isinstance(surface.metallic, Texture)
                                    or (not surface.use_specular_workflow and surface.metallic > 0.0)):
            # textured (or metallic-darkened) diffuse: the effective albedo at the vertices' UVs
            albedo = surface.at_vertices(uvs, vertex_count)["diffuse"].astype(np.float32)
        skin = None
        if skin_info is not None:
            skin = self._read_skin_binding(skin_info, path, vertex_count)
        return Mesh(
            path=path,
            points=rest,
            faces=faces.astype(np.int32),
            animation=animation,
            transforms=xfs,
            point_samples=samples,
            normals=normals,
            uvs=uvs,
            albedo=albedo,
            skin=skin,
            dropped_face_count=dropped,
            surface=surface,
        )

    def _points_at(self, attr, time, vertex_count, path) -> np.ndarray:
        pts = attr.Get(time)
        pts = np.asarray(pts if pts is not None else [], dtype=np.float64).reshape(-1, 3)
        if pts.shape[0] != vertex_count:
            raise ValueError(
                f"mesh {path} in {self.path}: {pts.shape[0]} points at time {time.GetValue():g} but "
                f"{vertex_count} at the first frame (point count must not change)"
            )
        self._check_finite(pts, path, time.GetValue())
        return pts

    def _check_finite(self, pts, path, time) -> None:
        bad = ~np.all(np.isfinite(pts), axis=1)
        if bad.any():
            raise ValueError(
                f"mesh {path} in {self.path}: {int(bad.sum())} point(s) with NaN or infinite coordinates at "
                f"time {time:g} (first: point {int(np.flatnonzero(bad)[0])})"
            )

    def _warn_unranged(self, path) -> None:
        if not self._warned_unranged:
            warnings.warn(
                f"USD file {self.path}: mesh {path} has time-sampled points but the stage has no "
                "startTimeCode/endTimeCode; loading time code 0 only",
                stacklevel=4,
            )
            self._warned_unranged = True

    def _primvar(self, prim, name):
        from pxr import UsdGeom

        pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
        if pv and pv.HasAuthoredValue():
            return pv
        return None

    def _to_vertex(self, values, interp, path, what, vertex_count, indices, counts, corner_weights=None):
        """Per-vertex values from a primvar of any interpolation, or None (with a warning)."""
        values = np.asarray(values, dtype=np.float64)
        if values.ndim == 1:
            values = values[:, None]
        n = values.shape[0]
        if interp in ("vertex", "varying") and n == vertex_count:
            return values
        if interp == "faceVarying" and n == indices.size:
            corner_values = values
        elif interp == "uniform" and n == counts.size:
            corner_values = np.repeat(values, counts, axis=0)
        elif interp == "constant" and n >= 1:
            return np.broadcast_to(values[:1], (vertex_count, values.shape[1])).copy()
        else:
            warnings.warn(f"mesh {path} in {self.path}: {what} has {n} values with interpolation {interp!r}; ignored", stacklevel=4)
            return None
        w = np.ones(indices.size) if corner_weights is None else corner_weights
        acc = np.zeros((vertex_count, values.shape[1]))
        np.add.at(acc, indices, corner_values * w[:, None])
        total = np.bincount(indices, weights=w, minlength=vertex_count)
        used = total > 0
        acc[used] /= total[used, None]
        return acc

    def _read_normals(self, mesh, path, vertex_count, indices, counts, poly_area):
        pv = self._primvar(mesh.GetPrim(), "normals")
        if pv is not None:
            values, interp = pv.ComputeFlattened(self.times[0]), pv.GetInterpolation()
        else:
            attr = mesh.GetNormalsAttr()
            if not attr.HasAuthoredValue():
                return None
            values, interp = attr.Get(self.times[0]), mesh.GetNormalsInterpolation()
        if values is None or len(values) == 0:
            return None
        corner_w = np.repeat(poly_area, counts)
        n = self._to_vertex(values, str(interp), path, "normals", vertex_count, indices, counts, corner_w)
        if n is None:
            return None
        length = np.linalg.norm(n, axis=1)
        referenced = np.zeros(vertex_count, dtype=bool)
        referenced[indices] = True
        if not np.all(np.isfinite(n)) or np.any(length[referenced] < 1e-6):
            warnings.warn(
                f"mesh {path} in {self.path}: authored normals have NaN/zero-length entries; "
                "area-weighted normals are computed instead",
                stacklevel=3,
            )
            return None
        return n / np.maximum(length, 1e-30)[:, None]

    def _read_uvs(self, mesh, path, vertex_count, indices, counts):
        from pxr import Sdf, UsdGeom

        prim = mesh.GetPrim()
        pv = self._primvar(prim, "st")
        if pv is None:
            for cand in UsdGeom.PrimvarsAPI(prim).GetPrimvarsWithAuthoredValues():
                if cand.GetTypeName().role == Sdf.ValueTypeNames.TexCoord2f.role:
                    pv = cand
                    break
        if pv is None:
            return None
        values = pv.ComputeFlattened(self.times[0])
        if values is None or len(values) == 0:
            return None
        uv = self._to_vertex(values, str(pv.GetInterpolation()), path, pv.GetName(), vertex_count, indices, counts)
        return None if uv is None or uv.shape[1] != 2 else uv

    def _read_albedo(self, prim, mesh, path, vertex_count, indices, counts, poly_area):
        rgb = self._material_diffuse(prim, path)
        if rgb is not None:
            return np.asarray(rgb, np.float32)
        pv = self._primvar(mesh.GetPrim(), "displayColor")
        if pv is not None:
            values = pv.ComputeFlattened(self.times[0])
            if values is not None and not hasattr(values, "__len__"):
                raise ValueError(f"mesh {path} in {self.path}: primvars:displayColor has a value of unknown type "
                                 f"({pv.GetTypeName()})")
            if values is not None and len(values):
                corner_w = np.repeat(poly_area, counts)
                col = self._to_vertex(values, str(pv.GetInterpolation()), path, "displayColor", vertex_count, indices, counts, corner_w)
                if col is not None and col.shape[1] == 3 and np.all(np.isfinite(col)):
                    return col.astype(np.float32)
        return np.asarray(_DEFAULT_ALBEDO, np.float32)

    def _material_diffuse(self, prim, path):
        from pxr import UsdShade

        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        if not material:
            return None
        shader = material.ComputeSurfaceSource()[0]
        if not shader or shader.GetIdAttr().Get() != "UsdPreviewSurface":
            return None
        inp = shader.GetInput("diffuseColor")
        if not inp:
            return _PREVIEW_SURFACE_DEFAULT_DIFFUSE
        for attr in inp.GetValueProducingAttributes():
            if UsdShade.Utils.GetBaseNameAndType(attr.GetName())[1] == UsdShade.AttributeType.Output:
                source = UsdShade.Shader(attr.GetPrim())
                if source and source.GetIdAttr().Get() == "UsdUVTexture":
                    return None  # sampled at the vertices from Mesh.surface (warpshade.io.textures)
                warnings.warn(
                    f"mesh {path} in {self.path}: material {material.GetPath()} has a connected (textured) "
                    "diffuseColor, which is not sampled; using displayColor or the default albedo",
                    stacklevel=4,
                )
                return None
            value = attr.Get(self.times[0])
            if value is not None:
                return tuple(float(c) for c in value)
        return _PREVIEW_SURFACE_DEFAULT_DIFFUSE

    # -- point instancers ------------------------------------------------------------------
    def _read_point_instancer(self, prim) -> list[Mesh]:
        from pxr import Usd, UsdGeom

        inst = UsdGeom.PointInstancer(prim)
        base = str(prim.GetPath())
        protos = inst.GetPrototypesRel().GetTargets()
        per_frame = []
        masks = []
        for t in self.times:
            xf = inst.ComputeInstanceTransformsAtTime(t, t)
            per_frame.append(np.array(xf, dtype=np.float64).reshape(-1, 4, 4))
            mask = inst.ComputeMaskAtTime(t)
            masks.append(np.ones(per_frame[-1].shape[0], bool) if not mask else np.asarray(mask, bool))
        counts = {a.shape[0] for a in per_frame}
        if len(counts) != 1:
            raise ValueError(f"point instancer {base} in {self.path}: instance count changes over time, which is not supported")
        proto_indices = np.asarray(inst.GetProtoIndicesAttr().Get(self.times[0]) or [], dtype=np.int64)
        inst_xf = np.stack(per_frame, axis=1)  # (N, T, 4, 4)
        visible = np.all(np.stack(masks), axis=0)
        instancer_world = self._world_transforms(prim)
        meshes = []
        for i, p in enumerate(proto_indices):
            if not visible[i]:
                continue
            if not 0 <= p < len(protos):
                raise ValueError(f"point instancer {base} in {self.path}: protoIndices[{i}] = {p} but there are {len(protos)} prototypes")
            proto = self.stage.GetPrimAtPath(protos[p])
            if not proto:
                raise ValueError(f"point instancer {base} in {self.path}: prototype {protos[p]} does not exist")
            for sub in Usd.PrimRange(proto, self.predicate):
                if not sub.IsA(UsdGeom.Mesh):
                    continue
                # mesh -> prototype-root space, per frame; the instance transforms computed by
                # USD already include the prototype root's own ops (IncludeProtoXform).
                to_proto = self._world_transforms(sub) @ np.linalg.inv(self._world_transforms(proto))
                frames = max(to_proto.shape[0], inst_xf.shape[1], instancer_world.shape[0])
                xf = np.stack(
                    [
                        to_proto[min(k, to_proto.shape[0] - 1)]
                        @ inst_xf[i, min(k, inst_xf.shape[1] - 1)]
                        @ instancer_world[min(k, instancer_world.shape[0] - 1)]
                        for k in range(frames)
                    ]
                )
                if np.all(xf == xf[:1]):
                    xf = xf[:1]
                rel = str(sub.GetPath())[len(str(proto.GetPath())) :]
                m = self._read_mesh(sub, transforms=xf, name=f"{base}/instance_{i}{rel}")
                if m is not None:
                    meshes.append(m)
        return meshes

    # -- skinning --------------------------------------------------------------------------
    def _read_skinning(self):
        """Skeletons, and per skinned mesh path (skeleton index, UsdSkel.SkinningQuery, Skeleton)."""
        from pxr import Usd, UsdSkel

        cache = UsdSkel.Cache()
        skins: dict[str, tuple[int, object]] = {}
        skeletons: list[Skeleton] = []
        index_of: dict[str, int] = {}
        for prim in Usd.PrimRange(self.stage.GetPseudoRoot(), self.predicate):
            if not prim.IsA(UsdSkel.Root):
                continue
            root = UsdSkel.Root(prim)
            cache.Populate(root, self.predicate)
            for binding in cache.ComputeSkelBindings(root, self.predicate):
                skel = binding.GetSkeleton()
                skel_path = str(skel.GetPrim().GetPath())
                query = cache.GetSkelQuery(skel)
                if not query:
                    raise ValueError(f"skeleton {skel_path} in {self.path}: invalid skeleton (check joints and bindTransforms)")
                if skel_path not in index_of:
                    index_of[skel_path] = len(skeletons)
                    skeletons.append(self._read_skeleton(skel, query))
                for target in binding.GetSkinningTargets():
                    skins[str(target.GetPrim().GetPath())] = (index_of[skel_path], target, skeletons[index_of[skel_path]])
        return skins, skeletons

    def _read_skeleton(self, skel, query) -> Skeleton:
        path = str(skel.GetPrim().GetPath())
        joints = [str(j) for j in query.GetJointOrder()]
        if not joints:
            raise ValueError(f"skeleton {path} in {self.path}: has no joints")
        j = len(joints)
        topology = query.GetTopology()
        valid, why = topology.Validate()
        if not valid:
            raise ValueError(f"skeleton {path} in {self.path}: invalid joint hierarchy ({why})")
        parents = np.asarray(topology.GetParentIndices(), dtype=np.int64)
        bind = np.array(query.GetJointWorldBindTransforms(), dtype=np.float64).reshape(-1, 4, 4)
        if bind.shape[0] != j:
            raise ValueError(f"skeleton {path} in {self.path}: {bind.shape[0]} bindTransforms for {j} joints")
        rest_attr = skel.GetRestTransformsAttr().Get()
        if rest_attr is not None and len(rest_attr) == j:
            rest = np.array(rest_attr, dtype=np.float64).reshape(j, 4, 4)
        else:
            rest = np.array(query.ComputeJointLocalTransforms(self.times[0], True), dtype=np.float64).reshape(j, 4, 4)
        local = np.stack(
            [np.array(query.ComputeJointLocalTransforms(t), dtype=np.float64).reshape(j, 4, 4) for t in self.times]
        )
        if not (np.all(np.isfinite(local)) and np.all(np.isfinite(bind))):
            raise ValueError(f"skeleton {path} in {self.path}: joint transforms have NaN or infinite entries")
        if np.all(local == local[:1]):
            local = local[:1]
        return Skeleton(
            path=path,
            joint_names=joints,
            parents=parents,
            bind_transforms=bind,
            rest_transforms=rest,
            local_transforms=local,
            skel_to_world=self._world_transforms(skel.GetPrim()),
        )

    def _read_skin_binding(self, skin_info, path, vertex_count) -> SkinBinding:
        from pxr import UsdGeom

        skel_index, query, skeleton = skin_info
        t0 = self.times[0]
        idx_pv = query.GetJointIndicesPrimvar()
        w_pv = query.GetJointWeightsPrimvar()
        if not (idx_pv and w_pv and idx_pv.HasAuthoredValue() and w_pv.HasAuthoredValue()):
            raise ValueError(f"mesh {path} in {self.path}: bound to skeleton {skeleton.path} but has no jointIndices/jointWeights")
        k = int(query.GetNumInfluencesPerComponent())
        idx = np.asarray(idx_pv.Get(t0), dtype=np.int64)
        w = np.asarray(w_pv.Get(t0), dtype=np.float64)
        if idx.size != w.size or k < 1 or idx.size % k:
            raise ValueError(
                f"mesh {path} in {self.path}: {idx.size} jointIndices and {w.size} jointWeights do not match "
                f"elementSize {k}"
            )
        interp = str(query.GetInterpolation())
        if interp == UsdGeom.Tokens.constant:
            if idx.size != k:
                raise ValueError(f"mesh {path} in {self.path}: constant skinning needs {k} influences, found {idx.size}")
            idx = np.tile(idx.reshape(1, k), (vertex_count, 1))
            w = np.tile(w.reshape(1, k), (vertex_count, 1))
        elif interp == UsdGeom.Tokens.vertex:
            if idx.size != vertex_count * k:
                raise ValueError(
                    f"mesh {path} in {self.path}: {idx.size} jointIndices for {vertex_count} points x {k} influences"
                )
            idx = idx.reshape(vertex_count, k)
            w = w.reshape(vertex_count, k)
        else:
            raise ValueError(f"mesh {path} in {self.path}: skinning interpolation {interp!r} (need constant or vertex)")
        skin_order = query.GetJointOrder()
        if skin_order:
            names = [str(n) for n in skin_order]
            lookup = {name: i for i, name in enumerate(skeleton.joint_names)}
            missing = [n for n in names if n not in lookup]
            if missing:
                raise ValueError(
                    f"mesh {path} in {self.path}: skel:joints names {len(missing)} joint(s) not in skeleton "
                    f"{skeleton.path}: {', '.join(missing[:5])}"
                )
            remap = np.array([lookup[n] for n in names], dtype=np.int64)
            limit = len(names)
        else:
            remap = None
            limit = skeleton.joint_count
        if idx.size and (idx.min() < 0 or idx.max() >= limit):
            raise ValueError(
                f"mesh {path} in {self.path}: jointIndices {int(idx.min())}..{int(idx.max())} out of range for "
                f"{limit} joints ({'skel:joints' if remap is not None else 'skeleton ' + skeleton.path})"
            )
        if remap is not None:
            idx = remap[idx]
        if not np.all(np.isfinite(w)) or np.any(w < 0):
            raise ValueError(f"mesh {path} in {self.path}: jointWeights must be finite and >= 0")
        total = w.sum(axis=1)
        if np.any(total <= 0):
            raise ValueError(f"mesh {path} in {self.path}: {int(np.sum(total <= 0))} point(s) have all-zero joint weights")
        w = w / total[:, None]
        method = query.GetSkinningMethod() if hasattr(query, "GetSkinningMethod") else "classicLinear"
        if str(method) not in ("", "classicLinear"):
            warnings.warn(f"mesh {path} in {self.path}: skinning method {method!r} is evaluated as linear blend skinning", stacklevel=3)
        if query.HasBlendShapes():
            warnings.warn(f"mesh {path} in {self.path}: blend shapes are ignored", stacklevel=3)
        return SkinBinding(
            skeleton=skel_index,
            joint_indices=idx.astype(np.int32),
            joint_weights=w.astype(np.float32),
            geom_bind_transform=np.array(query.GetGeomBindTransform(t0), dtype=np.float64),
        )

    # -- lights and camera -----------------------------------------------------------------
    def _read_light(self, prim):
        """A warpshade light from a UsdLux light prim, or None (recorded in ``skipped``).

        Emission ``L = color * intensity * 2**exposure`` (times the blackbody colour when
        enabled) is radiance. ``DistantLight``: irradiance ``E = L * solid angle of the
        angular disc`` (``E = L`` for angle 0), or ``E = L`` when ``normalize`` is on (UsdLux:
        a normalised distant light's intensity is illuminance). ``SphereLight``: radiance ``L``,
        divided by the world-space surface area ``4 pi r**2`` when ``normalize`` is on.
        ``DomeLight``: the texture times ``L`` (or ``L`` alone without a texture).
        """
        from pxr import UsdLux

        path = str(prim.GetPath())
        api = UsdLux.LightAPI(prim)
        t0 = self.times[0]
        intensity = _value_or(api.GetIntensityAttr().Get(t0), 1.0)
        exposure = _value_or(api.GetExposureAttr().Get(t0), 0.0)
        color_value = api.GetColorAttr().Get(t0)
        color = np.asarray((1.0, 1.0, 1.0) if color_value is None else color_value, dtype=np.float64)
        if api.GetEnableColorTemperatureAttr().Get(t0):
            color = color * np.asarray(UsdLux.BlackbodyTemperatureAsRgb(float(api.GetColorTemperatureAttr().Get(t0))))
        emission = color * intensity * 2.0**exposure
        normalize = bool(api.GetNormalizeAttr().Get(t0))
        world = self._world_transforms(prim)[0]
        if not np.all(np.isfinite(emission)):
            raise ValueError(f"light {path} in {self.path}: non-finite emission")
        type_name = str(prim.GetTypeName())
        if type_name in ("DomeLight", "DomeLight_1"):
            return self._read_dome(prim, emission, world)
        if type_name == "DistantLight":
            light = UsdLux.DistantLight(prim)
            angle = _value_or(light.GetAngleAttr().Get(t0), 0.53)
            # The light shines along its local -Z, so the direction towards it is local +Z.
            direction = world[2, :3]
            half = math.radians(angle) / 2.0
            solid = 2.0 * math.pi * (1.0 - math.cos(half)) if half > 0 else 1.0
            irradiance = emission if normalize else emission * solid
            return lighting.DistantLight(direction=direction, irradiance=irradiance, angle_deg=angle, path=path)
        if type_name == "SphereLight":
            light = UsdLux.SphereLight(prim)
            scale = abs(np.linalg.det(world[:3, :3])) ** (1.0 / 3.0)
            radius = _value_or(light.GetRadiusAttr().Get(t0), 0.5) * scale
            if light.GetTreatAsPointAttr().Get(t0):
                warnings.warn(f"light {path} in {self.path}: treatAsPoint is ignored (sphere of radius {radius:g})", stacklevel=3)
            if not radius > 0:
                raise ValueError(f"light {path} in {self.path}: SphereLight radius must be > 0, got {radius}")
            radiance = emission / (4.0 * math.pi * radius * radius) if normalize else emission
            return lighting.SphereLight(position=world[3, :3], radius=radius, radiance=radiance, path=path)
        self.skipped.append((path, f"unsupported light type {type_name}"))
        return None

    def _with_track(self, prim, light):
        """The light with a :class:`~warpshade.scene.LightTrack` when its transform is animated."""
        from dataclasses import replace

        mats = self._world_transforms(prim)
        if len(mats) < 2:
            return light
        try:
            track = lighting.LightTrack(np.asarray(self.frames, np.float64), mats)
        except ValueError as exc:
            raise ValueError(f"light {prim.GetPath()} in {self.path}: {exc}") from None
        return replace(light, track=track)

    def _read_dome(self, prim, emission, world):
        from pxr import UsdLux

        from .images import read_image

        path = str(prim.GetPath())
        t0 = self.times[0]
        api = UsdLux.DomeLight_1(prim) if str(prim.GetTypeName()) == "DomeLight_1" else UsdLux.DomeLight(prim)
        fmt = str(api.GetTextureFormatAttr().Get(t0) or "automatic")
        # Rotation only: strip scale from the row-vector matrix, then to column convention.
        u, _, vt = np.linalg.svd(world[:3, :3])
        dome_to_world = (u @ vt).T
        if str(prim.GetTypeName()) == "DomeLight_1":
            pole = str(api.GetPoleAxisAttr().Get() or "scene")
            if pole == "Z" or (pole == "scene" and self.up_axis == "Z"):
                # UsdLux: the +90 degree rotation about X that takes the dome's +Y pole to +Z,
                # applied to the dome itself before its transform.
                dome_to_world = dome_to_world @ np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
        asset = api.GetTextureFileAttr().Get(t0)
        if asset is None or not asset.path:
            return lighting.Environment.constant(emission.astype(np.float32))
        if fmt not in ("automatic", "latlong"):
            raise ValueError(f"dome light {path} in {self.path}: texture format {fmt!r} is not supported (need latlong)")
        resolved = asset.resolvedPath
        if not resolved or not os.path.isfile(resolved):
            raise ValueError(f"dome light {path} in {self.path}: texture file {asset.path!r} not found")
        try:
            image = read_image(resolved)
        except (ValueError, OSError) as exc:
            raise ValueError(f"dome light {path} in {self.path}: cannot read texture {resolved}: {exc}") from exc
        return lighting.Environment.from_usd_dome(image * emission.astype(np.float32), dome_to_world, path=resolved)

    def _read_camera(self, prim) -> Camera:
        from pxr import Gf, UsdGeom

        cam = UsdGeom.Camera(prim).GetCamera(self.times[0])
        frustum = cam.frustum
        position = np.array(frustum.GetPosition(), dtype=np.float64)
        forward = np.array(frustum.ComputeViewDirection(), dtype=np.float64)
        up = np.array(frustum.ComputeUpVector(), dtype=np.float64)
        distance = float(cam.focusDistance) if cam.focusDistance > 0 else 1.0
        positions = None
        if len(self.times) > 1:  # an animated camera: its eye at every time code
            samples = np.array([UsdGeom.Camera(prim).GetCamera(t).frustum.GetPosition() for t in self.times], np.float64)
            if not np.all(np.isfinite(samples)):
                raise ValueError(f"camera {prim.GetPath()} in {self.path}: non-finite position")
            if np.max(np.abs(samples - samples[0])) > 1e-9 * max(1.0, float(np.max(np.abs(samples)))):
                positions = samples
        return Camera(
            position=position,
            target=position + distance * forward / np.linalg.norm(forward),
            up=up / np.linalg.norm(up),
            vertical_fov=float(cam.GetFieldOfView(Gf.Camera.FOVVertical)),
            path=str(prim.GetPath()),
            positions=positions,
        )


def _retriangulate_concave(corners: np.ndarray, counts: np.ndarray, indices: np.ndarray, points: np.ndarray):
    """Replace the fan triangles of concave polygons by an ear-clipping triangulation.

    A polygon is concave when one of its corners turns against its Newell normal. Each such
    polygon is projected onto its plane and triangulated with mapbox-earcut; the triangles keep
    the polygon's winding and its ``count - 2`` slots in ``corners`` (corner indices into
    ``faceVertexIndices``). Polygons that ear clipping cannot split into ``count - 2``
    triangles (self-intersecting outlines) keep their fan.
    """
    counts = np.asarray(counts, np.int64)
    big = np.flatnonzero(counts > 3)
    if big.size == 0:
        return corners
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    first_tri = np.cumsum(counts - 2) - (counts - 2)
    # per corner of the big polygons: previous, this and next point
    face = np.repeat(big, counts[big])
    local = np.arange(face.size) - np.repeat(np.cumsum(counts[big]) - counts[big], counts[big])
    n = counts[face]
    at = lambda k: points[indices[starts[face] + (local + k) % n]]  # noqa: E731
    prev, here, nxt = at(-1), at(0), at(1)
    # Newell normal per polygon (sum of cross products of consecutive corners)
    newell = np.zeros((counts.size, 3))
    np.add.at(newell, face, np.cross(here, nxt))
    turn = np.einsum("ij,ij->i", np.cross(here - prev, nxt - here), newell[face])
    scale = np.linalg.norm(newell[face], axis=1) * np.linalg.norm(here - prev, axis=1) * np.linalg.norm(nxt - here, axis=1)
    reflex = turn < -1e-9 * np.maximum(scale, 1e-300)
    concave = np.unique(face[reflex])
    if concave.size == 0:
        return corners
    import mapbox_earcut

    corners = corners.copy()
    for f in concave:
        k = int(counts[f])
        nrm = newell[f] / max(np.linalg.norm(newell[f]), 1e-300)
        u = np.cross(nrm, [1.0, 0.0, 0.0] if abs(nrm[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(nrm, u)  # (u, v, nrm) right-handed: the outline stays counter-clockwise
        poly = points[indices[starts[f]:starts[f] + k]]
        flat = np.stack([poly @ u, poly @ v], axis=1)
        tri = np.asarray(mapbox_earcut.triangulate_float64(flat, np.array([k], dtype=np.uint32)), np.int64)
        if tri.size != 3 * (k - 2):
            continue
        tri = tri.reshape(-1, 3)
        e1, e2 = flat[tri[:, 1]] - flat[tri[:, 0]], flat[tri[:, 2]] - flat[tri[:, 0]]
        flip = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
        tri[flip] = tri[flip][:, [0, 2, 1]]
        corners[first_tri[f]:first_tri[f] + k - 2] = starts[f] + tri
    return corners


def _fan_corners(counts: np.ndarray):
    """Fan triangulation of polygons: corner indices (T, 3) into faceVertexIndices, face per tri."""
    counts = np.asarray(counts, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    tri_per_face = counts - 2
    face_of_tri = np.repeat(np.arange(counts.size), tri_per_face)
    first_tri = np.cumsum(tri_per_face) - tri_per_face
    k = np.arange(face_of_tri.size) - first_tri[face_of_tri]
    s = starts[face_of_tri]
    return np.stack([s, s + k + 1, s + k + 2], axis=1), face_of_tri
