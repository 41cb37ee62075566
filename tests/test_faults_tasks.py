"""Faults of the executors and of long precompute (issue 23, families 2 and 6).

Hangs (family 2): a scheduler address that accepts the connection and never answers fails
within the connect timeout, naming the address, the timeout and how to change it; local worker
processes (and the multiprocessing resource tracker) exit when the run that started them is
killed; an interrupt or a failing task stops the pool without leaking semaphores.

Nothing lost on interrupt (family 6): training frames and ground-truth frames are kept in the
cache task by task, so a run interrupted after k tasks computes only the others when run again,
gives the uninterrupted result bit for bit, and recomputes a damaged entry.
"""

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from hang import START_S

from warpshade import tasks as task_module
from warpshade.tasks import CONNECT_TIMEOUT_ENV, DaskExecutor, SerialExecutor, TaskError, executor
from warpshade.graph import ArtifactCache, GraphSpec, StageSpec
from warpshade.io import load_scene
from warpshade.measure import ground_truth
from warpshade.methods._shared import training
from warpshade.methods.datadriven._rows import stages_for
from warpshade.scene import LightingSource

ROOT = Path(__file__).resolve().parents[1]
#: seconds a connection attempt may run past its timeout (thread hand-offs, closing the client;
#: generous for a loaded machine: without the timeout the attempt would never return)
CONNECT_SLACK_S = 10.0
#: seconds within which orphaned workers must be gone (they poll their parent every 0.5 s; a
#: hang guard, generous for a loaded machine)
ORPHAN_EXIT_S = 60.0


# ---- family 2: a scheduler that never answers ------------------------------------------------
@pytest.fixture
def silent_server():
    """A TCP server that accepts every connection and never sends a byte; yields its address."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    accepted = []

    def accept():
        while True:
            try:
                accepted.append(server.accept()[0])
            except OSError:  # closed at teardown
                return

    threading.Thread(target=accept, daemon=True).start()
    yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    server.close()
    for conn in accepted:
        conn.close()


def _raised_within(seconds: float, fn) -> BaseException | None:
    """What ``fn()`` raises, failing the test when it has not returned after ``seconds`` (it
    is left running on a daemon thread rather than hanging the test session)."""
    outcome = []

    def call():
        try:
            fn()
            outcome.append(None)
        except BaseException as exc:
            outcome.append(exc)

    thread = threading.Thread(target=call, daemon=True)
    thread.start()
    thread.join(seconds)
    assert outcome, f"still waiting after {seconds} s"
    return outcome[0]


def test_a_scheduler_that_never_answers_fails_within_the_timeout(silent_server):
    pytest.importorskip("distributed")
    exc = _raised_within(1.5 + CONNECT_SLACK_S, lambda: DaskExecutor(silent_server, timeout=1.5))
    assert isinstance(exc, ValueError), exc
    message = str(exc)
    assert f"'{silent_server}'" in message and "1.5 s" in message and "larger timeout" in message


def test_the_connect_timeout_comes_from_the_environment(silent_server, monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setenv(CONNECT_TIMEOUT_ENV, "1")
    exc = _raised_within(1 + CONNECT_SLACK_S, lambda: executor(silent_server))
    assert isinstance(exc, ValueError) and f"'{silent_server}' within 1 s" in str(exc), exc
    assert f"${CONNECT_TIMEOUT_ENV}" in str(exc)


@pytest.mark.parametrize("value", ["soon", "0", "-3", "nan", "inf"])
def test_a_bad_connect_timeout_is_named(monkeypatch, value):
    monkeypatch.setenv(CONNECT_TIMEOUT_ENV, value)
    with pytest.raises(ValueError, match=rf"\${CONNECT_TIMEOUT_ENV} must be a positive number.*{value!r}"):
        task_module.connect_timeout()


# ---- family 2: local workers die with their run ----------------------------------------------
RUN_LONG_TASKS = """
import signal
import sys
from warpshade.tasks import ProcessExecutor
import task_helpers

