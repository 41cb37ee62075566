"""What a graph takes from outside it: the frames a run steps, the lighting and a static scene made longer.

* :func:`parse_frames` -- time codes of the scene selected by ``"A:B"``, one time code or a list;
* :func:`lighting_from_spec` -- a graph's ``[lighting]`` table as a
  :class:`~warpshade.scene.LightingSource`;
* :func:`extend_static_frames` -- a static scene given a number of frames (to rotate lighting);
  :func:`scene_animation` -- what moves in a scene, if anything.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..scene._lighting import Environment, LightingSource, SphereLight, scaled_light, up_rotation
from ._errors import GraphError

__all__: list[str] = []


def parse_frames(spec, scene) -> np.ndarray:
    """Select time codes of ``scene.frames`` from a spec.

    ``None`` = all frames; ``"A:B"`` = time codes ``A <= t < B`` (either end may be empty);
    ``"A"`` = one frame; a list of numbers = those frames. Raises ValueError when the selection
    is empty or names frames the scene does not have.
    """
    frames = scene.frames
    if spec is None:
        return frames.copy()
    if isinstance(spec, (list, tuple, np.ndarray)):
        if len(spec) == 0:
            raise ValueError("the list of frames is empty")
        return np.array([scene.frames[scene.frame_index(f)] for f in spec])
    if not isinstance(spec, str):
        raise TypeError(f"frames must be 'A:B', one time code or a list of time codes, got {spec!r}")

    def number(part: str, default: float) -> float:
        if not part.strip():
            return default
        try:
            value = float(part)
        except ValueError:
            raise ValueError(f"{part.strip()!r} in {spec!r} is not a number (expected 'A:B', 'A' or a list)") from None
        if not np.isfinite(value):
            raise ValueError(f"{spec!r} is not a finite time code")
        return value

    text = spec.strip()
    if ":" in text:
        a, b = text.split(":", 1)
        lo, hi = number(a, -np.inf), number(b, np.inf)
        sel = frames[(frames >= lo) & (frames < hi)]
    else:
        sel = np.array([frames[scene.frame_index(number(text, np.nan))]])
    if sel.size == 0:
        raise ValueError(
            f"frames {spec!r} select nothing from the scene's time codes {frames[0]:g}..{frames[-1]:g}"
        )
    return sel



def lighting_from_spec(spec: dict, scene, base_dir: Path | None = None) -> LightingSource:
    """A graph's ``[lighting]`` table as a :class:`~warpshade.scene.LightingSource`.

    Keys: ``source`` ("scene" default; "distant": the scene's environments and distant lights
    without its sphere lights; "sky", "constant", or an .hdr/.exr path relative to the graph file), ``rotate_degrees_per_frame`` (0), ``intensity`` (1.0, scales every light),
    ``color`` (for "constant").

    Raises:
        ValueError: naming the key at fault.
    """
    spec = dict(spec or {})
    source = spec.pop("source", "scene")
    speed = float(spec.pop("rotate_degrees_per_frame", 0.0))
    intensity = float(spec.pop("intensity", 1.0))
    color = spec.pop("color", (1.0, 1.0, 1.0))
    if spec:
        raise ValueError(f"[lighting]: unknown key(s) {sorted(spec)}")
    to_world = up_rotation(scene.up_axis)
    if source == "scene":
        lights = list(scene.lights) or [Environment.sky(to_world=to_world)]
    elif source == "distant":
        lights = [light for light in scene.lights if not isinstance(light, SphereLight)] or [Environment.sky(to_world=to_world)]
    elif source == "sky":
        lights = [Environment.sky(to_world=to_world)]
    elif source == "constant":
        lights = [Environment.constant(color)]
    else:
        from ..io._images import read_image

        p = Path(source)
        if not p.is_absolute() and base_dir is not None:
            p = base_dir / p
        lights = [Environment(read_image(p), to_world=to_world, path=str(p))]
    if intensity != 1.0:
        lights = [scaled_light(light, intensity) for light in lights]
    return LightingSource(lights, scene.up_axis, speed, float(scene.frames[0]))


def scene_animation(scene) -> str | None:
    """What moves in ``scene`` over its time codes (``"mesh /Arm is skinned"``, ``"light /Sun
    moves"``, ``"camera /Cam moves"``), or None when nothing does (a static asset, whatever its
    time range)."""
    for mesh in scene.meshes:
        if not (mesh.animation == "static" or (mesh.animation == "rigid" and mesh.transforms.shape[0] == 1)):
            return f"mesh {mesh.path} is {mesh.animation}"
    for light in scene.lights:
        if getattr(light, "track", None) is not None:
            return f"light {getattr(light, 'path', None) or type(light).__name__} moves"
    if scene.camera is not None and scene.camera.moving:
        return f"camera {scene.camera.path} moves"
    return None


def extend_static_frames(scene, frame_count: int):
    """A static scene with ``frame_count`` time codes 0..frame_count-1 (e.g. to rotate lighting).

    A static asset needs no ``frame_count``: it is one frame (time code 0), and its animated
    lights or camera give it their time codes. ``frame_count`` gives a scene in which nothing
    moves (:func:`scene_animation`) that many frames, for lighting that turns per frame.

    Raises:
        GraphError: when something in the scene moves (its own time codes must be used), naming it.
    """
    if frame_count < 1:
        raise GraphError(f"frame_count must be >= 1, got {frame_count}")
    moving = scene_animation(scene)
    if moving is not None:
        raise GraphError(f"scene {scene.source}: frame_count only applies to static scenes (in this one {moving}; it "
                         f"runs its own {len(scene.frames)} time codes {scene.frames[0]:g}..{scene.frames[-1]:g}): "
                         "remove frame_count from [graph]")
    from ..scene import Scene

    return Scene(
        scene.meshes, frames=range(frame_count), fps=scene.fps, skeletons=scene.skeletons, lights=scene.lights,
        camera=scene.camera, up_axis=scene.up_axis, source=scene.source, skipped=scene.skipped,
    )
