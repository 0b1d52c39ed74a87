"""How many torch threads training uses: ``train.threads: auto | 0 | N``.

``auto`` (the default) derives the count from the machine when training starts:

1. several processes train together (torchrun's ``WORLD_SIZE`` or ``LOCAL_WORLD_SIZE`` above 1): 1
   thread each;
2. ``OMP_NUM_THREADS`` set in the environment: that count (the user's or the launcher's choice), never
   more than the cores this process may run on;
3. otherwise the cores this process may run on (``os.sched_getaffinity``, which honours ``taskset``
   and container CPU sets) less the machine's one-minute load average, rounded down, at least 1.

Rule 3 is deliberately conservative.  torch's intra-op threads meet at a barrier after every
operation, so one thread that waits for a busy core stalls all of them: on a machine already busy
with other work, 2 threads ran an iteration many times slower than 1 thread, while on idle cores a
second thread saves at most half the time (docs/design.md#training-threads; measured by
``bench/bench_threads.py``).  ``0`` leaves torch's own default; a number is used as given.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from typing import Literal

from ompn_ros.train.errors import TrainConfigError

Threads = int | Literal["auto"]
AUTO = "auto"


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity; ``os.cpu_count()`` where that is unknown)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not Linux
        return max(1, os.cpu_count() or 1)


def machine_load() -> float:
    """The one-minute load average (0.0 where the platform has none)."""
    try:
        return os.getloadavg()[0]
    except (AttributeError, OSError):
        return 0.0


def auto_threads(cores: int, load: float, env: Mapping[str, str]) -> int:
    """The ``auto`` rule (module docstring) for ``cores`` usable cores, a load average ``load`` and the
    environment ``env``."""
    for name in ("WORLD_SIZE", "LOCAL_WORLD_SIZE"):
        if _positive(env.get(name, "")) > 1:
            return 1
    chosen = _positive(env.get("OMP_NUM_THREADS", ""))
    if chosen:
        return min(chosen, cores)
    return max(1, min(cores, math.floor(cores - load)))


def resolve_threads(setting: Threads) -> int:
    """The thread count to give ``torch.set_num_threads`` (0 = leave torch's default)."""
    check_threads(setting)
    if setting == AUTO:
        return auto_threads(usable_cores(), machine_load(), os.environ)
    assert isinstance(setting, int)
    return setting


def check_threads(setting: object) -> None:
    """:class:`TrainConfigError` unless ``setting`` is ``'auto'`` or an int >= 0."""
    if setting == AUTO or (isinstance(setting, int) and not isinstance(setting, bool) and setting >= 0):
        return
    raise TrainConfigError(f"TrainConfig.threads must be 'auto' or an int >= 0, got {setting!r}")


def _positive(text: str) -> int:
    """``text`` as a positive int, else 0."""
    try:
        value = int(text.strip())
    except ValueError:
        return 0
    return max(0, value)


__all__ = ["AUTO", "Threads", "auto_threads", "check_threads", "machine_load", "resolve_threads",
           "usable_cores"]
