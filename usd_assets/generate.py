"""Write the bundled test scenes of warpshade (run: ``python usd_assets/generate.py [--out DIR]``).

Every scene is Z-up, in metres (``metersPerUnit = 1``), 24 frames per second, time codes
0..59 (60 frames) for animated scenes unless said otherwise below, and has:

* a ``DomeLight`` (/World/Sky) whose lat-long texture ``sky.hdr`` (64 x 128, Radiance RGBE) is
  a procedural sky with a soft sun, written by this script; the dome carries USD's
  ``rotateX:orientToStageUpAxis`` op so its +Y pole points up (+Z);
* a ``Camera`` (/World/Camera) framing the action;
* meshes only (no implicit prims), with per-vertex ``displayColor`` or a UsdPreviewSurface.

Scenes:

* ``blockers.usda`` -- a 40 x 40 vertex ground grid (6 m square, UsdPreviewSurface material)
  and three rigid blockers animated over it with time-sampled transforms: two UV spheres of
  radius 0.5 and 0.3 (quads with triangle fans at the poles) and a 0.7 m box (a 4 x 4 quad
  grid per face) that spins while it travels.
* ``figure.usda`` -- a UsdSkel figure: 12 joints (hips, spine, chest, head, two arms with
  elbows, two legs with knees), 11 capsules merged into one skinned mesh (about 2,000
  vertices, two influences per vertex blended near the joints), swinging its arms forward
  and across the chest so they shadow the torso, while the spine twists and the legs step;
  standing on a separate static 40 x 40 ground grid. The mesh lists its joints in its own
  order (``skel:joints``, reversed) and has a non-identity ``geomBindTransform``; the
  SkelRoot is translated and turned, so loading exercises every part of the binding.
* ``figure_train.usda`` and ``figure_walk.usda`` -- the same figure (identical mesh, skeleton,
  binding, ground, sky and camera: one function writes all three files, only the joint
  rotations differ) in two more clips, for data-driven PRT, which learns transfer as a linear
  function of the joint angles on one clip and is tested on others. ``figure_train`` (600
  frames, :func:`training_clip`) is a range of motion (frames 0-299,
  :func:`range_of_motion_clip`): each joint swept alone through its range, then all joints at
  once as sums of sinusoids at incommensurate frequencies, over ``FIGURE_LIMITS``, which hold
  every joint-angle component of ``figure.usda`` and ``figure_walk.usda`` with at least 0.05 rad
  to spare; then a motion library (frames 300-599, ``FIGURE_LIBRARY``), natural coordinated
  motions cross-faded into each other, none of them a held-out motion: idle sway, arm swings,
  four reaches (forward-up, out to the side, across the body, down to the floor), marching with
  varied knee lift, a walk in place that livens up, torso twists and bends holding the arms in
  front, head looks with the hands on the hips, a slow step with the left hand raised to head
  height (shading the eyes). ``figure_walk`` (96 frames) is a held-out walk in place: arms
  swinging against the legs, hips and head turning, a forward reach with the right arm at the
  end.
* ``wanderer_train.usdc`` and ``wanderer_test.usdc`` -- a larger character at the scale of the
  paper's "Master Pai" (11.5k vertices, a large hat): the wanderer, 33 joints (hips, spine,
  chest, neck, head; shoulder, elbow and wrist of each arm; thumb, index, middle and ring
  finger of each hand with two segments each; hip, knee and ankle of each leg) and about
  12,300 skinned vertices: a body of smooth tubes (torso, neck and head in one; each arm,
  palm, finger, leg and foot) with elliptical, tapering cross-sections, 10,578 vertices skinned
  with 4 influences (smoothstep blends across every joint, up to three non-zero; the top of
  the chest takes part of each shoulder), and a wide-brimmed hat (1,682 vertices, brim radius
  0.45 m) skinned rigidly to the head joint (constant interpolation, its own ``skel:joints``),
  whose shadow sweeps over the face, shoulders and chest as the head turns, tilts and bows.
  Ground grid, sky and camera as the figure's. ``wanderer_train`` (1000 frames) is a range of
  motion over ``WANDERER_LIMITS`` (frames 0-599, as above), then a motion library (frames
  600-999, ``WANDERER_LIBRARY``): a slow and a brisk walk (other strides and speeds than the test
  walk), five reaches (forward, to the side, up, to the chest, up to a shelf to grip something),
  picking something up from the floor, looking around (hands behind the back, then peering
  down), waving, hand gestures (a fist opening and closing, pointing, counting), a shrug and a
  crouch; ``wanderer_test`` (120 frames) is held out: a walk, a reach up to grip the brim while
  looking up, and a bow.
* ``ripples.usda`` -- an animated water surface as a procedural height field (8 m square, 512 x 512
  vertices, 48 frames that loop): a swell, three crossing chop waves, two circular ripples and a
  static seeded terrain term, described by the ``warpshade:heightField:*`` attributes of one Mesh
  prim (:mod:`warpshade.io.heightfield`, expanded by the loader), under the sky, with a camera
  looking across the water toward the sun at a glancing angle.
* ``cloth.usda`` -- a 30 x 30 sheet (faceVarying ``st`` UVs) with time-sampled points:
  travelling waves plus finer wrinkles, sagging at the free edge, over a ground grid.
* ``bend.usda`` -- a capped cylinder (24-gon caps) skinned to a 4-joint chain that bends and
  twists over 60 frames (smooth two-joint weights), for local deformable PRT.
* ``sunlit.usda`` -- all-frequency lighting of spatially varying glossy materials (48 frames,
  0..47, at 24 fps; written only on request, ``--scenes sunlit``, like ``ripples``). A (2, 3)
  torus knot (tube radius 0.12 m, 2,613 vertices with exact smooth vertex normals and vertex UVs,
  u along the knot repeating 4 times, v around it) resting on a 41 x 41 vertex ground grid (6 m
  square, UVs spanning [0, 1] over the plane). UsdPreviewSurface materials: the knot uses the
  specular workflow (diffuseColor (0.30, 0.07, 0.05), specularColor (0.75, 0.6, 0.4)) with a
  roughness texture ``sunlit_knot_roughness.png`` (128 x 128 grey, raw, repeat) of smooth bands
  broken by noise between 0.08 and 0.5; the ground uses the metallic workflow (metallic 0, so
  F0 = 0.04) with an sRGB diffuse texture ``sunlit_ground_diffuse.png`` (a 4 x 4 stone / slate
  checker) and a raw roughness texture ``sunlit_ground_roughness.png`` (rust-like noise, 0.15 to
  0.5). Roughness values are what ``warpshade.scene.materials.Microfacet(roughness=...)`` takes
  (its alpha; warpshade does not square UsdPreviewSurface roughness). Lights: a DomeLight with
  its own sky ``sunlit_sky.hdr`` (256 x 512 lat-long): a clear sky with a soft aureole plus a
  sun disc 1.2 degrees across at 40 degrees elevation (azimuth 70 degrees from +X towards +Y),
  painted by exact texel coverage so that its irradiance on the ground is ``SUNLIT_SUN_TO_SKY``
  (4) times the rest of the sky's (peak radiance ~3e4 against a sky of ~0.25-1), so the knot casts
  a sharp shadow on the plane; and an orange SphereLight (/World/Lamp, radius 0.08 m, intensity
  150) that circles the knot once over the clip 1.5 m from its axis, bobbing 0.65-1.15 m above the
  ground (time-sampled translate, :func:`sunlit_lamp_position`), always outside the knot's convex
  hull. The camera frames the knot and its shadow.

Output is deterministic: coordinates, weights and quaternions are rounded to 1e-4 (camera
matrices to 1e-6) before they are written, so the files only change when this script changes. A test regenerates them and compares bytes.
The binary ``.usdc`` (crate) files are reproducible byte for byte too, with a given USD release
(the thread count does not matter); like the text of the ``.usda`` files, they may change with
a USD release that writes another crate version.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, UsdSkel, Vt
from scipy.interpolate import PchipInterpolator
from scipy.spatial.transform import Rotation

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from warpshade.io.images import write_hdr  # noqa: E402
from warpshade.scene.lighting import sky_radiance, usd_dome_texel_directions  # noqa: E402

FRAME_COUNT = 60
FPS = 24.0
DECIMALS = 4  # coordinates are rounded to 0.1 mm: small files, stable bytes
SKY_FILE = "sky.hdr"
SKY_SIZE = (64, 128)
#: Sun direction (towards the sun), world space, Z-up: in front of the figure (-Y), high.
SUN_DIRECTION = np.array([0.35, -0.6, 0.72]) / np.linalg.norm([0.35, -0.6, 0.72])
SCENES = ("blockers", "figure", "figure_train", "figure_walk", "figure_orbit", "cloth", "bend", "wanderer_train", "wanderer_test")


# ---- small helpers --------------------------------------------------------------------------
def _r(a) -> np.ndarray:
    return np.round(np.asarray(a, dtype=np.float64), DECIMALS)


def _smoothstep(x):
    """0 below 0, 1 above 1, 3x^2 - 2x^3 between."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _vec3f(a) -> Vt.Vec3fArray:
    return Vt.Vec3fArray.FromNumpy(_r(a).astype(np.float32).reshape(-1, 3))


def _new_stage(animated: bool, frame_count: int = FRAME_COUNT) -> Usd.Stage:
    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(FPS)
    stage.SetFramesPerSecond(FPS)
    if animated:
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(frame_count - 1)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    return stage


def _save(stage: Usd.Stage, path: str) -> None:
    """Write the stage's root layer: text for ``.usda``, USD's crate format for ``.usdc``."""
    if path.endswith(".usdc"):
        tmp = path[: -len(".usdc")] + ".tmp.usdc"  # the extension picks the file format
        if not stage.GetRootLayer().Export(tmp):
            raise OSError(f"could not write {tmp}")
    else:
        tmp = path + ".tmp"
        with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(stage.GetRootLayer().ExportToString())
    os.replace(tmp, path)


def _mesh(stage, path, points, counts, indices, color=None):
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(_vec3f(points))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([int(c) for c in counts]))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray([int(i) for i in indices]))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*_r(pts.min(0))), Gf.Vec3f(*_r(pts.max(0)))]))
    if color is not None:
        mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, color))]))
    return mesh


def _sky(stage) -> None:
    dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
    dome.OrientToStageUpAxis()
    dome.CreateTextureFileAttr(Sdf.AssetPath("./" + SKY_FILE))
    dome.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
    dome.CreateIntensityAttr(1.0)


def _camera(stage, eye, target, focal=35.0):
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(focal)
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(24.0)
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    cam.CreateFocusDistanceAttr(float(np.linalg.norm(target - eye)))
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.05, 1000.0))
    view = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*target), Gf.Vec3d(0, 0, 1))
    UsdGeom.Xformable(cam).AddTransformOp().Set(_round_matrix(view.GetInverse()))


def _round_matrix(m, decimals: int = 6) -> Gf.Matrix4d:
    return Gf.Matrix4d(*[float(v) for v in np.round(np.array(m), decimals).ravel()])


def write_sky(out_dir: str) -> str:
    """The dome texture: sky_radiance at the world directions of the file's texels."""
    height, width = SKY_SIZE
    # Dome frame -> world for a DomeLight with rotateX:orientToStageUpAxis = 90 (column form).
    dome_to_world = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    dirs = usd_dome_texel_directions(height, width) @ dome_to_world.T
    image = sky_radiance(dirs, sun_direction=SUN_DIRECTION, up=(0.0, 0.0, 1.0))
    path = os.path.join(out_dir, SKY_FILE)
    write_hdr(path, image.astype(np.float32))
    return path


# ---- geometry builders (numpy) -------------------------------------------------------------
def grid(resolution: int, size: float, z: float = 0.0):
    """A square quad grid in the XY plane, (points, counts, indices), normal +Z."""
    s = np.linspace(-size / 2, size / 2, resolution)
    x, y = np.meshgrid(s, s, indexing="ij")
    pts = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], 1)
    i, j = np.meshgrid(np.arange(resolution - 1), np.arange(resolution - 1), indexing="ij")
    v00 = (i * resolution + j).ravel()
    quads = np.stack([v00, v00 + resolution, v00 + resolution + 1, v00 + 1], 1)  # +x then +y: CCW from +Z
    return pts, np.full(len(quads), 4), quads.ravel()


def revolution(profile, around: int, cap_polygons: bool = False):
    """Surface of revolution about +Z.

    Args:
        profile: (z, r) pairs from bottom to top; r == 0 at an end makes a pole (triangle fan).
        around: segments around the axis.
        cap_polygons: close open ends with one n-gon each instead of poles.

    Returns:
        points (N, 3), counts, indices, and each point's ring index.
    """
    ang = 2 * np.pi * np.arange(around) / around
    pts, ring_of, ring_start = [], [], []
    for k, (z, r) in enumerate(profile):
        ring_start.append(len(pts))
        if r == 0.0:
            pts.append([0.0, 0.0, z])
            ring_of.append(k)
        else:
            for a in ang:
                pts.append([r * np.cos(a), r * np.sin(a), z])
                ring_of.append(k)
    counts, idx = [], []
    for k in range(len(profile) - 1):
        a0, a1 = ring_start[k], ring_start[k + 1]
        r0, r1 = profile[k][1], profile[k + 1][1]
        for j in range(around):
            jn = (j + 1) % around
            if r0 == 0.0:  # bottom pole
                counts.append(3)
                idx += [a0, a1 + jn, a1 + j]
            elif r1 == 0.0:  # top pole
                counts.append(3)
                idx += [a0 + j, a0 + jn, a1]
            else:
                counts.append(4)
                idx += [a0 + j, a0 + jn, a1 + jn, a1 + j]
    if cap_polygons:
        counts.append(around)
        idx += [ring_start[0] + j for j in reversed(range(around))]  # bottom, facing -Z
        counts.append(around)
        idx += [ring_start[-1] + j for j in range(around)]  # top, facing +Z
    return np.asarray(pts), np.asarray(counts), np.asarray(idx), np.asarray(ring_of)


def uv_sphere(radius: float, around: int = 20, rings: int = 10):
    theta = np.linspace(np.pi, 0.0, rings + 1)
    profile = [(radius * np.cos(t), 0.0 if k in (0, rings) else radius * np.sin(t)) for k, t in enumerate(theta)]
    pts, counts, idx, _ = revolution(profile, around)
    return pts, counts, idx


def capsule_profile(length: float, radius: float, cap_rings: int = 4, body_rings: int = 5):
    """(z, r) profile of a capsule from z = -radius to z = length + radius."""
    prof = []
    for k in range(cap_rings + 1):  # bottom hemisphere, pole first
        t = np.pi / 2 * k / cap_rings
        prof.append((-radius * np.cos(t), radius * np.sin(t) if k else 0.0))
    for k in range(1, body_rings):
        prof.append((length * k / body_rings, radius))
    for k in range(cap_rings, -1, -1):  # top hemisphere, pole last
        t = np.pi / 2 * k / cap_rings
        prof.append((length + radius * np.cos(t), radius * np.sin(t) if k else 0.0))
    return prof


def box(size: float, cells: int = 4):
    """An axis-aligned cube centred at the origin; each face a cells x cells quad grid."""
    pts, counts, idx = [], [], []
    s = np.linspace(-size / 2, size / 2, cells + 1)
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u_axis, v_axis = (axis + 1) % 3, (axis + 2) % 3
            if sign < 0:
                u_axis, v_axis = v_axis, u_axis  # keep (u, v, outward) right-handed
            base = len(pts)
            for a in s:
                for b in s:
                    p = [0.0, 0.0, 0.0]
                    p[axis] = sign * size / 2
                    p[u_axis], p[v_axis] = a, b
                    pts.append(p)
            n = cells + 1
            for i in range(cells):
                for j in range(cells):
                    v00 = base + i * n + j
                    counts.append(4)
                    idx += [v00, v00 + n, v00 + n + 1, v00 + 1]
    return np.asarray(pts), np.asarray(counts), np.asarray(idx)


