"""``wanderer_train.usdc`` and ``wanderer_test.usdc`` -- a larger character at the scale of the
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
"""

from __future__ import annotations

import numpy as np
from pxr import Gf

from .motions import Motion, bump, joint_limits, training_clip
from .shapes import revolution, smoothstep, tube
from .skeletons import bind_skin, chain_weights, strongest_influences, write_character
from .writing import define_mesh


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
            lateral = smoothstep((np.abs(pts[:, 0]) - 0.08) / 0.09)
            band = smoothstep((pts[:, 2] - 1.33) / 0.08) * (1.0 - smoothstep((pts[:, 2] - 1.45) / 0.05))
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
    walk = 1.0 - smoothstep((t - 36.0) / 16.0)
    reach = smoothstep((t - 36.0) / 16.0) * (1.0 - smoothstep((t - 72.0) / 14.0))
    bow = smoothstep((t - 76.0) / 16.0) * (1.0 - smoothstep((t - 104.0) / 14.0))
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


def _wanderer_hand(m: Motion, side: str, curl, thumb=None, spread=0.0) -> None:
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
    m = Motion(WANDERER_JOINTS, frames)
    ph = 2 * np.pi * m.t / period
    go = bump(m.t, 0.0, 8.0, frames - 17.0, 8.0)
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
    m = Motion(WANDERER_JOINTS, frames)
    a, b, c, d, e = (bump(m.t, frames / 5 * k + 1, 9.0, 2.0, 9.0) for k in range(5))
    grip = smoothstep((m.t - (frames * 4 / 5 + 8.0)) / 4.0)  # closes on the thing on the shelf
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
    m = Motion(WANDERER_JOINTS, frames)
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
    m = Motion(WANDERER_JOINTS, frames)
    times = [0.0, 7.0, 12.0, 19.0, 25.0, 31.0, 40.0]
    turn = m.keys(times, [0.0, 0.42, 0.42, -0.42, -0.2, 0.1, 0.0])
    m.add("Head", m.keys(times, [0.0, 0.0, -0.16, 0.02, 0.15, 0.1, 0.0]), 0.0, turn)
    nod = m.keys(times, [0.0, 0.05, -0.22, -0.1, 0.18, 0.15, 0.0])
    lean = m.keys([0.0, 24.0, 31.0, 34.0, 40.0], [0.0, 0.0, 1.0, 1.0, 0.0])
    m.add("Neck", nod, 0.0, 0.35 * turn)
    m.add("Spine", 0.2 * lean, 0.0, 0.25 * turn)
    m.add("Chest", 0.05 * nod + 0.18 * lean)
    hands = bump(m.t, 0.0, 8.0, frames - 17.0, 8.0)
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
    m = Motion(WANDERER_JOINTS, frames)
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
    m = Motion(WANDERER_JOINTS, frames)
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
    m = Motion(WANDERER_JOINTS, frames)
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
    m = Motion(WANDERER_JOINTS, frames)
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
#: :func:`.motions.training_clip`).
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
#: motion library (:func:`.motions.training_clip`).
WANDERER_TRAIN_CLIP = training_clip(
    joint_limits(WANDERER_JOINTS, WANDERER_LIMITS), 204, [make(frames) for _, make, frames in WANDERER_LIBRARY]
)


def _dress_wanderer(stage, skel, paths) -> None:
    """The wanderer's skinned body and the hat, rigidly on the head joint."""
    pts, counts, idx, infl, w = _wanderer_body()
    body = define_mesh(stage, "/World/Wanderer/Body", pts, counts, idx, (0.62, 0.45, 0.34))
    bind_skin(body, skel, infl, w, 4, Gf.Matrix4d(1.0))
    pts, counts, idx = _wanderer_hat()
    hat = define_mesh(stage, "/World/Wanderer/Hat", pts, counts, idx, (0.82, 0.72, 0.45))
    head = [p for p in paths if p.endswith("/Head")]
    bind_skin(hat, skel, [0], [1.0], 1, Gf.Matrix4d(1.0), joints=head, constant=True)


def _write_wanderer(out_dir: str, file_name: str, rotations, frame_count: int) -> str:
    """The wanderer (skeleton, skinned body, hat, ground, sky, camera) in one clip."""
    return write_character(
        out_dir, file_name, "/World/Wanderer", WANDERER_JOINTS, rotations, frame_count, _dress_wanderer,
        camera=((1.3, -3.2, 1.6), (0.0, 0.0, 1.0)),
    )


def make_wanderer_train(out_dir: str) -> str:
    return _write_wanderer(out_dir, "wanderer_train.usdc", WANDERER_TRAIN_CLIP.__getitem__, len(WANDERER_TRAIN_CLIP))


def make_wanderer_test(out_dir: str) -> str:
    return _write_wanderer(out_dir, "wanderer_test.usdc", wanderer_test_rotations, WANDERER_TEST_FRAMES)
