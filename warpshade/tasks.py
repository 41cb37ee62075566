"""One executor interface for precompute that outgrows one process: serial, local worker
processes, or a Dask distributed cluster.

``executor(scheduler, workers)`` picks the back end and every back end has the same
:meth:`Executor.map`: ``[fn(t) for t in tasks]``, in task order, with a progress bar over the
finished tasks, and a callback in this process as each task finishes (where a caller keeps each
result, e.g. in a cache, so that an interrupted map resumes where it stopped). ``fn`` is a
module-level function (it is pickled by reference) and each task is a picklable argument that
carries everything the task needs, its random seed included, so that where and in which order
the tasks run changes nothing: every back end returns what the serial loop returns.

* :class:`SerialExecutor` -- in this process, one task after another.
* :class:`ProcessExecutor` -- local worker processes (spawned, never forked: a forked child
  would inherit this process's Warp state and threads). Each worker runs Warp's CPU launches on
  one thread (``WARPSHADE_THREADS=1``), so N workers use N cores. A worker that dies (killed,
  out of memory, a crash in native code) breaks the pool; a new pool is started and every
  unfinished task is submitted again. The task that was running on the dead worker is charged
  for it, and a task whose worker dies more than ``retries`` times raises :class:`TaskError`.
  Workers ignore SIGINT (an interrupt reaches this process, which stops the pool) and exit when
  this process dies, even by SIGKILL (:func:`_exit_with_parent`), so nothing is left running.
* :class:`DaskExecutor` -- an existing ``distributed`` cluster, by its scheduler address. The
  scheduler reschedules the tasks of a worker that died; a task that keeps killing workers
  ends as ``KilledWorker``, which becomes :class:`TaskError`. Connecting, handshake included,
  is bounded by :func:`connect_timeout`.

Tasks import the parts of warpshade they need themselves: this module is part of the foundation
layer and imports no warpshade subpackage, and a worker process starts without Warp.
"""

from __future__ import annotations

import os
import re
import signal
import uuid
from abc import ABC, abstractmethod
from concurrent.futures import as_completed
from concurrent.futures.process import BrokenProcessPool

__all__ = [
    "SCHEDULER_ENV",
    "CONNECT_TIMEOUT",
    "CONNECT_TIMEOUT_ENV",
    "connect_timeout",
    "TaskError",
    "Executor",
    "SerialExecutor",
    "ProcessExecutor",
    "DaskExecutor",
    "executor",
    "progress_bar",
]

#: Environment variable read by :func:`executor` when no scheduler is given.
SCHEDULER_ENV = "WARPSHADE_SCHEDULER"
#: Seconds :class:`DaskExecutor` waits for its scheduler (connection and handshake) by default.
CONNECT_TIMEOUT = 10.0
#: Environment variable that overrides :data:`CONNECT_TIMEOUT` (seconds).
CONNECT_TIMEOUT_ENV = "WARPSHADE_CONNECT_TIMEOUT"
#: Seconds between a local worker's checks that its parent process still runs.
PARENT_POLL_S = 0.5
#: Set in every local worker process: Warp CPU launches on one thread (N workers, N cores).
WORKER_ENV = {"WARPSHADE_THREADS": "1"}
#: Set in every local worker process where not already set: one thread for the numerical
#: libraries that read these when they load.
WORKER_ENV_DEFAULTS = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


class TaskError(RuntimeError):
    """A task failed: it raised (the exception is the ``__cause__``), or its worker died too
    often.

    Attributes:
        index: position of the task in the ``tasks`` given to :meth:`Executor.map` (None when
            no single task is to blame).
        desc: the ``desc`` of that map call (None when it had none).
    """

    def __init__(self, message: str, index: int | None = None, desc: str | None = None):
        super().__init__(message)
        self.index = index
        self.desc = desc


def _task_name(index: int, desc: str | None) -> str:
    return f"task {index} of {desc!r}" if desc else f"task {index}"


def _failed(index: int, desc: str | None, exc: BaseException) -> TaskError:
    return TaskError(f"{_task_name(index, desc)} failed: {type(exc).__name__}: {exc}", index, desc)


def _progress_bar(total: int, desc: str | None, progress: bool):
    return progress_bar(total=total, desc=desc, unit="task", disable=not progress or total == 0)