if __name__ == "__main__":
    # a terminal's Ctrl-C meets Python's own handler; a suite started as a background job of a
    # non-interactive shell inherits SIGINT ignored, and so would this process
    signal.signal(signal.SIGINT, signal.default_int_handler)
    marker_dir, mode = sys.argv[1], sys.argv[2]
    with ProcessExecutor(2) as ex:
        if mode == "fail":  # the first task raises while the other is still running
            ex.map(task_helpers.fail_on, [(0, 0), (1, -1)], progress=False)
        ex.map(task_helpers.slow_seeded, [(seed, 120.0, marker_dir) for seed in range(4)], progress=False)
"""


def _children(pid: int) -> list[int]:
    """Processes whose parent is ``pid`` (Linux /proc)."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                out.append(int(entry.name))
    return out


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie (exited, not yet reaped by its new parent) counts as gone
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _start_run(tmp_path, mode: str):
    """A run of RUN_LONG_TASKS in its own session, once both its workers run a task: (process,
    its child processes: the workers and the resource tracker, stderr file)."""
    script = tmp_path / "run_long_tasks.py"
    script.write_text(RUN_LONG_TASKS)
    markers = tmp_path / "markers"
    markers.mkdir()
    stderr = tmp_path / "stderr.txt"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(ROOT / "tests")]))
    with open(stderr, "w") as err:
        proc = subprocess.Popen([sys.executable, str(script), str(markers), mode], stdout=subprocess.DEVNULL,
                                stderr=err, env=env, start_new_session=True)
    deadline = time.monotonic() + START_S
    while len(list(markers.glob("start-*"))) < 2:
        assert proc.poll() is None, stderr.read_text()
        assert time.monotonic() < deadline, "the workers did not start"
        time.sleep(0.1)
    return proc, _children(proc.pid), stderr


def _assert_gone(pids, within: float) -> None:
    deadline = time.monotonic() + within
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [p for p in pids if _alive(p)]
    for pid in left:  # do not leave them to the next test
        os.kill(pid, signal.SIGKILL)
    assert not left, f"still running {within} s later: {left}"


linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


@linux_only
def test_workers_and_the_resource_tracker_exit_when_the_run_is_killed(tmp_path):
    proc, children, _ = _start_run(tmp_path, "long")
    assert len(children) >= 3, children  # two workers and the resource tracker
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    _assert_gone(children, ORPHAN_EXIT_S)


@linux_only
def test_an_interrupt_stops_the_pool_without_leaks(tmp_path):
    proc, children, stderr = _start_run(tmp_path, "long")
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C in a terminal reaches the whole process group
    proc.wait(timeout=START_S)
    text = stderr.read_text()
    assert proc.returncode != 0 and "KeyboardInterrupt" in text
    assert "leaked" not in text, text
    _assert_gone(children, ORPHAN_EXIT_S)


@linux_only
def test_a_failing_task_stops_the_pool_without_leaks(tmp_path):
    script = tmp_path / "run_long_tasks.py"
    script.write_text(RUN_LONG_TASKS)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(ROOT / "tests")]))
    done = subprocess.run([sys.executable, str(script), str(tmp_path), "fail"], capture_output=True, text=True,
                          env=env, timeout=START_S)
    assert done.returncode != 0 and "task 0 failed: ValueError: refusing 0" in done.stderr
    assert "leaked" not in done.stderr, done.stderr
    assert not list(tmp_path.glob("start-*")), "the long map never ran"


# ---- family 6: training data resumes ------------------------------------------------------------
@pytest.fixture(scope="module")
def bend():
    return load_scene("bundled:bend")


FRAMES = np.arange(6)


class Interrupt(Exception):
    """What the counted task raises on its k-th call (a failing task, or an interrupt)."""


