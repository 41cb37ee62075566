"""The stage-graph runtime: precompute (cached), then one recorded frame replayed per step.

Typical use from a Python frame loop::

    rt = warpshade.graph.load("stages/bunny_prt.toml").compile(device="cuda:0")
    for frame in rt.scene.frames:
        radiance = rt.step(frame)          # wp.array, (vertex_count, 3) float32, linear RGB

A :class:`Runtime` is made of parts a reader can find by name:

* :mod:`._precompute` -- precompute stages run once, their artifacts cached and checked;
* :mod:`._frame` -- frame stages set up once, the frame (scene evaluation and every frame
  stage) recorded and replayed; :meth:`Runtime.timing_summary` lists what runs unrecorded;
* :mod:`._changes` -- changes that do not come from the frame (:meth:`~Runtime.set_lighting`,
  :meth:`~Runtime.set_albedo`, :meth:`~Runtime.set_material`, :meth:`~Runtime.set_eye`,
  :meth:`~Runtime.set_parameter`, the material track) and :meth:`~Runtime.notify_changed`,
  marked dirty and applied together by :meth:`~Runtime.update` (:meth:`~Runtime.batch`).

This module steps, times and describes a run. Measuring against ground truth and writing USD,
pictures and reports are the measuring layer's (:mod:`warpshade.measure`).
"""

from __future__ import annotations

import threading
import time

import numpy as np

from .._wp import resolve_device, wp
from ..methods.stage import StageContext
from ..scene._lighting import LightingSource
from ..scene._state import FrameEvaluator
from ._cache import ArtifactCache, default_cache_dir
from ._changes import MaterialTrack, RunChanges
from ._errors import GraphError
from ._frame import FrameGraph
from ._precompute import StageTiming, precompute
from ._scene_inputs import parse_frames

__all__: list[str] = []


def _check_spaces(stages, wiring) -> None:
    """Refuse a wire from a port in one frame (``Port.space``: local tangent frames or world)
    into a port expecting the other, before anything runs (the numbers would be read in the
    wrong frame and shade silently wrong)."""
    outputs = {st.name: st.output_ports() for st in stages}
    for st in stages:
        wanted = st.input_ports()
        for port, w in wiring[st.name].items():
            have = outputs.get(w.provider, {}).get(w.port)
            want = wanted.get(port)
            if have is not None and want is not None and have.space and want.space and have.space != want.space:
                raise GraphError(f"stage {st.name!r} input {port!r} expects {want.space}-frame values; stage "
                                 f"{w.provider!r} output {w.port!r} is in the {have.space} frame (set the consumer's "
                                 "frame parameter, e.g. visibility_space, to match)")


