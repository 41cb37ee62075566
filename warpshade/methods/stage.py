"""Stages: the unit of work of a stage graph.

A stage declares typed input and output ports and typed parameters, and is one of two kinds:

* ``"precompute"`` -- runs once per scene and parameters; :meth:`PrecomputeStage.precompute` returns
  host artifacts (NumPy arrays) that the runtime caches on disk, keyed by a content hash of
  everything that matters (stage type and version, parameters, the scene when the stage reads
  it, and the keys of its input artifacts), so a change anywhere upstream recomputes it and
  nothing else;
* ``"frame"`` -- runs every frame. :meth:`FrameStage.setup` allocates its device outputs once and
  binds its inputs (device arrays of upstream ports, the scene's per-frame arrays);
  :meth:`FrameStage.launch` ``(state)`` only launches kernels on fixed buffers, reading what
  changes per frame from the :class:`~warpshade.scene._state.FrameState` -- never from the
  runtime or another stage -- so the whole frame (scene evaluation and every stage) is recorded
  once and replayed, on CUDA and on the CPU (:func:`warpshade._wp.record_program`).

Changes that do not come from the frame (a new lighting, albedo, eye or a stage parameter)
reach a frame stage through one call per update, :meth:`FrameStage.notify_changed` with
:class:`~warpshade.scene._state.Change` flags and the names of the parameters that changed
(after Newton's ``notify_model_changed`` and Mitsuba's ``SceneParameters.update``).

Every stage type registers itself under a dotted name (``"prt.transfer"``) with
:func:`register_stage`; stage graphs (TOML or Python, :mod:`warpshade.graph`) refer to stages
by that name. This module sits in the methods layer so that each method's ``_stages.py`` can
subclass :class:`Stage` without importing the graph runtime above it.

Port shape symbols, the same in every method: ``V`` vertices, ``F`` triangles, ``T`` frames of
the scene; ``C`` SH coefficients (``order**2``) and ``N`` SH bands (``order``, the length of a
zonal-harmonic coefficient vector), both from the stage's own order; a stage may add symbols of
its own through :meth:`Stage.dims`.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any, ClassVar

from ..scene._state import Change

__all__: list[str] = []

#: dtypes a port may carry. Array ports carry Warp arrays per frame and NumPy arrays as
#: precompute artifacts; "arrays" carries a named set of NumPy arrays (a structured model such
#: as a sphere hierarchy: cached as one artifact, handed to consumers as a host dict, never
#: uploaded as a whole); "lighting" carries the per-frame lighting object; "object" carries any
#: host object (validated by type name only).
PORT_DTYPES = ("float32", "float64", "int32", "vec3", "mat33", "arrays", "lighting", "object")

#: Parameters renamed so that each name has one meaning (``frames``: time codes; ``samples``: rays
#: per vertex; ``model``: the fitted artifact port): ``(stage type, old name) -> new name``. A graph
#: that still uses an old name is refused with the new one named.
RENAMED_PARAMS = {("datadriven.fit", "model"): "reduction", ("visibility.fit", "model"): "regressor",
                  ("visibility.fit", "frames"): "space", ("shexp.tables", "samples"): "quadrature"}
#: Stage types renamed for the same reason: old type -> new type.
RENAMED_TYPES = {"ldprt.frames": "ldprt.tangents"}


class StageError(ValueError):
    """A stage or graph problem, always naming the stage (and port or parameter) at fault."""


@dataclass(frozen=True)
class Port:
    """A typed port.

    Attributes:
        dtype: one of ``PORT_DTYPES``.
        shape: tuple of ints or symbolic dimension names. Symbols are resolved per scene:
            ``"V"`` vertex count, ``"T"`` frame count, ``"F"`` triangle count; and per stage
            (:meth:`Stage.dims`): ``"C"`` SH coefficients, ``"N"`` SH bands, and the stage's own.
        doc: one line saying what the port carries (frame, units).
        space: the frame directions in the array are in, ``"local"`` (per-vertex tangent
            frames) or ``"world"``, or None when it does not matter; a wire joining ports of
            two different spaces is refused before anything runs.
    """

    dtype: str
    shape: tuple = ()
    doc: str = ""
    space: str | None = None

    def __post_init__(self):
        if self.dtype not in PORT_DTYPES:
            raise ValueError(f"port dtype must be one of {PORT_DTYPES}, got {self.dtype!r}")


@dataclass(frozen=True)
class Param:
    """A typed stage parameter with a default and optional bounds or choices (a ``tuple``
    parameter holds finite numbers: a colour, a position, a range)."""

    default: Any
    type: type = float
    doc: str = ""
    choices: tuple | None = None
    minimum: float | None = None
    maximum: float | None = None

    def check(self, stage: str, name: str, value):
        if self.type is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if self.type is tuple and isinstance(value, list):
            value = tuple(value)
        if self.default is None and value is None:
            return None
        if not isinstance(value, self.type) or (self.type is int and isinstance(value, bool)):
            raise StageError(
                f"stage {stage!r}: parameter {name!r} must be {self.type.__name__}, got {value!r}"
            )
        if self.type is float and not math.isfinite(value):
            raise StageError(f"stage {stage!r}: parameter {name!r} must be finite, got {value!r}")
        if self.type is tuple and not all(isinstance(x, numbers.Real) and not isinstance(x, bool) for x in value):
            raise StageError(f"stage {stage!r}: parameter {name!r} must hold numbers, got {value!r}")
        if self.type is tuple and any(isinstance(x, float) and not math.isfinite(x) for x in value):
            raise StageError(f"stage {stage!r}: parameter {name!r} must hold finite numbers, got {value!r}")
        if self.choices is not None and value not in self.choices:
            raise StageError(f"stage {stage!r}: parameter {name!r} must be one of {self.choices}, got {value!r}")
        if self.minimum is not None and value < self.minimum:
            raise StageError(f"stage {stage!r}: parameter {name!r} must be >= {self.minimum}, got {value!r}")
        if self.maximum is not None and value > self.maximum:
            raise StageError(f"stage {stage!r}: parameter {name!r} must be <= {self.maximum}, got {value!r}")
        return value


@dataclass
class StageContext:
    """What a stage sees when it precomputes or sets up (per-frame data is the FrameState).

    Attributes:
        scene: the :class:`~warpshade.scene.Scene`.
        device: the Warp device.
        dims: scene dimensions ``{"V": vertices, "T": frames, "F": triangles}``.
        lighting: the :class:`~warpshade.scene._lighting.LightingSource` of the run (host).
        state: the run's :class:`~warpshade.scene._state.FrameState` (its arrays keep their
            addresses; bind them in ``setup``); None during precompute.
        progress: whether long work may show progress bars.
        base_dir: directory that relative file parameters resolve against (the stage graph
            file's), or None (the working directory).
        scheduler: where independent precompute tasks run (:func:`warpshade.tasks.executor`:
            None = ``$WARPSHADE_SCHEDULER`` or local worker processes, ``"serial"``,
            ``"local:N"``, a Dask scheduler address).
        cache: the run's artifact cache (:class:`~warpshade.graph._cache.ArtifactCache`:
            ``load(key)``, ``store(key, arrays)``, ``path(key)``), where a precompute made of
            many tasks keeps each finished task's result so that an interrupted run resumes
            where it stopped; None (or a disabled cache): nothing is kept.
    """

    scene: Any
    device: Any
    dims: dict
    lighting: Any = None
    state: Any = None
    progress: bool = False
    base_dir: Any = None
    scheduler: Any = None
    cache: Any = None

    def executor(self):
        """A new :class:`warpshade.tasks.Executor` for :attr:`scheduler` (use it as a context
        manager so that its workers are released)."""
        from ..tasks import executor

        return executor(self.scheduler)

    def resolve_path(self, path: str):
        """``path`` made absolute against :attr:`base_dir` (a :class:`pathlib.Path`); ``bundled:NAME``
        is the file NAME of the bundled assets (:func:`warpshade.io.bundled_asset_directory`)."""
        from pathlib import Path

        if str(path).startswith("bundled:"):
            import os

            from ..io import bundled_asset_directory

            name = str(path)[len("bundled:"):]
            root = os.path.realpath(bundled_asset_directory())
            target = Path(bundled_asset_directory()) / name
            if os.path.commonpath([root, os.path.realpath(target)]) != root:
                raise ValueError(f"file {path!r}: {name!r} leads out of the directory of the bundled assets ({root}); "
                                 "bundled:NAME names a file in it: give another file by its path")
            return target
        p = Path(path).expanduser()
        if not p.is_absolute() and self.base_dir is not None:
            p = Path(self.base_dir) / p
        return p.resolve()


class Stage:
    """What every stage has: a registered type name, typed parameters and typed ports.

    A method never subclasses this directly: it writes a :class:`PrecomputeStage` (runs once,
    cached) or a :class:`FrameStage` (runs every frame). Parameters are available as
    ``self.params`` (a dict, validated against ``parameters``).
    """

    type_name: ClassVar[str] = ""
    kind: ClassVar[str] = ""  # set by PrecomputeStage ("precompute") and FrameStage ("frame")
    parameters: ClassVar[dict[str, Param]] = {}
    description: ClassVar[str] = ""
    #: Quick settings: parameter -> value that make a stage of this type run in seconds where the
    #: ready-made graphs' own settings take minutes, running the same code (tests run every graph of
    #: ``stages/`` with them, :meth:`quick_params`). Empty: the stage is quick as written.
    quick: ClassVar[dict] = {}
    #: True when the stage's precompute scales with the environment's texels (a prefiltered table):
    #: a quick run lights its graph with a small procedural sky.
    quick_sky: ClassVar[bool] = False

    @classmethod
    def quick_params(cls, params: dict) -> dict:
        """The quick settings of a stage of this type written with ``params`` (the graph's
        parameters, before defaults): the parameters to override, :attr:`quick` by default; a
        type whose slow cases depend on its parameters overrides this."""
        return dict(cls.quick)

    def __init__(self, name: str, params: dict | None = None):
        self.name = name
        params = dict(params or {})
        unknown = sorted(set(params) - set(self.parameters))
        if unknown:
            renamed = "".join(f"; {k!r} was renamed {RENAMED_PARAMS[(self.type_name, k)]!r}" for k in unknown
                              if (self.type_name, k) in RENAMED_PARAMS)
            raise StageError(
                f"stage {name!r} ({self.type_name}): unknown parameter(s) {unknown}; "
                f"known: {sorted(self.parameters)}{renamed}"
            )
        self.params = {k: p.check(name, k, params.get(k, p.default)) for k, p in self.parameters.items()}

    # ---- ports (may depend on parameters) -----------------------------------------------
    def input_ports(self) -> dict[str, Port]:
        """Declared inputs: name -> Port."""
        return {}

    def output_ports(self) -> dict[str, Port]:
        """Declared outputs: name -> Port."""
        return {}

    def dims(self) -> dict[str, int]:
        """Stage-specific symbolic dimensions (e.g. ``{"C": order**2}``)."""
        return {}

    def describe(self) -> dict:
        return {"name": self.name, "type": self.type_name, "kind": self.kind, "params": dict(self.params)}

    # ---- checks before any work -----------------------------------------------------------
    def check_wiring(self, upstream: dict) -> None:
        """Raise StageError when this stage cannot run with what feeds it: ``upstream`` maps each
        input port to ``(provider, port)``, the provider a :class:`Stage` (its ``params`` and
        ``type_name`` readable) or None for the scene. Called when the graph is checked, before any
        scene is loaded or any work done (e.g. a model fitted in a frame this stage cannot take,
        an order above the provider's). Only parameters and wiring: nothing is computed."""

    def check_scene(self, scene, ctx) -> None:
        """Raise StageError when this stage cannot run on ``scene`` (e.g. a glossy stage with no
        viewer, a file parameter whose header is wrong): called by ``GraphSpec.compile`` after
        the scene is loaded and before any precompute, so that a parameter-only problem is not
        found after minutes of baking. ``ctx``: a :class:`StageContext` of the run to come
        (``resolve_path`` against the graph file's folder, ``dims``, ``device``; no frame state).
        Only parameters, file headers and the scene's description: nothing is computed."""


class PrecomputeStage(Stage):
    """A stage that runs once per scene and parameters; its artifacts are cached on disk.

    A method writes :meth:`precompute` (and :meth:`check_artifact`, and bumps :attr:`version` when
    the artifact's format or algorithm changes); :meth:`cache_params` and :meth:`cache_key` only
    when a parameter names a file.
    """

    kind: ClassVar[str] = "precompute"
    version: ClassVar[int] = 1  # bump when the artifact format or algorithm changes
    uses_scene: ClassVar[bool] = True  # does the artifact depend on the scene?

    #: A small JSON-ready summary a precompute may leave (histograms, fit errors, choices made).
    #: The runtime stores it with the cached artifacts and restores it on a cache hit, and
    #: includes it in run reports.
    report: dict | None = None

    def precompute(self, ctx, inputs: dict) -> dict:
        """Compute artifacts from host inputs. Returns output name -> NumPy array."""
        raise NotImplementedError(f"stage {self.name!r} ({self.type_name}) has no precompute")

    def cache_params(self) -> dict:
        """The parameters that enter the artifact's cache key (default: all of them). A stage
        that names a file by path leaves the path out and puts the file's content in
        :meth:`cache_key`, so the same file spelt two ways shares one cache entry."""
        return self.params

    def cache_key(self, ctx) -> dict:
        """Content the artifact depends on beyond the parameters, inputs and the scene (e.g. the
        fingerprint of another file the stage reads); part of the artifact's cache key."""
        return {}

    def check_artifact(self, outputs: dict) -> None:
        """Raise ValueError when cached ``outputs`` are not a valid artifact of this stage.

        Called on every cache hit; the runtime recomputes on ValueError, so an artifact left by
        an older format is replaced instead of failing (or silently misleading) the run. The
        default accepts anything that has the declared ports.
        """

    def describe(self) -> dict:
        out = super().describe()
        if self.report:
            out["report"] = self.report
        return out


class FrameStage(Stage):
    """A stage that runs every frame, inside the recorded frame.

    A method writes :meth:`setup` (allocate outputs, bind inputs: once) and :meth:`launch` (kernel
    launches on those buffers: every frame), and :meth:`notify_changed` when a change from
    outside the frame can be absorbed without a new set-up.
    """

    kind: ClassVar[str] = "frame"
    #: False when :meth:`launch` cannot be recorded (it runs from Python every frame, between
    #: the recorded segments); :attr:`capture_note` says why.
    capturable: ClassVar[bool] = True
    capture_note: ClassVar[str] = ""
    #: True when the stage traces rays against the frame's geometry: the runtime then keeps a
    #: BVH over the state's points (``state.bvh``), refit inside the recorded frame.
    needs_bvh: ClassVar[bool] = False
    #: True when the stage shades the run's BRDFs (``state.materials``, told by
    #: :data:`~warpshade.scene._state.Change.MATERIAL`): a material change or track is refused on
    #: a graph without such a stage, where it would be ignored.
    reads_materials: ClassVar[bool] = False
    #: True when the stage's radiance includes the run's sphere lights (local lights). A stage
    #: reading the ``lighting`` port without it shades the distant lights (SH) alone: the runtime
    #: says so, naming the lights, when a run has sphere lights.
    shades_sphere_lights: ClassVar[bool] = False

    def setup(self, ctx: StageContext, inputs: dict) -> dict:
        """Allocate fixed device outputs and bind the inputs (device arrays of upstream ports;
        ``points``/``normals``/``albedo`` and ``lighting`` -- the state's
        :class:`~warpshade.scene._lighting_warp.FrameLighting` -- from the scene).

        Returns output name -> device array (the same arrays are filled every frame).
        """
        raise NotImplementedError(f"stage {self.name!r} ({self.type_name}) has no setup")

    def launch(self, state) -> None:
        """Kernel launches on fixed buffers only, for the frame ``state`` holds (recordable)."""
        raise NotImplementedError(f"stage {self.name!r} ({self.type_name}) has no launch")

    def notify_changed(self, flags: Change, keys: frozenset = frozenset()) -> bool:
        """Something outside the frame changed (:class:`~warpshade.scene._state.Change` flags);
        with :data:`~warpshade.scene._state.Change.PARAMETERS`, ``keys`` names the parameters of
        this stage that changed (``self.params`` already holds their new values). Called once per
        ``Runtime.update``: changes made together (``Runtime.batch``) arrive as one call, their
        flags and parameter names merged.

        Returns True when the stage keeps working with its current set-up (what changed is read
        from device arrays it already binds, or the stage has just written it into them: the
        recorded frame is replayed as it is), False when it must be set up again -- the runtime
        then re-runs :meth:`setup` for it and every stage reading its outputs, once each, and
        records the frame anew.
        The default: a changed parameter needs a new set-up, anything else is read per frame. A
        stage absorbs a parameter it can write into its bound arrays by checking ``keys``.
        """
        return not (flags & Change.PARAMETERS)

    def model_bytes(self) -> int:
        """Bytes of per-scene model data this stage keeps on the device (for reports)."""
        return 0

    def diagnostics(self) -> dict:
        """Facts about the last frame worth reporting (e.g. receivers that fell back to a
        cheaper estimate); read from the device, so only after a frame, never inside one."""
        return {}


_REGISTRY: dict[str, type[Stage]] = {}


def register_stage(cls: type[Stage]) -> type[Stage]:
    """Class decorator: register a stage type under ``cls.type_name``."""
    if not cls.type_name:
        raise ValueError(f"{cls.__name__}: type_name is empty")
    if not issubclass(cls, (PrecomputeStage, FrameStage)):
        raise ValueError(f"{cls.__name__}: a stage type subclasses PrecomputeStage or FrameStage")
    existing = _REGISTRY.get(cls.type_name)
    if existing is not None and existing is not cls and existing.__qualname__ != cls.__qualname__:
        raise ValueError(f"stage type {cls.type_name!r} registered twice ({existing.__name__}, {cls.__name__})")
    _REGISTRY[cls.type_name] = cls
    return cls


def stage_types() -> dict[str, type[Stage]]:
    """All registered stage types, name -> class.

    The built-in ones are registered by importing :mod:`warpshade.methods` (which Python does
    before this module: it is the package's), plugins by importing their modules.
    """
    return dict(_REGISTRY)


def get_stage_type(type_name: str, stage_name: str = "?") -> type[Stage]:
    """Look up a stage type by name; raises StageError naming the stage when unknown."""
    types = stage_types()
    if type_name not in types:
        renamed = f" ({type_name!r} was renamed {RENAMED_TYPES[type_name]!r})" if type_name in RENAMED_TYPES else ""
        raise StageError(
            f"stage {stage_name!r}: unknown stage type {type_name!r}{renamed}; known types: {sorted(types)}"
        )
    return types[type_name]