def _count_calls(monkeypatch, module, name: str, fail_at: int | None = None, exc=Interrupt):
    """Replace ``module.name`` (a task function) by one that records its calls and raises
    ``exc`` on call ``fail_at``; returns the list of calls."""
    real = getattr(module, name)
    calls = []

    def counted(task):
        calls.append(task)
        if fail_at is not None and len(calls) == fail_at:
            raise exc(f"call {fail_at}")
        return real(task)

    monkeypatch.setattr(module, name, counted)
    return calls


def _task_entries(cache_dir: Path) -> list[Path]:
    return sorted(cache_dir.glob("datadriven-task-*.npz"))


def _trace(bend, cache):
    return training.trace_training(bend, FRAMES, 2, 16, seed=1, executor=SerialExecutor(), cache=cache)


@pytest.mark.parametrize("exc", [Interrupt, KeyboardInterrupt])
def test_interrupted_training_resumes_where_it_stopped(bend, tmp_path, monkeypatch, exc):
    monkeypatch.setattr(training, "FRAMES_PER_TASK", 1)  # one task per frame
    uninterrupted = _trace(bend, None)
    cache = ArtifactCache(tmp_path)
    k = 3
    with monkeypatch.context() as m:
        _count_calls(m, training, "trace_task", fail_at=k, exc=exc)
        with pytest.raises(TaskError if exc is Interrupt else KeyboardInterrupt) as info:
            _trace(bend, cache)
    if exc is Interrupt:
        assert "training frames 2..2" in str(info.value)
    assert len(_task_entries(tmp_path)) == k - 1, "each finished task is kept"
    calls = _count_calls(monkeypatch, training, "trace_task")
    report = {}
    resumed = training.trace_training(bend, FRAMES, 2, 16, seed=1, executor=SerialExecutor(), cache=cache,
                                      report=report)
    assert [t["frame_indices"] for t in calls] == [[i] for i in FRAMES[k - 1:]], "only the unfinished tasks run"
    assert report == {"tasks": len(FRAMES), "tasks_cached": k - 1}
    assert resumed.dtype == uninterrupted.dtype and resumed.tobytes() == uninterrupted.tobytes()
    assert not _task_entries(tmp_path), "assembled: the per-task entries are removed"


