"""Ctrl-C during training: stop after the update under way, keep a resumable state, say so in one line.

The first SIGINT only asks the training loop to stop: the update under way finishes (a torch
operation cannot be cut short anyway, and a half-applied Adam step could not be resumed), the
resumable state of that iteration is saved and :class:`TrainingInterrupted` carries the way on.  A
second SIGINT interrupts at once; the resumable state is then that of the last evaluation (every
state is written whole or not at all, :mod:`ompn_ros.train.state`).

:class:`TrainingInterrupted` derives from ``KeyboardInterrupt``, not from the error tree: it is no
error, nothing catches it on the way up, and the commands print its message as their one line
(``cli/_common.py``, exit code 130 like any process ended by SIGINT).
"""

from __future__ import annotations

import signal
import threading
from types import FrameType, TracebackType


class TrainingInterrupted(KeyboardInterrupt):
    """Training stopped on Ctrl-C; the message says what was kept and how to go on."""


class StopRequest:
    """Within ``with StopRequest() as stop:`` the first SIGINT sets ``stop.requested`` and the second
    raises ``KeyboardInterrupt``.  Outside the main thread (where no handler can be installed) or with
    ``enabled=False`` (several processes: each would stop at another update) SIGINT keeps its default
    behaviour."""

    def __init__(self, enabled: bool = True) -> None:
        self.requested = False
        self._enabled = enabled and threading.current_thread() is threading.main_thread()
        self._previous: signal.Handlers | object = None

    def __enter__(self) -> StopRequest:
        if self._enabled:
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._enabled:
            signal.signal(signal.SIGINT, self._previous)  # type: ignore[arg-type]

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True


__all__ = ["StopRequest", "TrainingInterrupted"]
