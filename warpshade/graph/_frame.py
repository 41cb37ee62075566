"""The per-frame part of a run: frame stages bound once, one frame recorded and replayed.

:class:`FrameGraph` sets the frame stages up in order (:meth:`FrameGraph.setup`: each stage's
inputs are the scene's per-frame arrays of the :class:`~warpshade.scene._state.FrameState`,
upstream frame outputs and precompute artifacts uploaded once) and runs a frame: the scene
evaluation (:class:`~warpshade.scene._state.FrameEvaluator`) followed by every frame stage's
``launch(state)``. The first frame runs directly (kernels compile); the second is recorded
(:func:`warpshade._wp.record_program`: a Warp graph capture, on CUDA and on the CPU) and every
later one replays the recording. What cannot be recorded (chunked multi-core CPU launches, a
stage that says so, point samples too large for the device) runs as Python calls between
recorded segments. A new set-up drops the recording, as does a first live input of a mesh
(its staging buffer is new); the next frame records anew.
"""

from __future__ import annotations

import numpy as np

from .._wp import record_program, wp
from ..methods.stage import Port
from ._errors import GraphError

__all__ = ["FrameGraph"]

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



class FrameGraph:
    """The frame stages of a run, set up on the evaluator's state, and the recorded frame.

    Args:
        stages: every stage of the graph in order (the frame stages are taken from it).
        wiring: stage name -> {input port: Wire}.
        artifacts: precompute artifacts, stage name -> output name -> array.
        evaluator: the run's :class:`~warpshade.scene._state.FrameEvaluator`.
        ctx: the :class:`~warpshade.methods.stage.StageContext` stages are set up with.
        output: the graph's output, ``"stage.port"``.
        capture: record the frame once and replay it (False: every frame from Python).

    Attributes:
        stages: the frame stages, in order.
        outputs: stage name -> output name -> device array (fixed between set-ups).
        output: the output device array.
        program: the recorded frame (:class:`~warpshade._wp.FrameProgram`) or None.
    """

    def __init__(self, stages, wiring, artifacts, evaluator, ctx, output: str, capture: bool = True):
        self.stages = [s for s in stages if s.kind == "frame"]
        self._ports = {s.name: s.output_ports() for s in stages}
        self.wiring = wiring
        self.artifacts = artifacts
        self.evaluator = evaluator
        self.ctx = ctx
        self.capture = bool(capture)
        self._output = output.split(".", 1)
        self._uploaded: dict = {}
        self.outputs: dict = {}
        self.output = None
        self.program = None
        self._warm = False
        self._recorded_live = evaluator.live_version
        self.setup(0)

    def _scene_input(self, port: str):
        state = self.evaluator.state
        if port == "points":
            return state.points
        if port == "normals":
            return state.normals
        if port == "albedo":
            return self.evaluator.albedo
        if port == "lighting":
            return state.lighting
        raise GraphError(f"unknown scene port {port!r}")

    def _artifact_input(self, w):
        """A precompute artifact as a frame stage input: uploaded once ("arrays" ports stay a host
        dict: the stage uploads what it needs)."""
        key = (w.provider, w.port)
        if key not in self._uploaded:
            port = self._ports[w.provider][w.port]
            value = self.artifacts[w.provider][w.port]
            self._uploaded[key] = value if port.dtype == "arrays" else _to_device(
                value, port, self.ctx.device, f"stage {w.provider!r} output {w.port!r}")
        return self._uploaded[key]

    def setup(self, start: int) -> None:
        """Set up frame stages ``start..`` (in order), binding upstream outputs; the recording is
        dropped first (the next frame records anew), so a set-up that fails part way never leaves a
        recording of buffers some stages no longer use."""
        self._setup(self.stages[start:])

    def setup_stages(self, names) -> list:
        """Set up the frame stages ``names`` and every frame stage that reads an output of one set
        up (directly or through others), each once, in order; the others keep their set-up and
        buffers. Returns the names set up (the recording is dropped as by :meth:`setup`)."""
        again = set(names)
        chosen = []
        for st in self.stages:
            if st.name in again or any(w.provider in again for w in self.wiring[st.name].values()):
                again.add(st.name)
                chosen.append(st)
        self._setup(chosen)
        return [st.name for st in chosen]

    def _setup(self, stages) -> None:
        self.program = None
        for st in stages:
            inputs = {}
            for port, w in self.wiring[st.name].items():
                if w.provider == "scene":
                    inputs[port] = self._scene_input(w.port)
                elif w.provider in self.outputs:
                    inputs[port] = self.outputs[w.provider][w.port]
                else:
                    inputs[port] = self._artifact_input(w)
            outs = st.setup(self.ctx, inputs)
            missing = set(st.output_ports()) - set(outs)
            if missing:
                raise GraphError(f"stage {st.name!r}: setup did not allocate {sorted(missing)}")
            self.outputs[st.name] = outs
        self.output = self.outputs[self._output[0]][self._output[1]]

    def launch(self, recorder=None) -> None:
        """One frame's launches: scene evaluation, then every frame stage."""
        state = self.evaluator.state
        self.evaluator.launch(recorder)
        for st in self.stages:
            if recorder is not None and not st.capturable:
                recorder.call(lambda st=st: st.launch(state), f"stage {st.name!r}: {st.capture_note or 'not capturable'}")
            else:
                st.launch(state)

    def run(self) -> None:
        """Run the frame the evaluator's host inputs name: replay the recording; record it on the
        second frame after a set-up; run it directly before (kernels compile) or without capture.
        A recording made before the evaluator allocated a staging buffer for live inputs does
        not read it: it is recorded anew. Returns once the device is done."""
        if self.program is not None and self._recorded_live != self.evaluator.live_version:
            self.program = None
        if self.program is not None:
            self.program.replay()
        elif self.capture and self._warm:
            self._recorded_live = self.evaluator.live_version
            self.program = record_program(self.launch, self.ctx.device)
            self.program.replay()
        else:
            self.launch()
            self._warm = True
        wp.synchronize_device(self.ctx.device)

    def model_bytes(self) -> int:
        """Bytes of precomputed model data the frame loop needs: per frame stage, what it keeps
        on the device (its ``model_bytes()``) or, when it reports nothing, the precompute
        artifacts it reads. Artifacts only precompute stages read (training data) are not counted."""
        total = 0
        for st in self.stages:
            own = int(st.model_bytes())
            if own:
                total += own
                continue
            for w in self.wiring[st.name].values():
                if w.provider in self.artifacts:
                    a = self.artifacts[w.provider][w.port]
                    total += sum(int(np.asarray(v).nbytes) for v in (a.values() if isinstance(a, dict) else (a,)))
        return total