#: Seconds between the plain progress lines written where stderr is not a terminal.
PLAIN_PROGRESS_INTERVAL_S = 15.0
_CURSOR_ONLY = re.compile(r"^(?:[\r\n ]|\x1b\[A)*$")


class _LineStream:
    """The stream a plain progress bar writes to: each of tqdm's status updates becomes one
    line (the leading carriage return and trailing padding dropped), and the cursor movements
    and clears tqdm writes between updates are dropped, so a log gets whole lines only."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> int:
        if not _CURSOR_ONLY.match(text):
            self._stream.write(text.strip("\r\n").rstrip() + "\n")
        return len(text)

    def flush(self) -> None:
        self._stream.flush()

    def __getattr__(self, name):
        return getattr(self._stream, name)


def progress_bar(iterable=None, *, total=None, desc=None, unit="it", leave=True, disable=False, stream=None,
                 interval_s: float = PLAIN_PROGRESS_INTERVAL_S):
    """A progress bar (tqdm) on ``stream`` (default: stderr), the one every long loop of
    warpshade shows.

    On a terminal (and in a notebook) it is tqdm's bar, redrawn in place. Elsewhere -- a log
    file, a pipe, a batch job -- it writes plain lines with no carriage returns: one when it
    starts, one every ``interval_s`` seconds and one with the totals when it closes.

    Args:
        iterable, total, desc, unit, leave, disable: as :class:`tqdm.tqdm`.
        stream: where the bar is written (a text stream); default ``sys.stderr``.
        interval_s: seconds between plain lines.
    """
    import sys

    from tqdm.auto import tqdm

    stream = sys.stderr if stream is None else stream
    notebook = any(cls.__module__ == "tqdm.notebook" for cls in tqdm.__mro__)
    isatty = getattr(stream, "isatty", None)
    if disable or notebook or (isatty is not None and isatty()):
        return tqdm(iterable, total=total, desc=desc, unit=unit, leave=leave, disable=disable, file=stream)
    from tqdm.std import tqdm as plain

    return plain(iterable, total=total, desc=desc, unit=unit, leave=True, file=_LineStream(stream), ascii=True,
                 mininterval=interval_s, maxinterval=max(interval_s, 10.0), dynamic_ncols=False)


class Executor(ABC):
    """Runs ``fn`` over a list of tasks; see the module docstring for the back ends.

    Attributes:
        name: ``"serial"``, ``"local:N"`` or ``"dask:ADDRESS"``.
        workers: how many tasks run at once.

    An executor is a context manager whose exit calls :meth:`close`.
    """

    name: str = "executor"
    workers: int = 1

    @abstractmethod
    def map(self, fn, tasks, desc: str | None = None, progress: bool = True, on_result=None) -> list:
        """``[fn(t) for t in tasks]``, in task order.

        Args:
            fn: a module-level function of one argument (pickled by reference for workers).
            tasks: iterable of picklable arguments, each carrying its own seed where ``fn`` draws
                random numbers, so that the results do not depend on where a task runs.
            desc: what the tasks are, for the progress bar and error messages.
            progress: show a progress bar (tqdm) counting finished tasks.
            on_result: ``on_result(index, value)``, called in this process as each task
                finishes (in the order they finish), before the next result is taken: what it
                keeps survives an interrupt of the map. What it raises stops the map.

        Returns:
            The results, ``result[i] == fn(tasks[i])``.

        Raises:
            TaskError: a task raised (its exception is the cause), or its worker died too often.
        """

    def close(self) -> None:
        """Release the workers (or the cluster connection); the executor is not used after."""

    def __enter__(self):
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.name} workers={self.workers}>"


class SerialExecutor(Executor):
    """Every task in this process, one after another (Warp CPU launches keep their threads)."""

    name = "serial"
    workers = 1

    def map(self, fn, tasks, desc: str | None = None, progress: bool = True, on_result=None) -> list:
        tasks = list(tasks)
        results = []
        with _progress_bar(len(tasks), desc, progress) as bar:
            for index, task in enumerate(tasks):
                try:
                    value = fn(task)
                except Exception as exc:
                    raise _failed(index, desc, exc) from exc
                results.append(value)
                if on_result is not None:
                    on_result(index, value)
                bar.update(1)
        return results


# ---- local worker processes ------------------------------------------------------------------
#: In a worker process: the queue on which it reports ``(task index, pid)`` as a task starts.
_started_queue = None


def _exit_with_parent(poll_s: float = PARENT_POLL_S) -> None:
    """Start a daemon thread that ends this worker process as soon as its parent is gone.

    The parent holds the write end of a pipe whose read end is this process's parent sentinel
    (:func:`multiprocessing.parent_process`): the pipe closes when the parent dies, however it
    dies (SIGKILL included), on every platform, and the thread wakes at once. Every ``poll_s``
    seconds the thread also compares the parent's pid with the first one (POSIX re-parents an
    orphan), for a sentinel kept open by some other process that inherited it. A signal sent
    at parent death (Linux ``PR_SET_PDEATHSIG``) is not used: it fires when the *thread* that
    started the worker ends, and a pool outlives the thread of its first map.
    """
    import multiprocessing
    import threading
    import time

    parent = multiprocessing.parent_process()
    parent_pid = os.getppid()

    def watch() -> None:
        while True:
            if parent is not None:
                parent.join(poll_s)  # returns early when the parent's end of the pipe closes
                gone = not parent.is_alive()
            else:
                time.sleep(poll_s)
                gone = False
            if gone or os.getppid() != parent_pid:
                os._exit(1)  # the task's result has no one to go to

    threading.Thread(target=watch, name="warpshade-parent-watch", daemon=True).start()


def _init_worker(started_queue) -> None:
    """Initialiser of a local worker process: its environment, the start-report queue, SIGINT
    ignored (a Ctrl-C reaches the whole process group: the parent stops the pool in order) and
    a watch on the parent (:func:`_exit_with_parent`).

    Kept to the standard library so that a worker starts quickly; tasks import warpshade.
    """
    global _started_queue
    _started_queue = started_queue
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _exit_with_parent()
    os.environ.update(WORKER_ENV)
    for key, value in WORKER_ENV_DEFAULTS.items():
        os.environ.setdefault(key, value)


def _run_in_worker(fn, index: int, task):
    """Run one task in a local worker, first reporting that it started here."""
    if _started_queue is not None:
        _started_queue.put((index, os.getpid()))
    return fn(task)


def _main_hint() -> str:
    """Why spawned workers die at start when this runs from a script, and the fix."""
    import sys

    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if path is None or getattr(getattr(main, "__spec__", None), "name", None):
        return ""
    return (f"; worker processes are spawned and import the main script {path}: if it starts work at its top level, "
            "put that under `if __name__ == \"__main__\":`, or run with scheduler 'serial'")


def _describe_exit(code: int | None) -> str:
    if code is None:
        return "still running"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


class ProcessExecutor(Executor):
    """Local worker processes (spawn start method), each running one task at a time.

    Args:
        workers: worker processes (default :func:`warpshade._wp.cpu_workers`: the cores this
            process may use, at most 8, or ``$WARPSHADE_THREADS``).
        retries: how many times a task may lose its worker and be run again; one more loss
            raises :class:`TaskError`. The same bound applies to pools that die before any of
            their tasks finishes without a task to blame (e.g. a worker that cannot start).

    Attributes:
        restarts: pools started again after a worker died, over the executor's life.

    The pool is started at the first :meth:`map` and kept for later ones (workers keep what
    they imported and Warp's loaded modules) until :meth:`close`.
    """

    def __init__(self, workers: int | None = None, retries: int = 2):
        if workers is None:
            from ._wp import cpu_workers

            workers = cpu_workers()
        if not isinstance(workers, int) or isinstance(workers, bool) or workers < 1:
            raise ValueError(f"workers must be a positive integer, got {workers!r}")
        if not isinstance(retries, int) or retries < 0:
            raise ValueError(f"retries must be a non-negative integer, got {retries!r}")
        self.workers = workers
        self.retries = retries
        self.name = f"local:{workers}"
        self.restarts = 0
        self._pool = None
        self._queue = None

    # pool life cycle
    def _start_pool(self):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        context = multiprocessing.get_context("spawn")
        self._queue = context.SimpleQueue()
        self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=context,
                                         initializer=_init_worker, initargs=(self._queue,))
        return self._pool

    @staticmethod
    def _processes_of(pool) -> dict:
        """pid -> multiprocessing.Process of a pool's workers (empty if unknown)."""
        return dict(getattr(pool, "_processes", None) or {})

    def _stop_pool(self, kill: bool = False) -> None:
        pool, self._pool = self._pool, None
        if pool is not None:
            if kill:  # running tasks are not waited for (an error, an interrupt)
                for process in self._processes_of(pool).values():
                    if process.is_alive():
                        process.terminate()
            pool.shutdown(wait=True, cancel_futures=True)
        queue, self._queue = self._queue, None
        if queue is not None:
            queue.close()

    def _drain_started(self, started: dict) -> None:
        """Move the start reports waiting on the queue into ``started``: pid -> [indices]."""
        queue = self._queue
        while queue is not None and not queue.empty():
            index, pid = queue.get()
            started.setdefault(pid, []).append(index)

    def close(self) -> None:
        self._stop_pool()

    # the map
    def map(self, fn, tasks, desc: str | None = None, progress: bool = True, on_result=None) -> list:
        tasks = list(tasks)
        results: list = [None] * len(tasks)
        unfinished = set(range(len(tasks)))
        losses = [0] * len(tasks)  # times each task's worker died under it
        barren_breaks = 0  # consecutive broken pools with no task finished and none to blame
        with _progress_bar(len(tasks), desc, progress) as bar:
            try:
                while unfinished:
                    pool = self._pool or self._start_pool()
                    started: dict[int, list[int]] = {}
                    futures = {}
                    broken = False
                    try:
                        for index in sorted(unfinished):
                            futures[pool.submit(_run_in_worker, fn, index, tasks[index])] = index
                    except BrokenProcessPool:  # a worker died while tasks were being submitted
                        broken = True
                    processes = self._processes_of(pool)
                    finished_here = 0
                    for future in as_completed(futures):
                        index = futures[future]
                        self._drain_started(started)
                        try:
                            value = future.result()
                        except BrokenProcessPool:
                            broken = True
                            continue
                        except Exception as exc:
                            raise _failed(index, desc, exc) from exc
                        results[index] = value
                        unfinished.discard(index)
                        finished_here += 1
                        if on_result is not None:
                            on_result(index, value)
                        bar.update(1)
                    if not broken:
                        continue
                    # The pool is broken: its manager has terminated the other workers. Find
                    # the worker that died first and the task it was running, then start again.
                    pool.shutdown(wait=True)  # its workers are gone; their reports are in the pipe
                    processes.update(self._processes_of(pool))
                    self._drain_started(started)
                    self._stop_pool()
                    blamed = self._blame(processes, started, unfinished)
                    self.restarts += 1
                    dead = ", ".join(f"pid {pid} {_describe_exit(p.exitcode)}" for pid, p in processes.items()
                                     if p.exitcode is not None and p.exitcode != -signal.SIGTERM)
                    if progress:
                        bar.write(f"{desc or 'tasks'}: a worker process died ({dead or 'unknown cause'}); "
                                  f"running {len(unfinished)} unfinished task(s) again")
                    bar.set_postfix_str(f"{self.restarts} worker loss(es)")
                    for index in blamed:
                        losses[index] += 1
                        if losses[index] > self.retries:
                            raise TaskError(f"{_task_name(index, desc)} failed: its worker process died "
                                            f"{losses[index]} times ({dead or 'unknown cause'})", index, desc)
                    barren_breaks = 0 if (blamed or finished_here) else barren_breaks + 1
                    if barren_breaks > self.retries:
                        raise TaskError(f"{desc or 'tasks'}: the worker processes died {barren_breaks} times "
                                        f"before finishing any task ({dead or 'unknown cause'}){_main_hint()}",
                                        None, desc)
            except BaseException:
                self._stop_pool(kill=True)
                raise
        return results

    def _blame(self, processes: dict, started: dict, unfinished: set) -> list[int]:
        """Tasks to charge for a broken pool.

        The worker that died first is the one that did not exit by the pool's own SIGTERM; the
        task it was running is the last one it started. When no such worker is known, every
        started unfinished task is charged.
        """
        dead = [pid for pid, p in processes.items() if p.exitcode is not None and p.exitcode != -signal.SIGTERM]
        if dead:
            blamed = []
            for pid in dead:
                running = [i for i in started.get(pid, []) if i in unfinished]
                if running:
                    blamed.append(running[-1])
            return blamed
        return sorted({i for indices in started.values() for i in indices if i in unfinished})


# ---- Dask distributed --------------------------------------------------------------------------
def _run_on_dask_worker(fn, task):
    """Run one task on a Dask worker thread: Warp CPU launches on one thread unless the worker's
    environment sets ``WARPSHADE_THREADS``."""
    os.environ.setdefault("WARPSHADE_THREADS", "1")
    return fn(task)


def connect_timeout() -> float:
    """Seconds to wait for a Dask scheduler: ``$WARPSHADE_CONNECT_TIMEOUT`` if set, else
    :data:`CONNECT_TIMEOUT`.

    Raises:
        ValueError: the variable is not a positive finite number (the message names it).
    """
    import math

    text = os.environ.get(CONNECT_TIMEOUT_ENV, "").strip()
    if not text:
        return CONNECT_TIMEOUT
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"${CONNECT_TIMEOUT_ENV} must be a positive number of seconds, got {text!r}")
    return value


