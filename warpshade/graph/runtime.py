"""The stage-graph runtime: precompute (cached), per-frame stepping, recording and reports.

Typical use from a Python frame loop::

    rt = warpshade.graph.load("stages/blockers_prt.toml").compile(scene, device="cuda:0")
    for frame in scene.frames:
        radiance = rt.step(frame)          # wp.array, (vertex_count, 3) float32, linear RGB
    rt.write_usd("out/shaded.usda")

On CUDA (``capture=True``, the default there) the launches of all per-frame stages are captured
once as a Warp graph after a warm-up frame and replayed every frame; only host-side
``prepare`` work (scene evaluation, uploads into fixed buffers) runs in Python per frame. On
the CPU the same launches run as plain launches.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._fileio import _json_default, write_json_atomic
from .._wp import resolve_device, wp
from ..methods.stage import Port
from .cache import ArtifactCache, default_cache_dir, hash_arrays, hash_json
from .graph import GraphError, GraphSpec
from .lighting import LightingSource

__all__ = ["Runtime", "Context", "parse_frames", "scene_fingerprint"]


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
        return np.array([scene.frames[scene.frame_index(f)] for f in spec])
    text = str(spec).strip()
    if ":" in text:
        a, b = text.split(":", 1)
        lo = float(a) if a.strip() else -np.inf
        hi = float(b) if b.strip() else np.inf
        sel = frames[(frames >= lo) & (frames < hi)]
    else:
        sel = np.array([frames[scene.frame_index(float(text))]])
    if sel.size == 0:
        raise ValueError(
            f"frames {spec!r} select nothing from the scene's time codes {frames[0]:g}..{frames[-1]:g}"
        )
    return sel


def scene_fingerprint(scene) -> str:
    """Content hash of everything in a scene that precomputed artifacts can depend on."""
    arrays = [scene.frames]
    for m in scene.meshes:
        arrays += [m.points, m.faces, m.transforms, m.point_samples, m.albedo, m.normals]
        if m.skin is not None:
            arrays += [m.skin.joint_indices, m.skin.joint_weights, m.skin.geom_bind_transform]
    for s in scene.skeletons:
        arrays += [s.parents, s.bind_transforms, s.rest_transforms, s.local_transforms, s.skel_to_world]
    return hash_arrays(arrays)


@dataclass
class StageTiming:
    precompute_s: float = 0.0
    cache: str = ""  # "hit" | "miss" | "off" for precompute stages
    frame_s: list = field(default_factory=list)
    prepare_s: list = field(default_factory=list)


class Context:
    """What stages see: the scene, device, lighting and the current frame.

    Attributes:
        scene: the :class:`~warpshade.scene.Scene`.
        device: the Warp device.
        dims: scene dimensions (``V``, ``T``, ``F``).
        frame: current time code (None during precompute).
        frame_state: current :class:`~warpshade.scene.FrameState` (None during precompute).
        progress: whether long work may show progress bars.
    """

    def __init__(self, scene, device, lighting: LightingSource, progress: bool):
        self.scene = scene
        self.device = device
        self.dims = {"V": scene.vertex_count, "T": len(scene.frames), "F": scene.triangle_count}
        self.lighting = lighting
        self.progress = progress
        self.frame = None
        self.frame_state = None
        self._override = None

    def lights(self) -> list:
        """Light objects of the current frame (or of the first frame during precompute)."""
        if self._override is not None and not isinstance(self._override, np.ndarray):
            return list(self._override) if isinstance(self._override, (list, tuple)) else [self._override]
        frame = self.frame if self.frame is not None else float(self.scene.frames[0])
        return self.lighting.lights_at(frame)

    def lighting_sh(self, order: int, window: str | None = None, **window_args) -> np.ndarray:
        """SH of the current frame's distant lighting, world frame, (3, order**2), float64."""
        ov = self._override
        if isinstance(ov, np.ndarray):
            if ov.shape != (3, order * order):
                raise ValueError(f"lighting override has shape {ov.shape}, the stage needs (3, {order * order})")
            return ov.astype(np.float64)
        if ov is not None:
            src = LightingSource(self.lights(), self.scene.up_axis)
            return src.sh(order, 0.0, window, **window_args)
        frame = self.frame if self.frame is not None else float(self.scene.frames[0])
        return self.lighting.sh(order, frame, window, **window_args)


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
        spec: the validated :class:`GraphSpec`.
        scene: the scene to run on.
        device: Warp device; None = Warp's default.
        cache_dir: artifact cache directory; None disables caching; default
            :func:`~warpshade.graph.cache.default_cache_dir`.
        progress: show tqdm progress bars for long work.
        capture: capture per-frame launches as a CUDA graph (default: True on CUDA devices).
        lighting: a :class:`LightingSource` overriding the graph's ``[lighting]`` table.
    """

    def __init__(
        self,
        spec: GraphSpec,
        scene,
        device=None,
        cache_dir="default",
        progress: bool = True,
        capture: bool | None = None,
        lighting: LightingSource | None = None,
    ):
        self.spec = spec
        self.scene = scene
        self.device = resolve_device(device)
        self.cache = ArtifactCache(default_cache_dir() if cache_dir == "default" else cache_dir)
        self.progress = progress
        self.capture = self.device.is_cuda if capture is None else bool(capture)
        if self.capture and not self.device.is_cuda:
            raise ValueError(f"graph capture needs a CUDA device, got {self.device}")
        dims = {"V": scene.vertex_count, "T": len(scene.frames), "F": scene.triangle_count}
        self.stages, self.wiring = spec.build(dims)
        base = spec.source_path.parent if spec.source_path else None
        if lighting is None:
            try:
                lighting = LightingSource.from_spec(spec.lighting, scene, base)
            except ValueError as exc:
                raise GraphError(f"graph {spec.name!r}: {exc}") from None
        self.ctx = Context(scene, self.device, lighting, progress)
        self.timings = {s.name: StageTiming() for s in self.stages}
        self.frame_s: list = []
        self.host_s: list = []
        self.python_s: list = []
        self.artifacts: dict = {}
        self.artifact_keys: dict = {}
        self.stale_artifacts: list = []  # cached artifacts rejected by their stage's check (recomputed)
        self.results: dict = {}
        self.references: dict = {}  # frame -> ray-traced radiance (V, 3) kept by measure_error
        self._fingerprint = None
        self._graph = None
        self._frames_stepped = 0
        self._precompute()
        self._setup()

    # ---- precompute ---------------------------------------------------------------------
    @property
    def fingerprint(self) -> str:
        if self._fingerprint is None:
            self._fingerprint = scene_fingerprint(self.scene)
        return self._fingerprint

    def _host_input(self, wire):
        if wire.provider == "scene":
            if wire.port == "albedo":
                return self.scene.albedo
            raise GraphError(f"scene port {wire.port!r} is per-frame")
        return self.artifacts[wire.provider][wire.port]

    def _valid_cached(self, st, cached, ports):
        """The cached artifact of ``st`` when it has every port and passes the stage's check."""
        if cached is None:
            return None
        out = _unflatten(cached, ports)
        if not set(out) >= set(ports):
            return None
        try:
            st.check_artifact({k: v for k, v in out.items() if k in ports})
        except (ValueError, KeyError) as exc:
            self.stale_artifacts.append(f"{st.name}: {exc}")
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
                "params": st.params,
                "inputs": {
                    p: (self.artifact_keys[w.provider] + "." + w.port) if w.provider != "scene" else f"scene.{w.port}"
                    for p, w in self.wiring[st.name].items()
                },
            }
            if st.uses_scene or any(w.provider == "scene" for w in self.wiring[st.name].values()):
                key_parts["scene"] = self.fingerprint
            key = f"{st.type_name.replace('.', '-')}-{hash_json(key_parts)[:32]}"
            self.artifact_keys[st.name] = key
            t0 = time.perf_counter()
            cached = self.cache.load(key)
            timing = self.timings[st.name]
            ports = st.output_ports()
            out = self._valid_cached(st, cached, ports)
            if out is not None:
                timing.cache = "hit"
                if _REPORT_KEY in out:
                    st.report = json.loads(str(out.pop(_REPORT_KEY)))
            else:
                out = st.precompute(self.ctx, inputs)
                missing = set(ports) - set(out)
                if missing:
                    raise GraphError(f"stage {st.name!r}: precompute did not produce {sorted(missing)}")
                for name, port in ports.items():
                    if port.dtype == "arrays" and not isinstance(out[name], dict):
                        raise GraphError(f"stage {st.name!r}: output {name!r} must be a dict of arrays")
                timing.cache = "miss" if self.cache.enabled else "off"
                stored = _flatten(out, ports)
                if st.report:
                    stored[_REPORT_KEY] = np.array(json.dumps(st.report, default=_json_default))
                self.cache.store(key, stored)
            timing.precompute_s = time.perf_counter() - t0
            self.artifacts[st.name] = out

    # ---- frame set-up -------------------------------------------------------------------
    def _setup(self) -> None:
        dev = self.device
        # one FrameState whose buffers every frame is evaluated into (fixed addresses)
        self._frame_state = self.scene.evaluate(self.scene.frames[0], device=dev)
        self.scene_buffers = {
            "points": self._frame_state.points,
            "normals": self._frame_state.normals,
            "albedo": wp.array(self.scene.albedo, dtype=wp.float32, device=dev),
            "lighting": self.ctx,  # stages query ctx.lighting_sh / ctx.lights per frame
        }
        self.frame_outputs: dict = {}
        uploaded: dict = {}
        for st in self.stages:
            if st.kind != "frame":
                continue
            inputs = {}
            for port, w in self.wiring[st.name].items():
                if w.provider == "scene":
                    inputs[port] = self.scene_buffers[w.port]
                elif w.provider in self.frame_outputs:
                    inputs[port] = self.frame_outputs[w.provider][w.port]
                else:
                    key = (w.provider, w.port)
                    prov = next(s for s in self.stages if s.name == w.provider)
                    if prov.output_ports()[w.port].dtype == "arrays":
                        uploaded[key] = self.artifacts[w.provider][w.port]  # host dict, the stage uploads what it needs
                    if key not in uploaded:
                        uploaded[key] = _to_device(
                            self.artifacts[w.provider][w.port], prov.output_ports()[w.port], dev, f"stage {w.provider!r} output {w.port!r}"
                        )
                    inputs[port] = uploaded[key]
            outs = st.setup(self.ctx, inputs)
            missing = set(st.output_ports()) - set(outs)
            if missing:
                raise GraphError(f"stage {st.name!r}: setup did not allocate {sorted(missing)}")
            self.frame_outputs[st.name] = outs
        oname, oport = self.spec.output.split(".", 1)
        self.output = self.frame_outputs[oname][oport]

    @property
    def frame_stages(self) -> list:
        return [s for s in self.stages if s.kind == "frame"]

    # ---- stepping -----------------------------------------------------------------------
    def step(self, frame, lighting=None):
        """Shade one frame.

        Args:
            frame: a time code of the scene.
            lighting: optional override for this frame: an Environment, a list of lights, or
                SH coefficients of shape (3, n*n) in the world frame.

        Returns:
            the output device array (per-vertex radiance, (vertex_count, 3) float32). The same
            array is overwritten by the next step; copy it (``.numpy()``) to keep it.
        """
        t_start = time.perf_counter()
        fs = self.scene.evaluate(frame, device=self.device, out=self._frame_state)
        self.ctx.frame = float(fs.frame)
        self.ctx.frame_state = fs
        self.ctx._override = lighting
        for st in self.frame_stages:
            t0 = time.perf_counter()
            st.prepare(self.ctx, fs.frame)
            self.timings[st.name].prepare_s.append(time.perf_counter() - t0)
        t_host = time.perf_counter()
        self.host_s.append(t_host - t_start)
        if self._graph is not None:
            wp.capture_launch(self._graph)
            self.python_s.append(time.perf_counter() - t_start)
            wp.synchronize_device(self.device)
        else:
            for st in self.frame_stages:
                t0 = time.perf_counter()
                st.launch(self.ctx)
                wp.synchronize_device(self.device)
                self.timings[st.name].frame_s.append(time.perf_counter() - t0)
            if self.capture and self._frames_stepped >= 1:
                # kernels are compiled and buffers fixed: capture the launch sequence once
                with wp.ScopedCapture(device=self.device) as cap:
                    for st in self.frame_stages:
                        st.launch(self.ctx)
                self._graph = cap.graph
        self.frame_s.append(time.perf_counter() - t_start)
        self._frames_stepped += 1
        return self.output

    def run(self, frames=None, record: bool = True, warmup: bool = True) -> np.ndarray:
        """Step over frames (default: the graph's frame range), with a progress bar.

        The first frame is stepped once more before timing starts when ``warmup`` is set, so
        kernel compilation never counts as frame time. Returns the frames that were run.
        """
        from tqdm.auto import tqdm

        sel = parse_frames(frames if frames is not None else self.spec.frames, self.scene)
        if warmup:
            self.step(sel[0])
            self.reset_timings()
        for f in tqdm(sel, desc=f"{self.spec.name}: frames", disable=not self.progress, unit="frame"):
            out = self.step(f)
            if record:
                self.results[float(f)] = out.numpy().copy()
        return sel

    def reset_timings(self) -> None:
        """Forget per-frame timings (precompute timings are kept)."""
        for t in self.timings.values():
            t.frame_s.clear()
            t.prepare_s.clear()
        self.frame_s.clear()
        self.host_s.clear()
        self.python_s.clear()

    # ---- outputs ------------------------------------------------------------------------
    def model_bytes(self) -> int:
        """Bytes of precomputed model data (artifacts) plus what stages keep on the device."""
        total = 0
        for arts in self.artifacts.values():
            for a in arts.values():
                total += sum(int(np.asarray(v).nbytes) for v in (a.values() if isinstance(a, dict) else (a,)))
        return total + sum(int(s.model_bytes()) for s in self.stages)

    def timing_summary(self) -> dict:
        """Median per-frame times (seconds) per stage and overall."""

        def med(xs):
            return float(np.median(xs)) if len(xs) else None

        stages = {}
        for st in self.stages:
            t = self.timings[st.name]
            stages[st.name] = (
                {"precompute_s": t.precompute_s, "cache": t.cache}
                if st.kind == "precompute"
                else {"median_frame_s": med(t.frame_s), "median_prepare_s": med(t.prepare_s)}
            )
        return {
            "stages": stages,
            "median_frame_s": med(self.frame_s),
            "median_host_s": med(self.host_s),
            "median_python_launch_s": med(self.python_s),
            "captured": self._graph is not None,
            "frames_timed": len(self.frame_s),
        }

    def measure_error(self, frames=None, samples: int = 1024, seed: int = 7) -> dict:
        """Error of the recorded (or freshly stepped) output against ray-traced ground truth.

        Args:
            frames: time codes (default: the graph's ``[validate]`` frames, else the first).
            samples: ground-truth samples per vertex.
        """
        from ..reference import shade, shade_glossy
        from .metrics import combine_metrics, error_metrics

        out_name = self.spec.output.split(".", 1)[0]
        model = next(s for s in self.stages if s.name == out_name).reference_model(self)
        spec = self.spec.validate_spec
        if frames is None:
            frames = spec.get("frames", [float(self.scene.frames[0])])
        samples = int(spec.get("samples", samples))
        per_frame = []
        for f in parse_frames(list(frames), self.scene):
            est = self.results.get(float(f))
            if est is None:
                est = self.step(f).numpy()
            lights = self.ctx.lighting.lights_at(f)
            if model is None:
                gt = shade(self.scene, f, lights, samples, device=self.device, seed=seed)
            else:
                gt = shade_glossy(self.scene, f, lighting=lights, samples=samples, device=self.device, seed=seed, **model)
            self.references[float(f)] = np.asarray(gt.radiance)
            m = error_metrics(est, np.asarray(gt.radiance), np.asarray(gt.stderr))
            m["frame"] = float(f)
            per_frame.append(m)
        return {"per_frame": per_frame, "mean": combine_metrics(per_frame), "samples": samples,
                "reference": "diffuse" if model is None else f"glossy {model['brdf'].describe()}"}

    def report(self, error: dict | None = None) -> dict:
        """A JSON-ready description of the run: graph, scene, device, timings, model size, error."""
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
            "frames_run": sorted(self.results),
            "timings": self.timing_summary(),
            "model_bytes": self.model_bytes(),
            "cache_dir": str(self.cache.root) if self.cache.enabled else None,
            "stale_artifacts": list(self.stale_artifacts),
            "error": error,
        }

    def write_report(self, path, error: dict | None = None) -> Path:
        """Write :meth:`report` as JSON, atomically."""
        return write_json_atomic(path, self.report(error))

    def write_usd(self, path, extra_primvars: dict | None = None) -> Path:
        """Write the recorded frames as a new USD layer (never over the input).

        The layer sublayers the input scene (when it came from a file) and adds per-vertex
        ``primvars:displayColor`` (vertex interpolation, time-sampled per recorded frame) to
        each shaded mesh; meshes not in the input file (e.g. a generated ground plane) are
        written in full.
        """
        from ..io.usd_write import write_vertex_colors

        if not self.results:
            raise ValueError("write_usd: no recorded frames; call run() first")
        frames = sorted(self.results)
        colors = np.stack([self.results[f] for f in frames])
        return write_vertex_colors(path, self.scene, np.array(frames), colors, extra_primvars=extra_primvars)

    def render_comparisons(self, out_dir, frames=None, width: int = 400, height: int = 300) -> list:
        """Write ``<graph>_<frame>_vs_reference.png`` (method | ray-traced | signed error) per frame.

        Uses the references kept by :meth:`measure_error` (default: every frame it measured).
        """
        from ..render import comparison_figure

        frames = sorted(self.references) if frames is None else [float(f) for f in frames]
        missing = [f for f in frames if f not in self.references or f not in self.results]
        if missing:
            raise ValueError(f"render_comparisons: no recorded output and reference for frame(s) {missing}; "
                             "run measure_error(frames) first")
        env = next((l for l in self.ctx.lighting.lights if hasattr(l, "image")), None)
        paths = []
        for f in frames:
            env_f = self.ctx.lighting.lights_at(f)[self.ctx.lighting.lights.index(env)] if env is not None else None
            p = Path(out_dir) / f"{self.spec.name}_{int(round(f)):04d}_vs_reference.png"
            paths.append(comparison_figure(self.scene, f, self.results[f], self.references[f], p, label=self.spec.name,
                                           environment=env_f, width=width, height=height, device=self.device))
        return paths

    def render_previews(self, out_dir, frames=None, width: int = 480, height: int = 360, exposure: float | None = None) -> list:
        """Render PNG previews of recorded frames (default: first, middle and last).

        One exposure is used for all frames of a run so they compare; by default it maps the
        99th percentile of the recorded radiance to 0.9 before sRGB encoding.
        """
        from ..render import render

        rec = sorted(self.results)
        if not rec:
            raise ValueError("render_previews: no recorded frames; call run() first")
        if frames is None:
            frames = sorted({rec[0], rec[len(rec) // 2], rec[-1]})
        if exposure is None:
            lum = np.concatenate([self.results[f].mean(axis=1) for f in frames])
            p99 = float(np.percentile(lum, 99)) if lum.size else 1.0
            exposure = float(np.log2(0.9 / p99)) if p99 > 0 else 0.0
        env = next((l for l in self.ctx.lighting.lights if hasattr(l, "image")), None)
        paths = []
        for f in frames:
            p = Path(out_dir) / f"{self.spec.name}_{int(round(f)):04d}.png"
            env_f = self.ctx.lighting.lights_at(f)[self.ctx.lighting.lights.index(env)] if env is not None else None
            render(self.scene, f, colors=self.results[float(f)], width=width, height=height, environment=env_f,
                   exposure=exposure, path=p, device=self.device, supersample=2)
            paths.append(p)
        return paths
