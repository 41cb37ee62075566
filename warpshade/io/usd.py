"""USD stages in: meshes, animation, skinning, lights and camera as a :class:`~warpshade.scene.Scene`.

The stage reader: this module walks the stage; :mod:`warpshade.io.usd_mesh` (meshes),
:mod:`warpshade.io.usd_skel` (UsdSkel), :mod:`warpshade.io.usd_lights` (lights, camera),
:mod:`warpshade.io.textures` (materials) and :mod:`warpshade.io.heightfield` read the prims.
Scene specs are resolved by :mod:`warpshade.io.scene_specs`. What :func:`load_usd` reads:

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
    (times the blackbody colour when ``enableColorTemperature``); see :func:`warpshade.io.usd_lights.read_light`
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
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .._fileio import captured_stderr
from .._limits import MAX_TIME_CODES
from ..scene import lighting
from ..scene.scene import Mesh, Scene
from .scene_specs import resolve_scene_path
from .textures import SurfaceReader
from .usd_lights import read_camera, read_light, with_track
from .usd_mesh import read_mesh, read_point_instancer
from .usd_skel import read_skinning

__all__: list[str] = []


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
            skins, skeletons = read_skinning(self, )
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
                    meshes.extend(read_point_instancer(self, prim))
                    it.PruneChildren()
                    continue
                if prim.IsA(UsdGeom.Mesh):
                    mesh = read_mesh(self, prim, skins.get(str(prim.GetPath())))
                    if mesh is not None:
                        meshes.append(mesh)
                elif prim.IsA(UsdGeom.Gprim):
                    self.skipped.append((str(prim.GetPath()), f"implicit {prim.GetTypeName()} (only Mesh prims are read)"))
                elif prim.HasAPI(UsdLux.LightAPI):
                    light = read_light(self, prim)
                    if light is not None:
                        lights.append(with_track(self, prim, light))
                elif prim.IsA(UsdGeom.Camera) and camera is None:
                    camera = read_camera(self, prim)
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

    # -- per-mesh helpers (used by warpshade.io.usd_mesh and .textures) --------------------
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
