"""Worker processes that die with the process that started them.

A pool's worker waits for its next task on a pipe whose writing end it holds itself, so it never
sees the end of its parent: a parent killed with SIGKILL (or by the out-of-memory killer) leaves its
workers alive, each holding its model and its bag in memory, for good.  :func:`die_with_parent`,
run first in every worker (a pool's ``initializer``), ends the worker within about a second of its
parent's end, however the parent ended:

* on Linux, ``prctl(PR_SET_PDEATHSIG, SIGKILL)`` (through ``ctypes``): the kernel kills the worker
  when the thread that started it ends, so it is asked for only when that thread is its process's
  main thread (``parent_main_thread``);
* everywhere, a daemon thread that checks every :data:`WATCH_S` seconds that the worker's parent is
  still the process that started it (an orphan is adopted by another process), and that the run it
  works for still runs when that is another process (a fork server's workers), and otherwise ends
  the worker at once (``os._exit``: its tasks are abandoned, their outputs are written atomically).

Cost: one ``getppid`` per second per worker.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time

WATCH_S = 1.0
"""Seconds between two checks of the parent by a worker's watchdog thread."""
ORPHAN_EXIT = 70
"""Exit status of a worker whose parent has gone."""
_PR_SET_PDEATHSIG = 1


def _kill_with_parent() -> bool:
    """Ask the kernel to SIGKILL this process when its parent thread ends (Linux); True when granted."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return int(libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)) == 0
    except (OSError, AttributeError):
        return False


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, dead but not yet reaped, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        state = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True
    return state != "Z"


def _watch(parent: int, run: int | None) -> None:
    while True:
        if os.getppid() != parent or (run is not None and not _alive(run)):
            os._exit(ORPHAN_EXIT)
        time.sleep(WATCH_S)


def die_with_parent(parent: int, parent_main_thread: bool = True, ignore_stop_signals: bool = False,
                    run: int | None = None) -> None:
    """Make this worker end when process ``parent`` (the pid that started it) ends.

    Args:
        parent: ``os.getpid()`` of the starting process, read there (a worker whose parent already
            ended sees another one and exits at once).
        parent_main_thread: the worker was started by its parent's main thread (the kernel's parent
            death signal is then safe to use; otherwise only the watchdog thread watches).
        ignore_stop_signals: ignore SIGINT and SIGTERM (a Ctrl-C reaches the whole process group: the
            parent decides how the run stops, the worker finishes its task).
        run: the process the work is for when it is not the parent (a worker forked by a fork
            server, which lives as long as its workers do): the watchdog also ends the worker when
            ``run`` ends.
    """
    if ignore_stop_signals:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if parent_main_thread:
        _kill_with_parent()
    if os.getppid() != parent:
        os._exit(ORPHAN_EXIT)
    threading.Thread(target=_watch, args=(parent, run), name="die_with_parent", daemon=True).start()


def started_here() -> tuple[int, bool]:
    """The arguments of :func:`die_with_parent` for workers started by the calling thread."""
    return os.getpid(), threading.current_thread() is threading.main_thread()


__all__ = ["ORPHAN_EXIT", "WATCH_S", "die_with_parent", "started_here"]
