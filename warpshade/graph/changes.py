"""Changes of a run that do not come from the frame: lighting, albedo, BRDFs, the eye, parameters.

:class:`RunChanges` is the part of :class:`~warpshade.graph.runtime.Runtime` that takes them. A
setter writes the change where the frame reads it (through the
:class:`~warpshade.scene.state.FrameEvaluator`, the only writer of the frame's host inputs) and
tells the frame stages with :meth:`RunChanges.notify_changed`: each stage's
:meth:`~warpshade.methods.stage.FrameStage.notify_changed` gets the
:class:`~warpshade.scene.state.Change` flags and, for a changed parameter, its name, and says
whether it absorbs the change; the first that does not is set up again with every stage after it.

:class:`MaterialTrack` is the graph's ``[[material]]`` track: the BRDFs of each time code.
"""

from __future__ import annotations

import numpy as np

from ..methods.stage import Change
from ..scene.lighting import DistantLight, Environment, LightingSource, SphereLight
from ..scene.state import MaterialAssignment
from .errors import GraphError
from .scene_inputs import parse_frames

__all__ = ["MaterialTrack", "RunChanges"]


class MaterialTrack:
    """The graph's ``[[material]]`` tables with their frame ranges resolved to time codes.

    Args:
        entries: the spec's material entries (``{"frames", "prims", "brdf", "where"}``).
        scene: the run's scene (time codes and mesh prims are checked against it).

    Raises:
        GraphError: a frame range or a prim the scene does not have.
    """

    def __init__(self, entries, scene):
        self.entries = []
        for entry in entries or ():
            try:
                frames = parse_frames(entry["frames"], scene) if entry["frames"] is not None else scene.frames
            except ValueError as exc:
                raise GraphError(f"{entry['where']} frames: {exc}") from None
            if entry["prims"] is not None:
                known = {m.path for m in scene.meshes}
                unknown = sorted(set(entry["prims"]) - known)
                if unknown:
                    raise GraphError(f"{entry['where']}: no mesh prim {unknown} in {scene.source} (meshes: {sorted(known)})")
            self.entries.append({**entry, "times": {float(f) for f in np.asarray(frames, np.float64).reshape(-1)}})

    def __bool__(self) -> bool:
        return bool(self.entries)

    def at(self, frame) -> MaterialAssignment:
        """The assignment of time code ``frame``: the entries covering it (later ones win)."""
        out = MaterialAssignment()
        for entry in self.entries:
            if float(frame) in entry["times"]:
                if entry["prims"] is None:
                    out.default = entry["brdf"]
                    out.prims.clear()
                else:
                    for p in entry["prims"]:
                        out.prims[p] = entry["brdf"]
        return out


def _identity(assignment: MaterialAssignment) -> tuple:
    """What tells two assignments apart (the BRDF objects, per prim)."""
    default = None if assignment.default is None else id(assignment.default)
    return default, tuple(sorted((p, id(b)) for p, b in assignment.prims.items()))


