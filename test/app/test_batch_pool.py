"""The batch pool's costs per task (``app/batch_pool.py``): what crosses to a worker with each bag, what a
forked worker copies, and records that are not synced bag by bag (``app/batch_bags.py``)."""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import subprocess
import sys
import threading
from collections import deque
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import pytest
from pool_tasks import CountedTask, StartedTask, died

from ompn_ros import atomic
from ompn_ros.app import batch_bags

SUPPORT = Path(__file__).resolve().parents[1]
ROOT = SUPPORT.parent


def test_the_task_goes_to_each_worker_once_not_with_every_item(monkeypatch: pytest.MonkeyPatch) -> None:
    # spawned workers: the task and its settings (a boundary head is ~100 KB) are pickled here, in the
    # run's process, once per worker; before, once per bag
    from ompn_ros.app import batch_pool  # torch: imported by the test, not at collection
    from ompn_ros.app.batch_pool import Pool, Stop

    monkeypatch.setattr(batch_pool, "pool_context", lambda device: multiprocessing.get_context("spawn"))
    CountedTask.pickled = 0
    out = list(Pool(CountedTask(), died, 2, "cpu", Stop()).run(list(range(8))))
    assert sorted(doc["item"] for doc in out) == list(range(8))
    assert all("died" not in doc for doc in out)
    assert {doc["pid"] for doc in out} - {os.getpid()}, "the items ran in workers"
    assert 1 <= CountedTask.pickled <= 2, f"pickled {CountedTask.pickled} times for 2 workers and 8 items"


FORKED = """
import gc, json
from ompn_ros.app.batch_pool import Pool, Stop, pool_context
from pool_tasks import CountedTask, StartedTask, died
method = pool_context("cpu").get_start_method()
out = list(Pool(CountedTask(), died, 2, "cpu", Stop()).run(list(range(6))))
print(json.dumps({"method": method, "frozen": [d["frozen"] for d in out],
                  "items": sorted(d["item"] for d in out), "parent_frozen_after": gc.get_freeze_count(),
                  "pickled": CountedTask.pickled}))
"""


def test_forked_workers_inherit_a_frozen_heap_and_the_run_unfreezes_it() -> None:
    # a single-threaded run forks its workers; the collector of a worker then leaves the inherited
    # objects alone (no copy of the parent's pages), and the run's own process is unfrozen afterwards
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
           "NUMBA_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join([str(ROOT), str(SUPPORT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-c", FORKED], env=env, capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    doc = json.loads(done.stdout.strip().splitlines()[-1])
    assert doc["method"] == "fork"
    assert doc["items"] == list(range(6))
    assert min(doc["frozen"]) > 1000, doc["frozen"]
    assert doc["parent_frozen_after"] == 0
    assert doc["pickled"] == 0, "a forked worker inherits its task: nothing is pickled"


def test_records_are_atomic_but_not_synced_bag_by_bag(monkeypatch: pytest.MonkeyPatch,
                                                       tmp_path: Path) -> None:
    synced: list[int] = []
    real = os.fsync

    def fsync(fd: int) -> None:
        synced.append(fd)
        real(fd)

    monkeypatch.setattr(atomic.os, "fsync", fsync)
    target = batch_bags.write_record(tmp_path, "lab/bag_0", {"status": "segmented"})
    assert json.loads(target.read_text())["status"] == "segmented"
    assert synced == []
    assert not [p for p in target.parent.iterdir() if p.name.startswith(".")], "no temporary left"
    atomic.atomic_write_text(tmp_path / "summary.json", "{}")
    assert len(synced) == 1, "other outputs stay synced"


def test_a_record_lost_to_a_power_failure_is_read_as_none(tmp_path: Path) -> None:
    # what an unsynced rename can leave after a crash of the machine: an empty or truncated file
    target = batch_bags.write_record(tmp_path, "bag_0", {"status": "segmented"})
    for broken in ("", target.read_text()[:7]):
        target.write_text(broken)
        assert batch_bags.read_record(tmp_path, "bag_0") is None