def _bounded_client(distributed, address: str, timeout: float):
    """A ``distributed.Client`` of ``address`` whose whole start -- connection, handshake,
    registration -- is bounded by ``timeout`` seconds (``Client(timeout=)`` bounds the
    connection only: a server that accepts it and never answers would hang the start)."""

    class BoundedStartClient(distributed.Client):
        def start(self, **kwargs):
            # the start coroutine under asyncio.wait_for: cancelled (its socket closed) at the bound
            try:
                super().start(callback_timeout=kwargs.get("timeout"), **kwargs)
            except TimeoutError:  # closed as distributed closes a client that could not connect
                self.close()
                raise

    return BoundedStartClient(address, timeout=timeout, set_as_default=False)


def _import_distributed():
    try:
        import distributed
    except ImportError as exc:
        raise ValueError("a Dask scheduler needs the 'distributed' package: "
                         "pip install 'warpshade[cluster]' (or 'dask[distributed]')") from exc
    return distributed


class DaskExecutor(Executor):
    """Tasks on an existing Dask distributed cluster.

    Args:
        address: the scheduler's address, e.g. ``"tcp://10.0.0.5:8786"``.
        timeout: seconds to wait for the scheduler to connect and answer (default
            :func:`connect_timeout`: ``$WARPSHADE_CONNECT_TIMEOUT``, else :data:`CONNECT_TIMEOUT`).
        retries: times Dask runs a task again after it raised; a task whose worker died is
            rescheduled by the scheduler (up to its ``allowed-failures``, then ``KilledWorker``).

    Raises:
        ValueError: ``distributed`` is not installed, or the scheduler cannot be reached or does
            not answer within ``timeout`` (the message names the address and the timeout).

    Each task is submitted under its own key (``"{desc}-{index}-{token}"``, ``pure=False``), so
    tasks of equal arguments are never merged with each other or with an earlier map. A task
    runs on one worker thread; start workers with ``--nthreads 1`` (one process per core, or per
    GPU on CUDA machines).
    """

    def __init__(self, address: str, timeout: float | None = None, retries: int = 2):
        distributed = _import_distributed()
        self.address = address
        self.retries = retries
        self.name = f"dask:{address}"
        longer = f"set ${CONNECT_TIMEOUT_ENV} (seconds)" if timeout is None else "give a larger timeout"
        timeout = connect_timeout() if timeout is None else float(timeout)
        try:
            self._client = _bounded_client(distributed, address, timeout)
        except Exception as exc:
            raise ValueError(f"cannot connect to the Dask scheduler {address!r} within {timeout:g} s "
                             f"({type(exc).__name__}: {exc}): check that a Dask scheduler answers at that address; "
                             f"{longer} to wait longer") from exc

    @property
    def workers(self) -> int:
        """Worker threads of the cluster now (workers may join and leave)."""
        return int(sum(self._client.nthreads().values()))

    @property
    def client(self):
        """The ``distributed.Client`` (for what this interface does not cover)."""
        return self._client

    def map(self, fn, tasks, desc: str | None = None, progress: bool = True, on_result=None) -> list:
        from distributed import as_completed as dask_as_completed

        tasks = list(tasks)
        if not tasks:
            return []
        token = uuid.uuid4().hex[:12]
        prefix = re.sub(r"[^\w.]+", "_", desc or getattr(fn, "__name__", "task"))
        keys = [f"{prefix}-{index}-{token}" for index in range(len(tasks))]
        futures = self._client.map(_run_on_dask_worker, [fn] * len(tasks), tasks, key=keys, pure=False,
                                   retries=self.retries)
        index_of = {future.key: index for index, future in enumerate(futures)}
        results: list = [None] * len(tasks)
        try:
            with _progress_bar(len(tasks), desc, progress) as bar:
                for future in dask_as_completed(futures, loop=self._client.loop):
                    index = index_of[future.key]
                    try:
                        results[index] = future.result()
                    except Exception as exc:  # what the task raised, or KilledWorker
                        raise _failed(index, desc, exc) from exc
                    future.release()
                    if on_result is not None:
                        on_result(index, results[index])
                    bar.update(1)
        finally:
            self._client.cancel([f for f in futures if not f.done()])
        return results

    def close(self) -> None:
        client, self._client = getattr(self, "_client", None), None
        if client is not None:
            client.close()


