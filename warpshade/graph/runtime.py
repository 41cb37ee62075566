"""The stage-graph runtime: precompute (cached), then one recorded frame replayed per step.

Typical use from a Python frame loop::

    rt = warpshade.graph.load("stages/bunny_prt.toml").compile(device="cuda:0")
    for frame in rt.scene.frames:
        radiance = rt.step(frame)          # wp.array, (vertex_count, 3) float32, linear RGB

A frame is the scene evaluation (:class:`~warpshade.scene.state.FrameEvaluator`: transforms,
skinning, normals, lighting, BVH refit) followed by every frame stage's ``launch(state)``. The
first step runs it directly (kernels compile); the second records it once
(:func:`warpshade._wp.record_program`: a Warp graph capture, on CUDA and on the CPU) and every
later step only writes the frame index (and any lighting override) into a small host input and
replays the recording -- no per-stage launches from Python. What cannot be recorded (chunked
multi-core CPU launches, a stage that says so, point samples too large for the device) runs as
Python calls between recorded segments; :meth:`Runtime.timing_summary` lists them.

Changes that do not come from the frame go through :meth:`Runtime.notify_changed` (and the
setters that call it: :meth:`~Runtime.set_lighting`, :meth:`~Runtime.set_albedo`,
:meth:`~Runtime.set_eye`, :meth:`~Runtime.set_parameter`).

The runtime steps and records; measuring against ground truth and writing USD, pictures and
reports are the measuring layer's (:mod:`warpshade.measure`).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field

import numpy as np

from .._fileio import _json_default
from .._hashing import hash_json
from .._wp import record_program, resolve_device, wp
from ..methods.stage import Change, Port, StageContext, StageError
from ..scene.lighting import DistantLight, Environment, LightingSource, SphereLight
from ..scene.state import FrameEvaluator
from .cache import ArtifactCache, default_cache_dir
from .errors import GraphError

__all__ = ["Runtime", "parse_frames"]


def parse_frames(spec, scene) -> np.ndarray:
    """Select time codes of ``scene.frames`` from a spec.

    ``None`` = all frames; ``"A:B"`` = time codes ``A <= t < B`` (either end may be empty);
    ``"A"`` = one frame; a list of numbers = those frames. Raises ValueError when the selection
    is empty or names frames the scene does not have.
    """
    frames = scene.frames
    if spec is None:
        return frames.copy()
    if isinstance(spec, (list, tuple, np.ndarray)):
        if len(spec) == 0:
            raise ValueError("the list of frames is empty")
        return np.array([scene.frames[scene.frame_index(f)] for f in spec])
    if not isinstance(spec, str):
        raise TypeError(f"frames must be 'A:B', one time code or a list of time codes, got {spec!r}")

    def number(part: str, default: float) -> float:
        if not part.strip():
            return default
        try:
            value = float(part)
        except ValueError:
            raise ValueError(f"{part.strip()!r} in {spec!r} is not a number (expected 'A:B', 'A' or a list)") from None
        if not np.isfinite(value):
            raise ValueError(f"{spec!r} is not a finite time code")
        return value

    text = spec.strip()
    if ":" in text:
        a, b = text.split(":", 1)
        lo, hi = number(a, -np.inf), number(b, np.inf)
        sel = frames[(frames >= lo) & (frames < hi)]
    else:
        sel = np.array([frames[scene.frame_index(number(text, np.nan))]])
    if sel.size == 0:
        raise ValueError(
            f"frames {spec!r} select nothing from the scene's time codes {frames[0]:g}..{frames[-1]:g}"
        )
    return sel


@dataclass
class StageTiming:
    precompute_s: float = 0.0
    cache: str = ""  # "hit" | "miss" | "off" for precompute stages
    frame_s: list = field(default_factory=list)  # per-frame stages: from profile()


_REPORT_KEY = "__report__"


def _flatten(out: dict, ports: dict) -> dict:
    """Artifacts as one flat name -> array dict ("arrays" ports become ``port/key`` entries)."""
    flat = {}
    for name, value in out.items():
        if name in ports and ports[name].dtype == "arrays":
            flat.update({f"{name}/{k}": np.asarray(v) for k, v in value.items()})
        else:
            flat[name] = value
    return flat


def _unflatten(flat: dict, ports: dict) -> dict:
    """Inverse of :func:`_flatten`."""
    out: dict = {n: {} for n, p in ports.items() if p.dtype == "arrays"}
    for key, value in flat.items():
        head, _, tail = key.partition("/")
        if tail and head in out:
            out[head][tail] = value
        else:
            out[key] = value
    return out


_DTYPES = {"float32": wp.float32, "float64": wp.float64, "int32": wp.int32, "vec3": wp.vec3, "mat33": wp.mat33}
#: NumPy dtype kind and trailing element shape of the artifact of each array port dtype.
_ARTIFACT_LAYOUT = {"float32": ("f", ()), "float64": ("f", ()), "int32": ("iu", ()), "vec3": ("f", (3,)), "mat33": ("f", (3, 3))}


def artifact_problem(port: Port, value, dims: dict) -> str | None:
    """Why ``value`` is not a valid artifact of ``port`` (None when it is).

    Checks the dtype kind, the shape against the port's (symbols resolved with ``dims``; vec3 and
    mat33 ports hold trailing 3 / 3x3 float axes) and, for floats, that every value is finite.
    An "arrays" port needs a dict of numeric arrays with finite floats.
    """
    if port.dtype == "arrays":
        if not isinstance(value, dict):
            return "is not a set of named arrays"
        for k, v in value.items():
            a = np.asarray(v)
            if a.dtype.kind == "O":
                return f"entry {k!r} holds Python objects"
            if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
                return f"entry {k!r} has NaN or infinite values"
        return None
    if port.dtype not in _ARTIFACT_LAYOUT:
        return None
    kinds, inner = _ARTIFACT_LAYOUT[port.dtype]
    a = np.asarray(value)
    if a.dtype.kind not in kinds:
        return f"has dtype {a.dtype}, the port is {port.dtype}"
    want = tuple(dims.get(d, d) if isinstance(d, str) else int(d) for d in port.shape)
    shape = a.shape
    if inner:
        flat = (int(np.prod(inner)),)
        if shape[len(want):] == flat:
            shape = shape[: len(want)] + inner
        if shape[len(want):] != inner:
            return f"has shape {a.shape}, the port is {port.dtype} of shape {want}"
        shape = shape[: len(want)]
    if len(shape) != len(want) or any(isinstance(w, int) and w != s for w, s in zip(want, shape)):
        return f"has shape {a.shape}, the port needs {want}"
    if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
        return f"has {int(np.count_nonzero(~np.isfinite(a)))} NaN or infinite values"
    return None


def _to_device(array: np.ndarray, port: Port, device, where: str):
    dtype = _DTYPES[port.dtype]
    a = np.asarray(array)
    if port.dtype in ("vec3", "mat33"):
        inner = 3 if port.dtype == "vec3" else 9
        a = a.reshape(a.shape[0], -1)
        if a.shape[1] != inner:
            raise GraphError(f"{where}: artifact has shape {array.shape}, not a {port.dtype} array")
        return wp.array(a.astype(np.float32), dtype=dtype, device=device)
    np_dtype = {"float32": np.float32, "float64": np.float64, "int32": np.int32}[port.dtype]
    return wp.array(a.astype(np_dtype), dtype=dtype, device=device)


class Runtime:
    """A compiled stage graph bound to a scene and a device.

    Args:
        spec: the validated :class:`~warpshade.graph.spec.GraphSpec`.
        scene: the scene to run on.
        device: Warp device; None = Warp's default.
        cache_dir: artifact cache directory; None disables caching; default
            :func:`~warpshade.graph.cache.default_cache_dir`.
        progress: show tqdm progress bars for long work.
        capture: record the frame once and replay it (default True, on every device); False
            runs every frame's launches from Python (for debugging and profiling).
        lighting: the :class:`~warpshade.scene.LightingSource` of the run (default: the scene's
            lights, fixed).
        scheduler: where precompute stages run their independent tasks (training frames):
            None = ``$WARPSHADE_SCHEDULER`` or local worker processes; ``"serial"``,
            ``"local:N"`` or a Dask scheduler address (:func:`warpshade._tasks.executor`).

    Attributes:
        state: the :class:`~warpshade.scene.state.FrameState` every frame is evaluated into.
        evaluator: the :class:`~warpshade.scene.state.FrameEvaluator` filling it.
        output: the output device array (per-vertex radiance (vertex_count, 3) float32).
        results: recorded frames, time code -> (vertex_count, 3) float32 NumPy copy.
    """

    def __init__(self, spec, scene, device=None, cache_dir="default", progress: bool = True, capture: bool = True,
                 lighting: LightingSource | None = None, scheduler: str | None = None):
        self.spec = spec
        self.scene = scene
        self.device = resolve_device(device)
        self.cache = ArtifactCache(default_cache_dir() if cache_dir == "default" else cache_dir)
        self.progress = progress
        self.capture = bool(capture)
        dims = {"V": scene.vertex_count, "T": len(scene.frames), "F": scene.triangle_count}
        self.stages, self.wiring = spec.build(dims)
        self.lighting = lighting if lighting is not None else LightingSource.fixed(scene.lights, scene.up_axis)
        source = getattr(spec, "source_path", None)
        self.scheduler = scheduler
        self.ctx = StageContext(scene, self.device, dims, self.lighting, None, progress,
                                base_dir=source.parent if source is not None else None, scheduler=scheduler)
        self.timings = {s.name: StageTiming() for s in self.stages}
        self.frame_s: list = []
        self.host_s: list = []
        self.artifacts: dict = {}
        self.artifact_keys: dict = {}
        self.stale_artifacts: list = []  # cached artifacts rejected by their stage's check (recomputed)
        self.results: dict = {}
        self._fingerprint = None
        self._program = None
        self._warm = False
        self._override_on = False
        self._precompute()
        needs_bvh = any(getattr(st, "needs_bvh", False) for st in self.frame_stages)
        self.evaluator = FrameEvaluator(scene, self.device, self.lighting, bvh=needs_bvh)
        self.state = self.evaluator.state
        self.ctx.state = self.state
        self._uploaded: dict = {}
        self.frame_outputs: dict = {}
        self._track = self._resolve_material_track()
        self._track_key = None
        self._setup(0)

    # ---- precompute ---------------------------------------------------------------------
    @property
    def fingerprint(self) -> str:
        if self._fingerprint is None:
            self._fingerprint = self.scene.fingerprint()
        return self._fingerprint

    def _host_input(self, wire):
        if wire.provider == "scene":
            if wire.port == "albedo":
                return self.scene.albedo
            raise GraphError(f"scene port {wire.port!r} is per-frame")
        return self.artifacts[wire.provider][wire.port]

    def _artifact_problems(self, st, out: dict, ports: dict) -> list[str]:
        dims = {**self.ctx.dims, **st.dims()}
        problems = []
        for name, port in ports.items():
            if name not in out:
                problems.append(f"output {name!r} is missing")
                continue
            why = artifact_problem(port, out[name], dims)
            if why:
                problems.append(f"output {name!r} {why}")
        return problems

    def _valid_cached(self, st, key, cached, ports):
        """The cached artifact of ``st`` when it matches the stage's ports and passes its check;
        else None, the entry is removed and the reason recorded in :attr:`stale_artifacts`."""
        if cached is None:
            return None
        out = _unflatten(cached, ports)
        problems = self._artifact_problems(st, out, ports)
        if not problems:
            try:
                st.check_artifact({k: v for k, v in out.items() if k in ports})
            except (ValueError, KeyError) as exc:
                problems = [str(exc)]
        if problems:
            reason = "; ".join(problems)
            self.stale_artifacts.append(f"{st.name}: {reason}")
            self.cache.discard(key, f"stage {st.name!r}: {reason}")
            return None
        return out

    def _precompute(self) -> None:
        for st in self.stages:
            if st.kind != "precompute":
                continue
            inputs = {port: self._host_input(w) for port, w in self.wiring[st.name].items()}
            key_parts = {
                "type": st.type_name,
                "version": st.version,
                "params": st.cache_params(),
                "inputs": {
                    p: (self.artifact_keys[w.provider] + "." + w.port) if w.provider != "scene" else f"scene.{w.port}"
                    for p, w in self.wiring[st.name].items()
                },
            }
            if st.uses_scene or any(w.provider == "scene" for w in self.wiring[st.name].values()):
                key_parts["scene"] = self.fingerprint
            try:
                extra = st.cache_key(self.ctx)
            except StageError:
                raise
            except (OSError, ValueError) as exc:
                raise GraphError(f"stage {st.name!r} ({st.type_name}): {exc}") from None
            if extra:
                key_parts["depends"] = extra
            key = f"{st.type_name.replace('.', '-')}-{hash_json(key_parts)[:32]}"
            self.artifact_keys[st.name] = key
            t0 = time.perf_counter()
            damaged_before = len(self.cache.damaged)
            cached = self.cache.load(key)
            for path, why in self.cache.damaged[damaged_before:]:
                self.stale_artifacts.append(f"{st.name}: cache entry {path} {why}")
            timing = self.timings[st.name]
            ports = st.output_ports()
            out = self._valid_cached(st, key, cached, ports)
            if out is not None:
                timing.cache = "hit"
                if _REPORT_KEY in out:
                    st.report = json.loads(str(out.pop(_REPORT_KEY)))
            else:
                out = st.precompute(self.ctx, inputs)
                problems = self._artifact_problems(st, out, ports)
                if problems:
                    raise GraphError(f"stage {st.name!r} ({st.type_name}): its precompute produced an invalid artifact: "
                                     + "; ".join(problems))
                timing.cache = "miss" if self.cache.enabled else "off"
                stored = _flatten(out, ports)
                if st.report:
                    stored[_REPORT_KEY] = np.array(json.dumps(st.report, default=_json_default))
                self.cache.store(key, stored)
            timing.precompute_s = time.perf_counter() - t0
            self.artifacts[st.name] = out

    # ---- frame set-up -------------------------------------------------------------------
    @property
    def frame_stages(self) -> list:
        return [s for s in self.stages if s.kind == "frame"]

    def _scene_input(self, port: str):
        if port == "points":
            return self.state.points
        if port == "normals":
            return self.state.normals
        if port == "albedo":
            return self.evaluator.albedo
        if port == "lighting":
            return self.state.lighting
        raise GraphError(f"unknown scene port {port!r}")

    def _setup(self, start: int) -> None:
        """Set up frame stages ``start..`` (in order), binding upstream outputs."""
        dev = self.device
        for st in self.frame_stages[start:]:
            inputs = {}
            for port, w in self.wiring[st.name].items():
                if w.provider == "scene":
                    inputs[port] = self._scene_input(w.port)
                elif w.provider in self.frame_outputs:
                    inputs[port] = self.frame_outputs[w.provider][w.port]
                else:
                    key = (w.provider, w.port)
                    prov = next(s for s in self.stages if s.name == w.provider)
                    if key not in self._uploaded:
                        if prov.output_ports()[w.port].dtype == "arrays":
                            self._uploaded[key] = self.artifacts[w.provider][w.port]  # host dict: the stage uploads what it needs
                        else:
                            self._uploaded[key] = _to_device(self.artifacts[w.provider][w.port], prov.output_ports()[w.port],
                                                             dev, f"stage {w.provider!r} output {w.port!r}")
                    inputs[port] = self._uploaded[key]
            outs = st.setup(self.ctx, inputs)
            missing = set(st.output_ports()) - set(outs)
            if missing:
                raise GraphError(f"stage {st.name!r}: setup did not allocate {sorted(missing)}")
            self.frame_outputs[st.name] = outs
        oname, oport = self.spec.output.split(".", 1)
        self.output = self.frame_outputs[oname][oport]
        self._program = None

    # ---- changes that do not come from the frame -----------------------------------------
    def notify_changed(self, flags: Change, stages=None) -> None:
        """Tell the frame stages that something outside the frame changed.

        Each stage's :meth:`~warpshade.methods.stage.Stage.notify_changed` says whether it keeps
        working; the first that does not is set up again with every stage after it, and the
        frame is recorded anew at the next step.

        Args:
            flags: :class:`~warpshade.scene.state.Change` flags.
            stages: names of the stages concerned (default: every frame stage).
        """
        names = None if stages is None else set(stages)
        first = None
        for i, st in enumerate(self.frame_stages):
            if names is not None and st.name not in names:
                continue
            if not st.notify_changed(Change(flags)) and first is None:
                first = i
        if first is not None:
            self._setup(first)

    def set_lighting(self, lighting) -> None:
        """Replace the run's lighting: a :class:`~warpshade.scene.LightingSource` or a list of
        lights (fixed). Every frame stage is set up again (lights may differ in number)."""
        if not isinstance(lighting, LightingSource):
            items = [lighting] if isinstance(lighting, (Environment, DistantLight, SphereLight)) else list(lighting)
            lighting = LightingSource.fixed(items, self.scene.up_axis)
        from ..scene.lighting_warp import FrameLighting

        self.lighting = lighting
        self.ctx.lighting = lighting
        self.evaluator.lighting_source = lighting
        self.state.lighting = FrameLighting(lighting, self.scene.frames, self.evaluator.input, self.device)
        self.evaluator.input.host[1] = 0
        self._override_on = False
        self._setup(0)  # the lights may differ in number: every stage binds the new arrays

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

    def _resolve_material_track(self) -> list:
        """The graph's ``[[material]]`` tables with their frame ranges resolved to time codes."""
        out = []
        for entry in getattr(self.spec, "materials", None) or ():
            try:
                frames = parse_frames(entry["frames"], self.scene) if entry["frames"] is not None else self.scene.frames
            except ValueError as exc:
                raise GraphError(f"{entry['where']} frames: {exc}") from None
            if entry["prims"] is not None:
                known = {m.path for m in self.scene.meshes}
                unknown = sorted(set(entry["prims"]) - known)
                if unknown:
                    raise GraphError(f"{entry['where']}: no mesh prim {unknown} in {self.scene.source} (meshes: {sorted(known)})")
            out.append({**entry, "times": {float(f) for f in np.asarray(frames, np.float64).reshape(-1)}})
        return out

    def materials_at(self, frame):
        """The :class:`~warpshade.scene.state.MaterialAssignment` of time code ``frame``: the
        material track's entries covering it (later ones win), else the current assignment."""
        from ..scene.state import MaterialAssignment

        if not self._track:
            return self.state.materials
        out = MaterialAssignment()
        for entry in self._track:
            if float(frame) in entry["times"]:
                if entry["prims"] is None:
                    out.default = entry["brdf"]
                    out.prims.clear()
                else:
                    for p in entry["prims"]:
                        out.prims[p] = entry["brdf"]
        return out

    def _apply_material_track(self, frame) -> None:
        if not self._track:
            return
        want = self.materials_at(frame)
        key = (None if want.default is None else id(want.default), tuple(sorted((p, id(b)) for p, b in want.prims.items())))
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
        """Change a frame stage's parameter between frames (validated like the TOML value).

        Raises:
            GraphError: an unknown stage or parameter, a precompute stage (its artifact would
                change: compile again), or a value that would change the stage's ports.
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
        self.notify_changed(Change.PARAMETERS, [stage])

    def _set_override(self, lighting) -> None:
        """This step's lighting: SH coefficients (3, n*n), or distant lights projected to SH."""
        fl = self.state.lighting
        if fl is None:
            raise ValueError("step: a lighting override needs a run with lighting")
        if isinstance(lighting, np.ndarray):
            coeffs = lighting
        else:
            items = [lighting] if isinstance(lighting, (Environment, DistantLight, SphereLight)) else list(lighting)
            if any(isinstance(x, SphereLight) for x in items):
                raise ValueError("step: a lighting override replaces the distant SH lighting only; "
                                 "use set_lighting() for sphere lights")
            order = max(fl.orders or (1,))
            coeffs = LightingSource.fixed(items, self.scene.up_axis).sh(order, float(self.scene.frames[0]))
        fl.set_override(coeffs)

    # ---- stepping -----------------------------------------------------------------------
    def _frame(self, recorder=None) -> None:
        """One frame's launches: scene evaluation, then every frame stage."""
        self.evaluator.launch(recorder)
        for st in self.frame_stages:
            if recorder is not None and not st.capturable:
                recorder.call(lambda st=st: st.launch(self.state), f"stage {st.name!r}: {st.capture_note or 'not capturable'}")
            else:
                st.launch(self.state)

    def step(self, frame, lighting=None, record: bool = False):
        """Shade one frame.

        Args:
            frame: a time code of the scene (a number; ValueError names the valid range).
            lighting: optional override of the SH lighting for this frame: world-frame SH
                coefficients (3, n*n) of at least the graph's highest order, an Environment, a
                DistantLight or a list of them (projected to SH on the host).
            record: keep a host copy of the result in :attr:`results` (what the USD layer,
                previews and error measurement of :mod:`warpshade.measure` read).

        Returns:
            the output device array (per-vertex radiance, (vertex_count, 3) float32). The same
            array is overwritten by the next step; copy it (``.numpy().copy()``) to keep it.
        """
        t_start = time.perf_counter()
        self.evaluator.set_frame(frame)
        self._apply_material_track(self.state.frame)
        if lighting is not None:
            self._set_override(lighting)
            self._override_on = True
            self.notify_changed(Change.LIGHTING)
        elif self._override_on:
            self.state.lighting.clear_override()
            self._override_on = False
            self.notify_changed(Change.LIGHTING)
        t_host = time.perf_counter()
        if self._program is not None:
            self._program.replay()
        elif self.capture and self._warm:
            self._program = record_program(self._frame, self.device)
            self._program.replay()
        else:
            self._frame()
            self._warm = True
        wp.synchronize_device(self.device)
        self.host_s.append(t_host - t_start)
        self.frame_s.append(time.perf_counter() - t_start)
        if record:
            self.results[float(self.state.frame)] = self.output.numpy().copy()
        return self.output

    def run(self, frames=None, record: bool = True, warmup: bool = True) -> np.ndarray:
        """Step over frames (default: the graph's frame range), with a progress bar.

        With ``warmup`` the first frame is stepped twice before timing starts (kernels compile,
        then the frame is recorded), so neither counts as frame time. Returns the frames run.
        """
        from tqdm.auto import tqdm

        sel = parse_frames(frames if frames is not None else self.spec.frames, self.scene)
        if warmup:
            self.step(sel[0])
            self.step(sel[0])
            self.reset_timings()
        for f in tqdm(sel, desc=f"{self.spec.name}: frames", disable=not self.progress, unit="frame"):
            self.step(f, record=record)
        return sel

    def profile(self, frames=None, repeats: int = 1) -> dict:
        """Median time per frame of the scene evaluation and of each frame stage, in seconds.

        Each piece is launched from Python and the device synchronised after it (no replay),
        so the times add up to more than a replayed frame; they say where a frame goes.
        The results are kept in :attr:`timings` (``frame_s``) for :meth:`timing_summary`.
        """
        sel = parse_frames(frames if frames is not None else self.spec.frames, self.scene)
        scene_s = []
        for t in self.timings.values():
            t.frame_s.clear()
        for _ in range(max(1, int(repeats))):
            for f in sel:
                self.evaluator.set_frame(f)
                t0 = time.perf_counter()
                self.evaluator.launch()
                wp.synchronize_device(self.device)
                scene_s.append(time.perf_counter() - t0)
                for st in self.frame_stages:
                    t0 = time.perf_counter()
                    st.launch(self.state)
                    wp.synchronize_device(self.device)
                    self.timings[st.name].frame_s.append(time.perf_counter() - t0)
        self._scene_s = scene_s
        out = {"scene": float(np.median(scene_s))}
        out.update({st.name: float(np.median(self.timings[st.name].frame_s)) for st in self.frame_stages})
        return out

    def reset_timings(self) -> None:
        """Forget per-frame timings (precompute timings are kept)."""
        for t in self.timings.values():
            t.frame_s.clear()
        self.frame_s.clear()
        self.host_s.clear()

    # ---- what the run is ------------------------------------------------------------------
    def model_bytes(self) -> int:
        """Bytes of precomputed model data the frame loop needs: per frame stage, what it keeps
        on the device (its ``model_bytes()``) or, when it reports nothing, the precompute
        artifacts it reads. Artifacts only precompute stages read (training data) are not counted."""
        total = 0
        for st in self.frame_stages:
            own = int(st.model_bytes())
            if own:
                total += own
                continue
            for w in self.wiring[st.name].values():
                if w.provider in self.artifacts:
                    a = self.artifacts[w.provider][w.port]
                    total += sum(int(np.asarray(v).nbytes) for v in (a.values() if isinstance(a, dict) else (a,)))
        return total

    @property
    def program(self):
        """The recorded frame (:class:`~warpshade._wp.FrameProgram`), or None before it exists."""
        return self._program

    def timing_summary(self) -> dict:
        """Median per-frame times (seconds) overall and, after :meth:`profile`, per stage."""

        def med(xs):
            return float(np.median(xs)) if len(xs) else None

        stages = {}
        for st in self.stages:
            t = self.timings[st.name]
            stages[st.name] = (
                {"precompute_s": t.precompute_s, "cache": t.cache}
                if st.kind == "precompute"
                else {"median_frame_s": med(t.frame_s)}
            )
        prog = self._program
        return {
            "stages": stages,
            "median_frame_s": med(self.frame_s),
            "median_host_s": med(self.host_s),
            "median_scene_s": med(getattr(self, "_scene_s", [])),
            "captured": prog is not None,
            "recorded_segments": prog.graph_count if prog is not None else 0,
            "uncaptured": prog.uncaptured if prog is not None else [],
            "frames_timed": len(self.frame_s),
        }

    def output_stage(self):
        """The frame stage whose port is the graph's output."""
        name = self.spec.output.split(".", 1)[0]
        return next(s for s in self.stages if s.name == name)

    def describe(self) -> dict:
        """A JSON-ready description of the run: graph, scene, device, stages, timings, model size."""
        sc = self.scene
        return {
            "graph": self.spec.name,
            "description": self.spec.description,
            "graph_file": str(self.spec.source_path) if self.spec.source_path else None,
            "scene": {
                "source": sc.source,
                "vertex_count": sc.vertex_count,
                "triangle_count": sc.triangle_count,
                "meshes": [m.path for m in sc.meshes],
                "frame_count": len(sc.frames),
            },
            "device": str(self.device),
            "stages": [s.describe() for s in self.stages],
            "diagnostics": {s.name: d for s in self.frame_stages if self.frame_s and (d := s.diagnostics())},
            "frames_run": sorted(self.results),
            "timings": self.timing_summary(),
            "model_bytes": self.model_bytes(),
            "cache_dir": str(self.cache.root) if self.cache.enabled else None,
            "stale_artifacts": list(self.stale_artifacts),
        }