def _orthonormal_side(direction, hint=(1.0, 0.0, 0.0)):
    """``direction`` normalised, and the unit vector perpendicular to it closest to ``hint``."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    side = np.asarray(hint, float) - np.dot(hint, d) * d
    return d, side / np.linalg.norm(side)


def tube(origin, direction, knots, around, rings, caps, cap_rings=5, hint=(1.0, 0.0, 0.0)):
    """A closed tube along a straight axis with an elliptical, varying cross-section.

    Args:
        origin: where the axis parameter s = 0 lies (skeleton space).
        direction: the axis (normalised here).
        knots: (s, rx, ry) rows, s increasing: radii along the side axis (``hint`` made
            perpendicular to the axis) and along ``direction x side``, interpolated smoothly
            (monotone cubic) over the ``rings`` evenly spaced rings from the first to the last s.
        around: vertices per ring.
        caps: lengths of the rounded (elliptical quarter-circle) ends before the first and after
            the last knot, each with ``cap_rings`` rings and a pole.

    Returns:
        points (N, 3), counts, indices, and each point's axis parameter s (N,).
    """
    knots = np.asarray(knots, float)
    s_body = np.linspace(knots[0, 0], knots[-1, 0], rings)
    radii = PchipInterpolator(knots[:, 0], knots[:, 1:], axis=0)(s_body)
    ring_s, ring_r = [], []
    t = np.linspace(0.0, np.pi / 2, cap_rings + 1)[:-1]  # pole first
    ring_s += list(s_body[0] - caps[0] * np.cos(t))
    ring_r += [radii[0] * np.sin(a) for a in t]
    ring_s += list(s_body)
    ring_r += list(radii)
    ring_s += list(s_body[-1] + caps[1] * np.cos(t[::-1]))
    ring_r += [radii[-1] * np.sin(a) for a in t[::-1]]
    profile = [(s, 0.0 if k in (0, len(ring_s) - 1) else 1.0) for k, s in enumerate(ring_s)]
    pts, counts, idx, ring_of = revolution(profile, around)
    ring_r = np.asarray(ring_r)
    local = pts * np.concatenate([ring_r[ring_of], np.ones((len(pts), 1))], 1)
    d, side = _orthonormal_side(direction, hint)
    other = np.cross(d, side)
    world = np.asarray(origin, float) + local[:, :1] * side + local[:, 1:2] * other + local[:, 2:3] * d
    return world, counts, idx, local[:, 2]


def _ground(stage, path="/World/Ground", size=6.0, material=False):
    pts, counts, idx = grid(40, size)
    mesh = _mesh(stage, path, pts, counts, idx, color=None if material else (0.8, 0.8, 0.8))
    if material:
        mat = UsdShade.Material.Define(stage, "/World/Looks/Ground")
        shader = UsdShade.Shader.Define(stage, "/World/Looks/Ground/Surface")
        shader.CreateIdAttr("UsdPreviewSurface")
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.7, 0.68, 0.62))
        shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.9)
        mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    return mesh


# ---- (a) blockers ---------------------------------------------------------------------------
def blocker_paths(frame: int):
    """World translations of the blockers and the box's spin angle (degrees) at a frame."""
    t = frame / (FRAME_COUNT - 1)
    big = np.array([-2.0 + 4.0 * t, 0.6 * np.sin(2 * np.pi * t), 0.5 + 0.25 + 0.3 * np.sin(np.pi * t)])
    small = np.array([1.5 * np.cos(2 * np.pi * t), 1.5 * np.sin(2 * np.pi * t), 0.3 + 0.5])
    cube = np.array([1.8 - 3.6 * t, -1.0 + 0.8 * t, 0.35 + 0.15 + 0.4 * np.sin(np.pi * t) ** 2])
    return big, small, cube, 360.0 * t


def make_blockers(out_dir: str) -> str:
    stage = _new_stage(animated=True)
    _sky(stage)
    _ground(stage, material=True)
    specs = [("BigSphere", uv_sphere(0.5), (0.85, 0.3, 0.25)), ("SmallSphere", uv_sphere(0.3, 16, 8), (0.25, 0.45, 0.85))]
    xforms = []
    for name, (pts, counts, idx), color in specs:
        xf = UsdGeom.Xform.Define(stage, f"/World/Blockers/{name}")
        _mesh(stage, f"/World/Blockers/{name}/Mesh", pts, counts, idx, color)
        xforms.append(xf.AddTranslateOp())
    cube_xf = UsdGeom.Xform.Define(stage, "/World/Blockers/Box")
    pts, counts, idx = box(0.7)
    _mesh(stage, "/World/Blockers/Box/Mesh", pts, counts, idx, (0.3, 0.75, 0.35))
    cube_t = cube_xf.AddTranslateOp()
    cube_r = cube_xf.AddRotateZOp()
    for f in range(FRAME_COUNT):
        big, small, cube, spin = blocker_paths(f)
        xforms[0].Set(Gf.Vec3d(*_r(big)), f)
        xforms[1].Set(Gf.Vec3d(*_r(small)), f)
        cube_t.Set(Gf.Vec3d(*_r(cube)), f)
        cube_r.Set(float(_r(spin)), f)
    _camera(stage, eye=(4.5, -5.5, 3.8), target=(0.0, 0.0, 0.4))
    path = os.path.join(out_dir, "blockers.usda")
    _save(stage, path)
    return path


# ---- skeletons and skinning ----------------------------------------------------------------
def joint_paths(joints):
    names = {}
    for name, parent, _ in joints:
        names[name] = name if parent is None else f"{names[parent]}/{name}"
    return [names[n] for n, _, _ in joints]


def _quat_array(rotvecs) -> Vt.QuatfArray:
    q = Rotation.from_rotvec(rotvecs).as_quat()  # (x, y, z, w)
    q = _r(q)
    return Vt.QuatfArray([Gf.Quatf(float(w), Gf.Vec3f(float(x), float(y), float(z))) for x, y, z, w in q])


def _skeleton(stage, root_path, joints, rotations, frame_count):
    """A Skeleton and its Animation under ``root_path``: rest/bind poses from ``joints`` offsets.

    ``joints`` lists (name, parent, rest offset from the parent); rest rotations are identity, so
    the authored rotations ``rotations(frame)`` (rotation vectors, (J, 3)) are the joint angles
    relative to the rest pose. Returns the Skeleton and the joint paths.
    """
    paths = joint_paths(joints)
    skel = UsdSkel.Skeleton.Define(stage, f"{root_path}/Skel")
    skel.CreateJointsAttr(Vt.TokenArray(paths))
    world = {}
    local_rest, bind = [], []
    for name, par, off in joints:
        world[name] = np.asarray(off, float) + (world[par] if par else 0.0)
        local_rest.append(Gf.Matrix4d().SetTranslate(Gf.Vec3d(*_r(off))))
        bind.append(Gf.Matrix4d().SetTranslate(Gf.Vec3d(*_r(world[name]))))
    skel.CreateRestTransformsAttr(Vt.Matrix4dArray(local_rest))
    skel.CreateBindTransformsAttr(Vt.Matrix4dArray(bind))
    anim = UsdSkel.Animation.Define(stage, f"{root_path}/Anim")
    anim.CreateJointsAttr(Vt.TokenArray(paths))
    anim.CreateTranslationsAttr(Vt.Vec3fArray([Gf.Vec3f(*_r(off)) for _, _, off in joints]))
    anim.CreateScalesAttr(Vt.Vec3hArray([Gf.Vec3h(1.0, 1.0, 1.0)] * len(paths)))
    attr = anim.CreateRotationsAttr()
    for f in range(frame_count):
        attr.Set(_quat_array(rotations(f)), f)
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    return skel, paths


