"""What the measuring layer asks of a stage, as structural protocols (:class:`typing.Protocol`).

The stage contract (:mod:`warpshade.methods.stage`) says how a stage runs; what it is measured
against is the measuring layer's question, so its interface lives here. A stage implements a
protocol by having the members (the methods layer never imports this module); a stage that
implements none is measured against the default ground truth, the diffuse reference of
:func:`warpshade.reference.shade` with the scene's albedo.

* :class:`MeasuredStage` -- a stage measured against another ground truth (interreflected
  transfer, a glossy BRDF toward an eye);
* :class:`ViewerStage` -- a stage that shades toward the state's eye (the camera or
  ``Runtime.set_eye``): its reference follows the eye of each frame measured;
* :class:`PixelStage` -- a stage that shades G-buffers per pixel;
* :class:`MeasurableStage` -- a stage whose parameters can rule out a ground truth, and
  :func:`check_measurable`, which asks it before any work;
* :func:`ground_truth_model` -- the ground truth a stage's output is measured against, for one
  frame's materials and eye (the default and the follows-eye rule included).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

__all__ = [
    "MeasurableStage",
    "MeasuredStage",
    "PixelStage",
    "ViewerStage",
    "check_measurable",
]


@runtime_checkable
class MeasuredStage(Protocol):
    """A frame stage whose output is measured against something other than the diffuse reference."""

    def reference_model(self, materials=None) -> dict | None:
        """Keyword arguments of the ground truth, from the stage's parameters and inputs (known
        after ``setup``): ``{"bounces": n}`` for :func:`warpshade.reference.shade`, or ``brdf``,
        ``eye`` (3,) float64 world position and ``color`` (3,) float64 (optionally ``roughness``
        and ``color`` per vertex, and ``groups``: a list of ``{"vertices": indices, "brdf": BRDF}``
        for meshes with BRDFs of their own) for :func:`warpshade.reference.shade_glossy`; None
        for the diffuse reference.

        Args:
            materials: the :class:`~warpshade.scene._state.MaterialAssignment` of the frame
                measured; None = the run's current assignment.
        """


@runtime_checkable
class ViewerStage(Protocol):
    """A stage that may shade toward the state's eye."""

    #: True when the stage shades toward ``state.eye`` (not a fixed ``eye`` parameter): its
    #: reference then takes the eye of the frame measured (an animated camera).
    follows_state_eye: bool


@runtime_checkable
class PixelStage(Protocol):
    """A frame stage that shades the pixels of a G-buffer with its current lights, eye and visibility."""

    def render_pixels(self, gbuffer, albedo=None, specular=None, roughness=None, normals=None):
        """Shade every pixel of ``gbuffer`` (:func:`warpshade.render.render_gbuffer`); per-pixel
        materials (rows of ``gbuffer.pixel_count``) and ``normals`` replace the interpolated
        ones. Returns ``wp.array(vec3)`` of linear radiance, 0 for misses."""

    def pixel_reference_model(self, materials=None) -> dict | None:
        """:meth:`MeasuredStage.reference_model` for a per-pixel reference (which takes
        roughness and colours per pixel, so textured materials can be measured). A stage whose
        detail is geometry the run does not have returns ``geometry`` instead (a callable: time
        code -> the :class:`~warpshade.scene.Scene` the diffuse ground truth is traced on, e.g.
        an LDPRT patch's displaced fine mesh), ``include`` (``("diffuse",)``) and optionally
        ``prims`` (the mesh paths whose pixels are measured)."""


@runtime_checkable
class MeasurableStage(Protocol):
    """A stage whose parameters alone can rule out a ground truth (checked before any work)."""

    def check_measurable(self, per_pixel: bool = False) -> None:
        """Raise :class:`~warpshade.methods.stage.StageError` naming the stage and parameter when
        its output cannot be measured (per vertex, or per pixel with ``per_pixel``); needs only
        the parameters (the stage is built, not set up)."""


def check_measurable(stage, per_pixel: bool = False) -> None:
    """Refuse before any work a stage that cannot be measured (:class:`MeasurableStage`); a stage
    that is no :class:`MeasurableStage` is measurable as far as its parameters tell."""
    if isinstance(stage, MeasurableStage):
        stage.check_measurable(per_pixel)


def ground_truth_model(stage, materials=None, eye=None, per_pixel: bool = False) -> dict | None:
    """What ``stage``'s output is measured against, for one frame.

    Args:
        stage: a frame stage; one that is no :class:`MeasuredStage` gets the default (None, the
            diffuse reference).
        materials: the frame's :class:`~warpshade.scene._state.MaterialAssignment` (None: the
            run's current one).
        eye: the frame's eye, (3,) world position, or None (the stage's current eye). It
            replaces the model's eye when the stage is a :class:`ViewerStage` that follows the
            state's eye.
        per_pixel: the model of a per-pixel reference (the stage must be a :class:`PixelStage`).

    Returns:
        keyword arguments of the reference (see :meth:`MeasuredStage.reference_model`) or None.
    """
    if per_pixel:
        if not isinstance(stage, PixelStage):
            raise ValueError(f"stage {stage.name!r} ({stage.type_name}) does not shade pixels")
        model = stage.pixel_reference_model(materials)
    elif isinstance(stage, MeasuredStage):
        model = stage.reference_model(materials)
    else:
        return None
    if model is not None and "eye" in model and eye is not None and isinstance(stage, ViewerStage) and stage.follows_state_eye:
        model = {**model, "eye": np.asarray(eye, np.float64)}
    return model
