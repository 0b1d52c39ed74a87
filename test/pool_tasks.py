"""Tasks for the batch pool's tests, importable by the workers a pool spawns or forks."""

from __future__ import annotations

import gc
import os
import signal
import time
from typing import Any


class CountedTask:
    """A pool task that counts how often it is pickled in this process (each pickle is one copy of the
    task sent to a worker) and reports, per item, the worker's process and its frozen objects."""

    pickled = 0

    def __call__(self, item: int) -> dict[str, Any]:
        return {"item": item, "pid": os.getpid(), "frozen": gc.get_freeze_count()}

    def __reduce__(self) -> tuple[type[CountedTask], tuple[()]]:
        CountedTask.pickled += 1
        return (CountedTask, ())


def died(item: int, reason: str) -> dict[str, Any]:
    return {"item": item, "died": reason}


class StartedTask:
    """A pool task that leaves a file ``started_<item>`` in ``folder`` when it starts, then works for
    ``seconds``: which tasks began is read from the folder, whatever the pool reported.  Item ``kill``
    kills its worker process instead (SIGKILL, as the out-of-memory killer does)."""

    def __init__(self, folder: str, seconds: float, kill: int | None = None) -> None:
        self.folder, self.seconds, self.kill = folder, seconds, kill

    def __call__(self, item: int) -> dict[str, Any]:
        with open(os.path.join(self.folder, f"started_{item}"), "w", encoding="utf-8"):
            pass
        if item == self.kill:
            os.kill(os.getpid(), signal.SIGKILL)
        time.sleep(self.seconds)
        return {"item": item, "pid": os.getpid()}
