"""USD stages in: meshes, animation, skinning, lights and camera as a :class:`~warpshade.scene.Scene`.

The stage reader: this module walks the stage; :mod:`warpshade.io._usd_mesh` (meshes),
:mod:`warpshade.io._usd_implicit` (implicit prims), :mod:`warpshade.io._usd_skel` (UsdSkel),
:mod:`warpshade.io._usd_lights` (lights, camera), :mod:`warpshade.io._textures` (materials) and
:mod:`warpshade.io._heightfield` read the prims.
Scene specs are resolved by :mod:`warpshade.io._scene_specs`. What :func:`load_usd` reads:

Meshes
    Every ``UsdGeom.Mesh`` reached by a traversal of active, defined, non-abstract prims,
    *including instance proxies* (scene-graph instancing is flattened: each instance becomes its
    own :class:`~warpshade.scene.Mesh`, named by its proxy path) and the mesh prototypes of
    ``UsdGeom.PointInstancer`` prims (one mesh per instance and prototype mesh, named
    ``<instancer>/instance_<i>/<path below the prototype>``; the prototype root's own transform
    is applied before the instance transform; instances hidden by ``invisibleIds`` or inactive
    at any frame are left out).

    Implicit gprims -- ``Sphere``, ``Cube``, ``Cylinder``, ``Cone``, ``Capsule``, ``Plane`` and
    the USD 24 ``Capsule_1`` / ``Cylinder_1`` -- are tessellated into meshes
    (:mod:`warpshade.io._usd_implicit` states the shapes and the density: 32 segments around every
    circle, analytic normals), with their transform over time, animated shape attributes, bound
    material and ``displayColor`` read as for meshes; ``Mesh.implicit`` records the shape and its
    parameters.

    Skipped, each listed with its reason in ``Scene.skipped`` (and by ``warpshade info``): prims
    whose computed purpose is ``guide`` or ``proxy``, prims that are invisible at the first frame
    (with everything under them, also inside point instancer prototypes), empty meshes, other
    gprims (``Points``, ``BasisCurves``, ...), point instances hidden at some frame (one entry per
    instancer), unsupported lights and every camera after the first. A stage with nothing to
    render is refused with the skipped prims and their reasons (or the prims it has, and how many
    prims are inactive, ``over`` or ``class`` and so not read) in the message.

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
    :class:`~warpshade.scene._textures.SurfaceMaps` (diffuse colour, roughness, specular colour
    or metallic, each a constant or a ``UsdUVTexture``; read by :mod:`warpshade.io._textures`,
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
    Frames are every integer time code from the stage's startTimeCode to its endTimeCode when it
    authors both. A stage without that range is sampled at its own animation's time samples: the
    sorted union of the authored time samples of every attribute the reader follows over time
    (xform ops of any prim -- meshes, their parents, lights, cameras --, mesh ``points``,
    implicit shape attributes, point instancer positions / orientations / scales / protoIndices /
    invisibleIds, UsdSkel animation translations / rotations / scales), counting attributes with
    two or more samples, on the prims a load traverses except guide and proxy prims. Fractional
    time codes stay fractional (samples closer than 1e-6 merge); more than
    :data:`~warpshade._limits.MAX_TIME_CODES` is refused naming the attribute. A stage with no
    animated attribute is one frame at time code 0 (a static asset needs no frame range; its
    animated lights or camera alone give it frames). Per mesh: time-sampled points ->
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
    (times the blackbody colour when ``enableColorTemperature``); see :func:`warpshade.io._usd_lights.read_light`
    for ``normalize``. Animated light transforms are followed (a
    :class:`~warpshade.scene.LightTrack` per light: domes and distant lights rotate, sphere
    lights move); emission and radius are read at the first frame.

Camera
    The first ``UsdGeom.Camera`` in traversal order, at the first frame.

Errors name the file or prim: missing file (FileNotFoundError), unreadable stage, nothing to
render (naming the skipped prims), an implicit prim's radius, height or size that makes no
surface,
NaN/inf points, face indices out of range, inconsistent face counts, a skin that does not match
its skeleton, a missing or unreadable dome texture, a missing, unreadable or unusable material
texture or the UVs it needs (ValueError; see :mod:`warpshade.io._textures`). Zero-area triangles are
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
from ..scene import _lighting as lighting
from ..scene._scene import Mesh, Scene
from ._scene_specs import resolve_scene_path
from ._textures import SurfaceReader
from ._usd_implicit import IMPLICIT_TYPES, is_implicit, read_implicit, shape_attributes
from ._usd_lights import read_camera, read_light, with_track
from ._usd_mesh import read_mesh, read_point_instancer
from ._usd_skel import read_skinning

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
        self.predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
        self.frames, self.range_authored = self._frames()
        self.times = [Usd.TimeCode(float(f)) for f in self.frames]
        self.xform_caches = [UsdGeom.XformCache(t) for t in self.times]
        self.skipped: list[tuple[str, str]] = []
        self._prototype_cache: dict = {}  # point instancer prototype path -> its Mesh / implicit prims
        self._surfaces = SurfaceReader()

    # -- time ------------------------------------------------------------------------------
    def _frames(self):
        """``(frames, range_authored)``: the stage's integer time codes start..end when it authors
        both startTimeCode and endTimeCode; else the time samples of its animation
        (:meth:`_animated_time_codes`), or time code 0 when nothing is animated."""
        st = self.stage
        if not st.HasAuthoredTimeCodeRange():
            codes = self._animated_time_codes()
            return (codes if codes.size else np.array([0.0])), False
        start, end = float(st.GetStartTimeCode()), float(st.GetEndTimeCode())
        if not (math.isfinite(start) and math.isfinite(end)) or end < start:
            raise ValueError(f"USD file {self.path}: invalid time code range {start}..{end}")
        count = math.floor(end) - math.ceil(start) + 1
        if count > MAX_TIME_CODES:
            raise ValueError(f"USD file {self.path}: startTimeCode {start:g} .. endTimeCode {end:g} spans {count:,} time codes; "
                             f"at most {MAX_TIME_CODES:,} are sampled")
        frames = np.arange(math.ceil(start), math.floor(end) + 1, dtype=np.float64)
        if frames.size == 0:
            frames = np.array([start])
        return frames, True

    def _animated_attributes(self, prim) -> list:
        """The attributes of ``prim`` whose time samples the reader follows: xform ops, mesh
        points, implicit shape attributes, point instancer positions / orientations / scales /
        protoIndices / invisibleIds, UsdSkel animation translations / rotations / scales."""
        from pxr import UsdGeom, UsdSkel

        attrs = []
        if prim.IsA(UsdGeom.Xformable):
            attrs += [op.GetAttr() for op in UsdGeom.Xformable(prim).GetOrderedXformOps()]
        if prim.IsA(UsdGeom.Mesh):
            attrs.append(UsdGeom.Mesh(prim).GetPointsAttr())
        elif is_implicit(prim):
            attrs += shape_attributes(prim)
        elif prim.IsA(UsdGeom.PointInstancer):
            pi = UsdGeom.PointInstancer(prim)
            attrs += [pi.GetPositionsAttr(), pi.GetOrientationsAttr(), pi.GetScalesAttr(), pi.GetProtoIndicesAttr(),
                      pi.GetInvisibleIdsAttr()]
        elif prim.IsA(UsdSkel.Animation):
            anim = UsdSkel.Animation(prim)
            attrs += [anim.GetTranslationsAttr(), anim.GetRotationsAttr(), anim.GetScalesAttr()]
        return attrs

    def _animated_time_codes(self) -> np.ndarray:
        """Frames of a stage without startTimeCode/endTimeCode: the union of the time samples of
        every animated attribute (:meth:`_animated_attributes`, on attributes with two or more
        samples) of the prims a load traverses (guide and proxy prims left out), sorted, as they
        are (fractional time codes stay fractional; codes closer than 1e-6 merge).

        Raises:
            ValueError: more than :data:`~warpshade._limits.MAX_TIME_CODES` time codes, naming the
                file and the attribute that crossed the limit.
        """
        from pxr import Usd, UsdGeom

        codes: set = set()
        it = iter(Usd.PrimRange(self.stage.GetPseudoRoot(), self.predicate))
        for prim in it:
            if prim.IsA(UsdGeom.Imageable) and UsdGeom.Imageable(prim).ComputePurpose() in (UsdGeom.Tokens.guide,
                                                                                          UsdGeom.Tokens.proxy):
                it.PruneChildren()
                continue
            with self._reading(prim):
                for attr in self._animated_attributes(prim):
                    n = attr.GetNumTimeSamples() if attr else 0
                    if n < 2:
                        continue
                    if n <= MAX_TIME_CODES:  # a single attribute over the limit is refused before reading its samples
                        codes.update(attr.GetTimeSamples())
                    if n > MAX_TIME_CODES or len(codes) > MAX_TIME_CODES:
                        raise ValueError(
                            f"USD file {self.path}: the stage has no startTimeCode/endTimeCode and its animation has "
                            f"more than {MAX_TIME_CODES:,} time samples (reached at {attr.GetPath()}); at most "
                            f"{MAX_TIME_CODES:,} are sampled: author startTimeCode "
                            "and endTimeCode to sample the integer time codes between them")
        frames = np.array(sorted(float(c) for c in codes if math.isfinite(c)), np.float64)
        if frames.size > 1:
            keep = np.concatenate([[True], np.diff(frames) > 1e-6])
            frames = frames[keep]
        return frames

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
                why = self._hidden_reason(prim)
                if why is not None:
                    self.skipped.append((str(prim.GetPath()), why))
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
                elif is_implicit(prim):
                    meshes.append(read_implicit(self, prim))
                elif prim.IsA(UsdGeom.Gprim):
                    self.skipped.append((str(prim.GetPath()), self._unsupported_gprim(prim)))
                elif prim.HasAPI(UsdLux.LightAPI):
                    light = read_light(self, prim)
                    if light is not None:
                        lights.append(with_track(self, prim, light))
                elif prim.IsA(UsdGeom.Camera):
                    if camera is None:
                        camera = read_camera(self, prim)
                    else:
                        self.skipped.append((str(prim.GetPath()), f"camera (only the first camera, {camera.path}, is read)"))
        if not meshes:
            raise ValueError(f"USD file {self.path}: contains no (visible, renderable) UsdGeom.Mesh or implicit "
                             f"({', '.join(IMPLICIT_TYPES)}) prims; {self._nothing_renderable()}")
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

    # -- what is left out --------------------------------------------------------------------
    def _hidden_reason(self, prim, prototype: bool = False) -> str | None:
        """Why an imageable prim (and everything under it) is not read, or None: guide or proxy
        purpose, or invisible at the first frame."""
        from pxr import UsdGeom

        img = UsdGeom.Imageable(prim)
        purpose = img.ComputePurpose()
        if purpose in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
            return f"purpose {purpose}" + (" (in a point instancer's prototype)" if prototype else "")
        if img.ComputeVisibility(self.times[0]) == UsdGeom.Tokens.invisible:
            return "invisible" + (" (in a point instancer's prototype)" if prototype else "")
        return None

    @staticmethod
    def _unsupported_gprim(prim) -> str:
        return (f"unsupported gprim type {prim.GetTypeName() or 'untyped'} (Mesh and the implicit "
                f"{', '.join(IMPLICIT_TYPES)} are read)")

    def _nothing_renderable(self) -> str:
        """What a stage without renderable prims holds: the skipped prims with their reasons, or
        the prims it has, and those a traversal does not reach (inactive, ``over``, ``class``)."""
        from collections import Counter

        from pxr import Usd

        parts = []
        if self.skipped:
            shown = "; ".join(f"{p} ({why})" for p, why in self.skipped[:6])
            more = f"; and {len(self.skipped) - 6} more" if len(self.skipped) > 6 else ""
            parts.append(f"skipped {len(self.skipped)} prim(s): {shown}{more}")
        reached = [p for p in Usd.PrimRange(self.stage.GetPseudoRoot(), self.predicate) if not p.IsPseudoRoot()]
        everything = [p for p in Usd.PrimRange(self.stage.GetPseudoRoot(), Usd.TraverseInstanceProxies(Usd.PrimAllPrimsPredicate))
                      if not p.IsPseudoRoot()]
        if not self.skipped:
            kinds = Counter(str(p.GetTypeName()) or "untyped" for p in reached)
            listed = ", ".join(f"{n} {k}" for k, n in kinds.most_common(6))
            parts.append(f"its {len(reached)} prim(s) are {listed}" if reached else "the stage defines no prims")
        reached_paths = {p.GetPath() for p in reached}
        unreached = [p for p in everything if p.GetPath() not in reached_paths]
        if unreached:
            first = unreached[0]
            parts.append(f"{len(unreached)} prim(s) are inactive, undefined ('over') or abstract ('class') and are not "
                         f"read (first: {first.GetPath()})")
        return "; ".join(parts)

    # -- per-mesh helpers (used by warpshade.io._usd_mesh and .textures) --------------------
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