def _bind_skin(mesh, skel, indices, weights, element_size, geom_bind, joints=None, constant=False):
    """Bind a mesh to a skeleton: per-vertex (or ``constant``) joint indices and weights."""
    binding = UsdSkel.BindingAPI.Apply(mesh.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    if joints is not None:  # the mesh's own joint order, which its indices refer to
        binding.CreateJointsAttr(Vt.TokenArray(joints))
    binding.CreateJointIndicesPrimvar(constant, element_size).Set(Vt.IntArray([int(v) for v in np.ravel(indices)]))
    binding.CreateJointWeightsPrimvar(constant, element_size).Set(Vt.FloatArray([float(v) for v in _r(weights).ravel()]))
    binding.CreateGeomBindTransformAttr(geom_bind)
    return binding


def _write_character(out_dir, file_name, root_path, joints, rotations, frame_count, dress, camera, place=None) -> str:
    """One clip of a skinned character over the ground grid, under the sky, with a camera.

    Args:
        root_path: the SkelRoot, which ``place(root)`` (optional) may move; the skeleton and its
            animation (:func:`_skeleton`: ``joints``, ``rotations(frame)``) go below it.
        dress: ``dress(stage, skeleton, joint paths)`` adds the character's skinned meshes.
        camera: (eye, target).
    """
    stage = _new_stage(animated=True, frame_count=frame_count)
    _sky(stage)
    _ground(stage)
    root = UsdSkel.Root.Define(stage, root_path)
    if place is not None:
        place(root)
    skel, paths = _skeleton(stage, root_path, joints, rotations, frame_count)
    dress(stage, skel, paths)
    _camera(stage, *camera)
    path = os.path.join(out_dir, file_name)
    _save(stage, path)
    return path


def chain_weights(s, chain) -> np.ndarray:
    """Smooth skinning weights along a tube that follows a chain of joints, (N, len(chain)).

    Args:
        s: the points' axis parameters (N,).
        chain: (joint, s where its bone begins, blend half-width) rows in order along the
            tube; the first joint owns everything before the second's start, the last
            everything after its own. Across each bone start the weight passes from the previous
            joint to the next by a smoothstep over +-half-width (0.5 each at the start), so a
            point near a bone shorter than its two half-widths takes three joints.

    Returns:
        weights per chain joint, rows sum to 1.
    """
    w = np.ones((len(s), len(chain)))
    for k in range(1, len(chain)):
        _, start, half = chain[k]
        rise = _smoothstep((s - start + half) / (2.0 * half))
        w[:, k] *= rise
        w[:, k - 1] *= 1.0 - rise
    return w / w.sum(1, keepdims=True)


def strongest_influences(joints, weights, count: int):
    """The ``count`` largest weights per row (strongest first) and their joints, renormalised.

    ``joints`` (N, M) or (M,) joint indices, ``weights`` (N, M); with fewer than ``count``
    columns, each row is padded with its strongest joint at weight 0.
    """
    joints = np.broadcast_to(np.asarray(joints), weights.shape)
    order = np.argsort(-weights, axis=1, kind="stable")[:, :count]
    if order.shape[1] < count:
        order = np.concatenate([order, np.repeat(order[:, :1], count - order.shape[1], 1)], 1)
    w = np.take_along_axis(weights, order, 1)
    w = np.where(np.arange(count) < weights.shape[1], w, 0.0)
    return np.take_along_axis(joints, order, 1), w / w.sum(1, keepdims=True)


# ---- range-of-motion training clips -----------------------------------------------------------
#: Frames of one single-joint sweep in a range-of-motion clip.
SWEEP_FRAMES = 12
#: Frequency band (Hz) of the sinusoids of the mixed part, and their relative amplitudes.
MIXED_BAND = (0.2, 0.8)
MIXED_AMPLITUDES = (1.0, 0.55, 0.3)
_GOLDEN = 0.6180339887498949  # Weyl sequences: frequencies and phases that never repeat
_PLASTIC = 0.7548776662466927


def joint_limits(joints, limits) -> np.ndarray:
    """Per-joint rotation-vector ranges, shape (J, 3, 2) (lo, hi per component), from a table.

    ``limits`` maps a joint name to ((lo, hi) for x, y, z); a left/right pair is given once
    under the name without its side letter ("Shoulder" for "LShoulder" and "RShoulder"), for
    the left side; the right side is its mirror image in the x = 0 plane, (x, y, z) -> (x, -y, -z).
    """
    out = np.zeros((len(joints), 3, 2))
    for j, (name, _, _) in enumerate(joints):
        sided = name[0] in "LR" and name[1:2].isupper()
        lim = np.asarray(limits[name[1:] if sided else name], dtype=np.float64)
        if sided and name[0] == "R":
            lim = np.stack([lim[0], -lim[1, ::-1], -lim[2, ::-1]])
        if np.any(lim[:, 0] >= lim[:, 1]):
            raise ValueError(f"joint limits of {name}: every range needs lo < hi")
        out[j] = lim
    return out


def _sweep_pattern() -> np.ndarray:
    """One joint's normalised sweep, (SWEEP_FRAMES, 3): each component reaches -1 and +1.

    x: two 6-frame lobes (+, -); y and z: three 4-frame lobes with the signs (+, -, +) and
    (+, +, -), so the three components are not proportional. Each lobe is sin^2-shaped: it leaves
    and returns to 0 with zero velocity and passes through its peak on a frame; the pattern
    starts and ends at 0.
    """
    t = np.arange(SWEEP_FRAMES)
    six = np.sin(np.pi * (t % 6) / 6) ** 2
    four = np.sin(np.pi * (t % 4) / 4) ** 2
    return np.stack(
        [six * np.where(t < 6, 1.0, -1.0), four * np.array([1.0, -1.0, 1.0])[t // 4], four * np.array([1.0, 1.0, -1.0])[t // 4]],
        1,
    )


def range_of_motion_clip(limits: np.ndarray, mixed_frames: int) -> np.ndarray:
    """A training clip that covers ``limits`` (J, 3, 2) and moves the joints independently.

    Every joint's base pose is the centre of its ranges (the clip's first frame, in general not
    the rest pose), so no joint's mean changes between the two parts (a shared offset would
    correlate all joints). The parts:

    1. single-joint sweeps, one joint at a time in skeleton order (SWEEP_FRAMES each, the
       others at their base): every component of the joint's rotation vector goes from the
       centre to both ends of its range and back (:func:`_sweep_pattern`);
    2. ``mixed_frames`` of every joint at once: each component is the centre of its range plus
       half its width times a sum of three sinusoids (amplitudes MIXED_AMPLITUDES, normalised
       to [-1, 1]), every sinusoid of the clip at its own frequency in MIXED_BAND (a Weyl
       sequence, so no two are commensurate in practice) and phase.

    Returns:
        rotation vectors, shape (J * SWEEP_FRAMES + mixed_frames, J, 3); every value lies in
        its range, and both ends of every range are reached exactly.
    """
    centre = 0.5 * (limits[..., 0] + limits[..., 1])
    half = 0.5 * (limits[..., 1] - limits[..., 0])
    joint_count = len(limits)
    pattern = _sweep_pattern()
    sweeps = np.tile(centre, (joint_count * SWEEP_FRAMES, 1, 1))
    for j in range(joint_count):
        sweeps[j * SWEEP_FRAMES : (j + 1) * SWEEP_FRAMES, j] += pattern * half[j]
    t = np.arange(mixed_frames, dtype=np.float64)[:, None, None]
    amplitudes = np.asarray(MIXED_AMPLITUDES)
    wave = np.zeros((mixed_frames, joint_count, 3))
    for i, a in enumerate(amplitudes):
        n = 3 * np.arange(joint_count * 3).reshape(joint_count, 3) + i
        freq = MIXED_BAND[0] + (MIXED_BAND[1] - MIXED_BAND[0]) * np.mod(0.5 + n * _GOLDEN, 1.0)
        phase = 2 * np.pi * np.mod(n * _PLASTIC, 1.0)
        wave += a * np.sin(2 * np.pi * freq * t / FPS + phase)
    mixed = centre + half * wave / amplitudes.sum()
    return np.concatenate([sweeps, mixed])


# ---- motion libraries: natural motions after the range of motion ------------------------------
#: Frames over which consecutive parts of a training clip cross-fade (the range of motion into
#: the first library segment, each segment into the next).
LIBRARY_BLEND = 6


class _Motion:
    """One motion segment being built: joint rotation vectors over ``frames`` frames, (T, J, 3).

    Terms are added per joint (:meth:`add`); a term for a sided joint is written for the left
    side and mirrored for the right, (x, y, z) -> (x, -y, -z), as in :func:`joint_limits`, so one
    expression serves both arms or legs.
    """

    def __init__(self, joints, frames: int):
        self.index = {name: k for k, (name, _, _) in enumerate(joints)}
        self.t = np.arange(frames, dtype=np.float64)
        self.rot = np.zeros((frames, len(joints), 3))

    def add(self, name: str, x=0.0, y=0.0, z=0.0, side: str = "") -> None:
        """Add (x, y, z) (scalars or per-frame arrays) to joint ``side + name``."""
        mirror = -1.0 if side == "R" else 1.0
        x, y, z, _ = np.broadcast_arrays(np.asarray(x, np.float64), y, z, self.t)
        self.rot[:, self.index[side + name]] += np.stack([x, mirror * y, mirror * z], -1)

    def keys(self, times, values) -> np.ndarray:
        """:func:`_keys` over this segment, the key times scaled so the last falls on its last frame."""
        times = np.asarray(times, np.float64)
        return _keys(self.t, times * (len(self.t) - 1) / times[-1], values)


def _keys(t, times, values) -> np.ndarray:
    """A smooth curve through (time, value) keys at the frames ``t`` (monotone cubic: no
    overshoot, flat at every key that is a local extremum), held at the end values outside."""
    times = np.asarray(times, np.float64)
    return PchipInterpolator(times, np.asarray(values, np.float64))(np.clip(t, times[0], times[-1]))


def _bump(t, start: float, rise: float, hold: float, fall: float) -> np.ndarray:
    """0 before ``start``, up to 1 over ``rise`` frames (smoothstep), held, back to 0 over ``fall``."""
    return _smoothstep((t - start) / rise) * (1.0 - _smoothstep((t - start - rise - hold) / fall))


def _cross_fade(parts) -> np.ndarray:
    """Clips (T_k, J, 3) joined into one: each overlaps the next by LIBRARY_BLEND frames, over
    which the pose passes from one to the other (smoothstep weights), so nothing jumps."""
    w = _smoothstep(np.arange(1, LIBRARY_BLEND + 1) / (LIBRARY_BLEND + 1))[:, None, None]
    out = parts[0]
    for part in parts[1:]:
        mixed = (1.0 - w) * out[-LIBRARY_BLEND:] + w * part[:LIBRARY_BLEND]
        out = np.concatenate([out[:-LIBRARY_BLEND], mixed, part[LIBRARY_BLEND:]])
    return out


def training_clip(limits: np.ndarray, mixed_frames: int, library) -> np.ndarray:
    """A character's training clip: :func:`range_of_motion_clip`, then a motion library.

    The range of motion reaches every joint's limits but moves the joints independently, about
    the middle of their ranges; natural motions move them in coordinated patterns, mostly near
    the rest pose, and a model linear in the joint angles trained on the range of motion alone
    generalises badly to them. The library adds such motions -- like a motion-capture session
    of the same actor, none of them a held-out clip's motion.

    Args:
        limits: the joint ranges, (J, 3, 2).
        mixed_frames: frames of the range of motion's mixed part.
        library: the motion segments, each (T_k, J, 3); every value is clipped to ``limits``.

    Returns:
        rotation vectors, (R + sum T_k - (len(library) - 1) * LIBRARY_BLEND, J, 3): the R frames
        of the range of motion unchanged, its sinusoids running on for LIBRARY_BLEND more frames
        while they fade into the first segment, then each segment fading into the next
        (:func:`_cross_fade`). Every value lies in its range.
    """
    rom = range_of_motion_clip(limits, mixed_frames + LIBRARY_BLEND)
    segments = [np.clip(s, limits[..., 0], limits[..., 1]) for s in library]
    return _cross_fade([rom, *segments])


# ---- (b) figure -----------------------------------------------------------------------------
#: name, parent, rest offset from the parent joint (skeleton space, no rest rotations)
FIGURE_JOINTS = [
    ("Hips", None, (0.0, 0.0, 0.95)),
    ("Spine", "Hips", (0.0, 0.0, 0.12)),
    ("Chest", "Spine", (0.0, 0.0, 0.25)),
    ("Neck", "Chest", (0.0, 0.0, 0.2)),
    ("LShoulder", "Chest", (0.25, 0.0, 0.1)),
    ("LElbow", "LShoulder", (0.0, 0.0, -0.28)),
    ("RShoulder", "Chest", (-0.25, 0.0, 0.1)),
    ("RElbow", "RShoulder", (0.0, 0.0, -0.28)),
    ("LHip", "Hips", (0.1, 0.0, -0.05)),
    ("LKnee", "LHip", (0.0, 0.0, -0.42)),
    ("RHip", "Hips", (-0.1, 0.0, -0.05)),
    ("RKnee", "RHip", (0.0, 0.0, -0.42)),
]
#: capsule per joint: (joint, end point offset in the joint's frame or None for the child, radius)
FIGURE_CAPSULES = [
    ("Hips", ((-0.1, 0.0, 0.0), (0.1, 0.0, 0.0)), 0.12),
    ("Spine", ((0.0, 0.0, 0.02), (0.0, 0.0, 0.42)), 0.15),
    ("Neck", ((0.0, 0.0, 0.12), (0.0, 0.0, 0.22)), 0.11),
    ("LShoulder", ((0.0, 0.0, 0.0), (0.0, 0.0, -0.26)), 0.05),
    ("LElbow", ((0.0, 0.0, 0.0), (0.0, 0.0, -0.25)), 0.045),
    ("RShoulder", ((0.0, 0.0, 0.0), (0.0, 0.0, -0.26)), 0.05),
    ("RElbow", ((0.0, 0.0, 0.0), (0.0, 0.0, -0.25)), 0.045),
    ("LHip", ((0.0, 0.0, 0.0), (0.0, 0.0, -0.4)), 0.075),
    ("LKnee", ((0.0, 0.0, 0.0), (0.0, 0.0, -0.4)), 0.06),
    ("RHip", ((0.0, 0.0, 0.0), (0.0, 0.0, -0.4)), 0.075),
    ("RKnee", ((0.0, 0.0, 0.0), (0.0, 0.0, -0.4)), 0.06),
]
#: where the SkelRoot stands and which way it faces (degrees about +Z)
FIGURE_ROOT_TRANSLATE = (0.3, -0.2, 0.0)
FIGURE_ROOT_ROTATE_Z = 20.0
#: geomBindTransform of the body mesh: its points are authored this far from skeleton space
FIGURE_GEOM_BIND_OFFSET = np.array([0.0, 0.05, -0.1])


def figure_joint_rotations(frame: int) -> np.ndarray:
    """Joint-local rotations (rotation vectors, radians) of the figure at a frame, shape (12, 3).

    The arms swing forward (towards -Y, the figure's front) and across the chest, half a cycle
    apart; elbows bend; the spine twists; the legs step. Rest rotations are identity, so these
    are also the joint angles relative to the rest pose.
    """
    phase = 2 * np.pi * frame / FRAME_COUNT
    rot = {name: np.zeros(3) for name, _, _ in FIGURE_JOINTS}

    def arm(side: float, ph: float):
        lift = 1.25 * (0.5 - 0.5 * np.cos(ph))  # 0 .. 1.25 rad forward
        across = 0.8 * (0.5 - 0.5 * np.cos(ph))  # hand moves over to the other side
        r = Rotation.from_rotvec([0.0, side * across, 0.0]) * Rotation.from_rotvec([-lift, 0.0, 0.0])
        return r.as_rotvec()

    rot["LShoulder"] = arm(1.0, phase)
    rot["RShoulder"] = arm(-1.0, phase + np.pi)
    rot["LElbow"] = np.array([-0.2 - 0.6 * (0.5 - 0.5 * np.cos(phase)), 0.0, 0.0])
    rot["RElbow"] = np.array([-0.2 - 0.6 * (0.5 + 0.5 * np.cos(phase)), 0.0, 0.0])
    rot["Spine"] = np.array([0.0, 0.0, 0.3 * np.sin(phase)])
    rot["Chest"] = np.array([0.08 * np.sin(2 * phase), 0.0, 0.0])
    rot["Neck"] = np.array([0.15 * np.sin(phase + 0.5), 0.0, 0.1 * np.sin(phase)])
    rot["LHip"] = np.array([0.35 * np.sin(phase), 0.0, 0.0])
    rot["RHip"] = np.array([-0.35 * np.sin(phase), 0.0, 0.0])
    rot["LKnee"] = np.array([0.45 * max(0.0, np.sin(phase + 0.8)), 0.0, 0.0])
    rot["RKnee"] = np.array([0.45 * max(0.0, -np.sin(phase + 0.8)), 0.0, 0.0])
    return np.stack([rot[name] for name, _, _ in FIGURE_JOINTS])


FIGURE_WALK_FRAMES = 96
FIGURE_WALK_PERIOD = 32  # frames per stride (left and right step)


def figure_walk_rotations(frame: int) -> np.ndarray:
    """Joint-local rotation vectors of the figure's walk clip at a frame, shape (12, 3).

    A walk in place, three strides of 32 frames: the legs swing (+-0.4 rad) with the knees
    bending through each swing, the hips sway and turn with the stride while the spine
    counter-twists, the arms swing in counter-phase with the legs (forward and back, slightly
    out from the body), and the head looks slowly around. Over the last stride the right arm
    reaches forward to shoulder height with the elbow straightening. Unlike ``figure.usda``
    (arms lifting in phase with the step, across the chest) the arms move opposite the legs,
    over a different range, and the hips and head turn.
    """
    ph = 2 * np.pi * frame / FIGURE_WALK_PERIOD
    slow = 2 * np.pi * frame / FIGURE_WALK_FRAMES
    reach = _smoothstep((frame - 60) / 14.0) * (1.0 - _smoothstep((frame - 82) / 12.0))
    rot = {name: np.zeros(3) for name, _, _ in FIGURE_JOINTS}
    rot["Hips"] = np.array([0.0, 0.04 * np.sin(ph), 0.08 * np.sin(ph)])
    rot["Spine"] = np.array([0.04, 0.0, -0.15 * np.sin(ph)])
    rot["Chest"] = np.array([0.06 + 0.03 * np.cos(2 * ph), 0.0, 0.0])
    rot["Neck"] = np.array([0.1 * np.sin(slow), 0.0, 0.3 * np.sin(slow + 1.0)])
    rot["LShoulder"] = np.array([0.35 * np.sin(ph) - 0.1, -0.1, 0.0])
    rot["RShoulder"] = np.array([-0.35 * np.sin(ph) - 0.1 - 1.0 * reach, 0.1 - 0.3 * reach, 0.0])
    rot["LElbow"] = np.array([-0.3 - 0.15 * (1.0 - np.sin(ph)), 0.0, 0.0])
    rot["RElbow"] = np.array([(-0.3 - 0.15 * (1.0 + np.sin(ph))) * (1.0 - 0.7 * reach), 0.0, 0.0])
    rot["LHip"] = np.array([-0.4 * np.sin(ph), 0.0, 0.0])
    rot["RHip"] = np.array([0.4 * np.sin(ph), 0.0, 0.0])
    rot["LKnee"] = np.array([0.3 * (1.0 + np.cos(ph)), 0.0, 0.0])
    rot["RKnee"] = np.array([0.3 * (1.0 - np.cos(ph)), 0.0, 0.0])
    return np.stack([rot[name] for name, _, _ in FIGURE_JOINTS])


#: Range of motion of the figure's training clip (rotation-vector components, radians; right
#: side mirrored, see :func:`joint_limits`): the ranges of figure.usda and figure_walk.usda
#: with at least 0.05 rad to spare on each side.
FIGURE_LIMITS = {
    "Hips": ((-0.1, 0.1), (-0.1, 0.1), (-0.15, 0.15)),
    "Spine": ((-0.1, 0.15), (-0.1, 0.1), (-0.4, 0.4)),
    "Chest": ((-0.15, 0.2), (-0.1, 0.1), (-0.1, 0.1)),
    "Neck": ((-0.25, 0.25), (-0.1, 0.1), (-0.45, 0.45)),
    "Shoulder": ((-1.6, 0.4), (-0.25, 0.85), (-0.1, 0.65)),
    "Elbow": ((-0.95, 0.0), (-0.1, 0.1), (-0.2, 0.2)),
    "Hip": ((-0.55, 0.55), (-0.2, 0.05), (-0.2, 0.2)),
    "Knee": ((-0.05, 0.75), (-0.05, 0.05), (-0.1, 0.1)),
}


def _lift_across(lift, across) -> np.ndarray:
    """A left shoulder's rotation vectors, (T, 3): the arm lifted forward by ``lift`` (about -x),
    then swung ``across`` (about +y: the hand towards the body's midline), per frame."""
    lift, across = np.broadcast_arrays(np.asarray(lift, np.float64), across)
    zero = np.zeros(lift.shape)
    swing = Rotation.from_rotvec(np.stack([zero, across, zero], -1))
    return (swing * Rotation.from_rotvec(np.stack([-lift, zero, zero], -1))).as_rotvec()


def _figure_idle(frames: int = 22) -> np.ndarray:
    """Standing idle: the weight shifts from leg to leg (hips tilting, the spine countering, the
    knees giving in turn), breathing, the arms hanging loosely, the head drifting."""
    m = _Motion(FIGURE_JOINTS, frames)
    ph = 2 * np.pi * m.t / frames
    s = np.sin(ph)
    m.add("Hips", 0.0, 0.06 * s, 0.04 * np.sin(ph + 1.2))
    m.add("Spine", 0.02, -0.05 * s, 0.0)
    m.add("Chest", 0.03 + 0.02 * np.sin(2 * ph), 0.0, 0.0)
    m.add("Neck", 0.06 * np.sin(ph + 2.0), 0.0, 0.12 * np.sin(ph + 0.7))
    for side, sign in (("L", 1.0), ("R", -1.0)):
        m.add("Shoulder", 0.06 * sign * s, -0.06, 0.03, side=side)
        m.add("Elbow", -0.15 - 0.05 * sign * s, side=side)
        m.add("Knee", 0.05 + 0.07 * (1.0 - sign * s), side=side)
        m.add("Hip", -0.03, 0.0, 0.03 * sign * s, side=side)
    return m.rot


def _figure_arm_swings(frames: int = 40) -> np.ndarray:
    """Arm swings with the legs still: the left arm's swing grows while the right one's shrinks,
    a little over a quarter cycle apart (not opposite), the cycle quickening; each arm swings
    back half as far as forward, the hand comes across towards the midline and the elbow bends
    as the arm comes forward; the torso twists with the left arm, the head a little against it,
    the chest and the knees bob with every swing. The swings start from and end at the arms
    hanging."""
    m = _Motion(FIGURE_JOINTS, frames)
    u = m.t / frames
    ph = 2 * np.pi * (m.t / 24.0 + 0.2 * u * u)  # 24 frames per swing at first, quicker later
    env = _bump(m.t, 0.0, 6.0, frames - 13.0, 6.0)
    for side, amp, lag in (("L", 0.35 + 0.6 * u, 0.0), ("R", 0.9 - 0.5 * u, 0.6 * np.pi)):
        fwd = np.sin(ph - lag)  # > 0: the arm is in front
        swing = env * amp * (0.75 * fwd + 0.25 * fwd * fwd)  # +amp forward, -amp / 2 back
        m.add("Shoulder", *_lift_across(0.2 + swing, 0.6 * np.maximum(swing, 0.0) - 0.05).T, side=side)
        m.add("Elbow", -0.25 - 0.35 * env * (0.5 + 0.5 * fwd), side=side)
    m.add("Spine", 0.0, 0.0, 0.25 * env * np.sin(ph))
    m.add("Chest", 0.04 + 0.06 * env * np.sin(2 * ph), 0.0, 0.04 * env * np.sin(ph))
    m.add("Neck", 0.05, 0.0, -0.1 * env * np.sin(ph))
    for side in "LR":  # the knees give a little with each swing
        m.add("Knee", 0.06 + 0.1 * env * (0.5 - 0.5 * np.cos(2 * ph)), side=side)
    return m.rot


def _figure_reaches(frames: int = 88) -> np.ndarray:
    """Four reaches of 22 frames, out and back: the left hand forward and up (looking up after
    it, leaning back), the right hand out to the side (turning towards it), the left hand across
    the body to the right (the torso twisting), the right hand down to the floor in front
    (bending at the spine and the knees); the free arm balances."""
    m = _Motion(FIGURE_JOINTS, frames)
    a, b, c, d = (_bump(m.t, frames / 4 * k + 1, 9.0, 3.0, 9.0) for k in range(4))
    # forward and up, left
    m.add("Shoulder", *_lift_across(1.5 * a, 0.1 * a).T, side="L")
    m.add("Elbow", -0.1 * a, side="L")
    m.add("Shoulder", 0.15 * a, -0.05 * a, side="R")
    m.add("Elbow", -0.3 * a, side="R")
    m.add("Spine", -0.07 * a, 0.0, 0.08 * a)
    m.add("Chest", -0.08 * a)
    m.add("Neck", -0.2 * a, 0.0, 0.12 * a)
    # out to the side, right
    m.add("Shoulder", -1.05 * b, -0.15 * b, 0.55 * b, side="R")
    m.add("Elbow", -0.15 * b, side="R")
    m.add("Shoulder", 0.1 * b, -0.1 * b, side="L")
    m.add("Elbow", -0.35 * b, side="L")
    m.add("Spine", 0.0, -0.05 * b, -0.2 * b)
    m.add("Neck", -0.05 * b, 0.0, -0.32 * b)
    m.add("Hips", 0.0, -0.05 * b, -0.06 * b)
    # across the body to the right, left
    m.add("Shoulder", *_lift_across(0.95 * c, 0.75 * c).T, side="L")
    m.add("Elbow", -0.5 * c, side="L")
    m.add("Shoulder", 0.12 * c, -0.12 * c, side="R")
    m.add("Elbow", -0.2 * c, side="R")
    m.add("Spine", 0.03 * c, 0.0, -0.28 * c)
    m.add("Chest", 0.05 * c, 0.0, -0.06 * c)
    m.add("Neck", 0.08 * c, 0.0, -0.18 * c)
    # down to the floor in front, right
    m.add("Shoulder", -0.6 * d, 0.08 * d, side="R")
    m.add("Elbow", -0.1 * d, side="R")
    m.add("Shoulder", -0.25 * d, -0.05 * d, side="L")
    m.add("Elbow", -0.45 * d, side="L")
    m.add("Hips", 0.08 * d)
    m.add("Spine", 0.14 * d)
    m.add("Chest", 0.19 * d)
    m.add("Neck", 0.22 * d)
    for side, knee in (("L", 0.45), ("R", 0.55)):
        m.add("Hip", -0.8 * knee * d, side=side)
        m.add("Knee", knee * d, side=side)
    return m.rot


def _figure_march(frames: int = 40) -> np.ndarray:
    """Marching in place, four steps of 10 frames (left, right, left, right) with the knee
    lifted 0.45, 0.75, 1 and 0.65 times the full lift (thigh 0.52 rad forward, knee 0.68 rad
    bent); the bent arms swing against the legs, the hips and spine turn with the lifted leg."""
    m = _Motion(FIGURE_JOINTS, frames)
    length = frames / 4.0
    step = np.minimum(m.t // length, 3).astype(int)
    lift = np.sin(np.pi * (m.t - length * step) / length) ** 2 * np.array([0.45, 0.75, 1.0, 0.65])[step]
    lifts = {"L": np.where(step % 2 == 0, lift, 0.0), "R": np.where(step % 2 == 1, lift, 0.0)}
    for side, other in (("L", "R"), ("R", "L")):
        m.add("Hip", -0.52 * lifts[side], 0.0, 0.0, side=side)
        m.add("Knee", 0.04 + 0.68 * lifts[side], side=side)
        m.add("Shoulder", 0.1 * lifts[side] - 0.55 * lifts[other], -0.06, 0.0, side=side)
        m.add("Elbow", -0.6 - 0.2 * lifts[other], side=side)
    turn = lifts["L"] - lifts["R"]
    m.add("Hips", 0.0, 0.04 * turn, 0.06 * turn)
    m.add("Spine", 0.03, 0.0, -0.12 * turn)
    m.add("Neck", -0.04, 0.0, 0.04 * turn)
    return m.rot


def _figure_swinging_walk(frames: int = 52) -> np.ndarray:
    """A walk in place that livens up: the stride (thighs +-0.2 rad at first, +-0.42 at the end)
    quickens from 44 frames, the arms swing against the legs ever wider (back half as far as
    forward), the left arm more than the right, each hand coming across in front; the spine
    counter-twists more and more; the walk stops over the last 8 frames."""
    m = _Motion(FIGURE_JOINTS, frames)
    u = m.t / frames
    ph = 2 * np.pi * (m.t / 44.0 + 0.12 * u * u)
    stop = 1.0 - _smoothstep((m.t - (frames - 9.0)) / 8.0)
    for side, sign, arm in (("L", 1.0, 0.25 + 0.7 * u), ("R", -1.0, 0.2 + 0.45 * u)):
        stride = sign * np.sin(ph) * stop  # > 0 while this leg swings forward
        m.add("Hip", -(0.2 + 0.22 * u) * stride, side=side)
        m.add("Knee", 0.05 + (0.3 + 0.3 * u) * stop * (0.5 + 0.5 * np.cos(ph - sign * 0.35)) ** 2, side=side)
        swing = arm * (0.75 * stride - 0.25 * stride * stride)  # < 0 while this arm swings forward
        m.add("Shoulder", *_lift_across(0.1 - swing, 0.4 * np.maximum(-swing, 0.0)).T, side=side)
        m.add("Elbow", -0.3 - (0.15 + 0.3 * u) * (0.5 - 0.5 * stride), side=side)
    m.add("Hips", 0.0, 0.03 * np.sin(ph) * stop, 0.06 * np.sin(ph) * stop)
    m.add("Spine", 0.05, 0.0, -(0.06 + 0.22 * u) * np.sin(ph) * stop)
    m.add("Chest", 0.04 + 0.02 * np.cos(2 * ph) * stop, 0.0, 0.0)
    m.add("Neck", 0.06, 0.0, 0.1 * np.sin(2 * np.pi * m.t / frames))
    return m.rot


def _figure_twist_and_bend(frames: int = 40) -> np.ndarray:
    """Holding the arms in front (as if carrying a box), the torso twists left and right while
    the chest bends forward and back twice as fast; the head keeps looking ahead."""
    m = _Motion(FIGURE_JOINTS, frames)
    hold = _bump(m.t, 0.0, 8.0, frames - 17.0, 8.0)
    turn = np.sin(2 * np.pi * m.t / frames)
    bend = np.sin(4 * np.pi * m.t / frames)
    for side in "LR":
        m.add("Shoulder", *_lift_across(0.95 * hold, 0.3 * hold).T, side=side)
        m.add("Elbow", -0.2 - 0.5 * hold, side=side)
    m.add("Spine", 0.02, 0.0, 0.35 * turn)
    m.add("Chest", 0.03 + 0.14 * bend, 0.0, 0.08 * turn)
    m.add("Hips", 0.0, 0.0, -0.08 * turn)
    m.add("Neck", -0.1 * bend, 0.0, -0.2 * turn)
    return m.rot


def _figure_head_looks(frames: int = 26) -> np.ndarray:
    """Looking around while standing: left, up, right, down and back (the spine turning a
    little with the head), the hands resting on the hips."""
    m = _Motion(FIGURE_JOINTS, frames)
    times = [0.0, 7.0, 12.0, 19.0, 25.0, 32.0]
    turn = m.keys(times, [0.0, 0.42, 0.3, -0.4, -0.15, 0.0])
    nod = m.keys(times, [0.0, 0.04, -0.22, -0.08, 0.22, 0.0])
    m.add("Neck", nod, 0.0, turn)
    m.add("Spine", 0.0, 0.0, 0.3 * turn)
    m.add("Chest", 0.05 * nod, 0.0, 0.05 * turn)
    hands = _bump(m.t, 0.0, 7.0, frames - 15.0, 7.0)
    for side in "LR":  # hands on the hips: upper arm out and back, elbow bent
        m.add("Shoulder", 0.25 * hands, -0.22 * hands, -0.05 * hands, side=side)
        m.add("Elbow", -0.2 - 0.7 * hands, 0.0, 0.1 * hands, side=side)
        m.add("Knee", 0.04, side=side)
    return m.rot


def _figure_step_and_look(frames: int = 34) -> np.ndarray:
    """A combined action: a slow step in place (one stride over the segment, thighs +-0.25 rad)
    with the left hand raised to head height in front (shading the eyes) while the head scans
    the horizon; the right arm swings."""
    m = _Motion(FIGURE_JOINTS, frames)
    ph = 2 * np.pi * m.t / frames
    shade = _bump(m.t, 0.0, 10.0, frames - 21.0, 10.0)
    for side, sign in (("L", 1.0), ("R", -1.0)):
        stride = sign * np.sin(ph)
        m.add("Hip", -0.25 * stride, side=side)
        m.add("Knee", 0.08 + 0.35 * np.maximum(0.0, np.sin(ph * sign + 0.6)), side=side)
    m.add("Shoulder", *_lift_across(1.35 * shade, 0.55 * shade).T, side="L")
    m.add("Elbow", -0.2 - 0.72 * shade, side="L")
    m.add("Shoulder", -0.2 * np.sin(ph) - 0.05, -0.1, side="R")
    m.add("Elbow", -0.35, side="R")
    m.add("Neck", -0.08 * shade, 0.0, 0.35 * np.sin(ph + 0.4) * shade)
    m.add("Spine", 0.0, 0.0, 0.1 * np.sin(ph))
    m.add("Hips", 0.0, 0.03 * np.sin(ph), 0.05 * np.sin(ph))
    return m.rot


#: The figure's motion library (after its range of motion in ``figure_train.usda``): segment
#: name, function, frames (consecutive segments overlap by LIBRARY_BLEND frames, see
#: :func:`training_clip`).
FIGURE_LIBRARY = [
    ("idle sway", _figure_idle, 22),
    ("arm swings", _figure_arm_swings, 40),
    ("reaches", _figure_reaches, 88),
    ("march", _figure_march, 40),
    ("swinging walk", _figure_swinging_walk, 52),
    ("twist and bend", _figure_twist_and_bend, 40),
    ("head looks", _figure_head_looks, 26),
    ("step and look", _figure_step_and_look, 34),
]
#: The figure's training clip: joint-local rotation vectors per frame, (600, 12, 3): the range of
#: motion (12 joints x SWEEP_FRAMES of sweeps, then 156 frames of all joints at once), then the
#: motion library (:func:`training_clip`).
FIGURE_TRAIN_CLIP = training_clip(
    joint_limits(FIGURE_JOINTS, FIGURE_LIMITS), 156, [make(frames) for _, make, frames in FIGURE_LIBRARY]
)


def _figure_skin_geometry():
    """Bind-pose (skeleton space) body points, faces, and 2-influence weights by joint name."""
    index = {name: k for k, (name, _, _) in enumerate(FIGURE_JOINTS)}
    parent = {name: p for name, p, _ in FIGURE_JOINTS}
    world = {}
    for name, par, off in FIGURE_JOINTS:
        world[name] = np.asarray(off, float) + (world[par] if par else 0.0)
    pts_all, counts_all, idx_all, infl_all, w_all = [], [], [], [], []
    base = 0
    for joint, (a, b), radius in FIGURE_CAPSULES:
        a = world[joint] + np.asarray(a)
        b = world[joint] + np.asarray(b)
        axis = b - a
        length = float(np.linalg.norm(axis))
        pts, counts, idx, _ = revolution(capsule_profile(length, radius), 14)
        # frame with +Z along the capsule axis
        z = axis / length
        helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = np.cross(helper, z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        s = pts[:, 2] / length  # 0 at a, 1 at b (caps beyond)
        pts = a + pts[:, :1] * x + pts[:, 1:2] * y + pts[:, 2:3] * z
        # Two influences: the capsule's joint, blended with a neighbour near the joints.
        own = np.full(len(pts), index[joint])
        other = own.copy()
        w_other = np.zeros(len(pts))
        if joint == "Spine":  # torso: hips below, chest above
            lower = s < 0.5
            other = np.where(lower, index["Hips"], index["Chest"])
            w_other = np.where(lower, 0.5 * np.clip(1.0 - s / 0.2, 0.0, 1.0), 0.6 * np.clip((s - 0.45) / 0.4, 0.0, 1.0))
        elif parent[joint] is not None and joint != "Neck":  # limbs blend with their parent
            other = np.full(len(pts), index[parent[joint]])
            w_other = 0.5 * np.clip(1.0 - s / 0.25, 0.0, 1.0)
        infl = np.stack([own, other], 1)
        w = np.stack([1.0 - w_other, w_other], 1)
        pts_all.append(pts)
        counts_all.append(counts)
        idx_all.append(idx + base)
        infl_all.append(infl)
        w_all.append(w)
        base += len(pts)
    return (
        np.concatenate(pts_all),
        np.concatenate(counts_all),
        np.concatenate(idx_all),
        np.concatenate(infl_all),
        np.concatenate(w_all),
    )


def _dress_figure(stage, skel, paths) -> None:
    """The figure's skinned body."""
    pts, counts, idx, infl, w = _figure_skin_geometry()
    # Author points in a local frame offset from skeleton space; geomBindTransform undoes it.
    body = _mesh(stage, "/World/Figure/Body", pts - FIGURE_GEOM_BIND_OFFSET, counts, idx, (0.78, 0.62, 0.5))
    # The mesh names the joints in its own (reversed) order; indices refer to that order.
    order = list(reversed(range(len(paths))))
    to_mesh_order = {k: i for i, k in enumerate(order)}
    mesh_infl = np.vectorize(to_mesh_order.get)(infl)
    geom_bind = Gf.Matrix4d().SetTranslate(Gf.Vec3d(*FIGURE_GEOM_BIND_OFFSET))
    _bind_skin(body, skel, mesh_infl, w, 2, geom_bind, joints=[paths[k] for k in order])


def _place_figure(root) -> None:
    root.AddTranslateOp().Set(Gf.Vec3d(*FIGURE_ROOT_TRANSLATE))
    root.AddRotateZOp().Set(FIGURE_ROOT_ROTATE_Z)


def _write_figure(out_dir: str, file_name: str, rotations, frame_count: int) -> str:
    """The figure (skeleton, skinned body, ground, sky, camera) in one clip."""
    return _write_character(
        out_dir, file_name, "/World/Figure", FIGURE_JOINTS, rotations, frame_count, _dress_figure,
        camera=((1.2, -3.8, 1.6), (0.3, -0.2, 1.0)), place=_place_figure,
    )


def make_figure(out_dir: str) -> str:
    return _write_figure(out_dir, "figure.usda", figure_joint_rotations, FRAME_COUNT)


def make_figure_train(out_dir: str) -> str:
    return _write_figure(out_dir, "figure_train.usda", FIGURE_TRAIN_CLIP.__getitem__, len(FIGURE_TRAIN_CLIP))


def make_figure_walk(out_dir: str) -> str:
    return _write_figure(out_dir, "figure_walk.usda", figure_walk_rotations, FIGURE_WALK_FRAMES)


# ---- (c) cloth ------------------------------------------------------------------------------
CLOTH_RESOLUTION = 30


def cloth_points(frame: int) -> np.ndarray:
    """The sheet's points at a frame (world space), shape (900, 3)."""
    n = CLOTH_RESOLUTION
    s = np.linspace(-1.0, 1.0, n)
    x, y = np.meshgrid(s, s, indexing="ij")
    t = frame / FRAME_COUNT
    phase = 2 * np.pi * t
    # Pinned along y = -1 (amplitude grows with distance), travelling waves and wrinkles.
    reach = (y + 1.0) / 2.0
    wave = 0.18 * reach * np.sin(2.2 * x + 3.0 * y - phase)
    wrinkles = 0.025 * reach * np.sin(9.0 * x + 1.5 * phase) * np.cos(7.0 * y - phase)
    sag = -0.35 * reach**2 * (0.8 + 0.2 * np.cos(phase))
    z = 1.1 + wave + wrinkles + sag
    # The free edge drifts in x a little as the wave passes.
    xs = x + 0.05 * reach * np.sin(phase + y)
    return np.stack([xs.ravel(), y.ravel(), z.ravel()], 1)


def make_cloth(out_dir: str) -> str:
    stage = _new_stage(animated=True)
    _sky(stage)
    _ground(stage)
    n = CLOTH_RESOLUTION
    pts0 = cloth_points(0)
    _, counts, idx = grid(n, 2.0)
    mesh = _mesh(stage, "/World/Cloth", pts0, counts, idx, (0.35, 0.55, 0.75))
    mesh.CreateDoubleSidedAttr(True)
    attr = mesh.GetPointsAttr()
    for f in range(FRAME_COUNT):
        attr.Set(_vec3f(cloth_points(f)), f)
    s = np.linspace(0.0, 1.0, n)
    u, v = np.meshgrid(s, s, indexing="ij")
    st_vertex = np.stack([u.ravel(), v.ravel()], 1)
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set(Vt.Vec2fArray.FromNumpy(_r(st_vertex[idx]).astype(np.float32)))
    _camera(stage, eye=(2.6, -3.2, 2.4), target=(0.0, 0.0, 0.8))
    path = os.path.join(out_dir, "cloth.usda")
    _save(stage, path)
    return path


# ---- (d) bend -------------------------------------------------------------------------------
BEND_JOINTS = [("Base", None, (0.0, 0.0, 0.0)), ("Mid1", "Base", (0.0, 0.0, 0.5)), ("Mid2", "Mid1", (0.0, 0.0, 0.5)), ("Tip", "Mid2", (0.0, 0.0, 0.5))]
BEND_HEIGHT = 2.0
BEND_RADIUS = 0.22


def bend_joint_rotations(frame: int) -> np.ndarray:
    """Joint-local rotation vectors of the bending cylinder at a frame, shape (4, 3)."""
    t = frame / (FRAME_COUNT - 1)
    bend = 0.55 * np.sin(np.pi * t)  # per joint, about x: the tube curls over
    twist = 0.6 * np.sin(2 * np.pi * t)  # per joint, about the local z axis
    rot = [np.zeros(3)]
    for _ in range(3):
        r = Rotation.from_rotvec([bend, 0.0, 0.0]) * Rotation.from_rotvec([0.0, 0.0, twist])
        rot.append(r.as_rotvec())
    return np.stack(rot)


def make_bend(out_dir: str) -> str:
    stage = _new_stage(animated=True)
    _sky(stage)
    UsdSkel.Root.Define(stage, "/World/Bend")
    skel, _ = _skeleton(stage, "/World/Bend", BEND_JOINTS, bend_joint_rotations, FRAME_COUNT)

    rings = 33
    profile = [(BEND_HEIGHT * k / (rings - 1), BEND_RADIUS) for k in range(rings)]
    pts, counts, idx, _ = revolution(profile, 24, cap_polygons=True)
    # Smooth two-joint weights: joint spacing 0.5, blend over the middle of each segment.
    seg = np.clip(pts[:, 2] / 0.5, 0.0, 3.0)
    lower = np.minimum(np.floor(seg), 2).astype(int)
    frac = seg - lower
    w_upper = np.clip((frac - 0.25) / 0.5, 0.0, 1.0)
    w_upper = w_upper * w_upper * (3 - 2 * w_upper)  # smoothstep
    infl = np.stack([lower, lower + 1], 1)
    w = np.stack([1.0 - w_upper, w_upper], 1)
    mesh = _mesh(stage, "/World/Bend/Tube", pts, counts, idx, (0.7, 0.7, 0.72))
    _bind_skin(mesh, skel, infl, w, 2, Gf.Matrix4d(1.0))
    _camera(stage, eye=(3.5, -3.5, 2.2), target=(0.0, 0.0, 1.0))
    path = os.path.join(out_dir, "bend.usda")
    _save(stage, path)
    return path


# ---- (e) wanderer ---------------------------------------------------------------------------
_THUMB_DIRECTION = np.array([-0.2, -0.5, -1.0]) / np.linalg.norm([-0.2, -0.5, -1.0])
#: Digits of the left hand: name, first joint's offset from the wrist, (first segment length,
#: direction); the right hand mirrors x. The palm faces the body (-x on the left hand), the
#: fingers hang down from its lower edge and the thumb leaves its front edge, pointing down,
#: forward and in.
WANDERER_DIGITS = [
    ("Thumb", (-0.01, -0.036, -0.03), (0.035, tuple(_THUMB_DIRECTION))),
    ("Index", (0.0, -0.026, -0.09), (0.045, (0.0, 0.0, -1.0))),
    ("Middle", (0.0, 0.0, -0.092), (0.048, (0.0, 0.0, -1.0))),
    ("Ring", (0.0, 0.026, -0.088), (0.042, (0.0, 0.0, -1.0))),
]
#: Length of each digit's second (tip) segment.
WANDERER_TIP_LENGTH = {"Thumb": 0.032, "Index": 0.036, "Middle": 0.038, "Ring": 0.034}


def _wanderer_joints():
    """(name, parent, rest offset) of the wanderer's 33 joints, parents first, left side before right."""
    joints = [
        ("Hips", None, (0.0, 0.0, 0.95)),
        ("Spine", "Hips", (0.0, 0.0, 0.12)),
        ("Chest", "Spine", (0.0, 0.0, 0.22)),
        ("Neck", "Chest", (0.0, 0.0, 0.2)),
        ("Head", "Neck", (0.0, 0.0, 0.1)),
    ]
    for side, sx in (("L", 1.0), ("R", -1.0)):
        joints += [
            (f"{side}Shoulder", "Chest", (0.2 * sx, 0.0, 0.14)),
            (f"{side}Elbow", f"{side}Shoulder", (0.0, 0.0, -0.28)),
            (f"{side}Wrist", f"{side}Elbow", (0.0, 0.0, -0.25)),
        ]
        for digit, base, first in WANDERER_DIGITS:
            first_offset = np.asarray(first[1]) * first[0] * np.array([sx, 1.0, 1.0])
            joints += [
                (f"{side}{digit}1", f"{side}Wrist", (base[0] * sx, base[1], base[2])),
                (f"{side}{digit}2", f"{side}{digit}1", tuple(first_offset)),
            ]
    for side, sx in (("L", 1.0), ("R", -1.0)):
        joints += [
            (f"{side}Hip", "Hips", (0.1 * sx, 0.0, -0.06)),
            (f"{side}Knee", f"{side}Hip", (0.0, 0.0, -0.42)),
            (f"{side}Ankle", f"{side}Knee", (0.0, 0.0, -0.39)),
        ]
    return joints


WANDERER_JOINTS = _wanderer_joints()
WANDERER_TEST_FRAMES = 120


def _wanderer_parts():
    """The body's tubes: (part name, :func:`tube` arguments, :func:`chain_weights` chain).

    Chains hold joint indices (skeleton order); the parts are built in the bind pose, from the
    joints' rest positions (rest rotations are identity).
    """
    index = {name: k for k, (name, _, _) in enumerate(WANDERER_JOINTS)}
    world = {}
    for name, par, off in WANDERER_JOINTS:
        world[name] = np.asarray(off, float) + (world[par] if par else 0.0)
    down = (0.0, 0.0, -1.0)
    parts = [
        # torso, neck and head in one tube along +z (s = height): hips, waist, chest, shoulders,
        # neck, jaw, skull; wider (x) than deep (y) below the neck
        (
            "Torso",
            dict(
                origin=(0.0, 0.0, 0.0),
                direction=(0.0, 0.0, 1.0),
                knots=[
                    (0.86, 0.13, 0.1), (0.95, 0.15, 0.11), (1.07, 0.13, 0.095), (1.2, 0.145, 0.1),
                    (1.32, 0.17, 0.11), (1.4, 0.185, 0.1), (1.46, 0.13, 0.075), (1.5, 0.055, 0.055),
                    (1.57, 0.055, 0.058), (1.61, 0.075, 0.085), (1.67, 0.095, 0.105), (1.72, 0.098, 0.105),
                    (1.77, 0.085, 0.09),
                ],
                around=48, rings=52, caps=(0.07, 0.04), cap_rings=6,
            ),
            [("Hips", 0.0, 0.0), ("Spine", 1.07, 0.06), ("Chest", 1.29, 0.08), ("Neck", 1.49, 0.06), ("Head", 1.59, 0.05)],
        ),
    ]
    for side in "LR":
        sx = 1.0 if side == "L" else -1.0
        parts += [
            (
                f"{side}Arm",  # shoulder to wrist, s = distance below the shoulder
                dict(
                    origin=world[f"{side}Shoulder"], direction=down,
                    knots=[(0.0, 0.055, 0.055), (0.1, 0.05, 0.05), (0.26, 0.04, 0.042), (0.29, 0.038, 0.04),
                           (0.4, 0.037, 0.035), (0.5, 0.027, 0.024), (0.53, 0.026, 0.02)],
                    around=24, rings=32, caps=(0.05, 0.015),
                ),
                [("Chest", 0.0, 0.0), (f"{side}Shoulder", 0.0, 0.04), (f"{side}Elbow", 0.28, 0.05), (f"{side}Wrist", 0.53, 0.02)],
            ),
            (
                f"{side}Palm",  # thin across x (the palm faces the body), wide along y
                dict(
                    origin=world[f"{side}Wrist"], direction=down,
                    knots=[(0.0, 0.014, 0.03), (0.04, 0.016, 0.042), (0.085, 0.013, 0.04)],
                    around=20, rings=12, caps=(0.012, 0.01),
                ),
                [(f"{side}Elbow", 0.0, 0.0), (f"{side}Wrist", 0.0, 0.03)],
            ),
            (
                f"{side}Leg",  # hip to ankle
                dict(
                    origin=world[f"{side}Hip"], direction=down,
                    knots=[(0.0, 0.085, 0.085), (0.12, 0.08, 0.08), (0.38, 0.058, 0.058), (0.42, 0.052, 0.054),
                           (0.52, 0.052, 0.058), (0.72, 0.04, 0.042), (0.81, 0.036, 0.036)],
                    around=28, rings=38, caps=(0.06, 0.03),
                ),
                [("Hips", 0.0, 0.0), (f"{side}Hip", 0.0, 0.06), (f"{side}Knee", 0.42, 0.05), (f"{side}Ankle", 0.81, 0.03)],
            ),
            (
                f"{side}Foot",  # heel to toe along -y, flat underneath
                dict(
                    origin=world[f"{side}Ankle"] + np.array([0.0, 0.05, -0.035]), direction=(0.0, -1.0, 0.0),
                    knots=[(0.0, 0.04, 0.04), (0.08, 0.045, 0.035), (0.21, 0.042, 0.022)],
                    around=24, rings=16, caps=(0.03, 0.02),
                ),
                [(f"{side}Ankle", 0.0, 0.0)],  # rigid
            ),
        ]
        for digit, _, (first_length, direction) in WANDERER_DIGITS:
            length = first_length + WANDERER_TIP_LENGTH[digit]
            parts.append(
                (
                    f"{side}{digit}",
                    dict(
                        origin=world[f"{side}{digit}1"], direction=np.asarray(direction) * (sx, 1.0, 1.0),
                        knots=[(0.0, 0.011, 0.011), (first_length, 0.0095, 0.0095), (length, 0.0085, 0.0085)],
                        around=10, rings=10, caps=(0.009, 0.008), cap_rings=3,
                    ),
                    [(f"{side}Wrist", 0.0, 0.0), (f"{side}{digit}1", 0.0, 0.025), (f"{side}{digit}2", first_length, 0.025)],
                )
            )
    return [(name, args, [(index[j], start, half) for j, start, half in chain]) for name, args, chain in parts]


#: Share of the shoulder joint in the torso's skin over each shoulder (the top of the chest next
#: to the arm follows a raised arm part of the way).
WANDERER_SHOULDER_SHARE = 0.4


def _wanderer_body():
    """Bind-pose (skeleton space) body points, faces, and 4-influence weights (skeleton order)."""
    index = {name: k for k, (name, _, _) in enumerate(WANDERER_JOINTS)}
    pts_all, counts_all, idx_all, infl_all, w_all = [], [], [], [], []
    base = 0
    for name, args, chain in _wanderer_parts():
        pts, counts, idx, s = tube(**args)
        joints = [c[0] for c in chain]
        w = chain_weights(s, chain)
        if name == "Torso":  # blend in the shoulder on either side over the top of the chest
            lateral = _smoothstep((np.abs(pts[:, 0]) - 0.08) / 0.09)
            band = _smoothstep((pts[:, 2] - 1.33) / 0.08) * (1.0 - _smoothstep((pts[:, 2] - 1.45) / 0.05))
            share = WANDERER_SHOULDER_SHARE * lateral * band
            shoulder = np.where(pts[:, 0] > 0.0, index["LShoulder"], index["RShoulder"])
            joints = np.concatenate([np.broadcast_to(joints, w.shape), shoulder[:, None]], 1)
            w = np.concatenate([w * (1.0 - share[:, None]), share[:, None]], 1)
        infl, w = strongest_influences(joints, w, 4)
        pts_all.append(pts)
        counts_all.append(counts)
        idx_all.append(idx + base)
        infl_all.append(infl)
        w_all.append(w)
        base += len(pts)
    return tuple(np.concatenate(a) for a in (pts_all, counts_all, idx_all, infl_all, w_all))


#: The hat's profile (r, z above the brim's base), a closed surface of revolution from the
#: ceiling inside the crown out along the underside of the brim and back over the top.
WANDERER_HAT_BASE = 1.745  # skeleton-space height of the brim where it meets the crown
WANDERER_HAT_PROFILE = [
    (0.0, 0.068), (0.05, 0.068), (0.09, 0.062), (0.1, 0.045), (0.1, 0.02), (0.1, 0.0), (0.13, -0.003),
    (0.17, -0.007), (0.21, -0.011), (0.25, -0.016), (0.29, -0.021), (0.33, -0.026), (0.37, -0.031),
    (0.41, -0.036), (0.44, -0.04), (0.448, -0.033), (0.44, -0.026), (0.41, -0.022), (0.37, -0.017),
    (0.33, -0.012), (0.29, -0.007), (0.25, -0.002), (0.21, 0.003), (0.17, 0.008), (0.13, 0.012),
    (0.112, 0.018), (0.114, 0.05), (0.115, 0.09), (0.108, 0.115), (0.085, 0.133), (0.05, 0.142), (0.0, 0.145),
]


def _wanderer_hat():
    """The hat's points (skeleton space, bind pose: on the head), counts and indices."""
    profile = [(z, 0.0 if k in (0, len(WANDERER_HAT_PROFILE) - 1) else 1.0) for k, (_, z) in enumerate(WANDERER_HAT_PROFILE)]
    pts, counts, idx, ring_of = revolution(profile, 56)
    radius = np.array([r for r, _ in WANDERER_HAT_PROFILE])[ring_of]
    pts[:, :2] *= radius[:, None]
    pts[:, 2] += WANDERER_HAT_BASE
    return pts, counts, idx


def wanderer_test_rotations(frame: int) -> np.ndarray:
    """Joint-local rotation vectors of the wanderer's test clip at a frame, shape (33, 3).

    120 frames: the wanderer walks in place (strides of 32 frames, arms swinging against the
    legs; fading out over frames 36-52), raises the right hand to the front of the hat's brim,
    grips it and looks up (frames 36-86), then bows with the hands together in front of the
    chest and straightens again (frames 76-118); the head turns from side to side throughout.
    The hat's shadow sweeps over the face, shoulders and chest as the head turns, tilts and
    bows, and the raised arm shadows the face.
    """
    t = float(frame)
    ph = 2 * np.pi * t / 32.0
    walk = 1.0 - _smoothstep((t - 36.0) / 16.0)
    reach = _smoothstep((t - 36.0) / 16.0) * (1.0 - _smoothstep((t - 72.0) / 14.0))
    bow = _smoothstep((t - 76.0) / 16.0) * (1.0 - _smoothstep((t - 104.0) / 14.0))
    rot = {name: np.zeros(3) for name, _, _ in WANDERER_JOINTS}

    def add(name, value, weight=1.0):
        rot[name] = rot[name] + weight * np.asarray(value, dtype=np.float64)

    add("Hips", [0.0, 0.03 * np.sin(ph), 0.07 * np.sin(ph)], walk)
    add("Spine", [0.03, 0.0, -0.12 * np.sin(ph)], walk)
    add("Chest", [0.04 + 0.02 * np.cos(2 * ph), 0.0, 0.0], walk)
    add("Head", [0.0, 0.0, 0.35 * np.sin(2 * np.pi * t / 80.0)])
    add("Neck", [0.05 * np.sin(2 * np.pi * t / 60.0), 0.0, 0.1 * np.sin(2 * np.pi * t / 80.0 - 0.5)])
    for side, lateral in (("L", 1.0), ("R", -1.0)):  # lateral: the sign of y and z on this side
        stride = lateral * np.sin(ph)  # > 0 while this side's leg swings forward
        swing = lateral * np.cos(ph)
        add(f"{side}Hip", [-0.38 * stride, 0.0, 0.0], walk)
        add(f"{side}Knee", [0.3 * (1.0 + swing), 0.0, 0.0], walk)
        add(f"{side}Ankle", [0.15 * np.sin(lateral * ph + 1.0), 0.0, 0.0], walk)
        add(f"{side}Shoulder", [0.32 * stride, -0.08 * lateral, 0.0], walk)
        add(f"{side}Elbow", [-0.2, 0.0, 0.0])
        add(f"{side}Elbow", [-0.1 * (1.0 - stride), 0.0, 0.0], walk)
        add(f"{side}Thumb1", [0.1, 0.1 * lateral, 0.0])
        add(f"{side}Thumb2", [0.0, 0.15 * lateral, 0.0])
        for digit in ("Index", "Middle", "Ring"):  # relaxed fingers curl a little towards the palm
            add(f"{side}{digit}1", [0.0, 0.15 * lateral, 0.0])
            add(f"{side}{digit}2", [0.0, 0.2 * lateral, 0.0])
        # the bow: hands together in front of the chest
        add(f"{side}Shoulder", [-0.45, 0.3 * lateral, 0.0], bow)
        add(f"{side}Elbow", [-1.0, 0.0, 0.1 * lateral], bow)
        add(f"{side}Knee", [0.08, 0.0, 0.0], bow)
    # the reach: right hand up to the front of the brim, fingers gripping it, looking up
    add("RShoulder", [-1.8, -0.35, 0.0], reach)
    add("RElbow", [-0.9, 0.0, 0.0], reach)
    add("RWrist", [0.4, 0.0, 0.0], reach)
    add("RThumb1", [-0.3, -0.3, 0.0], reach)
    add("RThumb2", [0.0, -0.4, 0.0], reach)
    for k, digit in enumerate(("Index", "Middle", "Ring")):
        add(f"R{digit}1", [0.0, -0.6 - 0.05 * k, 0.0], reach)
        add(f"R{digit}2", [0.0, -0.75, 0.0], reach)
    add("Neck", [-0.12, 0.0, 0.0], reach)
    add("Head", [-0.1, 0.0, 0.0], reach)
    add("Spine", [0.2, 0.0, 0.0], bow)
    add("Chest", [0.2, 0.0, 0.0], bow)
    add("Neck", [0.12, 0.0, 0.0], bow)
    add("Head", [0.12, 0.0, 0.0], bow)
    return np.stack([rot[name] for name, _, _ in WANDERER_JOINTS])


_FINGER_LIMITS = (((-0.1, 0.1), (-0.15, 1.0), (-0.1, 0.1)), ((-0.05, 0.05), (-0.05, 1.1), (-0.05, 0.05)))
#: Range of motion of the wanderer's training clip (left side; see :func:`joint_limits`): the
#: ranges of wanderer_test.usdc with at least 0.05 rad to spare, and every joint's other
#: components over a small plausible range. Fingers curl about +y on the left hand.
WANDERER_LIMITS = {
    "Hips": ((-0.1, 0.1), (-0.1, 0.1), (-0.15, 0.15)),
    "Spine": ((-0.1, 0.3), (-0.1, 0.1), (-0.2, 0.2)),
    "Chest": ((-0.1, 0.3), (-0.1, 0.1), (-0.15, 0.15)),
    "Neck": ((-0.25, 0.2), (-0.1, 0.1), (-0.2, 0.2)),
    "Head": ((-0.2, 0.2), (-0.1, 0.1), (-0.45, 0.45)),
    "Shoulder": ((-1.95, 0.45), (-0.2, 0.5), (-0.15, 0.15)),
    "Elbow": ((-1.35, 0.0), (-0.1, 0.1), (-0.15, 0.25)),
    "Wrist": ((-0.4, 0.55), (-0.25, 0.25), (-0.2, 0.2)),
    "Thumb1": ((-0.35, 0.25), (-0.05, 0.55), (-0.15, 0.15)),
    "Thumb2": ((-0.1, 0.1), (-0.05, 0.7), (-0.1, 0.1)),
    "Index1": _FINGER_LIMITS[0],
    "Index2": _FINGER_LIMITS[1],
    "Middle1": _FINGER_LIMITS[0],
    "Middle2": _FINGER_LIMITS[1],
    "Ring1": _FINGER_LIMITS[0],
    "Ring2": _FINGER_LIMITS[1],
    "Hip": ((-0.5, 0.5), (-0.2, 0.1), (-0.2, 0.2)),
    "Knee": ((-0.05, 0.8), (-0.05, 0.05), (-0.1, 0.1)),
    "Ankle": ((-0.3, 0.3), (-0.1, 0.1), (-0.15, 0.15)),
}


#: The fingers of each hand (the thumb apart).
_WANDERER_FINGERS = ("Index", "Middle", "Ring")
#: Curl of the wanderer's fingers at rest in the motion library (see :func:`_wanderer_hand`).
WANDERER_RELAXED_CURL = 0.42


def _wanderer_hand(m: _Motion, side: str, curl, thumb=None, spread=0.0) -> None:
    """One hand's fingers: ``curl`` (scalar or per frame: -0.05 stretched, 0 straight, 1 a fist)
    for all three fingers, or a dict per finger; the ring finger curls a little more than the
    middle and the middle than the index; ``thumb`` (default with the fingers) folds the
    thumb in, ``spread`` fans the fingers apart (about z)."""
    curls = curl if isinstance(curl, dict) else dict.fromkeys(_WANDERER_FINGERS, curl)
    for k, digit in enumerate(_WANDERER_FINGERS):
        c = np.asarray(curls[digit], np.float64) + 0.03 * k * np.clip(curls[digit], 0.0, 1.0)
        m.add(f"{digit}1", 0.0, 0.9 * c, 0.07 * (k - 1) * np.asarray(spread), side=side)
        m.add(f"{digit}2", 0.0, c, side=side)
    t = 0.1 + 0.6 * np.asarray(curls["Middle"]) if thumb is None else np.asarray(thumb, np.float64)
    m.add("Thumb1", 0.12 - 0.4 * t, 0.45 * t, 0.0, side=side)
    m.add("Thumb2", 0.0, 0.6 * t, side=side)


def _wanderer_walk(frames, period, stride, knee, ankle, arm, elbow, lean, curl, look) -> np.ndarray:
    """A walk in place from standing and back to standing (starting and stopping over 8 frames):
    strides of ``period`` frames, thighs +-``stride``, knees bending by up to ``knee`` as each
    leg swings through, ankles +-``ankle``, arms swinging +-``arm`` against the legs with the
    elbows at ``elbow`` = (bend, more as the arm comes forward), the spine leaning ``lean``
    forward, the hands curled ``curl``, the head turning +-``look`` once over the clip."""
    m = _Motion(WANDERER_JOINTS, frames)
    ph = 2 * np.pi * m.t / period
    go = _bump(m.t, 0.0, 8.0, frames - 17.0, 8.0)
    for side, lateral in (("L", 1.0), ("R", -1.0)):
        forward = lateral * np.sin(ph) * go  # > 0 while this leg swings forward
        m.add("Hip", -stride * forward, side=side)
        m.add("Knee", 0.04 + knee * go * (0.5 + 0.5 * lateral * np.cos(ph - 0.35)) ** 1.5, side=side)
        m.add("Ankle", ankle * go * np.sin(lateral * ph + 1.6), side=side)
        m.add("Shoulder", arm * forward - 0.05, -0.05, 0.03, side=side)
        m.add("Elbow", elbow[0] - elbow[1] * (0.5 - 0.5 * forward), side=side)
        m.add("Wrist", 0.08, 0.0, 0.0, side=side)
        _wanderer_hand(m, side, curl + 0.05 * np.sin(2 * np.pi * m.t / 37.0 + lateral))
    m.add("Hips", 0.0, 0.025 * np.sin(ph) * go, 0.16 * stride * np.sin(ph) * go)
    m.add("Spine", lean, 0.0, -0.3 * stride * np.sin(ph) * go)
    m.add("Chest", 0.02 + 0.015 * np.cos(2 * ph) * go)
    m.add("Neck", 0.1 - lean, 0.0, 0.3 * look * np.sin(2 * np.pi * m.t / frames + 0.5))
    m.add("Head", 0.0, 0.0, look * np.sin(2 * np.pi * m.t / frames + 0.5))
    return m.rot


def _wanderer_slow_walk(frames: int = 54) -> np.ndarray:
    """An unhurried walk, 40 frames a stride, short steps, the arms hanging and swinging little,
    the hands loosely open, looking down at the path and slowly around."""
    return _wanderer_walk(frames, 40.0, 0.24, 0.4, 0.1, 0.18, (-0.42, 0.12), 0.0, 0.22, 0.25)


def _wanderer_fast_walk(frames: int = 48) -> np.ndarray:
    """A brisk walk, 22 frames a stride, long steps with high knees, bent arms pumping, the body
    leaning forward, loose fists, eyes ahead."""
    return _wanderer_walk(frames, 22.0, 0.46, 0.72, 0.22, 0.42, (-0.75, 0.3), 0.12, 0.55, 0.06)


def _wanderer_reaches(frames: int = 110) -> np.ndarray:
    """Five reaches of 22 frames, out and back, without touching the hat: the left hand forward
    at chest height (leaning after it), the right hand out to the side (turning to look), the
    left hand straight up (looking up after it, leaning back), the right hand flat to the chest
    (looking down at it), the right hand up to a high shelf, gripping something there and
    bringing it down; the reaching hand opens, the free arm balances."""
    m = _Motion(WANDERER_JOINTS, frames)
    a, b, c, d, e = (_bump(m.t, frames / 5 * k + 1, 9.0, 2.0, 9.0) for k in range(5))
    grip = _smoothstep((m.t - (frames * 4 / 5 + 8.0)) / 4.0)  # closes on the thing on the shelf
    # forward, left
    m.add("Shoulder", -1.35 * a, 0.12 * a, 0.0, side="L")
    m.add("Elbow", -0.3 + 0.18 * a - 0.2 * c, side="L")
    m.add("Wrist", 0.15 * a, side="L")
    m.add("Shoulder", 0.15 * a, side="R")
    m.add("Spine", 0.1 * a)
    m.add("Chest", 0.06 * a)
    for side in "LR":
        m.add("Knee", 0.08 * a, side=side)
    # out to the side, right
    m.add("Shoulder", -0.6 * b, -0.2 * b, 0.15 * b, side="R")
    m.add("Elbow", -0.3 + 0.1 * b - 1.0 * d + 0.15 * e, side="R")
    m.add("Wrist", 0.0, 0.2 * b, side="R")
    m.add("Shoulder", 0.1 * b, -0.1 * b, side="L")
    m.add("Head", 0.0, 0.0, -0.4 * b)
    m.add("Neck", 0.0, 0.0, -0.15 * b)
    m.add("Spine", 0.0, 0.0, -0.15 * b)
    # up, left
    m.add("Shoulder", -1.9 * c, -0.12 * c, 0.1 * c, side="L")
    m.add("Wrist", -0.3 * c, side="L")
    m.add("Shoulder", 0.12 * c, side="R")
    m.add("Elbow", -0.2 * c, side="R")
    m.add("Neck", -0.2 * c)
    m.add("Head", -0.16 * c)
    m.add("Spine", -0.08 * c)
    m.add("Chest", -0.06 * c)
    # flat to the chest, right
    m.add("Shoulder", -0.4 * d, 0.45 * d, 0.0, side="R")
    m.add("Wrist", -0.2 * d, side="R")
    m.add("Shoulder", 0.05 * d, side="L")
    m.add("Neck", 0.12 * d)
    m.add("Head", 0.0, 0.0, -0.1 * d)
    # up to the shelf, right
    m.add("Shoulder", -1.88 * e, 0.02 * e, -0.05 * e, side="R")
    m.add("Wrist", 0.2 * e, side="R")
    m.add("Shoulder", 0.1 * e, -0.08 * e, side="L")
    m.add("Elbow", -0.15 * e, side="L")
    m.add("Neck", -0.15 * e, 0.0, -0.05 * e)
    m.add("Head", -0.12 * e)
    m.add("Spine", -0.05 * e)
    m.add("Head", 0.0, 0.0, 0.15 * np.sin(2 * np.pi * m.t / frames))
    loose = 0.25  # the hands hang loosely open between the reaches
    _wanderer_hand(m, "L", loose - (loose + 0.05) * (a + c), spread=a + c)
    opened = b + e * (1.0 - grip)  # the right hand opens out to the side and up to the shelf
    _wanderer_hand(m, "R", loose - (loose + 0.05) * opened - 0.1 * d + 0.6 * grip, spread=b)
    return m.rot


def _wanderer_pick_up(frames: int = 46) -> np.ndarray:
    """Picking something up from the floor: knees and hips bend, the back bows, the right hand
    reaches down open, grips, and carries the thing up to the waist, the left hand on the knee;
    the eyes on the thing."""
    m = _Motion(WANDERER_JOINTS, frames)
    b = m.keys([0.0, 15.0, 23.0, 40.0, 50.0], [0.0, 1.0, 1.0, 0.0, 0.0])
    carry = m.keys([0.0, 22.0, 34.0, 50.0], [0.0, 0.0, 1.0, 1.0])
    grip = m.keys([0.0, 15.0, 21.0, 50.0], [0.0, 0.0, 1.0, 1.0])
    m.add("Hips", 0.08 * b)
    m.add("Spine", 0.28 * b)
    m.add("Chest", 0.26 * b)
    m.add("Neck", 0.16 * b)
    m.add("Head", 0.08 * b, 0.0, -0.25 * b - 0.1 * carry)
    for side, depth in (("L", 1.0), ("R", 0.9)):
        m.add("Hip", -0.45 * depth * b, side=side)
        m.add("Knee", 0.72 * depth * b, side=side)
        m.add("Ankle", -0.27 * depth * b, side=side)
    m.add("Shoulder", -0.7 * b * (1.0 - carry) - 0.5 * carry, 0.1, 0.0, side="R")
    m.add("Elbow", -0.3 + 0.2 * b - 0.75 * carry, side="R")
    m.add("Wrist", 0.2 * b, side="R")
    m.add("Shoulder", -0.35 * b, 0.1 * b, side="L")
    m.add("Elbow", -0.3 - 0.2 * b, side="L")
    reaching = b * (1.0 - grip)  # the right hand open on the way down, until it grips
    r = WANDERER_RELAXED_CURL
    _wanderer_hand(m, "R", r - (r + 0.05) * reaching + 0.55 * grip, spread=reaching)
    _wanderer_hand(m, "L", WANDERER_RELAXED_CURL)
    return m.rot


def _wanderer_look_around(frames: int = 40) -> np.ndarray:
    """Standing with the hands clasped behind the back, looking left, up, right, down and back
    (the neck and a little of the spine turning with the head), then leaning forward to peer at
    the ground in front and straightening again."""
    m = _Motion(WANDERER_JOINTS, frames)
    times = [0.0, 7.0, 12.0, 19.0, 25.0, 31.0, 40.0]
    turn = m.keys(times, [0.0, 0.42, 0.42, -0.42, -0.2, 0.1, 0.0])
    m.add("Head", m.keys(times, [0.0, 0.0, -0.16, 0.02, 0.15, 0.1, 0.0]), 0.0, turn)
    nod = m.keys(times, [0.0, 0.05, -0.22, -0.1, 0.18, 0.15, 0.0])
    lean = m.keys([0.0, 24.0, 31.0, 34.0, 40.0], [0.0, 0.0, 1.0, 1.0, 0.0])
    m.add("Neck", nod, 0.0, 0.35 * turn)
    m.add("Spine", 0.2 * lean, 0.0, 0.25 * turn)
    m.add("Chest", 0.05 * nod + 0.18 * lean)
    hands = _bump(m.t, 0.0, 8.0, frames - 17.0, 8.0)
    for side in "LR":
        m.add("Shoulder", 0.35 * hands, 0.15 * hands, 0.0, side=side)
        m.add("Elbow", -0.3 - 0.25 * hands, side=side)
        m.add("Wrist", 0.2 * hands, side=side)
        _wanderer_hand(m, side, WANDERER_RELAXED_CURL + 0.1 * hands)
    return m.rot


def _wanderer_wave(frames: int = 36) -> np.ndarray:
    """Waving with the right hand raised and open: first the forearm and wrist rocking from side
    to side (10 frames a wave), then the arm higher, the hand above the front of the brim,
    flapping at the wrist; the head tilts towards whoever is greeted."""
    m = _Motion(WANDERER_JOINTS, frames)
    raise_ = m.keys([0.0, 8.0, 28.0, 36.0], [0.0, 1.0, 1.0, 0.0])
    high = m.keys([0.0, 14.0, 20.0, 36.0], [0.0, 0.0, 1.0, 1.0]) * raise_
    w = raise_ * np.sin(2 * np.pi * (m.t - 8.0) / 10.0)
    m.add("Shoulder", -1.45 * raise_ - 0.35 * high, -0.15 * raise_ + 0.35 * high, 0.1 * w * (1.0 - high), side="R")
    m.add("Elbow", -0.3 - 0.75 * raise_ + 0.05 * high, 0.0, 0.12 * w * (1.0 - high), side="R")
    m.add("Wrist", -0.15 * raise_ + high * (0.3 + 0.25 * w), 0.0, 0.18 * w * (1.0 - high), side="R")
    m.add("Shoulder", 0.05, side="L")
    m.add("Elbow", -0.32, side="L")
    m.add("Head", 0.0, 0.07 * raise_, -0.18 * raise_)
    m.add("Neck", -0.05 * raise_)
    m.add("Spine", 0.0, -0.04 * raise_, 0.0)
    m.add("Hips", 0.0, 0.03 * raise_, 0.0)
    _wanderer_hand(m, "R", WANDERER_RELAXED_CURL - (WANDERER_RELAXED_CURL + 0.05) * raise_, spread=raise_)
    _wanderer_hand(m, "L", 0.25)
    return m.rot


def _wanderer_gestures(frames: int = 50) -> np.ndarray:
    """Hand gestures in front of the body, watched, leaning over them a little: the left hand
    opens and closes into a fist three times, the wrist turning; the right hand points with the
    index finger, then counts (middle and ring finger stretching out in turn, then the thumb)."""
    m = _Motion(WANDERER_JOINTS, frames)
    arms = m.keys([0.0, 8.0, 52.0, 60.0], [0.0, 1.0, 1.0, 0.0])
    m.add("Shoulder", -0.35 * arms, 0.15 * arms, 0.0, side="L")
    m.add("Elbow", -0.3 - 0.9 * arms, side="L")
    turn = arms * np.sin(2 * np.pi * m.t / 23.0)
    m.add("Wrist", 0.1 * np.sin(2 * np.pi * m.t / 30.0) * arms, 0.15 * arms, 0.12 * turn, side="L")
    m.add("Shoulder", -0.5 * arms, 0.1 * arms, 0.0, side="R")
    m.add("Elbow", -0.3 - 0.75 * arms, side="R")
    m.add("Wrist", 0.2 * arms, -0.1 * np.sin(2 * np.pi * m.t / 27.0) * arms, 0.0, side="R")
    rest = 0.1 + 0.6 * WANDERER_RELAXED_CURL  # the thumb of a relaxed hand
    fist = 0.5 - 0.5 * np.cos(6 * np.pi * m.t / (frames - 1))  # 0 open ... 1 closed, three times
    curl = WANDERER_RELAXED_CURL + arms * (1.05 * fist - 0.05 - WANDERER_RELAXED_CURL)
    _wanderer_hand(m, "L", curl, thumb=rest + arms * (0.7 * fist - rest), spread=arms * (1.0 - fist))
    r = WANDERER_RELAXED_CURL
    pointing = {
        "Index": m.keys([0.0, 6.0, 50.0, 60.0], [r, 0.0, 0.0, r]),
        "Middle": m.keys([0.0, 6.0, 34.0, 39.0, 54.0, 60.0], [r, 0.95, 0.95, 0.0, 0.0, r]),
        "Ring": m.keys([0.0, 6.0, 41.0, 46.0, 54.0, 60.0], [r, 0.95, 0.95, 0.0, 0.0, r]),
    }
    _wanderer_hand(m, "R", pointing, thumb=m.keys([0.0, 6.0, 48.0, 53.0, 60.0], [rest, 0.7, 0.7, 0.0, rest]))
    m.add("Spine", 0.16 * arms)
    m.add("Chest", 0.14 * arms)
    m.add("Neck", 0.15 * arms)
    m.add("Head", 0.05 * arms, 0.0, 0.12 * np.sin(2 * np.pi * m.t / frames))
    return m.rot


def _wanderer_shrug(frames: int = 30) -> np.ndarray:
    """A shrug: elbows bent, forearms out and palms up, hands open, the chest lifting, the head
    tilting."""
    m = _Motion(WANDERER_JOINTS, frames)
    s = m.keys([0.0, 9.0, 17.0, 30.0], [0.0, 1.0, 1.0, 0.0])
    for side in "LR":
        m.add("Shoulder", -0.2 * s, -0.18 * s, -0.1 * s, side=side)
        m.add("Elbow", -0.3 - 0.65 * s, 0.0, 0.2 * s, side=side)
        m.add("Wrist", -0.35 * s, 0.15 * s, 0.0, side=side)
        _wanderer_hand(m, side, WANDERER_RELAXED_CURL - (WANDERER_RELAXED_CURL + 0.05) * s, spread=s)
    m.add("Neck", -0.05 * s)
    m.add("Head", 0.0, 0.08 * s, 0.25 * np.sin(2 * np.pi * m.t / frames + 2.0))
    m.add("Chest", -0.08 * s)
    m.add("Spine", -0.03 * s)
    return m.rot


def _wanderer_crouch(frames: int = 34) -> np.ndarray:
    """Crouching down and rising: hips and knees deeply bent (the feet kept flat), the back
    bent forward, the arms forward for balance, the head up and turning."""
    m = _Motion(WANDERER_JOINTS, frames)
    c = m.keys([0.0, 14.0, 26.0, 40.0], [0.0, 1.0, 1.0, 0.0])
    m.add("Hips", 0.06 * c)
    m.add("Spine", 0.22 * c)
    m.add("Chest", 0.1 * c)
    m.add("Neck", -0.15 * c)
    m.add("Head", -0.05 * c, 0.0, 0.2 * np.sin(2 * np.pi * m.t / frames))
    for side, depth in (("L", 1.0), ("R", 0.96)):
        m.add("Hip", -0.48 * depth * c, 0.0, 0.1 * c, side=side)
        m.add("Knee", 0.78 * depth * c, side=side)
        m.add("Ankle", -0.28 * c, side=side)
        m.add("Shoulder", -0.95 * c, 0.15 * c, 0.0, side=side)
        m.add("Elbow", -0.3 - 0.15 * c, side=side)
        m.add("Wrist", 0.1 * c, side=side)
        _wanderer_hand(m, side, WANDERER_RELAXED_CURL)
    return m.rot


#: The wanderer's motion library (after its range of motion in ``wanderer_train.usdc``): segment
#: name, function, frames (consecutive segments overlap by LIBRARY_BLEND frames, see
#: :func:`training_clip`).
WANDERER_LIBRARY = [
    ("slow walk", _wanderer_slow_walk, 54),
    ("brisk walk", _wanderer_fast_walk, 48),
    ("reaches", _wanderer_reaches, 110),
    ("pick up", _wanderer_pick_up, 46),
    ("look around", _wanderer_look_around, 40),
    ("wave", _wanderer_wave, 36),
    ("hand gestures", _wanderer_gestures, 50),
    ("shrug", _wanderer_shrug, 30),
    ("crouch", _wanderer_crouch, 34),
]
#: The wanderer's training clip: joint-local rotation vectors per frame, (1000, 33, 3): the range
#: of motion (33 joints x SWEEP_FRAMES of sweeps, then 204 frames of all joints at once), then the
#: motion library (:func:`training_clip`).
WANDERER_TRAIN_CLIP = training_clip(
    joint_limits(WANDERER_JOINTS, WANDERER_LIMITS), 204, [make(frames) for _, make, frames in WANDERER_LIBRARY]
)


def _dress_wanderer(stage, skel, paths) -> None:
    """The wanderer's skinned body and the hat, rigidly on the head joint."""
    pts, counts, idx, infl, w = _wanderer_body()
    body = _mesh(stage, "/World/Wanderer/Body", pts, counts, idx, (0.62, 0.45, 0.34))
    _bind_skin(body, skel, infl, w, 4, Gf.Matrix4d(1.0))
    pts, counts, idx = _wanderer_hat()
    hat = _mesh(stage, "/World/Wanderer/Hat", pts, counts, idx, (0.82, 0.72, 0.45))
    head = [p for p in paths if p.endswith("/Head")]
    _bind_skin(hat, skel, [0], [1.0], 1, Gf.Matrix4d(1.0), joints=head, constant=True)


def _write_wanderer(out_dir: str, file_name: str, rotations, frame_count: int) -> str:
    """The wanderer (skeleton, skinned body, hat, ground, sky, camera) in one clip."""
    return _write_character(
        out_dir, file_name, "/World/Wanderer", WANDERER_JOINTS, rotations, frame_count, _dress_wanderer,
        camera=((1.3, -3.2, 1.6), (0.0, 0.0, 1.0)),
    )


def make_wanderer_train(out_dir: str) -> str:
    return _write_wanderer(out_dir, "wanderer_train.usdc", WANDERER_TRAIN_CLIP.__getitem__, len(WANDERER_TRAIN_CLIP))


def make_wanderer_test(out_dir: str) -> str:
    return _write_wanderer(out_dir, "wanderer_test.usdc", wanderer_test_rotations, WANDERER_TEST_FRAMES)


def make_figure_orbit(out_dir: str) -> str:
    """``figure.usda`` seen by a moving camera: a layer over it (sublayer) whose camera circles the
    figure a third of the way round over the clip, rising and falling (view-dependent shading
    under a moving view). Stage metadata is authored again: USD reads it from the root layer."""
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.subLayerPaths.append("./figure.usda")
    layer.startTimeCode, layer.endTimeCode = 0, FRAME_COUNT - 1
    layer.timeCodesPerSecond = layer.framesPerSecond = FPS
    layer.defaultPrim = "World"
    layer.pseudoRoot.SetInfo("upAxis", "Z")
    layer.pseudoRoot.SetInfo("metersPerUnit", 1.0)
    world = Sdf.PrimSpec(layer.pseudoRoot, "World", Sdf.SpecifierOver)
    cam = Sdf.PrimSpec(world, "Camera", Sdf.SpecifierOver)
    attr = Sdf.AttributeSpec(cam, "xformOp:transform", Sdf.ValueTypeNames.Matrix4d)
    target = np.array([0.0, 0.0, 1.0])
    for f in range(FRAME_COUNT):
        t = f / (FRAME_COUNT - 1)
        angle = np.radians(-72.0 + 120.0 * t)
        eye = target + np.array([3.9 * np.cos(angle), 3.9 * np.sin(angle), 0.6 + 0.5 * np.sin(np.pi * t)])
        view = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*target), Gf.Vec3d(0, 0, 1))
        layer.SetTimeSample(attr.path, float(f), _round_matrix(view.GetInverse()))
    path = os.path.join(out_dir, "figure_orbit.usda")
    tmp = path + ".tmp"
    with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
        fh.write(layer.ExportToString())
    os.replace(tmp, path)
    return path


# ---- (f) ripples ------------------------------------------------------------------------------
RIPPLES_FRAMES = 48
RIPPLES_RESOLUTION = 512


def make_ripples(out_dir: str, resolution: int = RIPPLES_RESOLUTION, frame_count: int = RIPPLES_FRAMES,
                 file_name: str = "ripples.usda") -> str:
    """The water height field (warpshade.io.heightfield): every wave advances a whole number of
    periods over the clip, so frame ``frame_count`` would equal frame 0."""
    from warpshade.io.heightfield import HeightFieldSpec, author

    duration = frame_count / FPS

    def speed(wavelength, cycles):
        return wavelength * cycles / duration

    planar = [  # amplitude, wavelength, direction, phase speed, phase
        (0.050, 2.6, 0.30, 1.00, speed(2.6, 1), 0.0),
        (0.020, 0.95, 1.00, 0.35, speed(0.95, 2), 1.3),
        (0.014, 0.62, -0.55, 1.00, speed(0.62, 3), 2.1),
        (0.008, 0.37, 0.85, -0.40, speed(0.37, 4), 0.4),
    ]
    circular = [  # amplitude, wavelength, centre, phase speed, phase, decay
        (0.012, 0.30, -1.4, 1.1, speed(0.30, 5), 0.0, 0.35),
        (0.009, 0.22, 1.7, -0.9, speed(0.22, 6), 1.0, 0.45),
    ]
    spec = HeightFieldSpec(resolution, (8.0, 8.0), planar, circular, terrain=(0.012, 1.4, 3, 7))
    stage = _new_stage(animated=True, frame_count=frame_count)
    _sky(stage)
    mesh = UsdGeom.Mesh.Define(stage, "/World/Water")
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(0.1, 0.25, 0.3)]))
    author(mesh, spec)
    _camera(stage, eye=(-3.0, 5.2, 1.3), target=(0.6, -1.0, 0.0))
    path = os.path.join(out_dir, file_name)
    _save(stage, path)
    return path


