"""Stage graphs: the specification, its wiring and validation, and compiling it to a run.

Graphs are written in Python (:class:`GraphSpec`) or TOML (:func:`warpshade.graph._loader.load`).

A graph names a scene, a lighting set-up, a frame range, a list of stages (each a registered
stage type with parameters) and the output port that carries per-vertex radiance. Stage inputs
are wired explicitly (``inputs = { transfer = "bake.transfer" }``) or, when omitted, to the one
upstream output with the same port name; the implicit source ``scene`` provides:

========== ======== =========== =====================================================
port        dtype    shape       meaning
========== ======== =========== =====================================================
points      vec3     (V,)        world-space vertex positions of the frame
normals     vec3     (V,)        world-space unit vertex normals of the frame
albedo      float32  (V, 3)      per-vertex diffuse albedo (changed only by notification)
lighting    lighting ()          the frame's lights (a ``FrameLighting``: SH, sphere, distant)
========== ======== =========== =====================================================

Validation happens before anything runs and raises :class:`GraphError` naming the stage and
port: unknown stage types or parameters, missing or ambiguous inputs, dtype or shape mismatch,
precompute stages fed by per-frame outputs, duplicate names and cycles.

TOML layout (paths are relative to the TOML file)::

    [graph]
    name = "blockers-shexp"
    description = "..."
    long_precompute = "..."                   # optional: why its precompute takes minutes on a CPU
    scene = "bundled:blockers"                # or "warp-example:bunny"
    ground_plane = false                      # optional scene option
    frames = "0:60"                           # time codes A <= t < B (optional)
    output = "shade.radiance"

    [lighting]                                # optional; default: the scene's lights
    source = "scene"                          # "scene" | "distant" | "sky" | "constant" | path to .hdr/.exr
    rotate_degrees_per_frame = 3.0
    intensity = 1.0

    [validate]                                # optional: error against ground truth
    frames = [0, 30]                          # those the run steps; others are left out, said
                                              # before the run (none in the scene: its first frame)
    samples = 1024

    [[material]]                              # optional material track (stages that shade BRDFs)
    frames = "30:60"                          # default: every frame; later tables win
    prims = ["/World/Bend/Tube"]              # default: every mesh
    brdf = "ggx"                              # warpshade.scene._materials.make_brdf kinds
    roughness = 0.3

    [[stage]]
    name = "bake"
    type = "prt.transfer"
    order = 4

    [[stage]]
    name = "shade"
    type = "prt.shade"
    inputs = { transfer = "bake.transfer" }
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..methods.stage import Port, Stage, StageContext, StageError, get_stage_type
from ..scene._lighting import LightingSource
from ._errors import GraphError
from ._runtime import Runtime
from ._scene_inputs import extend_static_frames, lighting_from_spec, parse_frames, scene_animation

__all__ = [
    "Wire",
]


SCENE_PORTS: dict[str, Port] = {
    "points": Port("vec3", ("V",), "world-space vertex positions of the frame (FrameState.points)"),
    "normals": Port("vec3", ("V",), "world-space unit vertex normals of the frame (FrameState.normals)"),
    "albedo": Port("float32", ("V", 3), "per-vertex diffuse albedo, linear RGB (changes only by notification)"),
    "lighting": Port("lighting", (), "the frame's lights (FrameState.lighting, a FrameLighting)"),
}
SCENE_STATIC_PORTS = ("albedo",)
#: Ports renamed so that each name has one meaning (``frames``: time codes): old name -> new name
#: (the parameters and stage types: :data:`warpshade.methods.stage.RENAMED_PARAMS`, ``RENAMED_TYPES``).
#: A wire that still names an old port is refused with the new name.
RENAMED_PORTS = {"frames": "tangents"}


def _renamed_port(port: str, ports) -> str:
    """``"; port 'old' was renamed 'new'"`` when ``port`` is a renamed port whose new name is among
    ``ports``, else ``""``."""
    new = RENAMED_PORTS.get(port)
    return f"; port {port!r} was renamed {new!r}" if new is not None and new in ports else ""


@dataclass
class StageSpec:
    """One stage of a graph: a unique name, a registered type, parameters and explicit inputs."""

    name: str
    type: str
    params: dict = field(default_factory=dict)
    inputs: dict = field(default_factory=dict)


@dataclass
class Wire:
    """A resolved connection: ``provider`` ("scene" or a stage name) and its ``port``."""

    provider: str
    port: str

    def __str__(self) -> str:
        return f"{self.provider}.{self.port}"


def _time_codes(scene) -> str:
    """The scene's time codes in words, for messages."""
    t = scene.frames
    if len(t) == 1:
        return f"one frame, time code {t[0]:g}"
    return f"{len(t)} frames, time codes {t[0]:g}..{t[-1]:g}"


