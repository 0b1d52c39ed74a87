"""The worker pool of a batch run: start-up paid once, a run that stops cleanly, workers that never
outlive it.

* **Start-up once.**  The run's process imports torch and loads the checkpoint before the pool starts
  (``batch.preload``); on Linux, with the policy on the CPU and a single-threaded parent, the workers
  are forked from it and inherit both, compiled kernel included, so a worker starts in milliseconds
  instead of seconds (each spawned worker imports torch and loads the checkpoint again).  A parent
  with threads (library thread pools, when ``OMP_NUM_THREADS`` and the like are unset) is not
  forked: a fork server, started single-threaded, imports the batch modules once and forks the
  workers, which then load the checkpoint once each.  With a GPU, or without fork, workers are
  spawned, and each loads the checkpoint once, for all its tasks.
* **Stopping.**  :class:`Stop` turns the first SIGINT or SIGTERM into a request: no task is started
  after it, the running ones finish, and the caller writes what finished (exit ``128 + signal``).
  A second signal stops at once (:class:`HardStop`): the workers are killed, their tasks lost.
  Workers ignore both signals (a Ctrl-C reaches the whole process group; the parent decides).
* **No orphans.**  Every worker dies with the run's process, however it ended
  (:func:`ompn_ros.workers.die_with_parent`).

Each worker has its next task queued while it runs one (at most ``2 * jobs`` in flight), so no worker
waits for the run's process between tasks, which on short bags is a large share of a bag's time.  A
stop request still waits only for the tasks running: a queued task that a worker takes after the
request comes back unstarted (:data:`NOT_STARTED`) and is not counted as done.  A worker marks each
task as started before it runs it, so when a worker dies, only the tasks that had started are given up
(``died``); the queued ones go to a new pool.  The pool runs any list of work items (bags today); a
task's result comes back as it completes.
"""

from __future__ import annotations

import gc
import multiprocessing
import os
import signal
import sys
import threading
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import forkserver
from multiprocessing.context import BaseContext
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any, Generic, TypeVar

import torch

from ompn_ros.workers import die_with_parent, started_here

Item = TypeVar("Item")
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class HardStop(KeyboardInterrupt):
    """A second stop signal: stop now, losing the tasks in flight."""


class Stop:
    """Stop requests of a run (a context manager: installs SIGINT/SIGTERM handlers in the main thread
    and restores the previous ones on exit).  ``signum`` is the first signal received (None: none)."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self.armed = True
        self.listeners: list[Callable[[], None]] = []
        self._previous: dict[int, Any] = {}

    @property
    def requested(self) -> bool:
        return self.signum is not None

    def settle(self) -> None:
        """The tasks are over: a later signal only asks for the stop again (the outputs of what
        finished are being written; nothing is left to stop at once)."""
        self.armed = False

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.signum is not None:
            if self.armed:
                raise HardStop
            return
        self.signum = signum
        for listener in self.listeners:  # at once, not when the run's loop next wakes
            listener()
        print(f"ompn_segment: {signal.Signals(signum).name}: stopping after the bags in progress "
              "(again: stop now)", file=sys.stderr, flush=True)

    def __enter__(self) -> Stop:
        if threading.current_thread() is threading.main_thread():
            for signum in STOP_SIGNALS:
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()


def _threads() -> int:
    """Threads of this process (0: unknown)."""
    try:
        text = Path("/proc/self/status").read_text()
    except OSError:
        return 0
    return next((int(line.split()[1]) for line in text.splitlines() if line.startswith("Threads:")), 0)


SINGLE_THREAD_ENV = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                                             "NUMBA_NUM_THREADS")}
"""The environment of the fork server: libraries start no thread pools (one thread per worker)."""


def pool_context(device: str) -> BaseContext:
    """Where workers come from: forked from this warm process where that is safe (Linux, CPU policy,
    one thread), else forked from a fork server that imported the batch modules once (started
    single-threaded), else spawned (and with a GPU, whose context must not cross a fork)."""
    methods = multiprocessing.get_all_start_methods()
    if device == "cpu" and "fork" in methods and _threads() == 1:
        return multiprocessing.get_context("fork")
    if device == "cpu" and "forkserver" in methods:
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(["ompn_ros.app.batch"])
        _start_fork_server()
        return context
    return multiprocessing.get_context("spawn")


def _start_fork_server() -> None:
    """Start the fork server single-threaded and deaf to SIGTERM (an ignored signal stays ignored
    across its exec; SIGINT it ignores itself): a SIGTERM sent to the whole process group, as a
    cluster scheduler sends it, must not end it under the workers; it ends with the run."""
    saved = {name: os.environ.get(name) for name in SINGLE_THREAD_ENV}
    os.environ.update(SINGLE_THREAD_ENV)
    main = threading.current_thread() is threading.main_thread()
    term = signal.signal(signal.SIGTERM, signal.SIG_IGN) if main else None
    try:
        forkserver.ensure_running()
    finally:
        if main:
            signal.signal(signal.SIGTERM, term)
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


_TASK: Callable[[Any], dict[str, Any]] | None = None
"""The task of this worker process, given once when it starts (:func:`init_worker`)."""
_HALT: Any = None
"""The run's stop request as this worker sees it (a multiprocessing event; :func:`init_worker`)."""
_STARTED: Any = None
"""One byte per task of the pool, shared with the run's process: set when a worker starts the task."""
NOT_STARTED: dict[str, Any] = {"not_started": True}
"""A worker's answer for a task it took after a stop request: the task did not run."""