class Runtime(RunChanges):
    """A compiled stage graph bound to a scene and a device (made by :meth:`GraphSpec.compile
    <warpshade.graph._spec.GraphSpec.compile>`).

    Args:
        spec: the validated :class:`~warpshade.graph._spec.GraphSpec`.
        scene: the scene to run on.
        stages: the graph's stages, in order (built once, by the spec).
        wiring: stage name -> {input port: Wire}.
        device: Warp device; None = Warp's default.
        cache_dir: artifact cache directory; None disables caching; default
            :func:`~warpshade.graph._cache.default_cache_dir`.
        progress: show tqdm progress bars for long work.
        capture: record the frame once and replay it (default True, on every device); False
            runs every frame's launches from Python (for debugging and profiling).
        lighting: the :class:`~warpshade.scene.LightingSource` of the run (default: the scene's
            lights, fixed).
        scheduler: where precompute stages run their independent tasks (training frames):
            None = ``$WARPSHADE_SCHEDULER`` or local worker processes; ``"serial"``,
            ``"local:N"`` or a Dask scheduler address (:func:`warpshade.tasks.executor`).

    Attributes:
        state: the :class:`~warpshade.scene._state.FrameState` every frame is evaluated into.
        evaluator: the :class:`~warpshade.scene._state.FrameEvaluator` filling it.
        frame: the :class:`~warpshade.graph._frame.FrameGraph` (frame stages, the recording).
        artifacts, artifact_keys, stale_artifacts: what precompute left
            (:class:`~warpshade.graph._precompute.Precomputed`).
        results: recorded frames, time code -> (vertex_count, 3) float32 NumPy copy.
    """

    def __init__(self, spec, scene, stages, wiring, device=None, cache_dir="default", progress: bool = True,
                 capture: bool = True, lighting: LightingSource | None = None, scheduler: str | None = None):
        self.spec = spec
        self.scene = scene
        self.device = resolve_device(device)
        self.cache = ArtifactCache(default_cache_dir() if cache_dir == "default" else cache_dir)
        self.progress = progress
        self.stages, self.wiring = stages, wiring
        dims = {"V": scene.vertex_count, "T": len(scene.frames), "F": scene.triangle_count}
        self.lighting = lighting if lighting is not None else LightingSource.fixed(scene.lights, scene.up_axis)
        source = getattr(spec, "source_path", None)
        self.scheduler = scheduler
        self.ctx = StageContext(scene, self.device, dims, self.lighting, None, progress,
                                base_dir=source.parent if source is not None else None, scheduler=scheduler,
                                cache=self.cache)
        self.timings = {s.name: StageTiming() for s in self.stages}
        self.frame_s: list = []
        self.host_s: list = []
        self.results: dict = {}
        self._fingerprint = None
        self._override_on = False
        self._start_changes()
        self._stepping = threading.Lock()
        self.track = MaterialTrack(getattr(spec, "materials", None), scene)
        self._track_key = None
        self._check_material_track()
        _check_spaces(self.stages, self.wiring)
        done = precompute(self.stages, self.wiring, self.ctx, self.cache, lambda: self.fingerprint, self.timings)
        self.artifacts, self.artifact_keys, self.stale_artifacts = done.artifacts, done.keys, done.stale
        needs_bvh = any(st.needs_bvh for st in self.stages if st.kind == "frame")
        self.evaluator = FrameEvaluator(scene, self.device, self.lighting, bvh=needs_bvh)
        self.state = self.evaluator.state
        self.ctx.state = self.state
        self.frame = FrameGraph(self.stages, self.wiring, self.artifacts, self.evaluator, self.ctx, spec.output, capture)
        self.frame_outputs = self.frame.outputs
        self._check_sphere_lights()

    def _check_sphere_lights(self) -> None:
        """Say once which stages leave the run's sphere lights out of their radiance."""
        spheres = self.lighting.sphere_lights() if self.lighting is not None else []
        if not spheres:
            return
        blind = [st for st in self.stages if st.kind == "frame" and "lighting" in st.input_ports()
                 and not st.shades_sphere_lights]
        if blind:
            import warnings

            names = ", ".join(f"{st.name!r} ({st.type_name})" for st in blind)
            paths = ", ".join(light.path or "<array>" for light in spheres)
            warnings.warn(f"graph {self.spec.name!r}: stage(s) {names} shade distant lighting (SH) only; the run's "
                          f"sphere light(s) {paths} are not in their radiance ([lighting] source = \"distant\" leaves "
                          "them out on purpose; shexp.shade and sg.shade shade sphere lights)", stacklevel=3)

    @property
    def fingerprint(self) -> str:
        """The scene's content fingerprint (computed once, when a precompute stage needs it)."""
        if self._fingerprint is None:
            self._fingerprint = self.scene.fingerprint()
        return self._fingerprint

    @property
    def frame_stages(self) -> list:
        """The frame stages, in order."""
        return self.frame.stages

    @property
    def output(self):
        """The output device array (per-vertex radiance (vertex_count, 3) float32)."""
        return self.frame.output

    @property
    def program(self):
        """The recorded frame (:class:`~warpshade._wp.FrameProgram`), or None before it exists."""
        return self.frame.program

    # ---- stepping -----------------------------------------------------------------------
    def step(self, frame, lighting=None, record: bool = False, points=None, joints=None):
        """Shade one frame.

        Args:
            frame: a time code of the scene (a number; ValueError names the valid range).
            points: live geometry for this frame, {mesh prim path: world-space points (V, 3)}
                of deforming or skinned meshes, NumPy or a wp.array on the run's device (copied
                device to device): they replace the time samples and flow through the recorded
                frame (normals, BVH refit, every stage). The first feed of a mesh records the
                frame anew; later ones copy into its staging buffer and replay.
            joints: live poses, {skeleton prim path: joint-local transforms (J, 4, 4)} in USD's
                row-vector convention (as UsdSkel animation gives them), NumPy or a wp.array
                on the run's device; skinning follows. A step without ``points`` / ``joints``
                uses the time samples again
                (:meth:`FrameEvaluator.set_frame <warpshade.scene._state.FrameEvaluator.set_frame>`).
            lighting: optional override of the SH lighting for this frame: world-frame SH
                coefficients (3, n*n) of at least the graph's highest order, an Environment, a
                DistantLight or a list of them (projected to SH on the host).
            record: keep a host copy of the result in :attr:`results` (what the USD layer,
                previews and error measurement of :mod:`warpshade.measure` read); the copy is
                checked for NaN and infinities first (:meth:`check_finite`).

        Returns:
            the output device array (per-vertex radiance, (vertex_count, 3) float32). The same
            array is overwritten by the next step; copy it (``.numpy().copy()``) to keep it.

        Changes still dirty (made in a :meth:`batch`) are applied first (:meth:`update`).

        Raises:
            GraphError: with ``record``, a frame whose output is not finite, naming the frame
                and the first stage that produced non-finite values (nothing is recorded).
            ValueError: a bad frame, or live inputs naming no deforming or skinned mesh /
                skeleton, of the wrong shape, dtype or device, or not finite (the prim is
                named); nothing is written, the next step is as if this one had not been made.
            RuntimeError: another thread is stepping this runtime (its frame is not disturbed).
        """
        if not self._stepping.acquire(blocking=False):
            raise RuntimeError(f"step({frame!r}): another thread is stepping this runtime (one frame at a time: "
                               "feed and step from one thread, or wait for its step to return)")
        try:
            if self._pending.keys:
                self.update()
            t_start = time.perf_counter()
            self.evaluator.set_frame(frame, points=points, joints=joints)
            self._apply_material_track(self.state.frame)
            self._step_lighting(lighting)
            t_host = time.perf_counter()
            self.frame.run()
            self.host_s.append(t_host - t_start)
            self.frame_s.append(time.perf_counter() - t_start)
            if record:
                result = self.output.numpy().copy()
                if not np.all(np.isfinite(result)):
                    self.check_finite()
                    raise GraphError(f"frame {float(self.state.frame):g}: the output {self.spec.output!r} is not finite")
                self.results[float(self.state.frame)] = result
                self._check_lit(result)
        finally:
            self._stepping.release()
        return self.output

    def _check_lit(self, result: np.ndarray) -> None:
        """Warn (once, until a frame is lit again) when a recorded frame is black at every
        vertex: an eye inside or behind the surface, a zero colour or zero lighting give a frame
        that looks like a failure; the warning names what the output stage's diagnostics and
        parameters show."""
        import warnings

        if result.any():
            self._black_warned = False
            return
        if getattr(self, "_black_warned", False):
            return
        self._black_warned = True
        why = []
        st = self.output_stage()
        diag = st.diagnostics() if hasattr(st, "diagnostics") else {}
        below = diag.get("below_horizon") if isinstance(diag, dict) else None
        if below:
            why.append(f"{below} of {self.scene.vertex_count} vertices see the eye at or below their horizon "
                       "(the eye is inside or behind the surface: Runtime.set_eye or the stage's 'eye')")
        spec = getattr(st, "params", {}).get("specular")
        if spec is not None and not np.any(np.asarray(spec, np.float64)):
            why.append("the stage's 'specular' colour is zero")
        warnings.warn(f"frame {float(self.state.frame):g}: the output {self.spec.output!r} is black at every vertex"
                      + (f": {'; '.join(why)}" if why else " (no cause found in the stage's diagnostics)"),
                      UserWarning, stacklevel=3)

    def check_finite(self) -> None:
        """Check the last frame's arrays for NaN and infinities, in the order they were made:
        the scene's (points, normals, albedo), then every frame stage's outputs.

        Raises:
            GraphError: naming the frame, the first stage (or the scene) and port holding a
                non-finite value, how many there are and the first row.
        """
        frame = float(self.state.frame)
        arrays = [("the scene evaluation", "points", self.state.points), ("the scene evaluation", "normals", self.state.normals),
                  ("the scene evaluation", "albedo", self.evaluator.albedo)]
        arrays += [(f"stage {st.name!r} ({st.type_name})", port, a)
                   for st in self.frame_stages for port, a in self.frame.outputs[st.name].items()]
        for where, port, array in arrays:
            if not isinstance(array, wp.array) or array.dtype not in (wp.float32, wp.float64, wp.vec3, wp.mat33):
                continue
            host = array.numpy()
            bad = ~np.isfinite(host.reshape(host.shape[0], -1)).all(axis=1) if host.ndim else ~np.isfinite(host)
            if np.any(bad):
                raise GraphError(f"frame {frame:g}: {where} output {port!r} has {int(bad.sum())} non-finite row(s) of "
                                 f"{bad.size} (first row {int(np.argmax(bad))}): NaN or infinity from here on; check the "
                                 "stage's parameters, BRDF and inputs")

    def run(self, frames=None, record: bool = True, warmup: bool = True) -> np.ndarray:
        """Step over frames (default: the graph's frame range), with a progress bar.

        With ``warmup`` the first frame is stepped twice before timing starts (kernels compile,
        then the frame is recorded), so neither counts as frame time. Returns the frames run.
        """
        from ..tasks import progress_bar

        sel = parse_frames(frames if frames is not None else self.spec.frames, self.scene)
        if warmup:
            self.step(sel[0])
            self.step(sel[0])
            self.reset_timings()
        for f in progress_bar(sel, desc=f"{self.spec.name}: frames", disable=not self.progress, unit="frame"):
            self.step(f, record=record)
        return sel

    def profile(self, frames=None, repeats: int = 1) -> dict:
        """Median time per frame of the scene evaluation and of each frame stage, in seconds.

        Each piece is launched from Python and the device synchronised after it (no replay),
        so the times add up to more than a replayed frame; they say where a frame goes.
        The results are kept in :attr:`timings` (``frame_s``) for :meth:`timing_summary`.
        """
        sel = parse_frames(frames if frames is not None else self.spec.frames, self.scene)
        self.update()
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
        """Bytes of precomputed model data the frame loop needs (:meth:`FrameGraph.model_bytes
        <warpshade.graph._frame.FrameGraph.model_bytes>`)."""
        return self.frame.model_bytes()

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
        prog = self.frame.program
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