@dataclass
class ValidationFrames:
    """What a ``--validate`` run measures (:meth:`GraphSpec.validation_plan`).

    Attributes:
        measured: time codes measured.
        outside_run: ``[validate]`` frames of the scene that the run does not step.
        not_in_scene: ``[validate]`` frames that are no time code of the scene.
        fallback: no ``[validate]`` frame is a time code of the scene, so the run's first frame
            is measured.
        run: the time codes the run steps; scene_times: the scene's time codes in words.
    """

    measured: list
    outside_run: list
    not_in_scene: list
    fallback: bool
    run: list
    scene_times: str

    @property
    def left_out(self) -> list:
        """Every ``[validate]`` frame not measured."""
        return self.outside_run + self.not_in_scene

    def note(self) -> str | None:
        """One line on what is measured instead of what ``[validate]`` asks, or None."""
        if not self.left_out:
            return None
        frames = ", ".join(f"{f:g}" for f in self.measured)
        parts = [f"--validate measures frame(s) {frames}" + (" (the first frame run)" if self.fallback else "")]
        if self.outside_run:
            parts.append(f"[validate] frame(s) {', '.join(f'{f:g}' for f in self.outside_run)} are outside the frames run "
                         f"({self.run[0]:g}..{self.run[-1]:g}) and are left out")
        if self.not_in_scene:
            parts.append(f"[validate] frame(s) {', '.join(f'{f:g}' for f in self.not_in_scene)} are not time codes of the "
                         f"scene ({self.scene_times}) and are left out")
        return "; ".join(parts)


