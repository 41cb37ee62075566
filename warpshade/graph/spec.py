"""Stage graphs: specification, TOML loading and validation.

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
    scene = "bundled:blockers"                # or "warp-example:bunny"
    ground_plane = false                      # optional scene option
    frames = "0:60"                           # time codes A <= t < B (optional)
    output = "shade.radiance"

    [lighting]                                # optional; default: the scene's lights
    source = "scene"                          # "scene" | "distant" | "sky" | "constant" | path to .hdr/.exr
    rotate_degrees_per_frame = 3.0
    intensity = 1.0

    [validate]                                # optional: error against ground truth
    frames = [0, 30]
    samples = 1024

    [[material]]                              # optional material track (stages that shade BRDFs)
    frames = "30:60"                          # default: every frame; later tables win
    prims = ["/World/Bend/Tube"]              # default: every mesh
    brdf = "ggx"                              # warpshade.scene.materials.make_brdf kinds
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

import math
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

from ..methods.stage import Port, Stage, StageError, get_stage_type
from ..scene.lighting import Environment, LightingSource, SphereLight, scaled_light, up_rotation
from .errors import GraphError
from .runtime import Runtime

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["StageSpec", "GraphSpec", "load", "lighting_from_spec", "extend_static_frames", "check_name", "check_frames_spec",
           "SCENE_PORTS", "SCENE_OPTIONS"]


SCENE_PORTS: dict[str, Port] = {
    "points": Port("vec3", ("V",), "world-space vertex positions of the frame (FrameState.points)"),
    "normals": Port("vec3", ("V",), "world-space unit vertex normals of the frame (FrameState.normals)"),
    "albedo": Port("float32", ("V", 3), "per-vertex diffuse albedo, linear RGB (changes only by notification)"),
    "lighting": Port("lighting", (), "the frame's lights (FrameState.lighting, a FrameLighting)"),
}
SCENE_STATIC_PORTS = ("albedo",)


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
        where = f"graph {self.name!r}" + (f" ({self.source_path})" if self.source_path else "")
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
                            f"(outputs: {sorted(outs)})"
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

    def load_scene(self):
        """The graph's scene (its ``scene`` spec and ``[graph]`` scene options).

        Raises:
            GraphError: the graph names no scene, or a bad option; FileNotFoundError /
                ValueError from the loader (naming the file and prim).
        """
        spec = self.resolve_scene_spec()
        if spec is None:
            raise GraphError(f"graph {self.name!r}: no scene given and the graph names none")
        from ..io import load_scene

        options = dict(self.scene_options)
        frame_count = options.pop("frame_count", None)
        try:
            scene = load_scene(spec, **options)
        except TypeError as exc:
            raise GraphError(f"graph {self.name!r}: bad scene option in [graph]: {exc}") from None
        if frame_count is not None:
            scene = extend_static_frames(scene, int(frame_count))
        return scene

    def run_frames(self, scene, frames=None):
        """The time codes a run steps: ``frames`` (e.g. ``--frames``), else ``[graph] frames``,
        else every frame of the scene.

        Raises:
            GraphError: naming the selection when it is malformed or selects nothing.
        """
        from .runtime import parse_frames

        where = "frames" if frames is not None else f"graph {self.name!r}: [graph] frames"
        try:
            return parse_frames(frames if frames is not None else self.frames, scene)
        except (TypeError, ValueError) as exc:
            raise GraphError(f"{where}: {exc}") from None

    def _check_validate_frames(self, scene) -> None:
        for f in self.validate_spec.get("frames") or ():
            try:
                scene.frame_index(f)
            except (TypeError, ValueError) as exc:
                raise GraphError(f"graph {self.name!r}: [validate] frames: {exc}") from None

    def validation_frames(self, scene, run_frames=None) -> tuple[list, list]:
        """The ``[validate]`` frames a run measures, and those it leaves out.

        A run measures the ``[validate]`` frames (default: its first frame) that it steps;
        the others are left out (reported). Checked before any work.

        Returns:
            ``(measured, left_out)`` lists of time codes.

        Raises:
            GraphError: a ``[validate]`` frame that is no time code of the scene, or none of
                them in the run's frames.
        """
        run = [float(f) for f in (self.run_frames(scene) if run_frames is None else run_frames)]
        wanted = self.validate_spec.get("frames")
        if wanted is None:
            return [run[0]], []
        self._check_validate_frames(scene)
        where = f"graph {self.name!r}: [validate] frames"
        measured = [float(f) for f in wanted if any(abs(float(f) - r) <= 1e-6 for r in run)]
        left_out = [float(f) for f in wanted if float(f) not in measured]
        if not measured:
            raise GraphError(f"{where} {list(wanted)} are all outside the frames run ({run[0]:g}..{run[-1]:g}); "
                             "run frames that include one of them, or change [validate] frames")
        return measured, left_out

    def compile(self, scene=None, device=None, lighting=None, **kwargs) -> Runtime:
        """Validate against a scene and return a :class:`~warpshade.graph.runtime.Runtime`.

        Everything about the scene is checked before any precompute: its frames against
        ``[graph] frames`` and ``[validate]``, the ``[lighting]`` (an image source is read), the
        stage ports against the scene's dimensions.

        Args:
            scene: a :class:`~warpshade.scene.Scene`; default: load the graph's ``scene`` spec.
            device: Warp device (default: Warp's default device).
            lighting: a :class:`~warpshade.scene.LightingSource` overriding ``[lighting]``.
            **kwargs: passed to :class:`~warpshade.graph.runtime.Runtime` (``cache_dir``,
                ``progress``, ``capture``).
        """
        if scene is None:
            scene = self.load_scene()
        self.run_frames(scene)
        self._check_validate_frames(scene)
        if lighting is None:
            lighting = self.lighting_source(scene)
        return Runtime(self, scene, device=device, lighting=lighting, **kwargs)


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
        from ..io.images import read_image

        p = Path(source)
        if not p.is_absolute() and base_dir is not None:
            p = base_dir / p
        lights = [Environment(read_image(p), to_world=to_world, path=str(p))]
    if intensity != 1.0:
        lights = [scaled_light(light, intensity) for light in lights]
    return LightingSource(lights, scene.up_axis, speed, float(scene.frames[0]))


def extend_static_frames(scene, frame_count: int):
    """A static scene with ``frame_count`` time codes 0..frame_count-1 (e.g. to rotate lighting).

    Raises:
        GraphError: when the scene is animated (its own time range must be used).
    """
    if frame_count < 1:
        raise GraphError(f"frame_count must be >= 1, got {frame_count}")
    if not scene.is_static:
        raise GraphError(f"scene {scene.source}: frame_count only applies to static scenes (this one is animated)")
    from ..scene import Scene

    return Scene(
        scene.meshes, frames=range(frame_count), fps=scene.fps, skeletons=scene.skeletons, lights=scene.lights,
        camera=scene.camera, up_axis=scene.up_axis, source=scene.source, skipped=scene.skipped,
    )


_GRAPH_KEYS = {"name", "description", "scene", "frames", "output"}
#: Scene options a ``[graph]`` table may carry (passed to :func:`warpshade.io.load_scene`, except
#: ``frame_count``) and their types.
SCENE_OPTIONS = {"ground_plane": bool, "sky": bool, "ground_resolution": int, "frame_count": int}
_TABLES = ("graph", "lighting", "validate", "stage", "material")
_LIGHTING_KEYS = ("source", "rotate_degrees_per_frame", "intensity", "color")
_VALIDATE_KEYS = ("frames", "samples")
#: Graph and stage names: they become file and cache-key names, so no separators, no "..".
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")


def check_name(name, where: str) -> str:
    """A graph or stage name usable as a file name: letters, digits, ``_ . -``, at most 100,
    starting with a letter or digit, no ``..`` (nothing is ever written outside ``--out``).

    Raises:
        GraphError: naming ``where``.
    """
    if not isinstance(name, str) or not NAME_PATTERN.match(name) or ".." in name:
        raise GraphError(f"{where}: name {name!r} is not allowed: use letters, digits, '_', '.' and '-' "
                         "(at most 100, starting with a letter or digit, no '..'); it names the output files")
    return name


def _number(value, where: str, minimum: float | None = None, integer: bool = False):
    kind = "an integer" if integer else "a number"
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
        raise GraphError(f"{where} must be {kind}, got {value!r}")
    if not math.isfinite(value):
        raise GraphError(f"{where} must be finite, got {value!r}")
    if minimum is not None and value < minimum:
        raise GraphError(f"{where} must be >= {minimum}, got {value!r}")
    return value


def check_frames_spec(spec, where: str):
    """Syntax of a frame selection (``"A:B"``, ``"A"``, a list of numbers): finite numbers only.

    Raises:
        GraphError: naming ``where``.
    """
    if spec is None:
        return None
    if isinstance(spec, (list, tuple)):
        if not spec:
            raise GraphError(f"{where}: the list of frames is empty")
        for f in spec:
            _number(f, f"{where}: frame")
        return list(spec)
    if not isinstance(spec, str):
        raise GraphError(f"{where} must be a range 'A:B', one time code or a list of numbers, got {spec!r}")
    parts = spec.split(":", 1) if ":" in spec else [spec]
    for part in parts:
        if not part.strip() and len(parts) == 2:
            continue
        try:
            value = float(part)
        except ValueError:
            raise GraphError(f"{where}: {part.strip()!r} in {spec!r} is not a number (expected 'A:B', 'A' or a list)") from None
        if not math.isfinite(value):
            raise GraphError(f"{where}: {spec!r} is not a finite time code")
    return spec


def _check_lighting_table(t, where: str) -> dict:
    if not isinstance(t, dict):
        raise GraphError(f"{where}: [lighting] must be a table")
    unknown = sorted(set(t) - set(_LIGHTING_KEYS))
    if unknown:
        raise GraphError(f"{where}: [lighting] has unknown key(s) {unknown}; known: {list(_LIGHTING_KEYS)}")
    if "source" in t and not isinstance(t["source"], str):
        raise GraphError(f"{where}: [lighting] source must be 'scene', 'sky', 'constant' or an image path, got {t['source']!r}")
    if "rotate_degrees_per_frame" in t:
        _number(t["rotate_degrees_per_frame"], f"{where}: [lighting] rotate_degrees_per_frame")
    if "intensity" in t:
        _number(t["intensity"], f"{where}: [lighting] intensity", minimum=0.0)
    if "color" in t:
        c = t["color"]
        if not isinstance(c, list) or len(c) != 3:
            raise GraphError(f"{where}: [lighting] color must be three numbers, got {c!r}")
        for x in c:
            _number(x, f"{where}: [lighting] color component", minimum=0.0)
    return t


def _check_validate_table(t, where: str) -> dict:
    from .._limits import MAX_RAYS_PER_VERTEX

    if not isinstance(t, dict):
        raise GraphError(f"{where}: [validate] must be a table")
    unknown = sorted(set(t) - set(_VALIDATE_KEYS))
    if unknown:
        raise GraphError(f"{where}: [validate] has unknown key(s) {unknown}; known: {list(_VALIDATE_KEYS)}")
    if "frames" in t:
        if not isinstance(t["frames"], list):
            raise GraphError(f"{where}: [validate] frames must be a list of time codes, got {t['frames']!r}")
        check_frames_spec(t["frames"], f"{where}: [validate] frames")
    if "samples" in t:
        n = _number(t["samples"], f"{where}: [validate] samples", minimum=4, integer=True)
        if n > MAX_RAYS_PER_VERTEX:
            raise GraphError(f"{where}: [validate] samples = {n} exceeds the limit of {MAX_RAYS_PER_VERTEX} rays per vertex")
    return t


def _check_material_tables(tables, where: str, base_dir) -> list:
    """The ``[[material]]`` track: a BRDF (the keys of :func:`warpshade.scene.materials.brdf_from_spec`)
    per frame range (``frames``, default every frame) for every mesh or the meshes ``prims``."""
    from ..scene.brdfs import brdf_from_spec

    if not isinstance(tables, list):
        raise GraphError(f"{where}: [[material]] must be an array of tables")
    out = []
    for i, t in enumerate(tables):
        at = f"{where}: [[material]] #{i + 1}"
        if not isinstance(t, dict):
            raise GraphError(f"{at} must be a table")
        frames = check_frames_spec(t.get("frames"), f"{at} frames")
        prims = t.get("prims")
        if prims is not None and (not isinstance(prims, list) or not all(isinstance(p, str) for p in prims) or not prims):
            raise GraphError(f"{at}: prims must be a non-empty list of mesh prim paths, got {prims!r}")
        try:
            brdf = brdf_from_spec({k: v for k, v in t.items() if k not in ("frames", "prims")}, at, base_dir)
        except ValueError as exc:
            raise GraphError(str(exc)) from None
        out.append({"frames": frames, "prims": prims, "brdf": brdf, "where": at})
    return out


def _check_scene_options(options: dict, where: str) -> dict:
    from .._limits import MAX_TIME_CODES

    for key, value in options.items():
        if key not in SCENE_OPTIONS:
            raise GraphError(f"{where}: [graph] has unknown key {key!r}; known: {sorted(_GRAPH_KEYS | set(SCENE_OPTIONS))}")
        want = SCENE_OPTIONS[key]
        if want is bool and not isinstance(value, bool):
            raise GraphError(f"{where}: [graph] {key} must be true or false, got {value!r}")
        if want is int:
            _number(value, f"{where}: [graph] {key}", minimum=1 if key == "frame_count" else 2, integer=True)
    if options.get("frame_count", 1) > MAX_TIME_CODES:
        raise GraphError(f"{where}: [graph] frame_count = {options['frame_count']} exceeds the limit of {MAX_TIME_CODES} "
                         "time codes (warpshade._limits.MAX_TIME_CODES)")
    return options


def load(path) -> GraphSpec:
    """Load a stage graph from a TOML file (see module docstring for the layout).

    Everything that can be checked without the scene is checked here: the file, TOML syntax,
    the tables and their keys, the types and ranges of values, graph and stage names, frame
    selections, stage types and parameters (:meth:`GraphSpec.build`).

    Raises:
        GraphError: naming the file and the table or key at fault.
    """
    path = Path(path)
    if not path.exists():
        raise GraphError(f"stage graph file {path} does not exist")
    if path.is_dir():
        raise GraphError(f"stage graph file {path} is a directory, not a TOML file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise GraphError(f"stage graph file {path}: cannot be read ({exc.strerror or exc})") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        raise GraphError(f"stage graph file {path}: is not a text (UTF-8 TOML) file") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise GraphError(f"stage graph file {path}: invalid TOML: {exc}") from None
    where = f"stage graph file {path}"
    unknown = sorted(set(doc) - set(_TABLES))
    if unknown:
        raise GraphError(f"{where}: unknown table(s) {unknown}; known: {list(_TABLES)}")
    g = doc.get("graph")
    if not isinstance(g, dict):
        raise GraphError(f"{where}: missing [graph] table")
    if "output" not in g:
        raise GraphError(f"{where}: [graph] needs an 'output = \"stage.port\"' entry")
    for key in ("output", "description", "scene"):
        if key in g and not isinstance(g[key], str):
            raise GraphError(f"{where}: [graph] {key} must be a string, got {g[key]!r}")
    default_name = re.sub(r"[^A-Za-z0-9_.-]", "_", path.stem).strip("._-") or "graph"
    name = check_name(g.get("name", default_name), f"{where}: [graph]")
    frames = check_frames_spec(g.get("frames"), f"{where}: [graph] frames")
    scene_options = _check_scene_options({k: v for k, v in g.items() if k not in _GRAPH_KEYS}, where)
    raw_stages = doc.get("stage", [])
    if not isinstance(raw_stages, list) or not raw_stages:
        raise GraphError(f"{where}: needs at least one [[stage]] table")
    stages = []
    for i, st in enumerate(raw_stages):
        if not isinstance(st, dict) or "name" not in st or "type" not in st:
            raise GraphError(f"{where}: [[stage]] #{i + 1} needs 'name' and 'type'")
        check_name(st["name"], f"{where}: [[stage]] #{i + 1}")
        if not isinstance(st["type"], str):
            raise GraphError(f"{where}: stage {st['name']!r}: 'type' must be a string, got {st['type']!r}")
        params = {k: v for k, v in st.items() if k not in ("name", "type", "inputs")}
        inputs = st.get("inputs", {})
        if not isinstance(inputs, dict) or not all(isinstance(v, str) for v in inputs.values()):
            raise GraphError(f"{where}: stage {st['name']!r}: 'inputs' must be a table of \"stage.port\" strings")
        stages.append(StageSpec(st["name"], st["type"], params, inputs))
    lighting = _check_lighting_table(doc.get("lighting", {}), where)
    validate = _check_validate_table(doc.get("validate", {}), where)
    material_track = _check_material_tables(doc.get("material", []), where, path.resolve().parent)
    spec = GraphSpec(
        stages=stages,
        output=g["output"],
        name=name,
        description=g.get("description", ""),
        scene=g.get("scene"),
        scene_options=scene_options,
        frames=frames,
        lighting=lighting,
        validate_spec=validate,
        source_path=path.resolve(),
        materials=material_track,
    )
    spec.build()  # stage types, parameters, wiring: before any scene is loaded
    return spec
