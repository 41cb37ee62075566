"""``figure.usda`` -- a UsdSkel figure: 12 joints (hips, spine, chest, head, two arms with
elbows, two legs with knees), 11 capsules merged into one skinned mesh (about 2,000
vertices, two influences per vertex blended near the joints), swinging its arms forward
and across the chest so they shadow the torso, while the spine twists and the legs step;
standing on a separate static 40 x 40 ground grid. The mesh lists its joints in its own
order (``skel:joints``, reversed) and has a non-identity ``geomBindTransform``; the
SkelRoot is translated and turned, so loading exercises every part of the binding.

``figure_train.usda`` and ``figure_walk.usda`` -- the same figure (identical mesh, skeleton,
binding, ground, sky and camera: one function writes all three files, only the joint
rotations differ) in two more clips, for data-driven PRT, which learns transfer as a linear
function of the joint angles on one clip and is tested on others. ``figure_train`` (600
frames, :func:`.motions.training_clip`) is a range of motion (frames 0-299,
:func:`.motions.range_of_motion_clip`): each joint swept alone through its range, then all joints at
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
"""

from __future__ import annotations

import numpy as np
from pxr import Gf
from scipy.spatial.transform import Rotation

from .motions import Motion, bump, joint_limits, training_clip
from .shapes import capsule_profile, revolution, smoothstep
from .skeletons import bind_skin, write_character
from .writing import FRAME_COUNT, define_mesh


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
    reach = smoothstep((frame - 60) / 14.0) * (1.0 - smoothstep((frame - 82) / 12.0))
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
    m = Motion(FIGURE_JOINTS, frames)
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
    m = Motion(FIGURE_JOINTS, frames)
    u = m.t / frames
    ph = 2 * np.pi * (m.t / 24.0 + 0.2 * u * u)  # 24 frames per swing at first, quicker later
    env = bump(m.t, 0.0, 6.0, frames - 13.0, 6.0)
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
    m = Motion(FIGURE_JOINTS, frames)
    a, b, c, d = (bump(m.t, frames / 4 * k + 1, 9.0, 3.0, 9.0) for k in range(4))
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
    m = Motion(FIGURE_JOINTS, frames)
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
    m = Motion(FIGURE_JOINTS, frames)
    u = m.t / frames
    ph = 2 * np.pi * (m.t / 44.0 + 0.12 * u * u)
    stop = 1.0 - smoothstep((m.t - (frames - 9.0)) / 8.0)
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
    m = Motion(FIGURE_JOINTS, frames)
    hold = bump(m.t, 0.0, 8.0, frames - 17.0, 8.0)
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
    m = Motion(FIGURE_JOINTS, frames)
    times = [0.0, 7.0, 12.0, 19.0, 25.0, 32.0]
    turn = m.keys(times, [0.0, 0.42, 0.3, -0.4, -0.15, 0.0])
    nod = m.keys(times, [0.0, 0.04, -0.22, -0.08, 0.22, 0.0])
    m.add("Neck", nod, 0.0, turn)
    m.add("Spine", 0.0, 0.0, 0.3 * turn)
    m.add("Chest", 0.05 * nod, 0.0, 0.05 * turn)
    hands = bump(m.t, 0.0, 7.0, frames - 15.0, 7.0)
    for side in "LR":  # hands on the hips: upper arm out and back, elbow bent
        m.add("Shoulder", 0.25 * hands, -0.22 * hands, -0.05 * hands, side=side)
        m.add("Elbow", -0.2 - 0.7 * hands, 0.0, 0.1 * hands, side=side)
        m.add("Knee", 0.04, side=side)
    return m.rot


def _figure_step_and_look(frames: int = 34) -> np.ndarray:
    """A combined action: a slow step in place (one stride over the segment, thighs +-0.25 rad)
    with the left hand raised to head height in front (shading the eyes) while the head scans
    the horizon; the right arm swings."""
    m = Motion(FIGURE_JOINTS, frames)
    ph = 2 * np.pi * m.t / frames
    shade = bump(m.t, 0.0, 10.0, frames - 21.0, 10.0)
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
#: :func:`.motions.training_clip`).
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
#: motion library (:func:`.motions.training_clip`).
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
    body = define_mesh(stage, "/World/Figure/Body", pts - FIGURE_GEOM_BIND_OFFSET, counts, idx, (0.78, 0.62, 0.5))
    # The mesh names the joints in its own (reversed) order; indices refer to that order.
    order = list(reversed(range(len(paths))))
    to_mesh_order = {k: i for i, k in enumerate(order)}
    mesh_infl = np.vectorize(to_mesh_order.get)(infl)
    geom_bind = Gf.Matrix4d().SetTranslate(Gf.Vec3d(*FIGURE_GEOM_BIND_OFFSET))
    bind_skin(body, skel, mesh_infl, w, 2, geom_bind, joints=[paths[k] for k in order])


def _place_figure(root) -> None:
    root.AddTranslateOp().Set(Gf.Vec3d(*FIGURE_ROOT_TRANSLATE))
    root.AddRotateZOp().Set(FIGURE_ROOT_ROTATE_Z)


def _write_figure(out_dir: str, file_name: str, rotations, frame_count: int) -> str:
    """The figure (skeleton, skinned body, ground, sky, camera) in one clip."""
    return write_character(
        out_dir, file_name, "/World/Figure", FIGURE_JOINTS, rotations, frame_count, _dress_figure,
        camera=((1.2, -3.8, 1.6), (0.3, -0.2, 1.0)), place=_place_figure,
    )


def make_figure(out_dir: str) -> str:
    return _write_figure(out_dir, "figure.usda", figure_joint_rotations, FRAME_COUNT)


def make_figure_train(out_dir: str) -> str:
    return _write_figure(out_dir, "figure_train.usda", FIGURE_TRAIN_CLIP.__getitem__, len(FIGURE_TRAIN_CLIP))


def make_figure_walk(out_dir: str) -> str:
    return _write_figure(out_dir, "figure_walk.usda", figure_walk_rotations, FIGURE_WALK_FRAMES)
