"""The viewer of view-dependent stages (``rpo.shade``, ``sg.shade``, ``ldprt.glossy_shade``).

Every glossy stage resolves where it shades toward here, by one rule:

1. its ``eye`` parameter, when given: a fixed world position;
2. else the run's viewer, ``state.eye``: the scene's camera (its path per frame when the camera
   is animated), or the position ``Runtime.set_eye`` set;
3. else the framing camera of the scene: :func:`warpshade.render.frame_camera` of the scene's
   bounds over all its frames (the first frame's for a static scene), in the scene's up axis --
   the 3/4 view from above the ground that previews use, fixed over the run. It is written into
   ``state.eye``, so ``Runtime.set_eye`` moves it and the measuring layer's references take the
   same viewer.

The stage's diagnostics say which viewer it used (:meth:`StageViewer.describe`). An explicit
``eye`` below the scene's lowest point along its up axis (a z-up position given to a y-up scene,
say) is warned about before any precompute (:func:`check_viewer`), naming the stage and parameter.
"""

from __future__ import annotations

import warnings
import weakref
from dataclasses import dataclass

import numpy as np

from .._wp import wp
from ..render._camera import frame_camera
from .stage import Param, StageError

__all__: list[str] = []

#: The ``eye`` parameter of every glossy stage.
EYE_PARAM = Param(None, tuple, "viewer position, world (default: the scene camera, else the framing camera of the "
                  "scene's bounds over its frames in its up axis; Runtime.set_eye moves it)")

_UP_INDEX = {"Y": 1, "Z": 2}
#: Framing cameras already computed, per scene (scenes are immutable once built).
_FRAMING: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def check_eye(stage: str, value) -> np.ndarray | None:
    """The ``eye`` parameter as a (3,) float64 world position, None when unset.

    Raises:
        StageError: naming the stage and parameter, when it is not three finite numbers.
    """
    if value is None:
        return None
    eye = np.asarray(value, np.float64).reshape(-1)
    if eye.shape != (3,) or not np.all(np.isfinite(eye)):
        raise StageError(f"stage {stage!r}: parameter 'eye' needs three finite numbers, got {value!r}")
    return eye


def framing_camera(scene):
    """The framing camera of ``scene``: :func:`~warpshade.render.frame_camera` of its bounds over
    all its frames (:meth:`~warpshade.scene.Scene.bounds_over_frames`), in its up axis."""
    try:
        return _FRAMING[scene]
    except (KeyError, TypeError):
        pass
    lo, hi = scene.bounds_over_frames()
    camera = frame_camera(lo, hi, getattr(scene, "up_axis", "Z"))
    try:
        _FRAMING[scene] = camera
    except TypeError:
        pass
    return camera


@dataclass(frozen=True)
class Viewer:
    """Where a glossy stage shades toward, and why.

    Attributes:
        source: ``"eye"`` (the stage's parameter), ``"camera"`` (the scene's camera),
            ``"set_eye"`` (``Runtime.set_eye``) or ``"framing"`` (the framing camera).
        position: world position (3,) float64 when it was resolved (a moving camera's first frame).
        note: what the source is, in words (the camera's prim path, the framing's up axis).
    """

    source: str
    position: np.ndarray
    note: str

    def describe(self, position=None) -> dict:
        """JSON-ready ``{"source", "position", "note"}``; ``position`` replaces the resolved one
        (the eye of the last frame)."""
        pos = self.position if position is None else np.asarray(position, np.float64).reshape(3)
        return {"source": self.source, "position": [round(float(x), 6) for x in pos], "note": self.note}


def scene_viewer(scene, eye=None) -> Viewer:
    """The viewer a glossy stage takes on ``scene`` before any run changes it: ``eye`` (a checked
    (3,) position) when given, else the scene's camera, else its framing camera."""
    if eye is not None:
        return Viewer("eye", np.asarray(eye, np.float64).reshape(3), "the stage's 'eye' parameter")
    camera = getattr(scene, "camera", None)
    if camera is not None:
        moving = " (animated: its position at every frame)" if camera.moving else ""
        return Viewer("camera", camera.position_at(0), f"the scene camera {camera.path or '<unnamed>'}{moving}")
    up = getattr(scene, "up_axis", "Z")
    frames = len(scene.frames)
    over = "its first frame (static)" if scene.is_static or frames == 1 else f"its {frames} frames"
    return Viewer("framing", np.asarray(framing_camera(scene).position, np.float64),
                  f"no scene camera: the framing camera of the scene's bounds over {over}, up axis {up}")