# ---- choosing one ------------------------------------------------------------------------------
_LOCAL = re.compile(r"^local(?::(?P<n>.*))?$")


def executor(scheduler: str | None = None, workers: int | None = None) -> Executor:
    """The executor for a scheduler string.

    Args:
        scheduler: ``None`` -- ``$WARPSHADE_SCHEDULER`` if set, else local processes (serial
            when there is one worker); ``"serial"``; ``"local"`` or ``"local:N"`` (N worker
            processes); a distributed address (``"tcp://host:8786"``, any ``scheme://...``) --
            a :class:`DaskExecutor` on that cluster.
        workers: local worker processes (default :func:`warpshade._wp.cpu_workers`); not for a
            Dask cluster, whose workers are its own.

    Raises:
        ValueError: a malformed scheduler string, a worker count that contradicts it, or a
            scheduler that cannot be reached; the message names the value, and
            ``$WARPSHADE_SCHEDULER`` when the value came from there.
    """
    origin = ""
    if scheduler is None:
        scheduler = os.environ.get(SCHEDULER_ENV, "").strip() or None
        origin = f" (from ${SCHEDULER_ENV})" if scheduler is not None else ""
    try:
        return _executor(scheduler, workers)
    except ValueError as exc:
        if not origin:
            raise
        raise ValueError(f"{exc}{origin}") from exc