# ---- (g) sunlit -------------------------------------------------------------------------------
SUNLIT_FRAMES = 48
SUNLIT_SKY_FILE = "sunlit_sky.hdr"
SUNLIT_SKY_SIZE = (256, 512)
SUNLIT_SUN_ELEVATION_DEG = 40.0
SUNLIT_SUN_AZIMUTH_DEG = 70.0  # from +X towards +Y: the shadow falls towards the camera's left
SUNLIT_SUN_DIAMETER_DEG = 1.2
#: The sun's irradiance on the ground plane over the rest of the sky's.
SUNLIT_SUN_TO_SKY = 4.0
SUNLIT_SUN_COLOR = np.array([1.0, 0.94, 0.84])
SUNLIT_TEXTURES = ("sunlit_knot_roughness.png", "sunlit_ground_diffuse.png", "sunlit_ground_roughness.png")
#: The (p, q) torus knot: core radius 2 s, wobble s, tube radius; segments along it, vertices around.
SUNLIT_KNOT = {"p": 2, "q": 3, "scale": 0.28, "tube": 0.12, "segments": 200, "around": 12, "u_repeat": 4}
SUNLIT_KNOT_ROUGHNESS = (0.08, 0.5)
SUNLIT_GROUND_ROUGHNESS = (0.15, 0.5)
SUNLIT_LAMP_RADIUS = 0.08
SUNLIT_LAMP_COLOR = (1.0, 0.55, 0.25)
SUNLIT_LAMP_INTENSITY = 150.0