def eye_below_scene(eye, scene) -> str | None:
    """Why ``eye`` lies below ``scene`` (its up coordinate under the scene's lowest point over all
    frames), or None when it does not."""
    up = str(getattr(scene, "up_axis", "Z")).upper()
    axis = _UP_INDEX.get(up)
    if axis is None:
        return None
    lo, hi = scene.bounds_over_frames()
    tolerance = 1e-6 * max(float(np.max(np.asarray(hi) - np.asarray(lo))), 1e-12)
    if float(eye[axis]) >= float(lo[axis]) - tolerance:
        return None
    other = "Z" if up == "Y" else "Y"
    return (f"its {up.lower()} = {float(eye[axis]):g} is below the scene's lowest {up.lower()} = {float(lo[axis]):g} "
            f"(up axis {up}; a position written for a {other}-up scene?)")


def check_viewer(stage: str, eye_param, scene) -> Viewer:
    """The viewer of a glossy stage on ``scene``, checked before any precompute: the ``eye``
    parameter's values (StageError), and a UserWarning naming the stage and parameter when an
    explicit eye lies below the scene -- receivers facing up then see it below their horizon
    and shade black."""
    eye = check_eye(stage, eye_param)
    if eye is not None:
        why = eye_below_scene(eye, scene)
        if why:
            warnings.warn(f"stage {stage!r}: parameter 'eye' {[float(x) for x in eye]}: {why}; surfaces facing up see "
                          "it below their horizon and shade black. Leave 'eye' unset to shade toward the scene "
                          "camera, or the framing camera when the scene has none", UserWarning, stacklevel=3)
    return scene_viewer(scene, eye)


class StageViewer:
    """A glossy stage's bound viewer: the device array its kernels read, and where it came from.

    Attributes:
        eye: ``wp.array(vec3)`` of shape (1,): the stage's own (an ``eye`` parameter) or the
            state's (the run's viewer, which the camera path and ``Runtime.set_eye`` write).
        follows_state_eye: True when ``eye`` is the state's
            (:class:`warpshade.measure._protocols.ViewerStage`).
        viewer: the :class:`Viewer` resolved at set-up.
    """

    def __init__(self, eye, viewer: Viewer, follows_state_eye: bool):
        self.eye, self.viewer, self.follows_state_eye = eye, viewer, follows_state_eye

    def moved(self) -> None:
        """``Runtime.set_eye`` moved the run's viewer (:data:`~warpshade.scene._state.Change.VIEW`)."""
        if self.follows_state_eye:
            self.viewer = Viewer("set_eye", self.eye.numpy()[0].astype(np.float64), "set by Runtime.set_eye")

    def describe(self) -> dict:
        """:meth:`Viewer.describe` with the eye of the last frame (for diagnostics; reads the device)."""
        return self.viewer.describe(self.eye.numpy()[0])


def bind_viewer(stage: str, eye_param, ctx) -> StageViewer:
    """The viewer of a glossy stage at set-up (the module's rule): a new device array for an
    ``eye`` parameter; else the state's eye, which holds the scene camera or ``Runtime.set_eye``'s
    position, or, when neither exists, is given the framing camera's position here."""
    eye = check_eye(stage, eye_param)
    if eye is not None:
        array = wp.array([wp.vec3(*eye.astype(np.float32))], dtype=wp.vec3, device=ctx.device)
        return StageViewer(array, scene_viewer(ctx.scene, eye), False)
    state = ctx.state
    if state is None:
        raise StageError(f"stage {stage!r}: set up outside a run (no frame state to take the viewer from); "
                         "set the 'eye' parameter")
    if state.has_eye:
        camera = getattr(ctx.scene, "camera", None)
        now = state.eye.numpy()[0].astype(np.float64)
        on_camera = camera is not None and np.allclose(now, camera.position_at(state.frame_index), rtol=1e-6, atol=1e-6)
        viewer = scene_viewer(ctx.scene) if on_camera else Viewer("set_eye", now, "set by Runtime.set_eye")
        return StageViewer(state.eye, viewer, True)
    viewer = scene_viewer(ctx.scene)
    state.eye.assign(np.asarray([viewer.position], np.float32))
    return StageViewer(state.eye, viewer, True)