def _executor(scheduler: str | None, workers: int | None) -> Executor:
    if workers is not None and (not isinstance(workers, int) or isinstance(workers, bool) or workers < 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")
    if scheduler is None:
        if workers is None:
            from ._wp import cpu_workers

            workers = cpu_workers()
        return SerialExecutor() if workers == 1 else ProcessExecutor(workers)
    if not isinstance(scheduler, str):
        raise ValueError(f"scheduler must be a string, got {scheduler!r}")
    text = scheduler.strip()
    if text == "serial":
        if workers not in (None, 1):
            raise ValueError(f"scheduler 'serial' runs one task at a time, but workers={workers}")
        return SerialExecutor()
    local = _LOCAL.match(text)
    if local:
        count = local.group("n")
        if count is not None:
            if not count.isdigit() or int(count) < 1:
                raise ValueError(f"scheduler {scheduler!r}: expected 'local:N' with N a positive integer")
            if workers is not None and workers != int(count):
                raise ValueError(f"scheduler {scheduler!r} contradicts workers={workers}")
            workers = int(count)
            cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
            if workers > cores:
                import warnings

                warnings.warn(f"scheduler {scheduler!r}: {workers} worker processes on {cores} cores; using {cores} "
                              "(more would only compete for the same cores and memory)", RuntimeWarning, stacklevel=3)
                workers = cores
        return ProcessExecutor(workers)
    if re.match(r"^[A-Za-z][A-Za-z0-9+.\-]*://\S+$", text):
        if workers is not None:
            raise ValueError(f"scheduler {scheduler!r}: workers={workers} applies to local processes only; "
                             "a Dask cluster has its own workers")
        return DaskExecutor(text)
    raise ValueError(f"scheduler {scheduler!r} is not 'serial', 'local', 'local:N' or a Dask scheduler address "
                     "such as 'tcp://host:8786'")