def sunlit_sun_direction() -> np.ndarray:
    """World direction towards the sun of ``sunlit.usda`` (Z-up), unit (3,)."""
    el, az = np.radians(SUNLIT_SUN_ELEVATION_DEG), np.radians(SUNLIT_SUN_AZIMUTH_DEG)
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def sunlit_lamp_position(frame: int) -> np.ndarray:
    """World position of the moving sphere light at a frame: one turn around the knot per clip,
    1.5 m from the vertical axis, bobbing between 0.65 and 1.15 m above the ground."""
    t = frame / SUNLIT_FRAMES
    angle = 2.0 * np.pi * t - 0.6
    return np.array([1.5 * np.cos(angle), 1.5 * np.sin(angle), 0.9 + 0.25 * np.sin(4.0 * np.pi * t)])


def torus_knot(p, q, scale, tube, segments, around, u_repeat):
    """A tube of radius ``tube`` around the (p, q) torus knot
    ``scale * ((2 + cos q t) cos p t, (2 + cos q t) sin p t, -sin q t)``, lifted to rest on z = 0.

    The cross-section frame is the knot's offset from the torus core circle made perpendicular
    to the tangent (smooth and periodic), so normals are exact: the radial direction of each
    ring. The seam ring and seam column are duplicated so UVs can be per vertex.

    Returns:
        points (V, 3), counts, indices, normals (V, 3), uvs (V, 2) with
        ``u = u_repeat * t / 2 pi`` along the knot and ``v = angle / 2 pi`` around it.
    """
    t = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    a = np.linspace(0.0, 2.0 * np.pi, around + 1)
    radius = 2.0 + np.cos(q * t)
    core = scale * np.stack([radius * np.cos(p * t), radius * np.sin(p * t), -np.sin(q * t)], 1)
    d_radius = -q * np.sin(q * t)
    tangent = np.stack([d_radius * np.cos(p * t) - p * radius * np.sin(p * t),
                        d_radius * np.sin(p * t) + p * radius * np.cos(p * t), -q * np.cos(q * t)], 1)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    offset = core - scale * 2.0 * np.stack([np.cos(p * t), np.sin(p * t), np.zeros_like(t)], 1)
    normal = offset - np.sum(offset * tangent, axis=1, keepdims=True) * tangent
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    binormal = np.cross(tangent, normal)
    ring = np.cos(a)[None, :, None] * normal[:, None, :] + np.sin(a)[None, :, None] * binormal[:, None, :]
    points = core[:, None, :] + tube * ring
    points[..., 2] += scale + tube  # lowest point on the ground
    n_around = around + 1
    i, j = np.meshgrid(np.arange(segments), np.arange(around), indexing="ij")
    v00 = (i * n_around + j).ravel()
    # (t, angle) is left-handed about the outward normal: go round the angle first (CCW outside)
    quads = np.stack([v00, v00 + 1, v00 + n_around + 1, v00 + n_around], 1)
    u, v = np.meshgrid(u_repeat * t / (2.0 * np.pi), a / (2.0 * np.pi), indexing="ij")
    return (points.reshape(-1, 3), np.full(len(quads), 4), quads.ravel(), ring.reshape(-1, 3),
            np.stack([u.ravel(), v.ravel()], 1))