class RunChanges:
    """Run-time changes of a :class:`~warpshade.graph.runtime.Runtime` (mixed into it).

    Uses the runtime's ``scene``, ``stages``, ``evaluator``, ``frame`` (the
    :class:`~warpshade.graph.frame.FrameGraph`), ``ctx``, ``lighting`` and ``track``.
    """

    def notify_changed(self, flags: Change, stages=None, keys=()) -> None:
        """Tell the frame stages that something outside the frame changed.

        Each stage's :meth:`~warpshade.methods.stage.FrameStage.notify_changed` says whether it
        keeps working; the first that does not is set up again with every stage after it, and
        the frame is recorded anew at the next step.

        Args:
            flags: :class:`~warpshade.scene.state.Change` flags.
            stages: names of the stages concerned (default: every frame stage).
            keys: with :data:`Change.PARAMETERS`, the names of the parameters that changed.
        """
        names = None if stages is None else set(stages)
        keys = frozenset(keys)
        first = None
        for i, st in enumerate(self.frame.stages):
            if names is not None and st.name not in names:
                continue
            if not st.notify_changed(Change(flags), keys) and first is None:
                first = i
        if first is not None:
            self.frame.setup(first)

    def set_lighting(self, lighting) -> None:
        """Replace the run's lighting: a :class:`~warpshade.scene.LightingSource` or a list of
        lights (fixed). Every frame stage is set up again (lights may differ in number)."""
        if not isinstance(lighting, LightingSource):
            items = [lighting] if isinstance(lighting, (Environment, DistantLight, SphereLight)) else list(lighting)
            lighting = LightingSource.fixed(items, self.scene.up_axis)
        self.evaluator.set_lighting(lighting)
        self.lighting = lighting
        self.ctx.lighting = lighting
        self._override_on = False
        self.frame.setup(0)  # the lights may differ in number: every stage binds the new arrays

    def set_albedo(self, albedo, prims=None) -> None:
        """New diffuse albedo for every vertex or for the meshes ``prims`` (see
        :meth:`~warpshade.scene.state.FrameEvaluator.set_albedo`); the next frame uses it."""
        self.evaluator.set_albedo(albedo, prims)
        self.notify_changed(Change.MATERIAL)

    def set_material(self, brdf, prims=None) -> None:
        """Change the BRDF of every mesh, or of the meshes ``prims`` (prim paths), at run time:
        a :class:`~warpshade.scene.materials.BRDF`, or None to go back to the stages' own. No
        precompute runs; stages that shade BRDFs rebuild their operators (cached per BRDF) into
        their fixed buffers through :data:`~warpshade.scene.state.Change.MATERIAL`, so the next
        frame, recorded or not, already uses it."""
        self.evaluator.set_material(brdf, prims)
        self.notify_changed(Change.MATERIAL)

    def materials_at(self, frame) -> MaterialAssignment:
        """The :class:`~warpshade.scene.state.MaterialAssignment` of time code ``frame``: the
        material track's entries covering it (later ones win), else the current assignment."""
        return self.track.at(frame) if self.track else self.state.materials

    def _apply_material_track(self, frame) -> None:
        if not self.track:
            return
        want = self.track.at(frame)
        key = _identity(want)
        if key == self._track_key:
            return
        self.evaluator.assign_materials(want.default, want.prims)
        self._track_key = key
        self.notify_changed(Change.MATERIAL)

    def set_eye(self, position) -> None:
        """Move the viewer of view-dependent stages (world position); the next frame uses it."""
        self.evaluator.set_eye(position)
        self.notify_changed(Change.VIEW)

    def set_parameter(self, stage: str, name: str, value) -> None:
        """Change a frame stage's parameter between frames (validated like the TOML value); the
        stage is told which parameter changed and is set up again unless it absorbs it.

        Raises:
            GraphError: an unknown stage or parameter, a precompute stage (its artifact would
                change: compile again), or a value that would change the stage's ports. Nothing
                changes then.
        """
        st = next((s for s in self.stages if s.name == stage), None)
        if st is None:
            raise GraphError(f"set_parameter: no stage {stage!r} (stages: {[s.name for s in self.stages]})")
        if st.kind != "frame":
            raise GraphError(f"set_parameter: stage {stage!r} is a precompute stage; change it in the graph and compile again")
        if name not in st.parameters:
            raise GraphError(f"set_parameter: stage {stage!r} has no parameter {name!r} (known: {sorted(st.parameters)})")
        old = st.params[name]
        before = (st.dims(), st.input_ports(), st.output_ports())
        st.params[name] = st.parameters[name].check(stage, name, value)
        if (st.dims(), st.input_ports(), st.output_ports()) != before:
            st.params[name] = old
            raise GraphError(f"set_parameter: {stage}.{name} = {value!r} changes the stage's ports; compile a new graph")
        self.notify_changed(Change.PARAMETERS, [stage], keys=[name])

    def _step_lighting(self, lighting) -> None:
        """This step's lighting override (None: the run's lights), and the stages told when it
        starts, changes or ends."""
        if lighting is not None:
            self.evaluator.set_lighting_override(self._override_coeffs(lighting))
            self._override_on = True
            self.notify_changed(Change.LIGHTING)
        elif self._override_on:
            self.evaluator.set_lighting_override(None)
            self._override_on = False
            self.notify_changed(Change.LIGHTING)

    def _override_coeffs(self, lighting) -> np.ndarray:
        """A step's lighting as SH coefficients (3, n*n): given, or distant lights projected to SH."""
        fl = self.state.lighting
        if fl is None:
            raise ValueError("step: a lighting override needs a run with lighting")
        if isinstance(lighting, np.ndarray):
            return lighting
        items = [lighting] if isinstance(lighting, (Environment, DistantLight, SphereLight)) else list(lighting)
        if any(isinstance(x, SphereLight) for x in items):
            raise ValueError("step: a lighting override replaces the distant SH lighting only; "
                             "use set_lighting() for sphere lights")
        order = max(fl.orders or (1,))
        return LightingSource.fixed(items, self.scene.up_axis).sh(order, float(self.scene.frames[0]))