class _Pending:
    """What ``_drive`` sees of an executor: it records the submitted tasks and completes none itself,
    except that a task submitted again completes the task of ``then`` (so the run can go on)."""

    def __init__(self, then: int) -> None:
        self.submitted: list[tuple[Future[dict[str, Any]], int]] = []
        self.then = then

    def submit(self, fn: Any, index: int, item: int) -> Future[dict[str, Any]]:
        future: Future[dict[str, Any]] = Future()
        future.set_running_or_notify_cancel()
        if item in self.items():
            self.future(self.then).set_result({"item": self.then})
        self.submitted.append((future, item))
        return future

    def items(self) -> list[int]:
        return [item for _, item in self.submitted]

    def future(self, item: int) -> Future[dict[str, Any]]:
        return next(f for f, i in self.submitted if i == item)


def test_each_worker_has_its_next_task_queued_and_an_unstarted_task_is_not_done() -> None:
    # short bags: a worker that waits for the run's process between bags loses a large share of each
    from ompn_ros.app.batch_pool import NOT_STARTED, Pool, Stop

    executor, queue = _Pending(then=1), deque(range(10))
    results = Pool(CountedTask(), died, 2, "cpu", Stop())._drive(executor, queue, bytearray(10))  # type: ignore[arg-type]
    threading.Timer(0.1, lambda: executor.future(0).set_result(NOT_STARTED)).start()
    out = next(results)  # waits for the timer: four tasks are in flight by then
    assert executor.items() == [0, 1, 2, 3, 0], "two tasks per worker in flight; the unstarted one again"
    assert out == {"item": 1}, "the unstarted task is not reported as done"


def test_a_stop_starts_no_queued_task_and_reports_every_task_that_started(
        monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from ompn_ros.app import batch_pool
    from ompn_ros.app.batch_pool import Pool, Stop

    monkeypatch.setattr(batch_pool, "pool_context", lambda device: multiprocessing.get_context("spawn"))
    out = []
    with Stop() as stop:
        for doc in Pool(StartedTask(str(tmp_path), 0.4), died, 2, "cpu", stop).run(list(range(12))):
            out.append(doc)
            if len(out) == 1:
                os.kill(os.getpid(), signal.SIGINT)  # the operator's Ctrl-C, through the handler
    started = sorted(int(p.name.split("_")[1]) for p in tmp_path.glob("started_*"))
    assert all("died" not in doc for doc in out)
    assert sorted(doc["item"] for doc in out) == started, "every task that began is reported, no other"
    assert len(started) <= 3, f"queued tasks began after the stop: {started}"
    assert stop.requested and stop.listeners == []


def test_a_dead_worker_gives_up_only_the_tasks_that_had_started(monkeypatch: pytest.MonkeyPatch,
                                                                  tmp_path: Path) -> None:
    # item 2 kills its worker (as the kernel's out-of-memory killer does); the bags queued behind it in
    # the broken pool never ran and must be segmented by the next pool, not refused
    from ompn_ros.app import batch_pool
    from ompn_ros.app.batch_pool import Pool, Stop

    monkeypatch.setattr(batch_pool, "pool_context", lambda device: multiprocessing.get_context("spawn"))
    out = list(Pool(StartedTask(str(tmp_path), 0.3, kill=2), died, 2, "cpu", Stop()).run(list(range(8))))
    started = {int(p.name.split("_")[1]) for p in tmp_path.glob("started_*")}
    gone = {doc["item"] for doc in out if "died" in doc}
    assert sorted(doc["item"] for doc in out) == list(range(8)), "each item reported once"
    assert 2 in gone and len(gone) <= 2, out
    assert gone <= started, f"refused without having run: {sorted(gone - started)}"


def test_workers_that_die_before_any_task_do_not_start_pool_after_pool() -> None:
    from concurrent.futures.process import BrokenProcessPool

    from ompn_ros.app.batch_pool import Pool, Stop

    queue: deque[int] = deque([7])
    broken = BrokenProcessPool("a child process terminated abruptly")
    lost = [(0, 3, broken), (1, 4, broken)]
    out = list(Pool(CountedTask(), died, 2, "cpu", Stop())._give_up(lost, bytearray(2), queue))
    assert [doc["item"] for doc in out] == [3, 4] and all("before they run" in doc["died"] for doc in out)
    assert list(queue) == [7]
    out = list(Pool(CountedTask(), died, 2, "cpu", Stop())._give_up(lost, bytearray([1, 0]), queue))
    assert [doc["item"] for doc in out] == [3] and list(queue) == [4, 7], "the unstarted one is run again"