def _periodic_noise(rng, size: int, cells: int) -> np.ndarray:
    """Smooth value noise on a size x size image that tiles: a random cells x cells lattice
    interpolated with smoothstep weights, in [0, 1]."""
    lattice = rng.random((cells, cells))
    x = np.arange(size) * cells / size
    k = np.floor(x).astype(int)
    w = _smoothstep(x - k)
    rows = (1 - w)[:, None] * lattice[k % cells] + w[:, None] * lattice[(k + 1) % cells]
    return (1 - w)[None, :] * rows[:, k % cells] + w[None, :] * rows[:, (k + 1) % cells]


def sunlit_texture_images() -> dict[str, np.ndarray]:
    """The sunlit textures as the 8-bit arrays written to PNG (row 0 = top = v 1), by file name.

    * knot roughness (128 x 128, grey, raw): three smooth glossy/rough bands per tile along the
      knot (u), broken up by tiling noise, between SUNLIT_KNOT_ROUGHNESS;
    * ground diffuse colour (128 x 128, RGB, sRGB): a 4 x 4 checker of warm stone and slate tiles
      with a little mottling;
    * ground roughness (128 x 128, grey, raw): rust-like noise between SUNLIT_GROUND_ROUGHNESS.
    """
    rng = np.random.default_rng(2009)
    size = 128
    u = (np.arange(size) + 0.5) / size
    bands = _smoothstep(0.5 + 1.6 * np.sin(2 * np.pi * 3 * u))[None, :]  # along u (columns)
    knot = np.clip(bands + 0.35 * (_periodic_noise(rng, size, 8) - 0.5), 0.0, 1.0)
    lo, hi = SUNLIT_KNOT_ROUGHNESS
    knot_rough = lo + (hi - lo) * knot
    cells = ((np.arange(size) * 4 // size)[:, None] + (np.arange(size) * 4 // size)[None, :]) % 2
    stone, slate = np.array([0.78, 0.70, 0.58]), np.array([0.36, 0.40, 0.44])  # sRGB-encoded
    mottle = 0.9 + 0.2 * _periodic_noise(rng, size, 16)
    diffuse = np.where(cells[..., None] == 1, slate, stone) * mottle[..., None]
    rust = _periodic_noise(rng, size, 6) * 0.65 + _periodic_noise(rng, size, 24) * 0.35
    rust = (rust - rust.min()) / (rust.max() - rust.min())
    lo, hi = SUNLIT_GROUND_ROUGHNESS
    ground_rough = lo + (hi - lo) * rust

    def to8(x):
        return np.clip(np.round(255.0 * x), 0, 255).astype(np.uint8)

    return dict(zip(SUNLIT_TEXTURES, (to8(knot_rough), to8(diffuse), to8(ground_rough))))


def _write_png(path: str, pixels: np.ndarray) -> str:
    from PIL import Image

    tmp = path[: -len(".png")] + ".tmp.png"
    Image.fromarray(pixels).save(tmp, format="PNG", compress_level=9)
    os.replace(tmp, path)
    return path


def _sunlit_sun_texels(height: int, width: int, dome_to_world: np.ndarray, sun: np.ndarray, sub: int = 16):
    """Fraction of each lat-long texel covered by the sun disc (H, W), by sub x sub samples."""
    half = np.radians(SUNLIT_SUN_DIAMETER_DEG) / 2.0
    centres = usd_dome_texel_directions(height, width) @ dome_to_world.T
    near = np.argwhere(centres @ sun > np.cos(half + 4.0 * np.pi / height))
    coverage = np.zeros((height, width))
    offsets = (np.arange(sub) + 0.5) / sub
    for r, c in near:
        lat = np.pi / 2.0 - (r + offsets) * (np.pi / height)
        lon = np.pi - (c + offsets) * (2.0 * np.pi / width)
        la, lo = np.meshgrid(lat, lon, indexing="ij")
        local = np.stack([np.cos(la) * np.sin(lo), np.sin(la), np.cos(la) * np.cos(lo)], -1)
        # sub-samples weighted by cos(lat): equal solid angle per weight
        inside = (local @ dome_to_world.T) @ sun > np.cos(half)
        coverage[r, c] = np.sum(inside * np.cos(la)) / np.sum(np.cos(la))
    return coverage


def write_sunlit_sky(out_dir: str) -> str:
    """The sunlit dome texture: a clear sky with a soft aureole, plus a sun disc of
    SUNLIT_SUN_DIAMETER_DEG whose irradiance on the ground is SUNLIT_SUN_TO_SKY times the sky's."""
    height, width = SUNLIT_SKY_SIZE
    dome_to_world = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    dirs = usd_dome_texel_directions(height, width) @ dome_to_world.T
    sun = sunlit_sun_direction()
    sky = sky_radiance(dirs, sun_direction=sun, sun_radiance=(3.0, 2.6, 2.0), sun_angle_deg=6.0,
                       zenith=(0.25, 0.45, 1.0), horizon=(0.95, 0.92, 0.85), up=(0.0, 0.0, 1.0))
    lat_edges = np.pi / 2.0 - np.arange(height + 1) * (np.pi / height)
    solid = (np.sin(lat_edges[:-1]) - np.sin(lat_edges[1:]))[:, None] * (2.0 * np.pi / width)  # (H, 1)
    cos_up = np.maximum(dirs[..., 2], 0.0)
    luminance = sky @ np.array([0.2126, 0.7152, 0.0722])
    sky_irradiance = np.sum(luminance * cos_up * solid)
    coverage = _sunlit_sun_texels(height, width, dome_to_world, sun)
    colour = SUNLIT_SUN_COLOR / (SUNLIT_SUN_COLOR @ np.array([0.2126, 0.7152, 0.0722]))
    sun_radiance = SUNLIT_SUN_TO_SKY * sky_irradiance / np.sum(coverage * cos_up * solid)
    image = sky + (sun_radiance * coverage)[..., None] * colour
    path = os.path.join(out_dir, SUNLIT_SKY_FILE)
    write_hdr(path, image.astype(np.float32))
    return path


def _texture_node(stage, material_path, name, file_name, reader, color_space, output, output_type):
    tex = UsdShade.Shader.Define(stage, f"{material_path}/{name}")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath("./" + file_name))
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(color_space)
    tex.CreateOutput(output, output_type)
    return tex


def _preview_material(stage, mesh, path, textures, constants):
    """A UsdPreviewSurface material at ``path`` bound to ``mesh``: ``textures`` maps an input
    (name, type) to (node name, file, colour space, output); ``constants`` input (name, type) -> value."""
    mat = UsdShade.Material.Define(stage, path)
    surface = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    reader = UsdShade.Shader.Define(stage, f"{path}/UVs")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    for (name, value_type), value in constants.items():
        surface.CreateInput(name, value_type).Set(value)
    for (name, value_type), (node, file_name, color_space, output) in textures.items():
        out_type = Sdf.ValueTypeNames.Float3 if output == "rgb" else Sdf.ValueTypeNames.Float
        tex = _texture_node(stage, path, node, file_name, reader, color_space, output, out_type)
        surface.CreateInput(name, value_type).ConnectToSource(tex.ConnectableAPI(), output)
    mat.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    return mat


def _vertex_uvs(mesh, uvs) -> None:
    st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set(Vt.Vec2fArray.FromNumpy(_r(uvs).astype(np.float32)))


def make_sunlit(out_dir: str) -> list[str]:
    """``sunlit.usda`` with its sky (``sunlit_sky.hdr``) and textures (``SUNLIT_TEXTURES``)."""
    written = [write_sunlit_sky(out_dir)]
    for name, pixels in sunlit_texture_images().items():
        written.append(_write_png(os.path.join(out_dir, name), pixels))
    stage = _new_stage(animated=True, frame_count=SUNLIT_FRAMES)
    dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
    dome.OrientToStageUpAxis()
    dome.CreateTextureFileAttr(Sdf.AssetPath("./" + SUNLIT_SKY_FILE))
    dome.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
    dome.CreateIntensityAttr(1.0)
    # ground: 41 x 41 vertices over 6 m, one texture tile over the whole plane
    pts, counts, idx = grid(41, 6.0)
    ground = _mesh(stage, "/World/Ground", pts, counts, idx)
    _vertex_uvs(ground, (pts[:, :2] + 3.0) / 6.0)
    C3, F = Sdf.ValueTypeNames.Color3f, Sdf.ValueTypeNames.Float
    _preview_material(
        stage, ground, "/World/Looks/Ground",
        {("diffuseColor", C3): ("DiffuseTexture", SUNLIT_TEXTURES[1], "sRGB", "rgb"),
         ("roughness", F): ("RoughnessTexture", SUNLIT_TEXTURES[2], "raw", "r")},
        {("metallic", F): 0.0, ("useSpecularWorkflow", Sdf.ValueTypeNames.Int): 0},
    )
    # the glossy knot: specular workflow, coloured specular, banded roughness
    pts, counts, idx, normals, uvs = torus_knot(**SUNLIT_KNOT)
    knot = _mesh(stage, "/World/Knot", pts, counts, idx)
    knot.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(_r(normals).astype(np.float32)))
    knot.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    _vertex_uvs(knot, uvs)
    _preview_material(
        stage, knot, "/World/Looks/Knot",
        {("roughness", F): ("RoughnessTexture", SUNLIT_TEXTURES[0], "raw", "r")},
        {("diffuseColor", C3): Gf.Vec3f(0.30, 0.07, 0.05), ("specularColor", C3): Gf.Vec3f(0.75, 0.6, 0.4),
         ("useSpecularWorkflow", Sdf.ValueTypeNames.Int): 1},
    )
    # the moving, tinted sphere light
    lamp = UsdLux.SphereLight.Define(stage, "/World/Lamp")
    lamp.CreateRadiusAttr(SUNLIT_LAMP_RADIUS)
    lamp.CreateColorAttr(Gf.Vec3f(*SUNLIT_LAMP_COLOR))
    lamp.CreateIntensityAttr(SUNLIT_LAMP_INTENSITY)
    move = UsdGeom.Xformable(lamp).AddTranslateOp()
    for f in range(SUNLIT_FRAMES):
        move.Set(Gf.Vec3d(*_r(sunlit_lamp_position(f))), f)
    _camera(stage, eye=(3.3, -3.7, 2.4), target=(-0.2, -0.45, 0.25))
    path = os.path.join(out_dir, "sunlit.usda")
    _save(stage, path)
    return [path] + written


MAKERS = {
    "ripples": make_ripples,
    "blockers": make_blockers,
    "figure_orbit": make_figure_orbit,
    "figure": make_figure,
    "figure_train": make_figure_train,
    "figure_walk": make_figure_walk,
    "cloth": make_cloth,
    "bend": make_bend,
    "wanderer_train": make_wanderer_train,
    "wanderer_test": make_wanderer_test,
    "sunlit": make_sunlit,
}


def generate(out_dir: str = HERE, scenes=SCENES) -> list[str]:
    """Write the sky texture and the named scenes into ``out_dir``; returns the written paths."""
    os.makedirs(out_dir, exist_ok=True)
    written = [write_sky(out_dir)]
    for name in scenes:
        result = MAKERS[name](out_dir)
        written.extend([result] if isinstance(result, str) else result)
    return written


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=HERE, help="output directory (default: this directory)")
    parser.add_argument("--scenes", nargs="*", default=list(SCENES), choices=sorted(MAKERS),
                        help="scenes to write (default: all but ripples and sunlit)")
    args = parser.parse_args(argv)
    for path in generate(args.out, args.scenes):
        print(f"{os.path.getsize(path):>9,d} bytes  {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