def _run_task(index: int, item: Any) -> dict[str, Any]:
    """What a worker runs for each item (the pool's ``index``-th task): only the item crosses the pipe,
    not the task's settings; none is started once the run asked to stop, each is marked as started."""
    if _TASK is None:
        raise RuntimeError("a pool task ran in a process that init_worker did not start")
    if _HALT is not None and _HALT.is_set():
        return NOT_STARTED
    if _STARTED is not None:
        _STARTED[index] = 1
    return _TASK(item)


def init_worker(parent: int, parent_main_thread: bool, via_server: bool = False,
                task: Callable[[Any], dict[str, Any]] | None = None, halt: Any = None,
                started: Any = None) -> None:
    """First thing in every worker: die with the run (``parent``, whether it forked the worker or a fork
    server did: ``via_server``), leave stopping to the run, one torch thread, and keep ``task``, the
    work of every item (sent once per worker, not with each item), and ``halt``, the run's stop
    request (an event: once set, queued tasks are not started), and ``started``, where it marks the
    tasks it starts (shared bytes, one per task of the pool)."""
    global _TASK, _HALT, _STARTED
    _TASK, _HALT, _STARTED = task, halt, started
    if via_server:  # the fork server outlives the run while its workers hold its pipe: watch the run
        die_with_parent(os.getppid(), True, ignore_stop_signals=True, run=parent)
    else:
        die_with_parent(parent, parent_main_thread, ignore_stop_signals=True)
    torch.set_num_threads(1)


def _kill(pool: ProcessPoolExecutor) -> None:
    processes = getattr(pool, "_processes", None) or {}
    for process in list(processes.values()):
        process.kill()
    pool.shutdown(wait=False, cancel_futures=True)


class Pool(Generic[Item]):
    """``task(item)`` for each item over ``jobs`` worker processes (see the module docstring);
    ``died(item, reason)`` is the result of an item whose worker died (killed, out of memory) while it
    ran, or that ran beside it when the pool broke (which of the running ones killed it is not known)."""

    def __init__(self, task: Callable[[Item], dict[str, Any]], died: Callable[[Item, str], dict[str, Any]],
                 jobs: int, device: str, stop: Stop) -> None:
        self.task, self.died, self.jobs, self.device, self.stop = task, died, jobs, device, stop

    def run(self, items: Sequence[Item]) -> Iterator[dict[str, Any]]:
        """Results as tasks complete; ends early (no new task started) once a stop is requested."""
        queue = deque(items)
        while queue and not self.stop.requested:
            yield from self._one_pool(queue)

    def _one_pool(self, queue: deque[Item]) -> Iterator[dict[str, Any]]:
        """Run ``queue`` on one pool until it is empty, a stop is requested or a worker dies."""
        context = pool_context(self.device)
        via_server = context.get_start_method() == "forkserver"
        forked = context.get_start_method() == "fork"
        if forked:  # the collector of a forked worker must not write into every inherited object,
            gc.collect()  # which copies the parent's memory page by page (CPU in every worker)
            gc.freeze()
        halt = context.Event()
        self.stop.listeners.append(halt.set)
        started = context.RawArray("b", len(queue))  # a pool submits each queued item at most once
        initargs = (*started_here(), via_server, self.task, halt, started)
        pool = ProcessPoolExecutor(max_workers=min(self.jobs, len(queue)), initializer=init_worker,
                                   mp_context=context, initargs=initargs)
        try:
            yield from self._drive(pool, queue, started)
        except BaseException:
            _kill(pool)
            raise
        finally:
            self.stop.listeners.remove(halt.set)
            if forked:
                gc.unfreeze()
        pool.shutdown(wait=True)

    def _drive(self, pool: ProcessPoolExecutor, queue: deque[Item], started: Any) -> Iterator[dict[str, Any]]:
        """Keep two tasks per worker in flight until ``queue`` is empty, a stop is requested or a worker
        dies.  A task that came back unstarted goes back to the front of ``queue``; when a worker died,
        so do the tasks of the broken pool that no worker had started (``started``)."""
        running: dict[Future[dict[str, Any]], tuple[int, Item]] = {}
        lost: list[tuple[int, Item, BrokenProcessPool]] = []
        submitted = 0
        while queue or running:
            while queue and len(running) < 2 * self.jobs and not (self.stop.requested or lost):
                item = queue.popleft()
                running[pool.submit(_run_task, submitted, item)] = (submitted, item)
                submitted += 1
            if not running:
                break
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                index, item = running.pop(future)
                try:
                    result = future.result()
                except BrokenProcessPool as exc:
                    lost.append((index, item, exc))
                    continue
                if result == NOT_STARTED:
                    queue.appendleft(item)
                else:
                    yield result
        yield from self._give_up(lost, started, queue)

    def _give_up(self, lost: list[tuple[int, Item, BrokenProcessPool]], started: Any,
                 queue: deque[Item]) -> Iterator[dict[str, Any]]:
        """The tasks of a broken pool: those a worker had started die with it, the others go back to the
        front of ``queue`` for the next pool; when none had started, the workers themselves cannot run
        (they die before any task), and every one dies rather than start pool after pool."""
        if not any(started[index] for index, _, _ in lost):
            for _, item, exc in lost:
                yield self.died(item, f"the worker processes die before they run a task ({exc})")
            return
        for index, item, _ in reversed(lost):
            if not started[index]:
                queue.appendleft(item)
        for index, item, exc in lost:
            if started[index]:
                yield self.died(item, f"a worker process died while this task ran ({exc})")


__all__ = ["NOT_STARTED", "STOP_SIGNALS", "HardStop", "Pool", "Stop", "init_worker", "pool_context"]