def test_a_damaged_task_entry_is_traced_again(bend, tmp_path, monkeypatch):
    monkeypatch.setattr(training, "FRAMES_PER_TASK", 2)
    uninterrupted = _trace(bend, None)
    cache = ArtifactCache(tmp_path)
    with monkeypatch.context() as m:
        _count_calls(m, training, "trace_task", fail_at=3)
        with pytest.raises(TaskError):
            _trace(bend, cache)
    first, second = _task_entries(tmp_path)
    data = bytearray(first.read_bytes())
    data[len(data) // 2] ^= 0xFF  # a flipped bit: the digest no longer matches
    first.write_bytes(bytes(data))
    # a valid archive with the wrong content (one frame, not two): not a result of this task
    cache.store(second.name.split(".")[0], {"transfer": np.zeros((1, bend.vertex_count, 4), np.float32)})
    calls = _count_calls(monkeypatch, training, "trace_task")
    resumed = _trace(bend, cache)
    assert len(calls) == 3, "the damaged and the wrong entries are traced again, with the missing task"
    assert any("digest" in why for _, why in cache.damaged)
    assert resumed.tobytes() == uninterrupted.tobytes()


def _data_graph(frames: str = "0:6"):
    stages = list(stages_for("", "reduced", order=2, samples=16, fit={"validation": 0.0, "ka": 2, "kv": 4}))
    stages[0] = ("data", "datadriven.data", {"order": 2, "samples": 16, "frames": frames}, {})
    return GraphSpec([StageSpec(n, t, dict(p), dict(i)) for (n, t, p, i) in stages], "shade.radiance", name="dd")


def test_the_data_stage_resumes_an_interrupted_run(bend, tmp_path, monkeypatch):
    monkeypatch.setattr(training, "FRAMES_PER_TASK", 1)
    uninterrupted = _data_graph().compile(bend, cache_dir=None, progress=False, scheduler="serial")
    cache_dir = tmp_path / "cache"
    with monkeypatch.context() as m:
        _count_calls(m, training, "trace_task", fail_at=5, exc=KeyboardInterrupt)
        with pytest.raises(KeyboardInterrupt):
            _data_graph().compile(bend, cache_dir=cache_dir, progress=False, scheduler="serial")
    assert len(_task_entries(cache_dir)) == 4
    calls = _count_calls(monkeypatch, training, "trace_task")
    resumed = _data_graph().compile(bend, cache_dir=cache_dir, progress=False, scheduler="serial")
    assert len(calls) == 2
    assert resumed.stages[0].report["tasks_cached"] == 4
    for name, want in uninterrupted.artifacts["data"]["data"].items():
        got = resumed.artifacts["data"]["data"][name]
        assert got.dtype == want.dtype and got.tobytes() == want.tobytes(), name
    assert not _task_entries(cache_dir)
    again = _data_graph().compile(bend, cache_dir=cache_dir, progress=False, scheduler="serial")
    assert again.timings["data"].cache == "hit" and len(calls) == 2


# ---- family 6: ground truth resumes --------------------------------------------------------------
GT_FRAMES = [0.0, 10.0, 20.0, 30.0]


def _truth(bend, cache_dir, ex=None):
    lighting = LightingSource.fixed(bend.lights, bend.up_axis)
    return ground_truth(bend, lighting, GT_FRAMES, samples=8, cache_dir=cache_dir, seed=3,
                        executor=SerialExecutor() if ex is None else ex)


def test_interrupted_ground_truth_resumes_where_it_stopped(bend, tmp_path, monkeypatch):
    import warpshade.measure._truth as truth

    uninterrupted = _truth(bend, None)
    cache_dir = tmp_path / "truth"
    with monkeypatch.context() as m:
        _count_calls(m, truth, "_truth_task", fail_at=3, exc=KeyboardInterrupt)
        with pytest.raises(KeyboardInterrupt):
            _truth(bend, cache_dir)
    entries = sorted(cache_dir.glob("gt-*.npz"))
    assert len(entries) == 2, "each finished frame is kept"
    data = bytearray(entries[0].read_bytes())
    data[-10] ^= 0x01
    entries[0].write_bytes(bytes(data))
    calls = _count_calls(monkeypatch, truth, "_truth_task")
    resumed = _truth(bend, cache_dir)
    frames = [t["frame"] for t in calls]
    assert len(frames) == 3 and {20.0, 30.0} <= set(frames), "the two left and the damaged one"
    for f in GT_FRAMES:
        for name in ("radiance", "stderr"):
            assert resumed[f][name].tobytes() == uninterrupted[f][name].tobytes(), (f, name)
    _truth(bend, cache_dir)
    assert len(calls) == 3, "all cached now"


def test_a_ground_truth_entry_of_the_wrong_shape_is_computed_again(bend, tmp_path, monkeypatch):
    import warpshade.measure._truth as truth

    cache_dir = tmp_path / "truth"
    _truth(bend, cache_dir)
    cache = ArtifactCache(cache_dir)
    entry = sorted(cache_dir.glob("gt-*.npz"))[0]
    key = entry.name.split(".")[0]
    cache.store(key, {"radiance": np.full((3, 3), np.nan, np.float32), "stderr": np.zeros((3, 3), np.float32)})
    calls = _count_calls(monkeypatch, truth, "_truth_task")
    again = _truth(bend, cache_dir)
    assert len(calls) == 1
    assert all(np.isfinite(hit["radiance"]).all() and hit["radiance"].shape == (bend.vertex_count, 3)
               for hit in again.values())
