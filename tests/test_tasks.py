"""The executor interface (warpshade.tasks): serial, local worker processes and a Dask
LocalCluster give the serial loop's results, survive a worker killed mid-run, and report failing
tasks and bad schedulers."""

import os
import re
import signal
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import task_helpers as th
from hang import START_S

from warpshade import tasks as task_module
from warpshade.tasks import DaskExecutor, ProcessExecutor, SerialExecutor, TaskError, executor

distributed = pytest.importorskip("distributed")

SEEDS = list(range(6))
# Slow tasks: 12 x 0.2 s on 2 workers last ~1.2 s, long enough to kill a worker mid-run.
SLOW_TASKS = 12
SLOW_SECONDS = 0.2


@pytest.fixture(scope="module")
def cluster():
    """One LocalCluster of two single-threaded worker processes for the whole module."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=40) as cluster:
        yield cluster


@pytest.fixture
def dask_executor(cluster):
    with DaskExecutor(cluster.scheduler_address) as ex:
        ex.client.wait_for_workers(2, timeout=START_S)
        yield ex


@pytest.fixture(scope="module")
def local_executor():
    with ProcessExecutor(workers=2) as ex:
        yield ex


def _equal(a, b) -> bool:
    if isinstance(a, tuple):
        return len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
    return a == b


# ---- identical results -------------------------------------------------------------------------
def test_serial_executor_is_the_loop():
    ex = executor("serial")
    assert isinstance(ex, SerialExecutor) and ex.name == "serial" and ex.workers == 1
    assert ex.map(th.seeded_sum, SEEDS, progress=False) == [th.seeded_sum(s) for s in SEEDS]


def test_local_processes_match_serial(local_executor):
    assert local_executor.name == "local:2" and local_executor.workers == 2
    assert local_executor.map(th.seeded_sum, SEEDS, desc="seeded", progress=False) == [th.seeded_sum(s) for s in SEEDS]
    assert local_executor.map(th.seeded_sum, [], progress=False) == []


def test_local_workers_run_warp_single_threaded(local_executor):
    expected = [th.warp_transfer(s) for s in (1, 2, 3)]
    got = local_executor.map(th.warp_transfer, [1, 2, 3], desc="transfer", progress=False)
    assert all(_equal(g, e) for g, e in zip(got, expected))
    assert local_executor.map(os.getenv, ["WARPSHADE_THREADS"], progress=False) == ["1"]


def test_dask_matches_serial(dask_executor, cluster):
    assert dask_executor.name == f"dask:{cluster.scheduler_address}" and dask_executor.workers == 2
    assert dask_executor.map(th.seeded_sum, SEEDS, desc="seeded", progress=False) == [th.seeded_sum(s) for s in SEEDS]
    expected = [th.warp_transfer(s) for s in (1, 2)]
    got = dask_executor.map(th.warp_transfer, [1, 2], desc="transfer", progress=False)
    assert all(_equal(g, e) for g, e in zip(got, expected))
    # Equal arguments in a second map are tasks of their own (distinct keys, pure=False).
    assert dask_executor.map(th.seeded_sum, [3, 3], progress=False) == [th.seeded_sum(3)] * 2


# ---- a worker killed mid-run -------------------------------------------------------------------
def _kill_a_running_worker(marker_dir: Path, killed: list, stop: threading.Event, after_done: int = 2) -> None:
    """Once ``after_done`` tasks finished, SIGKILL the process of one task still running."""
    deadline = time.monotonic() + START_S
    while not stop.is_set() and time.monotonic() < deadline:
        done = {int(p.name.split("-")[1]) for p in marker_dir.glob("done-*")}
        if len(done) >= after_done:
            running = [tuple(int(v) for v in p.name.split("-")[1:]) for p in marker_dir.glob("start-*")]
            running = [(seed, pid) for seed, pid in running if seed not in done]
            if running:
                seed, pid = running[0]
                os.kill(pid, signal.SIGKILL)
                killed.append((seed, pid, (marker_dir / f"done-{seed}").exists()))
                return
        time.sleep(0.01)


def _map_while_killing(ex, tmp_path):
    tasks = [(seed, SLOW_SECONDS, str(tmp_path)) for seed in range(SLOW_TASKS)]
    killed, stop = [], threading.Event()
    killer = threading.Thread(target=_kill_a_running_worker, args=(tmp_path, killed, stop))
    killer.start()
    try:
        results = ex.map(th.slow_seeded, tasks, desc="slow", progress=False)
    finally:
        stop.set()
        killer.join()
    assert killed, "no worker was killed while tasks ran"
    assert results == [th.seeded_sum(seed) for seed in range(SLOW_TASKS)]
    runs = {}
    for marker in tmp_path.glob("start-*"):
        seed, pid = (int(v) for v in marker.name.split("-")[1:])
        runs.setdefault(seed, set()).add(pid)
    assert any(len(pids) > 1 for pids in runs.values()), "no task lost with the killed worker was run again"
    seed, pid, finished_first = killed[0]
    assert finished_first or len(runs[seed]) > 1, f"task {seed} of the killed worker {pid} was not run again"
    return pid


def test_local_pool_survives_a_killed_worker(tmp_path):
    with ProcessExecutor(workers=2) as ex:
        _map_while_killing(ex, tmp_path)
        assert ex.restarts == 1
        assert ex.map(th.seeded_sum, SEEDS, progress=False) == [th.seeded_sum(s) for s in SEEDS]  # the new pool


def test_dask_survives_a_killed_worker(dask_executor, tmp_path):
    before = set(dask_executor.client.run(os.getpid).values())
    assert _map_while_killing(dask_executor, tmp_path) in before
    dask_executor.client.wait_for_workers(2, timeout=START_S)  # the nanny starts it again


def test_a_task_that_keeps_killing_its_worker_is_named():
    tasks = [(value, 2) for value in range(4)]
    with ProcessExecutor(workers=2, retries=2) as ex:
        with pytest.raises(TaskError, match=r"task 2 of 'suicidal' failed: its worker process died 3 times") as info:
            ex.map(th.kill_own_worker_on, tasks, desc="suicidal", progress=False)
        assert info.value.index == 2 and info.value.desc == "suicidal" and ex.restarts == 3
        assert ex.map(th.kill_own_worker_on, [(0, 2), (1, 2)], progress=False) == [0, 1]


# ---- failures ------------------------------------------------------------------------------------
@pytest.mark.parametrize("where", ["serial", "local", "dask"])
def test_a_failing_task_raises_task_error(where, local_executor, request):
    ex = {"serial": SerialExecutor(), "local": local_executor}.get(where) or request.getfixturevalue("dask_executor")
    with pytest.raises(TaskError, match=r"task 3 of 'picky' failed: ValueError: refusing 3") as info:
        ex.map(th.fail_on, [(v, 3) for v in range(5)], desc="picky", progress=False)
    assert info.value.index == 3 and isinstance(info.value.__cause__, ValueError)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("value", ["bogus", "local:0", "local:x", "localhost:8786", "tcp:/host"])
def test_a_bad_scheduler_string_is_named(value):
    with pytest.raises(ValueError, match=re.escape(repr(value))):
        executor(value)


def test_contradicting_worker_counts():
    with pytest.raises(ValueError, match="workers=3"):
        executor("local:2", workers=3)
    with pytest.raises(ValueError, match="workers"):
        executor("serial", workers=4)
    with pytest.raises(ValueError, match="positive"):
        executor(None, workers=0)


def test_an_unreachable_scheduler_is_named(monkeypatch):
    address = f"tcp://127.0.0.1:{_free_port()}"
    monkeypatch.setattr(task_module, "CONNECT_TIMEOUT", 1.0)
    with pytest.raises(ValueError, match=f"cannot connect to the Dask scheduler '{address}'"):
        executor(address)
    monkeypatch.setenv("WARPSHADE_SCHEDULER", address)
    with pytest.raises(ValueError, match=rf"'{address}'.*\(from \$WARPSHADE_SCHEDULER\)"):
        executor()


def test_the_scheduler_environment_variable_is_honoured(monkeypatch, cluster):
    monkeypatch.setenv("WARPSHADE_SCHEDULER", "serial")
    assert isinstance(executor(), SerialExecutor)
    monkeypatch.setenv("WARPSHADE_SCHEDULER", "local:2")
    with executor() as ex:
        assert isinstance(ex, ProcessExecutor) and ex.workers == 2
    monkeypatch.setenv("WARPSHADE_SCHEDULER", cluster.scheduler_address)
    with executor() as ex:
        assert isinstance(ex, DaskExecutor) and ex.map(th.seeded_sum, [5], progress=False) == [th.seeded_sum(5)]
    assert isinstance(executor("serial"), SerialExecutor)  # an explicit scheduler wins
    monkeypatch.setenv("WARPSHADE_SCHEDULER", "nonsense")
    with pytest.raises(ValueError, match=r"'nonsense'.*\$WARPSHADE_SCHEDULER"):
        executor()


def test_default_is_local_processes_or_serial(monkeypatch):
    monkeypatch.delenv("WARPSHADE_SCHEDULER", raising=False)
    assert isinstance(executor(workers=1), SerialExecutor)
    with executor(workers=2) as ex:
        assert isinstance(ex, ProcessExecutor) and ex.name == "local:2"
    monkeypatch.setenv("WARPSHADE_THREADS", "1")  # cpu_workers() == 1
    assert isinstance(executor(), SerialExecutor)
