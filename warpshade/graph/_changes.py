"""Changes of a run that do not come from the frame: lighting, albedo, BRDFs, the eye, parameters.

:class:`RunChanges` is the part of :class:`~warpshade.graph._runtime.Runtime` that takes them. A
setter checks its value (refusing a bad one at once), writes the change where the frame reads
it (through the :class:`~warpshade.scene._state.FrameEvaluator`, the only writer of the frame's
host inputs) and marks it dirty; :meth:`RunChanges.update` passes every dirty change to the frame
stages at once (after Mitsuba's ``SceneParameters.update`` and Newton's
``notify_model_changed``). Each stage's :meth:`~warpshade.methods.stage.FrameStage.notify_changed`
gets the :class:`~warpshade.scene._state.Change` flags and the names of its changed parameters,
once per update, and says whether it absorbs them; those that do not are set up again with the
stages reading their outputs, each once. Outside :meth:`RunChanges.batch` a setter updates at
once; inside, the changes of the block make one update.

:class:`MaterialTrack` is the graph's ``[[material]]`` track: the BRDFs of each time code.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from ..methods.stage import Change, FrameStage, stage_types
from ..scene._lighting import DistantLight, Environment, LightingSource, SphereLight
from ..scene._state import MaterialAssignment
from ._errors import GraphError
from ._scene_inputs import parse_frames

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


class _Pending:
    """Changes marked since the last :meth:`RunChanges.update`, not yet passed to the stages.

    Attributes:
        keys: the dirty keys, in the order marked (``"lighting"``, ``"albedo"``, ``"material"``,
            ``"eye"``, ``(stage, parameter)``, or a :class:`Change` flag name from
            :meth:`RunChanges.notify_changed`), as a dict used as an ordered set.
        what: the setter calls, for error messages.
        told: frame stage name -> [Change flags, parameter names] to tell it (merged).
        setup_all: every frame stage is set up again (a new lighting: new light arrays).
        undo: callables putting back what each setter wrote, in the order written.
    """

    def __init__(self):
        self.keys: dict = {}
        self.what: list = []
        self.told: dict = {}
        self.setup_all = False
        self.undo: list = []

    def __bool__(self) -> bool:
        return bool(self.told) or self.setup_all


class RunChanges:
    """Run-time changes of a :class:`~warpshade.graph._runtime.Runtime` (mixed into it).

    Uses the runtime's ``scene``, ``stages``, ``evaluator``, ``frame`` (the
    :class:`~warpshade.graph._frame.FrameGraph`), ``ctx``, ``lighting`` and ``track``.

    A setter checks its value (a bad one is refused there, with nothing marked), writes it where
    the frame reads it and marks what changed dirty; :meth:`update` passes every dirty change to
    the stages at once. Outside a :meth:`batch` a setter updates at once, so each change applies
    by itself; inside one, changes wait for the end of the block (or an explicit :meth:`update`,
    or the next :meth:`~warpshade.graph._runtime.Runtime.step`), and each frame stage is told
    once, with every flag and parameter name of the batch, set up again at most once, and the
    frame is recorded anew at most once.

    Every update is all or nothing: when a stage refuses it (while rebuilding its operators or
    setting up again), what the setters wrote is put back, the stages are brought back to it, and
    the error is raised. A rejected change leaves the run exactly as it was, and later frames step
    as before.
    """

    def _start_changes(self) -> None:
        """Nothing dirty, no batch open (called by the runtime's constructor)."""
        self._pending = _Pending()
        self._batching = 0

    @property
    def dirty(self) -> frozenset:
        """The keys marked and not yet passed to the stages (see :meth:`update`); empty outside a
        :meth:`batch`."""
        return frozenset(self._pending.keys)

    @contextmanager
    def batch(self):
        """Gather the changes made in a ``with`` block into one :meth:`update` at its end::

            with rt.batch():
                rt.set_lighting(sky)
                rt.set_parameter("shade", "window", "hanning")
                rt.set_eye((0.0, 2.0, 3.0))
            rt.step(frame)  # each stage set up at most once, the frame recorded once

        A setter still refuses a bad value at once (nothing is marked then). Blocks may nest: an
        inner one joins the outermost. An exception leaving a block puts back every change not
        yet applied, then is raised again.

        Raises:
            StageError, GraphError: at the end of the block, a change a stage refuses (every
                change of the batch is put back then, as by :meth:`update`).
        """
        self._batching += 1
        try:
            yield self
        except BaseException as exc:
            self._batching -= 1
            pending, self._pending = self._pending, _Pending()
            self._put_back(pending, exc)
            raise
        self._batching -= 1
        if not self._batching:
            self.update()

    def update(self) -> frozenset:
        """Pass every change marked since the last update to the frame stages, at once.

        Each frame stage concerned is told once
        (:meth:`~warpshade.methods.stage.FrameStage.notify_changed`, with the union of the
        :class:`~warpshade.scene._state.Change` flags and parameter names of the changes); the
        stages that do not absorb them are set up again with every stage reading their outputs,
        each once (a new lighting sets every frame stage up again), and the frame is recorded
        anew at the next step. With nothing dirty it does nothing. A step updates first.

        Returns:
            the dirty keys applied (empty when nothing was dirty).

        Raises:
            StageError, GraphError: a stage refuses the changes; every one of them is put back.
        """
        pending, self._pending = self._pending, _Pending()
        if not pending:
            return frozenset()
        try:
            self._tell(pending)
        except BaseException as exc:
            self._put_back(pending, exc)
            raise
        return frozenset(pending.keys)

    def notify_changed(self, flags: Change, stages=None, keys=()) -> None:
        """Tell the frame stages that something outside the frame changed (marked dirty, then
        passed on by :meth:`update`: at once outside a :meth:`batch`).

        Each stage's :meth:`~warpshade.methods.stage.FrameStage.notify_changed` says whether it
        keeps working; those that do not are set up again with every stage reading their
        outputs, and the frame is recorded anew at the next step.

        Args:
            flags: :class:`~warpshade.scene._state.Change` flags.
            stages: names of the stages concerned (default: every frame stage).
            keys: with :data:`Change.PARAMETERS`, the names of the parameters that changed.
        """
        name = "|".join(f.name.lower() for f in Change if f & flags and f.name not in ("NONE", "ALL"))
        self._mark("notify_changed", name or "none", lambda: None, flags, stages, keys)

    def _mark(self, what: str, key, undo, flags: Change = Change.NONE, stages=None, keys=(),
              setup_all: bool = False) -> None:
        """Mark ``key`` dirty: the stages ``stages`` (default: every frame stage) are to be told
        ``flags`` and ``keys``; ``undo()`` puts back what the setter wrote. Outside a batch the
        change is applied now."""
        p = self._pending
        p.keys[key] = None
        p.what.append(what)
        p.undo.append(undo)
        p.setup_all = p.setup_all or setup_all
        if flags:
            names = None if stages is None else set(stages)
            for st in self.frame.stages:
                if names is None or st.name in names:
                    told = p.told.setdefault(st.name, [Change.NONE, set()])
                    told[0] |= flags
                    told[1].update(keys)
        if not self._batching:
            self.update()

    def _tell(self, pending: _Pending) -> None:
        """Tell each stage of ``pending`` its changes once, then set up those that do not absorb
        them (every stage with a new lighting), each once."""
        again = set()
        for st in self.frame.stages:
            told = pending.told.get(st.name)
            if told is not None and not st.notify_changed(Change(told[0]), frozenset(told[1])):
                again.add(st.name)
        if pending.setup_all:
            self.frame.setup(0)
        elif again:
            self.frame.setup_stages(again)

    def _put_back(self, pending: _Pending, exc: BaseException) -> None:
        """Undo what the setters of ``pending`` wrote (last first) and bring the stages back to it.
        A failure to come back (the stages refuse the state they ran with) is a GraphError naming
        the changes: the run cannot go on."""
        for undo in reversed(pending.undo):
            undo()
        if not pending:
            return
        try:
            self._tell(pending)
        except Exception as again:
            raise GraphError(f"{', '.join(pending.what)}: rejected ({exc}), and the stages could not return to the "
                             f"run's state before it ({again}); compile the graph again") from again

    def _everyone(self, flags: Change) -> _Pending:
        """A change telling every frame stage ``flags`` (for changes a step makes itself)."""
        pending = _Pending()
        pending.told = {st.name: [flags, set()] for st in self.frame.stages}
        return pending

    def _tell_now(self, what: str, apply, undo, flags: Change) -> None:
        """Inside a step: ``apply()`` writes a change and every frame stage is told ``flags`` at
        once (not batched); all or nothing, as :meth:`update`."""
        pending = self._everyone(flags)
        pending.what.append(what)
        pending.undo.append(undo)
        try:
            apply()
            self._tell(pending)
        except BaseException as exc:
            self._put_back(pending, exc)
            raise

    def _write(self, write, undo) -> None:
        """Run a setter's ``write()``; when it raises (a bad value), ``undo()`` and raise: nothing
        is marked."""
        try:
            write()
        except BaseException:
            undo()
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
            ValueError, StageError: lights a stage cannot shade (nothing changes then; in a
                :meth:`batch`, at its end).
        """
        if not isinstance(lighting, LightingSource):
            items = [lighting] if isinstance(lighting, (Environment, DistantLight, SphereLight)) else list(lighting)
            lighting = LightingSource.fixed(items, self.scene.up_axis)
        ev = self.evaluator
        old = (ev.lighting_source, self.state.lighting, ev.input["sh_override"], self.lighting, self._override_on)

        def write():
            ev.set_lighting(lighting)
            self.lighting = self.ctx.lighting = lighting
            self._override_on = False

        def undo():
            ev.lighting_source, self.state.lighting = old[0], old[1]
            ev.input.write(sh_override=old[2])
            self.lighting = self.ctx.lighting = old[3]
            self._override_on = old[4]

        self._write(write, undo)
        # the lights may differ in number: every stage binds the new arrays
        self._mark("set_lighting", "lighting", undo, setup_all=True)

    def set_albedo(self, albedo, prims=None) -> None:
        """New diffuse albedo for every vertex or for the meshes ``prims`` (see
        :meth:`~warpshade.scene._state.FrameEvaluator.set_albedo`); the next frame uses it.

        Raises:
            ValueError: a bad albedo or prim (nothing changes then).
        """
        before = self.evaluator.albedo.numpy().copy()
        undo = lambda: self.evaluator.albedo.assign(before)  # noqa: E731
        self._write(lambda: self.evaluator.set_albedo(albedo, prims), undo)
        self._mark("set_albedo", "albedo", undo, Change.MATERIAL)

    def set_material(self, brdf, prims=None) -> None:
        """Change the BRDF of every mesh, or of the meshes ``prims`` (prim paths), at run time:
        a :class:`~warpshade.scene._materials.BRDF`, or None to go back to the stages' own. No
        precompute runs; stages that shade BRDFs rebuild their operators (cached per BRDF) into
        their fixed buffers through :data:`~warpshade.scene._state.Change.MATERIAL`, so the next
        frame, recorded or not, already uses it.

        Raises:
            GraphError: no frame stage shades run-time BRDFs.
            ValueError, StageError: a BRDF or prim refused by the scene or by a stage (too many
                distinct BRDFs, a model the stage does not shade); nothing changes then. A
                stage's refusal comes, in a :meth:`batch`, at its end.
        """
        self._material_stages("set_material")
        saved = self.state.materials.saved()
        undo = lambda: self.evaluator.assign_materials(*saved)  # noqa: E731
        self._write(lambda: self.evaluator.set_material(brdf, prims), undo)
        self._mark("set_material", "material", undo, Change.MATERIAL)

    def materials_at(self, frame) -> MaterialAssignment:
        """The :class:`~warpshade.scene._state.MaterialAssignment` of time code ``frame``: the
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

        try:
            self._tell_now("material track", lambda: self.evaluator.assign_materials(want.default, want.prims),
                           lambda: self.evaluator.assign_materials(*saved), Change.MATERIAL)
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

        self._write(lambda: ev.set_eye(position), undo)
        self._mark("set_eye", "eye", undo, Change.VIEW)

    def set_parameter(self, stage: str, name: str, value) -> None:
        """Change a frame stage's parameter between frames (validated like the TOML value, here);
        the stage is told which parameter changed and is set up again unless it absorbs it.

        Raises:
            GraphError: an unknown stage or parameter, a precompute stage (its artifact would
                change: compile again), or a value that would change the stage's ports.
            StageError: a value the parameter refuses (here, with nothing marked) or the stage's
                set-up refuses (in a :meth:`batch`, at its end). Nothing changes then: the old
                value stays and the stage is set up with it again.
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

        self._mark(f"set_parameter {stage}.{name}", (stage, name), undo, Change.PARAMETERS, [stage], keys=[name])

    def _step_lighting(self, lighting) -> None:
        """This step's lighting override (None: the run's lights), and the stages told when it
        starts, changes or ends."""
        if lighting is not None:
            self.evaluator.set_lighting_override(self._override_coeffs(lighting))
            self._override_on = True
            self._tell(self._everyone(Change.LIGHTING))
        elif self._override_on:
            self.evaluator.set_lighting_override(None)
            self._override_on = False
            self._tell(self._everyone(Change.LIGHTING))

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
