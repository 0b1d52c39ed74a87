"""Bag stamps in sim time for a recorder running under ``use_sim_time``.

DDS source timestamps are system time; the sims' own stamps (JointState headers, markers) follow
``/clock`` when they run under ``use_sim_time``.  :class:`SimStamper` maps a message's source stamp
``src`` to sim time with a function that is strictly increasing in ``src``, so the publish order of
the step contract survives any delivery order:

* each step opens a segment when its opening message (the step topic, ``ompn_ros.data.recorder.stop_cut``)
  arrives: ``base`` = the node's sim time then;
* a message of that step (by source stamp) is stamped ``base + (src − src_open) · compress``: the
  system-time spacing inside a step, compressed (default 1/100) so that a step never reaches into the
  next one even when sim time runs slower than system time or stands still between ``/clock`` ticks;
* a segment's base is raised, if needed, above the end of the previous segment, and a step whose
  opening message arrives after a message published later keeps the previous segment.

Before the first ``/clock`` message (sim time 0) stamps stay in system time.  The caller opens a
segment at every step-topic message, and also at any message while :attr:`SimStamper.started` is
false (the first message after ``/clock`` starts the sim time base) or when there is no step topic.

O(log history) per message.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field


@dataclass
class SimStamper:
    """Source stamp -> sim-time stamp (module docstring)."""

    compress: float = 0.01
    history: int = 256
    _opens: list[int] = field(default_factory=list)  # source stamps of the segment starts (sorted)
    _bases: list[int] = field(default_factory=list)  # their sim-time stamps
    _max_src: int = -1  # largest source stamp given a sim-time stamp so far

    @property
    def started(self) -> bool:
        """Whether stamps are in sim time yet."""
        return bool(self._opens)

    def open_step(self, src_ns: int, sim_now_ns: int) -> None:
        """A step-opening message published at ``src_ns`` arrived when sim time read ``sim_now_ns``."""
        if sim_now_ns <= 0 or src_ns <= self._max_src:
            return  # no /clock yet, or a later message came first: the current segment goes on
        base = sim_now_ns
        if self._opens:
            floor = self._bases[-1] + int((src_ns - self._opens[-1]) * self.compress) + 1
            base = max(base, floor)
        self._opens.append(src_ns)
        self._bases.append(base)
        if len(self._opens) > 2 * self.history:
            del self._opens[:self.history], self._bases[:self.history]

    def stamp(self, src_ns: int) -> int:
        """Stamp of a message published at ``src_ns`` (system time before the first segment)."""
        if not self._opens:
            return src_ns
        i = max(bisect.bisect_right(self._opens, src_ns) - 1, 0)
        self._max_src = max(self._max_src, src_ns)
        return self._bases[i] + int((src_ns - self._opens[i]) * self.compress)


__all__ = ["SimStamper"]