@dataclass
class GraphSpec:
    """A stage graph (see module docstring). Build from Python or with :func:`load`."""

    stages: list
    output: str
    name: str = "graph"
    description: str = ""
    scene: str | None = None
    scene_options: dict = field(default_factory=dict)
    frames: str | None = None
    lighting: dict = field(default_factory=dict)
    validate_spec: dict = field(default_factory=dict)
    source_path: Path | None = None
    #: the material track: ``[[material]]`` tables, each ``{"frames": spec, "prims": [...] or None,
    #: "brdf": BRDF, "where": str}`` (later entries win where they overlap).
    materials: list = field(default_factory=list)
    #: ``[graph] long_precompute``: why the precompute takes minutes on a CPU ("" when it takes
    #: seconds); it says so to readers (and the README's test), the run does not read it.
    long_precompute: str = ""
    #: The stages :func:`~warpshade.graph._loader.load` built to check the graph, with the stage
    #: table they were built from: the first compile uses them when the table is unchanged.
    _checked: tuple | None = field(default=None, init=False, repr=False, compare=False)

    # ---- validation ---------------------------------------------------------------------
    def build(self, dims: dict | None = None):
        """Instantiate and validate the stages.

        Args:
            dims: concrete scene dimensions (``{"V": ..., "T": ..., "F": ...}``); when given,
                symbolic shapes are checked against them too.

        Returns:
            (ordered stages, wiring) where wiring maps stage name -> {input port: Wire}.

        Raises:
            GraphError: naming the stage and port at fault.
        """
        return self._wire(self._instantiate(), dims)

    def check(self) -> None:
        """Check stage types, parameters and wiring before any scene is loaded; the stages built
        for it are kept for the first :meth:`compile` (while the stage table is unchanged)."""
        stages, _ = self.build()
        self._checked = (self._stage_table(), stages)

    def _where(self) -> str:
        return f"graph {self.name!r}" + (f" ({self.source_path})" if self.source_path else "")

    def _stage_table(self) -> list:
        """A copy of what the stages are built from (to tell whether it changed)."""
        return copy.deepcopy([(s.name, s.type, s.params, s.inputs) for s in self.stages])

    def _instantiate(self) -> dict[str, Stage]:
        where = self._where()
        if not self.stages:
            raise GraphError(f"{where}: has no stages")
        stages: dict[str, Stage] = {}
        for spec in self.stages:
            if spec.name in stages or spec.name == "scene":
                raise GraphError(f"{where}: stage name {spec.name!r} is used twice (or is reserved)")
            try:
                cls = get_stage_type(spec.type, spec.name)
                stages[spec.name] = cls(spec.name, spec.params)
            except StageError as exc:
                raise GraphError(f"{where}: {exc}") from None
        return stages

    def _stages_for_run(self, dims: dict):
        """The stages of a new run, wired and checked against the scene's ``dims``: those
        :meth:`check` built, once, when the stage table has not changed since; new ones else."""
        checked, self._checked = self._checked, None
        if checked is not None and checked[0] == self._stage_table():
            return self._wire({s.name: s for s in checked[1]}, dims)
        return self.build(dims)

    def _wire(self, stages: dict, dims: dict | None):
        """(ordered stages, wiring) of the instantiated ``stages``, validated (see :meth:`build`)."""
        where = self._where()
        providers: dict[str, list[Wire]] = {}
        for port in SCENE_PORTS:
            providers.setdefault(port, []).append(Wire("scene", port))
        for name, st in stages.items():
            for port in st.output_ports():
                providers.setdefault(port, []).append(Wire(name, port))

        wiring: dict[str, dict[str, Wire]] = {}
        explicit = {s.name: dict(s.inputs) for s in self.stages}
        for name, st in stages.items():
            wiring[name] = {}
            declared = st.input_ports()
            for port in explicit[name]:
                if port not in declared:
                    raise GraphError(
                        f"{where}: stage {name!r} has no input port {port!r} (inputs: {sorted(declared)})"
                        f"{_renamed_port(port, declared)}"
                    )
            for port, want in declared.items():
                if port in explicit[name]:
                    target = str(explicit[name][port])
                    if "." not in target:
                        raise GraphError(f"{where}: stage {name!r} input {port!r}: {target!r} is not 'stage.port'")
                    prov, pport = target.split(".", 1)
                    if prov != "scene" and prov not in stages:
                        raise GraphError(
                            f"{where}: stage {name!r} input {port!r} names unknown stage {prov!r}"
                        )
                    outs = SCENE_PORTS if prov == "scene" else stages[prov].output_ports()
                    if pport not in outs:
                        raise GraphError(
                            f"{where}: stage {name!r} input {port!r}: {prov!r} has no output {pport!r} "
                            f"(outputs: {sorted(outs)}){_renamed_port(pport, outs)}"
                        )
                    wire = Wire(prov, pport)
                else:
                    cands = [w for w in providers.get(port, []) if w.provider != name]
                    if not cands:
                        raise GraphError(f"{where}: stage {name!r} input {port!r} is not connected (no provider)")
                    if len(cands) > 1:
                        raise GraphError(
                            f"{where}: stage {name!r} input {port!r} is ambiguous: "
                            f"{', '.join(map(str, cands))}; wire it explicitly"
                        )
                    wire = cands[0]
                if wire.provider == name:
                    raise GraphError(f"{where}: stage {name!r} input {port!r} is wired to itself")
                self._check_types(where, stages, name, port, want, wire, dims)
                wiring[name][port] = wire

        for name, st in stages.items():  # each stage's own checks of what feeds it, before any work
            try:
                st.check_wiring({port: (stages.get(w.provider), w.port) for port, w in wiring[name].items()})
            except StageError as exc:
                raise GraphError(f"{where}: {exc}") from None
        order = self._topological_order(where, stages, wiring)
        if "." not in self.output:
            raise GraphError(f"{where}: output {self.output!r} is not 'stage.port'")
        oname, oport = self.output.split(".", 1)
        if oname not in stages or oport not in stages[oname].output_ports():
            raise GraphError(f"{where}: output {self.output!r} is not an output of any stage")
        if stages[oname].kind != "frame":
            raise GraphError(f"{where}: output {self.output!r} must come from a per-frame stage")
        return [stages[n] for n in order], wiring

    @staticmethod
    def _check_types(where, stages, name, port, want: Port, wire: Wire, dims):
        consumer = stages[name]
        if wire.provider == "scene":
            have = SCENE_PORTS[wire.port]
            have_dims = {}
            prov_kind = "static" if wire.port in SCENE_STATIC_PORTS else "frame"
        else:
            prov = stages[wire.provider]
            have = prov.output_ports()[wire.port]
            have_dims = prov.dims()
            prov_kind = prov.kind
        if consumer.kind == "precompute" and prov_kind == "frame":
            raise GraphError(
                f"{where}: precompute stage {name!r} input {port!r} is fed by per-frame output {wire}"
            )
        if want.dtype != "object" and have.dtype != want.dtype:
            raise GraphError(
                f"{where}: stage {name!r} input {port!r} expects dtype {want.dtype}, {wire} gives {have.dtype}"
            )
        if want.dtype in ("arrays", "lighting", "object"):
            return
        scene_dims = dict(dims or {})

        def concrete(shape, local):
            out = []
            for d in shape:
                if isinstance(d, str):
                    v = local.get(d, scene_dims.get(d))
                    out.append(v if v is not None else d)
                else:
                    out.append(int(d))
            return tuple(out)

        a = concrete(want.shape, consumer.dims())
        b = concrete(have.shape, have_dims)
        if len(a) != len(b) or any(
            (isinstance(x, int) and isinstance(y, int) and x != y) or (isinstance(x, str) and isinstance(y, str) and x != y)
            for x, y in zip(a, b)
        ):
            raise GraphError(
                f"{where}: stage {name!r} input {port!r} expects shape {a}, {wire} gives shape {b}"
            )

    @staticmethod
    def _topological_order(where, stages, wiring) -> list[str]:
        deps = {n: {w.provider for w in wiring[n].values() if w.provider != "scene"} for n in stages}
        order: list[str] = []
        ready = [n for n in stages if not deps[n]]
        remaining = {n: set(d) for n, d in deps.items()}
        while ready:
            n = ready.pop(0)
            order.append(n)
            for m in stages:
                if n in remaining[m]:
                    remaining[m].discard(n)
                    if not remaining[m] and m not in order and m not in ready:
                        ready.append(m)
        if len(order) != len(stages):
            cyc = sorted(n for n in stages if n not in order)
            raise GraphError(f"{where}: cycle among stages {cyc}")
        # precompute stages first (they never depend on frame stages), stable otherwise
        return [n for n in order if stages[n].kind == "precompute"] + [n for n in order if stages[n].kind == "frame"]

    # ---- compile ------------------------------------------------------------------------
    def resolve_scene_spec(self) -> str | None:
        """The scene spec with a relative path resolved against the TOML file's directory."""
        if self.scene is None:
            return None
        if ":" in self.scene and not Path(self.scene).drive and not self.scene.startswith(("/", ".")):
            return self.scene  # e.g. "warp-example:bunny"
        p = Path(self.scene)
        if not p.is_absolute() and self.source_path is not None:
            p = (self.source_path.parent / p).resolve()
        return str(p)

    def lighting_source(self, scene) -> LightingSource:
        """The graph's ``[lighting]`` table as a :class:`~warpshade.scene.LightingSource`."""
        try:
            return lighting_from_spec(self.lighting, scene, self.source_path.parent if self.source_path else None)
        except ValueError as exc:
            raise GraphError(f"graph {self.name!r}: {exc}") from None

    def load_scene(self, scene: str | None = None):
        """The graph's scene (its ``scene`` spec and ``[graph]`` scene options).

        Args:
            scene: a scene spec that replaces the graph's ``scene`` (``warpshade run --scene``): a
                USD file (relative to the current directory), ``warp-example:NAME`` or
                ``bundled:NAME``. The graph's scene options apply to it, ``frame_count`` only when
                nothing in it moves (:func:`~warpshade.graph._scene_inputs.scene_animation`): an
                animated scene runs its own time codes (:meth:`frame_count_skipped` says so).

        Raises:
            GraphError: the graph names no scene, or a bad option; FileNotFoundError /
                ValueError from the loader (naming the file and prim).
        """
        spec = scene if scene is not None else self.resolve_scene_spec()
        if spec is None:
            raise GraphError(f"graph {self.name!r}: no scene given and the graph names none")
        from ..io import load_scene

        options = dict(self.scene_options)
        frame_count = options.pop("frame_count", None)
        try:
            loaded = load_scene(spec, **options)
        except TypeError as exc:
            raise GraphError(f"graph {self.name!r}: bad scene option in [graph]: {exc}") from None
        if frame_count is not None and not (scene is not None and self.frame_count_skipped(loaded)):
            loaded = extend_static_frames(loaded, int(frame_count))
        return loaded

    def frame_count_skipped(self, scene) -> str | None:
        """Why the graph's ``frame_count`` does not apply to ``scene`` (what moves in it), or None
        when it applies or the graph has none."""
        if self.scene_options.get("frame_count") is None:
            return None
        return scene_animation(scene)

    def run_frames(self, scene, frames=None):
        """The time codes a run steps: ``frames`` (e.g. ``--frames``), else ``[graph] frames``,
        else every frame of the scene.

        Raises:
            GraphError: naming the selection when it is malformed or selects nothing.
        """
        where = "frames" if frames is not None else f"graph {self.name!r}: [graph] frames"
        try:
            return parse_frames(frames if frames is not None else self.frames, scene)
        except (TypeError, ValueError) as exc:
            raise GraphError(f"{where}: {exc}") from None

    def _check_validate_frames(self, scene) -> None:
        """Each ``[validate]`` frame is a finite number (whether the scene has it is decided by
        :meth:`validation_plan`, when a run measures)."""
        for f in self.validate_spec.get("frames") or ():
            if isinstance(f, (bool, np.bool_)) or not isinstance(f, (int, float, np.integer, np.floating)):
                raise GraphError(f"graph {self.name!r}: [validate] frames: frame must be a number (a time code), got {f!r}")
            if not np.isfinite(f):
                raise GraphError(f"graph {self.name!r}: [validate] frames: frame must be a finite time code, got {f!r}")

    def validation_plan(self, scene, run_frames=None) -> "ValidationFrames":
        """The ``[validate]`` frames a run measures, and those it leaves out and why.

        A run measures the ``[validate]`` frames (default: its first frame) that it steps. Of the
        others, those the scene has are left out as outside the frames run, and those it does not
        have (a graph copied onto another scene: a static asset is one frame, time code 0) as not
        time codes of the scene. When every ``[validate]`` frame is missing from the scene, the
        run's first frame is measured instead (a static scene validates its one frame). Checked
        before any work; :meth:`ValidationFrames.note` says what was decided.

        Raises:
            GraphError: every ``[validate]`` frame the scene has lies outside the frames run (and
                none is run): naming them and the fix.
        """
        run = [float(f) for f in (self.run_frames(scene) if run_frames is None else run_frames)]
        wanted = self.validate_spec.get("frames")
        if wanted is None:
            return ValidationFrames([run[0]], [], [], False, run, _time_codes(scene))
        self._check_validate_frames(scene)
        times = np.asarray(scene.frames, np.float64)
        in_scene = [float(f) for f in wanted if np.min(np.abs(times - float(f))) <= 1e-6]
        missing = [float(f) for f in wanted if float(f) not in in_scene]
        measured = [f for f in in_scene if any(abs(f - r) <= 1e-6 for r in run)]
        outside = [f for f in in_scene if f not in measured]
        if not measured and outside:
            where = f"graph {self.name!r}: [validate] frames"
            raise GraphError(f"{where} {list(wanted)} are all outside the frames run ({run[0]:g}..{run[-1]:g}); "
                             "run frames that include one of them, or change [validate] frames")
        fallback = not measured
        return ValidationFrames([run[0]] if fallback else measured, outside, missing, fallback, run, _time_codes(scene))

    def validation_frames(self, scene, run_frames=None) -> tuple[list, list]:
        """The ``[validate]`` frames a run measures, and those it leaves out (:meth:`validation_plan`).

        Returns:
            ``(measured, left_out)`` lists of time codes.
        """
        plan = self.validation_plan(scene, run_frames)
        return plan.measured, plan.left_out

    def compile(self, scene=None, device=None, lighting=None, **kwargs) -> Runtime:
        """Validate against a scene and return a :class:`~warpshade.graph._runtime.Runtime`.

        Everything about the scene is checked before any precompute: its frames against
        ``[graph] frames`` and ``[validate]``, the ``[lighting]`` (an image source is read), the
        stage ports against the scene's dimensions.

        Args:
            scene: a :class:`~warpshade.scene.Scene`; default: load the graph's ``scene`` spec.
            device: Warp device (default: Warp's default device).
            lighting: a :class:`~warpshade.scene.LightingSource` overriding ``[lighting]``.
            **kwargs: passed to :class:`~warpshade.graph._runtime.Runtime` (``cache_dir``,
                ``progress``, ``capture``).
        """
        if scene is None:
            scene = self.load_scene()
        self.run_frames(scene)
        self._check_validate_frames(scene)
        if lighting is None:
            lighting = self.lighting_source(scene)
        stages, wiring = self._stages_for_run({"V": scene.vertex_count, "T": len(scene.frames), "F": scene.triangle_count})
        source = getattr(self, "source_path", None)
        ctx = StageContext(scene, device, {"V": scene.vertex_count, "T": len(scene.frames), "F": scene.triangle_count},
                           base_dir=Path(source).parent if source is not None else None)
        for st in stages:  # parameter, file-header and scene checks of every stage before any precompute
            st.check_scene(scene, ctx)
        return Runtime(self, scene, stages, wiring, device=device, lighting=lighting, **kwargs)
