"""The bundled scenes under the measuring conventions (one place for the harness, the budgets
and the benchmarks).

Static scenes get :data:`STATIC_FRAME_COUNT` frames and every scene's distant lighting turns
:data:`ROTATE_DEGREES_PER_FRAME` about the up axis per frame, so a static scene still has
per-frame work and every method sees the lighting move.
"""

from __future__ import annotations

import numpy as np

from ..methods._rows import BENCH_SCENES  # the scenes measured: key -> scene spec, load options, training clip

__all__ = [
    "STATIC_FRAME_COUNT",
    "ROTATE_DEGREES_PER_FRAME",
]

STATIC_FRAME_COUNT = 24
ROTATE_DEGREES_PER_FRAME = 5.0


def load_bench_scene(key: str, rotate_degrees_per_frame: float = ROTATE_DEGREES_PER_FRAME):
    """``(scene, lighting)`` of a bundled scene key or any scene spec, under the conventions above.

    Raises:
        ValueError: an unknown key that is no loadable scene spec either.
    """
    from ..graph._scene_inputs import extend_static_frames
    from ..io import load_scene
    from ..scene import LightingSource

    cfg = BENCH_SCENES.get(key, {"spec": key, "options": {}})
    scene = load_scene(cfg["spec"], **cfg["options"])
    if scene.is_static:
        scene = extend_static_frames(scene, STATIC_FRAME_COUNT)
    lighting = LightingSource(scene.lights, scene.up_axis, rotate_degrees_per_frame, float(scene.frames[0]))
    return scene, lighting


def pick_frames(scene, count: int) -> np.ndarray:
    """``count`` frames spread over the scene's range, first and last included."""
    f = scene.frames
    idx = np.unique(np.linspace(0, len(f) - 1, count).round().astype(int))
    return f[idx]


def error_frames(scene, count: int = 2) -> np.ndarray:
    """``count`` frames spread inside the scene's range (first and last left out)."""
    f = scene.frames
    idx = np.unique(np.linspace(0, len(f) - 1, count + 2).round().astype(int))[1:-1]
    return f[idx] if idx.size else f[:1]


def scene_kinds(scene) -> set:
    """The selectors a harness row can name that apply to ``scene`` (see ``HarnessRow.scenes``)."""
    kinds = {"all", "static" if scene.is_static else "dynamic"}
    kinds |= {m.animation for m in scene.meshes if m.animation in ("skinned", "deforming")}
    return kinds
