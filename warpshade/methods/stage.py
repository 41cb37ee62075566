"""Stages: the unit of work of a stage graph.

A stage declares typed input and output ports and typed parameters, and is one of two kinds:

* ``"precompute"`` -- runs once per scene and parameters; :meth:`Stage.precompute` returns
  host artifacts (NumPy arrays) that the runtime caches on disk, keyed by a content hash of
  everything that matters (stage type and version, parameters, the scene when the stage reads
  it, and the keys of its input artifacts), so a change anywhere upstream recomputes it and
  nothing else;
* ``"frame"`` -- runs every frame. :meth:`Stage.setup` allocates its device outputs once;
  :meth:`Stage.prepare` does host-side per-frame work (uploads into those fixed buffers);
  :meth:`Stage.launch` only launches kernels on fixed buffers, so on CUDA the launch sequence of
  all frame stages can be captured once as a Warp graph and replayed per frame.

Every stage type registers itself under a dotted name (``"prt.transfer"``) with
:func:`register_stage`; stage graphs (TOML or Python, :mod:`warpshade.graph`) refer to stages
by that name. This module sits in the methods layer so that each method's ``stages.py`` can
subclass :class:`Stage` without importing the graph runtime above it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, ClassVar

__all__ = [
    "Port",
    "Param",
    "Stage",
    "StageError",
    "register_stage",
    "stage_types",
    "get_stage_type",
]

#: dtypes a port may carry. Array ports carry Warp arrays per frame and NumPy arrays as
#: precompute artifacts; "arrays" carries a named set of NumPy arrays (a structured model such
#: as a sphere hierarchy: cached as one artifact, handed to consumers as a host dict, never
#: uploaded as a whole); "lighting" carries the per-frame lighting object; "object" carries any
#: host object (validated by type name only).
PORT_DTYPES = ("float32", "float64", "int32", "vec3", "mat33", "arrays", "lighting", "object")


class StageError(ValueError):
    """A stage or graph problem, always naming the stage (and port or parameter) at fault."""


@dataclass(frozen=True)
class Port:
    """A typed port.

    Attributes:
        dtype: one of ``PORT_DTYPES``.
        shape: tuple of ints or symbolic dimension names. Symbols are resolved per scene:
            ``"V"`` vertex count, ``"T"`` frame count, ``"F"`` triangle count; stages may add
            their own (e.g. ``"C"`` = SH coefficient count, derived from their order).
        doc: one line saying what the port carries (frame, units).
    """

    dtype: str
    shape: tuple = ()
    doc: str = ""

    def __post_init__(self):
        if self.dtype not in PORT_DTYPES:
            raise ValueError(f"port dtype must be one of {PORT_DTYPES}, got {self.dtype!r}")


@dataclass(frozen=True)
class Param:
    """A typed stage parameter with a default and optional bounds or choices."""

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
        if self.choices is not None and value not in self.choices:
            raise StageError(f"stage {stage!r}: parameter {name!r} must be one of {self.choices}, got {value!r}")
        if self.minimum is not None and value < self.minimum:
            raise StageError(f"stage {stage!r}: parameter {name!r} must be >= {self.minimum}, got {value!r}")
        if self.maximum is not None and value > self.maximum:
            raise StageError(f"stage {stage!r}: parameter {name!r} must be <= {self.maximum}, got {value!r}")
        return value


class Stage:
    """Base class of all stages (see module docstring for the contract).

    Subclasses set the class attributes and override the methods of their kind. Parameters are
    available as ``self.params`` (a dict, validated against ``parameters``).
    """

    type_name: ClassVar[str] = ""
    kind: ClassVar[str] = "frame"  # "precompute" | "frame"
    version: ClassVar[int] = 1  # bump when the artifact format or algorithm changes
    uses_scene: ClassVar[bool] = True  # precompute: does the artifact depend on the scene?
    parameters: ClassVar[dict[str, Param]] = {}
    description: ClassVar[str] = ""

    def __init__(self, name: str, params: dict | None = None):
        self.name = name
        params = dict(params or {})
        unknown = sorted(set(params) - set(self.parameters))
        if unknown:
            raise StageError(
                f"stage {name!r} ({self.type_name}): unknown parameter(s) {unknown}; "
                f"known: {sorted(self.parameters)}"
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

    # ---- precompute stages --------------------------------------------------------------
    def precompute(self, ctx, inputs: dict) -> dict:
        """Compute artifacts from host inputs. Returns output name -> NumPy array."""
        raise NotImplementedError(f"stage {self.name!r} ({self.type_name}) has no precompute")

    def check_artifact(self, outputs: dict) -> None:
        """Raise ValueError when cached ``outputs`` are not a valid artifact of this stage.

        Called on every cache hit; the runtime recomputes on ValueError, so an artifact left by
        an older format is replaced instead of failing (or silently misleading) the run. The
        default accepts anything that has the declared ports.
        """

    def reference_model(self, runtime) -> dict | None:
        """What ground truth this stage's radiance is measured against, or None for the default.

        The default (None) is the diffuse reference of :func:`warpshade.reference.shade` with
        the scene's albedo. A stage whose output is something else returns keyword arguments
        for :func:`warpshade.reference.shade_glossy` (``brdf``, ``eye``, ``color``).
        """
        return None

    # ---- frame stages -------------------------------------------------------------------
    def setup(self, ctx, inputs: dict) -> dict:
        """Allocate fixed device outputs; ``inputs`` holds device arrays of upstream ports.

        Returns output name -> device array (the same arrays are filled every frame).
        """
        raise NotImplementedError(f"stage {self.name!r} ({self.type_name}) has no setup")

    def prepare(self, ctx, frame) -> None:
        """Host-side per-frame work (uploads into fixed buffers). Not captured."""

    def launch(self, ctx) -> None:
        """Kernel launches on fixed buffers only (capturable as a CUDA graph)."""
        raise NotImplementedError(f"stage {self.name!r} ({self.type_name}) has no launch")

    #: A small JSON-ready summary a precompute may leave (histograms, fit errors, choices made).
    #: The runtime stores it with the cached artifacts and restores it on a cache hit, and
    #: includes it in run reports.
    report: dict | None = None

    def model_bytes(self) -> int:
        """Bytes of per-scene model data this stage keeps on the device (for reports)."""
        return 0

    def describe(self) -> dict:
        out = {"name": self.name, "type": self.type_name, "kind": self.kind, "params": dict(self.params)}
        if self.report:
            out["report"] = self.report
        return out


_REGISTRY: dict[str, type[Stage]] = {}


def register_stage(cls: type[Stage]) -> type[Stage]:
    """Class decorator: register a stage type under ``cls.type_name``."""
    if not cls.type_name:
        raise ValueError(f"{cls.__name__}: type_name is empty")
    if cls.kind not in ("precompute", "frame"):
        raise ValueError(f"{cls.__name__}: kind must be 'precompute' or 'frame', got {cls.kind!r}")
    existing = _REGISTRY.get(cls.type_name)
    if existing is not None and existing is not cls and existing.__qualname__ != cls.__qualname__:
        raise ValueError(f"stage type {cls.type_name!r} registered twice ({existing.__name__}, {cls.__name__})")
    _REGISTRY[cls.type_name] = cls
    return cls


def _load_builtin_stages() -> None:
    # Importing the methods package registers every built-in stage type.
    import warpshade.methods  # noqa: F401


def stage_types() -> dict[str, type[Stage]]:
    """All registered stage types, name -> class."""
    _load_builtin_stages()
    return dict(_REGISTRY)


def get_stage_type(type_name: str, stage_name: str = "?") -> type[Stage]:
    """Look up a stage type by name; raises StageError naming the stage when unknown."""
    types = stage_types()
    if type_name not in types:
        raise StageError(
            f"stage {stage_name!r}: unknown stage type {type_name!r}; known types: {sorted(types)}"
        )
    return types[type_name]


Factory = Callable[..., Stage]
