"""Shared Warp set-up: quiet initialisation, explicit devices, parallel CPU launches, frame capture.

Every module that launches kernels imports ``wp`` from here so that Warp is initialised once,
quietly, and so that device handling is the same everywhere: a device is always an explicit
argument (``"cpu"``, ``"cuda:0"``, ...) that defaults to Warp's default device, and nothing
falls back silently from CUDA to the CPU.

Two launch-level tools live here because every layer uses them:

* :func:`launch_parallel` -- Warp runs one CPU launch on one thread (and releases the GIL), so a
  large CPU launch is split into chunks over a small thread pool; on CUDA it is one launch.
* :class:`FrameProgram` / :func:`record_program` -- a frame recorded once and replayed: Warp
  graph capture (``wp.ScopedCapture``) on CUDA and, since Warp 1.10, on the CPU too (the CPU
  replay runs the recorded operations in C++). Operations that must not be captured -- a
  chunked CPU launch (the replay is single-threaded, and launches from pool threads are not
  recorded), a host upload that cannot live on the device -- split the recording into
  segments: captured graphs with Python calls between them.
* :class:`HostFields` -- named int32 host inputs (frame index, flags) in one :class:`HostInput`;
* :class:`HostInput` -- a small device array written by the host before each replay (the time
  code of the frame, an override flag), through a pinned staging buffer on CUDA whose copy is
  part of the recorded frame.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import warp as wp

__all__ = [
    "wp",
    "resolve_device",
    "init",
    "cpu_workers",
    "launch_parallel",
    "HostFields",
    "HostInput",
    "FrameProgram",
    "record_program",
]

_initialised = False
#: What Warp's native start-up printed (e.g. that no CUDA driver was found); shown only when a
#: CUDA device is asked for, or with WARPSHADE_VERBOSE set.
_init_messages = ""


def init() -> None:
    """Initialise Warp once, quietly unless WARPSHADE_VERBOSE is set.

    Warp's native library reports a missing CUDA driver on stderr at start-up, on every machine
    without a GPU; that note is kept (:func:`resolve_device` repeats it when a CUDA device is
    asked for) instead of being printed by every command.
    """
    global _initialised, _init_messages
    if _initialised:
        return
    if os.environ.get("WARPSHADE_VERBOSE"):
        wp.init()
        _initialised = True
        return
    # Warp >= 1.10 uses log_level; older versions use the quiet flag.
    if hasattr(wp, "LOG_WARNING"):
        wp.config.log_level = wp.LOG_WARNING
    wp.config.quiet = True
    import sys

    from ._fileio import captured_stderr

    with captured_stderr() as printed:
        wp.init()
    _init_messages = " ".join(printed)
    _initialised = True
    if _init_messages and "CUDA driver" not in _init_messages:
        print(_init_messages, file=sys.stderr)  # anything else Warp said is worth seeing


def resolve_device(device=None) -> wp.context.Device:
    """Return the Warp device for ``device`` (None means Warp's default device).

    Raises:
        ValueError: if the device does not exist on this machine (for example ``"cuda:0"`` on a
            machine without a GPU). There is no silent fallback to the CPU.
    """
    init()
    try:
        return wp.get_device(device)
    except Exception as exc:  # Warp raises RuntimeError / ValueError depending on version
        available = ", ".join(str(d) for d in wp.get_devices())
        note = f"; Warp: {_init_messages}" if _init_messages and "cuda" in str(device).lower() else ""
        raise ValueError(f"device {device!r} is not available (available: {available}){note}") from exc


# ---- parallel CPU launches -----------------------------------------------------------------
def cpu_workers() -> int:
    """Threads a chunked CPU launch uses: ``$WARPSHADE_THREADS`` if set (1 = every CPU launch is
    one launch, so a recorded CPU frame is one replay), else the cores this process may run on,
    at most 8.

    Raises:
        ValueError: ``WARPSHADE_THREADS`` is not a positive integer.
    """
    env = os.environ.get("WARPSHADE_THREADS")
    if env:
        try:
            value = int(env)
        except ValueError:
            value = 0
        if value < 1:
            raise ValueError(f"WARPSHADE_THREADS must be a positive integer, got {env!r}")
        return value
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(int(cores), 8))


_pool_lock = threading.Lock()
_pools: dict[int, ThreadPoolExecutor] = {}


def _pool(workers: int) -> ThreadPoolExecutor:
    with _pool_lock:
        if workers not in _pools:
            _pools[workers] = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="warpshade-launch")
        return _pools[workers]


def _chunked(kernel, count: int, inputs_for, device, workers: int, chunks: int | None) -> None:
    chunks = min(count, chunks or 4 * workers)
    bounds = np.linspace(0, count, chunks + 1).astype(np.int64)

    def run(k):
        start, stop = int(bounds[k]), int(bounds[k + 1])
        if stop > start:
            wp.launch(kernel, dim=stop - start, inputs=inputs_for(start, stop), device=device)

    list(_pool(workers).map(run, range(chunks)))


def launch_parallel(kernel, count: int, inputs_for, device, workers: int | None = None, min_count: int = 1,
                    chunks: int | None = None) -> None:
    """Launch ``kernel`` over ``count`` items, split over a thread pool on the CPU.

    Args:
        kernel: a Warp kernel whose launch of ``stop - start`` threads covers items
            ``start .. stop`` (it adds ``start`` to ``wp.tid()``, or gets sliced arrays).
        count: total number of items.
        inputs_for: callable ``(start, stop) -> list`` of the kernel inputs of one chunk.
        device: Warp device. On CUDA this is always one launch.
        workers: CPU threads (default :func:`cpu_workers`); 1 = one launch on this thread.
        min_count: launches of fewer items are not split (a pool round trip costs ~0.1 ms).
        chunks: number of chunks (default ``4 * workers``, for load balance).

    Inside :func:`record_program` a chunked CPU launch ends the current captured segment and
    runs from Python at every replay (still on every core); under a plain ``wp.ScopedCapture``
    it is recorded as one launch.
    """
    if count <= 0:
        return
    dev = resolve_device(device)
    workers = cpu_workers() if workers is None else max(1, int(workers))
    if not dev.is_cpu or workers <= 1 or count < max(2, int(min_count)):
        wp.launch(kernel, dim=count, inputs=inputs_for(0, count), device=dev)
        return
    # compile/load on the calling thread so that the workers only launch
    wp.load_module(kernel.module, device=dev)
    recorder = _recording.get(dev.alias)
    if recorder is not None:
        recorder.call(lambda: _chunked(kernel, count, inputs_for, dev, workers, chunks), "chunked CPU launch")
        return
    if dev.is_capturing:  # a capture this module does not own: pool threads would not be recorded
        wp.launch(kernel, dim=count, inputs=inputs_for(0, count), device=dev)
        return
    _chunked(kernel, count, inputs_for, dev, workers, chunks)


# ---- host inputs of a recorded frame ---------------------------------------------------------
class HostInput:
    """A small device array the host writes before each frame (capture-safe).

    On the CPU the device array is host memory and :attr:`host` is a view of it. On CUDA
    :attr:`host` is a pinned staging buffer and :meth:`launch` (an operation of the recorded
    frame) copies it to the device, so a replay reads what the host wrote just before it.
    The runtime synchronises at the end of every frame, so the staging buffer is never written
    while a copy of it is in flight.

    Args:
        shape: array shape; dtype: a Warp scalar type (``wp.int32``, ``wp.float32``).
        device: the Warp device.

    Attributes:
        array: the device array kernels read (fixed address).
        host: a NumPy view the host writes.
    """

    def __init__(self, shape, dtype, device):
        dev = resolve_device(device)
        self.device = dev
        self.array = wp.zeros(shape, dtype=dtype, device=dev)
        self._staging = self.array if dev.is_cpu else wp.zeros(shape, dtype=dtype, device="cpu", pinned=True)
        self.host = self._staging.numpy()

    def launch(self) -> None:
        """Copy the host values to the device (nothing to do on the CPU)."""
        if self._staging is not self.array:
            wp.copy(self.array, self._staging)


class HostFields:
    """Named int32 host inputs of a recorded frame, packed in one :class:`HostInput`.

    Field ``i`` of ``names`` is element ``i`` of :attr:`array` (what kernels read); the host
    changes fields only through :meth:`write`, so one object -- the owner that calls it -- is
    the writer of every field.

    Args:
        names: the field names, in slot order.
        device: the Warp device.
    """

    def __init__(self, names, device):
        self.names = tuple(names)
        self._slot = {n: i for i, n in enumerate(self.names)}
        self._input = HostInput((len(self.names),), wp.int32, device)

    @property
    def array(self):
        """The device array kernels read, int32 (len(names),) (fixed address)."""
        return self._input.array

    def slot(self, name: str) -> int:
        """The element of :attr:`array` that holds field ``name`` (what a kernel indexes)."""
        return self._slot[name]

    def __getitem__(self, name: str) -> int:
        """The value the host last wrote to field ``name``."""
        return int(self._input.host[self._slot[name]])

    def write(self, **fields) -> None:
        """Set fields by name (ints) for the next frame; KeyError for an unknown name."""
        for name, value in fields.items():
            self._input.host[self._slot[name]] = int(value)

    def launch(self) -> None:
        """Copy the host values to the device (an operation of the recorded frame)."""
        self._input.launch()


# ---- recorded frames ------------------------------------------------------------------------
_recording: dict[str, "_Recorder"] = {}


class FrameProgram:
    """A recorded frame: captured Warp graphs and the Python calls between them, in order.

    Attributes:
        segments: list of ``("graph", wp.Graph)`` and ``("call", callable, why)`` entries.
        device: the Warp device.
    """

    def __init__(self, device):
        self.device = device
        self.segments: list = []

    @property
    def graph_count(self) -> int:
        return sum(1 for s in self.segments if s[0] == "graph")

    @property
    def uncaptured(self) -> list[str]:
        """Why each Python call between the graphs is not captured."""
        return [s[2] for s in self.segments if s[0] == "call"]

    def replay(self) -> None:
        """Run the frame: replay every graph and make every call, in recording order."""
        for seg in self.segments:
            if seg[0] == "graph":
                wp.capture_launch(seg[1])
            else:
                seg[1]()


class _Recorder:
    def __init__(self, device):
        self.device = device
        self.program = FrameProgram(device)
        self.ops = 0

    def begin(self) -> None:
        wp.capture_begin(device=self.device, force_module_load=False)

    def end(self) -> None:
        graph = wp.capture_end(device=self.device)
        self.program.segments.append(("graph", graph))

    def call(self, fn, why: str) -> None:
        """End the current capture, make ``fn`` a call of the program, begin a new capture."""
        self.end()
        self.program.segments.append(("call", fn, why))
        self.begin()


def record_program(fn, device) -> FrameProgram:
    """Record ``fn(recorder)`` (kernel launches on fixed buffers) as a :class:`FrameProgram`.

    Recording executes nothing (as with CUDA graph capture): run the program with
    :meth:`FrameProgram.replay`. What must not be captured -- chunked CPU launches of
    :func:`launch_parallel`, and calls the recorded code hands to :meth:`FrameRecorder.call` --
    becomes a Python call between captured segments, made at its place in every replay.

    Args:
        fn: callable taking a :class:`FrameRecorder`.
        device: the Warp device.
    """
    dev = resolve_device(device)
    if dev.alias in _recording:
        raise RuntimeError(f"record_program: already recording on {dev}")
    rec = _Recorder(dev)
    _recording[dev.alias] = rec
    rec.begin()
    try:
        fn(FrameRecorder(rec))
    except BaseException:
        try:
            wp.capture_end(device=dev)
        finally:
            _recording.pop(dev.alias, None)
        raise
    try:
        rec.end()
    finally:
        _recording.pop(dev.alias, None)
    return rec.program


class FrameRecorder:
    """What :func:`record_program` hands to the recorded function."""

    def __init__(self, rec: _Recorder):
        self._rec = rec

    def call(self, fn, why: str) -> None:
        """Make ``fn()`` a Python call at this point of every replay (not captured); ``why``
        says why it cannot be captured (reported by the runtime)."""
        self._rec.call(fn, why)
