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

from ..methods.stage import Change, FrameStage, stage_types
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

    Every change is all or nothing: it is checked, written and passed to the stages; when any of
    that fails (a bad value, a stage that refuses it while rebuilding its operators or setting up
    again), what was written is put back, the stages are brought back to it, and the error is
    raised. A rejected change leaves the run exactly as it was, and later frames step as before.
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

    def _all_or_nothing(self, what: str, apply, undo, bring_back) -> None:
        """Run ``apply()`` (write a change and pass it to the stages); when it raises, ``undo()``
        puts the old values back and ``bring_back()`` returns the stages to them, then the error
        is raised again. A failure to come back (the stages refuse the state they ran with) is a
        GraphError naming ``what``: the run cannot go on."""
        try:
            apply()
        except BaseException as exc:
            undo()
            try:
                bring_back()
            except Exception as again:
                raise GraphError(f"{what}: rejected ({exc}), and the stages could not return to the run's state "
                                 f"before it ({again}); compile the graph again") from again
            raise

    def _material_stages(self, what: str) -> None:
        """Refuse a material change on a graph where no frame stage shades BRDFs (it would be ignored)."""
        if not any(isinstance(st, FrameStage) and st.reads_materials for st in self.stages):
            shading = sorted(t for t, cls in stage_types().items() if issubclass(cls, FrameStage) and cls.reads_materials)
            raise GraphError(f"{what}: no frame stage of graph {self.spec.name!r} shades run-time BRDFs "
                             f"({', '.join(shading)} do); the change would be ignored")

    def set_lighting(self, lighting) -> None:
        """Replace the run's lighting: a :class:`~warpshade.scene.LightingSource` or a list of
        lights (fixed). Every frame stage is set up again (lights may differ in number).

        Raises:
            ValueError, StageError: lights a stage cannot shade (nothing changes then).
        """
        if not isinstance(lighting, LightingSource):
            items = [lighting] if isinstance(lighting, (Environment, DistantLight, SphereLight)) else list(lighting)
            lighting = LightingSource.fixed(items, self.scene.up_axis)
        ev = self.evaluator
        old = (ev.lighting_source, self.state.lighting, ev.input["sh_override"], self.lighting, self._override_on)

        def apply():
            ev.set_lighting(lighting)
            self.lighting = self.ctx.lighting = lighting
            self._override_on = False
            self.frame.setup(0)  # the lights may differ in number: every stage binds the new arrays

        def undo():
            ev.lighting_source, self.state.lighting = old[0], old[1]
            ev.input.write(sh_override=old[2])
            self.lighting = self.ctx.lighting = old[3]
            self._override_on = old[4]

        self._all_or_nothing("set_lighting", apply, undo, lambda: self.frame.setup(0))

    def set_albedo(self, albedo, prims=None) -> None:
        """New diffuse albedo for every vertex or for the meshes ``prims`` (see
        :meth:`~warpshade.scene.state.FrameEvaluator.set_albedo`); the next frame uses it.

        Raises:
            ValueError: a bad albedo or prim (nothing changes then).
        """
        before = self.evaluator.albedo.numpy().copy()
        self._all_or_nothing("set_albedo",
                             lambda: (self.evaluator.set_albedo(albedo, prims), self.notify_changed(Change.MATERIAL)),
                             lambda: self.evaluator.albedo.assign(before),
                             lambda: self.notify_changed(Change.MATERIAL))

    def set_material(self, brdf, prims=None) -> None:
        """Change the BRDF of every mesh, or of the meshes ``prims`` (prim paths), at run time:
        a :class:`~warpshade.scene.materials.BRDF`, or None to go back to the stages' own. No
        precompute runs; stages that shade BRDFs rebuild their operators (cached per BRDF) into
        their fixed buffers through :data:`~warpshade.scene.state.Change.MATERIAL`, so the next
        frame, recorded or not, already uses it.

        Raises:
            GraphError: no frame stage shades run-time BRDFs.
            ValueError, StageError: a BRDF or prim refused by the scene or by a stage (too many
                distinct BRDFs, a model the stage does not shade); nothing changes then.
        """
        self._material_stages("set_material")
        saved = self.state.materials.saved()
        self._all_or_nothing("set_material",
                             lambda: (self.evaluator.set_material(brdf, prims), self.notify_changed(Change.MATERIAL)),
                             lambda: self.evaluator.assign_materials(*saved),
                             lambda: self.notify_changed(Change.MATERIAL))

    def materials_at(self, frame) -> MaterialAssignment:
        """The :class:`~warpshade.scene.state.MaterialAssignment` of time code ``frame``: the
        material track's entries covering it (later ones win), else the current assignment."""
        return self.track.at(frame) if self.track else self.state.materials

    def _check_material_track(self) -> None:
        """Refuse a ``[[material]]`` track on a graph whose frame stages would ignore it."""
        if self.track:
            self._material_stages(f"{self.track.entries[0]['where']} (the graph's material track)")

    def _apply_material_track(self, frame) -> None:
        """Assign the track's BRDFs of time code ``frame`` when they differ from the last ones.

        Raises:
            GraphError: a stage refuses them, naming the track entries and the frame (the
                assignment before stays, and the frame is not run).
        """
        if not self.track:
            return
        want = self.track.at(frame)
        key = _identity(want)
        if key == self._track_key:
            return
        saved = self.state.materials.saved()

        def apply():
            self.evaluator.assign_materials(want.default, want.prims)
            self.notify_changed(Change.MATERIAL)

        try:
            self._all_or_nothing("material track", apply, lambda: self.evaluator.assign_materials(*saved),
                                 lambda: self.notify_changed(Change.MATERIAL))
        except (ValueError, GraphError) as exc:
            where = [e["where"] for e in self.track.entries if float(frame) in e["times"]]
            raise GraphError(f"{', '.join(where)} at frame {float(frame):g}: {exc}") from exc
        self._track_key = key

    def set_eye(self, position) -> None:
        """Move the viewer of view-dependent stages (world position); the next frame uses it.

        Raises:
            ValueError: not three finite numbers (nothing changes then).
        """
        ev = self.evaluator
        old = (self.state.eye.numpy().copy(), self.state.has_eye, ev.input["eye_from_host"], getattr(ev, "_eye_set", None))

        def undo():
            self.state.eye.assign(old[0])
            self.state.has_eye = old[1]
            ev.input.write(eye_from_host=old[2])
            ev._eye_set = old[3]

        self._all_or_nothing("set_eye", lambda: (ev.set_eye(position), self.notify_changed(Change.VIEW)), undo,
                             lambda: self.notify_changed(Change.VIEW))

    def set_parameter(self, stage: str, name: str, value) -> None:
        """Change a frame stage's parameter between frames (validated like the TOML value); the
        stage is told which parameter changed and is set up again unless it absorbs it.

        Raises:
            GraphError: an unknown stage or parameter, a precompute stage (its artifact would
                change: compile again), or a value that would change the stage's ports.
            StageError: a value the parameter or the stage's set-up refuses. Nothing changes then:
                the old value stays and the stage is set up with it again.
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

        def undo():
            st.params[name] = old

        self._all_or_nothing(f"set_parameter {stage}.{name}",
                             lambda: self.notify_changed(Change.PARAMETERS, [stage], keys=[name]), undo,
                             lambda: self.notify_changed(Change.PARAMETERS, [stage], keys=[name]))

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
