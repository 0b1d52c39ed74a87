"""Where a live recording commits, so that a recording killed with SIGKILL still ends with whole steps.

A recorder commits its storage now and then (a sqlite3 ``COMMIT``, an mcap chunk with its CRC, see
:mod:`ompn_ros.data.recorder.storage`); a SIGKILL loses what came after the last commit.  For the kept part to
end with whole steps, a commit must hold everything stamped before some step's opening message (the
observation that opens a step in the step contract of ``ompn_ros.layout``) and nothing from it on.
Committing right before that message is written is not enough under load: DDS delivers each topic
on its own, and an executor that finds several subscriptions ready serves them in creation order, so
while a recorder works off a backlog it takes step k's observation before step k − 1's action.

The rule, the same idea as the stop cut of :mod:`ompn_ros.data.recorder.stop_cut` but without dropping:

* once half a commit period has passed, the next step-opening message that no other topic has
  overtaken (none wrote a message stamped at or after it) fixes the commit's *cut* (its stamp) and
  is held back, with every later message stamped at or after the cut;
* messages stamped before the cut are written: they complete the steps before it;
* when every other topic that is streaming (a message written within ``STREAM_NS``) has delivered a
  message stamped at or after the cut, none of its messages before the cut can still come (each
  topic is delivered first in first out): :data:`COMMIT`, then the held messages are released;
* a whole commit period after the last commit, the commit is made anyway (bounded loss).

The held messages are at most about one step of every topic.  Costs O(1) per message, O(topics) when
a cut is fixed, O(held) when it is released.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final, Generic, TypeVar

T = TypeVar("T")

STREAM_NS = 500_000_000
"""A topic whose last message is older than this (0.5 s) is not waited for."""


class _Commit:
    def __repr__(self) -> str:
        return "COMMIT"


COMMIT: Final = _Commit()
"""Marker in :meth:`StepCommits.offer`'s output: commit the storage here."""


@dataclass
class StepCommits(Generic[T]):
    """Commit points of one recording (module docstring); stamps in ns, ages in seconds.

    ``T`` is whatever the caller writes (e.g. ``(topic, stamp, raw)``).  Without a step topic every
    message may be a commit point once half the period has passed.
    """

    step_topic: str | None
    period_s: float
    cut: int | None = None  # stamp of the held step opening of the pending commit
    waiting: set[str] = field(default_factory=set)  # topics still to deliver a message from the cut on
    held: list[T] = field(default_factory=list)
    last: dict[str, int] = field(default_factory=dict)  # topic -> last stamp offered
    forced: int = 0  # commits made after a whole period without the cut completing

    def __post_init__(self) -> None:
        if not self.period_s > 0:
            raise ValueError(f"period_s must be > 0, got {self.period_s}")

    def offer(self, topic: str, stamp: int, item: T, since_commit_s: float) -> list[T | _Commit]:
        """What to do with one message, in order: items to write and :data:`COMMIT` markers.
        ``since_commit_s``: seconds since the last commit."""
        previous = self.last.get(topic)
        self.last[topic] = stamp if previous is None else max(previous, stamp)
        if self.cut is None:
            opening = self.step_topic is None or topic == self.step_topic
            if since_commit_s < self.period_s / 2 or not opening:
                return [item]
            if self.step_topic is None:
                return [COMMIT, item]
            if any(last >= stamp for t, last in self.last.items() if t != topic):
                return [item]  # a topic ran ahead of this opening: written already, try the next one
            self.cut = stamp
            self.waiting = {t for t, last in self.last.items()
                            if t != topic and stamp - last <= STREAM_NS}
            self.held = [item]
            return self._release() if not self.waiting else []
        if stamp < self.cut:
            return [item]
        self.held.append(item)
        self.waiting.discard(topic)
        if not self.waiting:
            return self._release()
        return self.due(since_commit_s)

    def due(self, since_commit_s: float) -> list[T | _Commit]:
        """The pending commit made anyway once a whole period passed (call it from a timer too)."""
        if self.cut is None or since_commit_s < self.period_s:
            return []
        self.forced += 1
        return self._release()

    def idle_commit(self, since_commit_s: float) -> bool:
        """Whether a timer may commit: a whole period passed and no commit is pending."""
        return self.cut is None and since_commit_s >= self.period_s

    def flush(self) -> list[T]:
        """The held messages, without a commit (the recording closes)."""
        held, self.held, self.cut, self.waiting = self.held, [], None, set()
        return held

    def _release(self) -> list[T | _Commit]:
        return [COMMIT, *self.flush()]


__all__ = ["COMMIT", "STREAM_NS", "StepCommits"]
