"""Tasks for the batch pool's tests, importable by the workers a pool spawns or forks."""

from __future__ import annotations

import gc
import os
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
