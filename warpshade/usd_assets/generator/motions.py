"""Animation curves for the characters' training clips (data-driven PRT).

A training clip (:func:`training_clip`) is a range of motion (:func:`range_of_motion_clip`: each
joint swept alone through its limits, ``SWEEP_FRAMES`` frames each, then all joints at once as
sums of sinusoids at incommensurate frequencies) followed by a motion library: natural motions,
each built as a :class:`Motion` from keyed curves (:func:`keyed`, :func:`bump`), cross-faded
into each other over ``LIBRARY_BLEND`` frames (:func:`cross_fade`). Joint angles are rotation
vectors, shape (T, J, 3), radians. The characters' own motions and libraries live in their
scene modules (:mod:`.figure`, :mod:`.wanderer`).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator

from .shapes import smoothstep
from .writing import FPS


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


#: Frames over which consecutive parts of a training clip cross-fade (the range of motion into
#: the first library segment, each segment into the next).
LIBRARY_BLEND = 6


class Motion:
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
        """:func:`keyed` over this segment, the key times scaled so the last falls on its last frame."""
        times = np.asarray(times, np.float64)
        return keyed(self.t, times * (len(self.t) - 1) / times[-1], values)


def keyed(t, times, values) -> np.ndarray:
    """A smooth curve through (time, value) keys at the frames ``t`` (monotone cubic: no
    overshoot, flat at every key that is a local extremum), held at the end values outside."""
    times = np.asarray(times, np.float64)
    return PchipInterpolator(times, np.asarray(values, np.float64))(np.clip(t, times[0], times[-1]))


def bump(t, start: float, rise: float, hold: float, fall: float) -> np.ndarray:
    """0 before ``start``, up to 1 over ``rise`` frames (smoothstep), held, back to 0 over ``fall``."""
    return smoothstep((t - start) / rise) * (1.0 - smoothstep((t - start - rise - hold) / fall))


def cross_fade(parts) -> np.ndarray:
    """Clips (T_k, J, 3) joined into one: each overlaps the next by LIBRARY_BLEND frames, over
    which the pose passes from one to the other (smoothstep weights), so nothing jumps."""
    w = smoothstep(np.arange(1, LIBRARY_BLEND + 1) / (LIBRARY_BLEND + 1))[:, None, None]
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
        (:func:`cross_fade`). Every value lies in its range.
    """
    rom = range_of_motion_clip(limits, mixed_frames + LIBRARY_BLEND)
    segments = [np.clip(s, limits[..., 0], limits[..., 1]) for s in library]
    return cross_fade([rom, *segments])
