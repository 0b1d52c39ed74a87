"""Episodes split by pauses: the reader's ``split: gaps`` (``time_gap``) and ``ompn_node``'s ``episode_gap``.

A robot that publishes no episode markers still pauses between tasks.  The rule: a step starts a new
episode when it is stamped more than the gap after the step before it (:func:`apart`, the one
comparison both forms make).  :func:`gap_windows` runs it over a whole array of stamps (the bag reader,
O(N)); :func:`gap_ends_episode` is the rule for one incoming step (the stream rule of the node and the
replay, O(1)), so the node and the reader cut a stream in the same places.

Waiting for the next episode's first step would delay the end boundary of the last segment by the
whole pause, so :class:`SilenceWatch` also ends an open episode once no step has been accepted for
``episode_gap`` seconds of the receiver's clock (the node polls it from a timer; its clock is simulated
time under ``use_sim_time``, so a paused simulation does not end episodes).  A timer of period ``p``
ends the episode between ``gap`` and ``gap + p`` after its last step.  Both are O(1) per call.

A driver that keeps publishing while the robot waits never pauses: the idle rule
(:mod:`ompn_ros.data.cuts.idle`) cuts such a stream instead.
"""

from __future__ import annotations

import itertools
from typing import overload

import numpy as np

GAP_TIMER_FRACTION = 0.25
"""Period of the silence timer as a fraction of ``episode_gap`` (the end lags by at most this much)."""


@overload
def apart(later_ns: int, earlier_ns: int, gap_ns: int) -> bool: ...
@overload
def apart(later_ns: np.ndarray, earlier_ns: np.ndarray, gap_ns: int) -> np.ndarray: ...
def apart(later_ns: int | np.ndarray, earlier_ns: int | np.ndarray, gap_ns: int) -> bool | np.ndarray:
    """Whether ``later_ns`` lies more than ``gap_ns`` after ``earlier_ns`` (the gap rule): one step's
    stamps (ints, the live form) or element by element (arrays of ns, the batch form)."""
    return later_ns - earlier_ns > gap_ns


def gap_windows(stamps_ns: np.ndarray, gap_ns: int) -> list[tuple[int, int]]:
    """The episodes of a whole stream as ``(first_row, stop_row)`` (stop exclusive): a new one wherever
    two consecutive stamps are more than ``gap_ns`` apart (:func:`apart` over every pair)."""
    if stamps_ns.size == 0:
        return []
    starts = np.flatnonzero(apart(stamps_ns[1:], stamps_ns[:-1], gap_ns)) + 1
    bounds = np.concatenate([[0], starts, [stamps_ns.size]])
    return [(int(a), int(b)) for a, b in itertools.pairwise(bounds)]


def gap_ends_episode(stamp_ns: int, last_ns: int | None, gap_ns: int) -> bool:
    """True when a step stamped ``stamp_ns`` starts a new episode: the split is on (``gap_ns > 0``), the
    episode has a previous step and the two stamps are more than ``gap_ns`` apart (:func:`apart`)."""
    return gap_ns > 0 and last_ns is not None and apart(stamp_ns, last_ns, gap_ns)


class SilenceWatch:
    """Tells when an open episode has had no new step for ``gap_ns`` of the node's clock.

    Call :meth:`quiet` from a timer with the clock and the episode's accepted-step count; it compares
    the count with the previous call's, so the per-message path pays nothing.
    """

    def __init__(self, gap_ns: int) -> None:
        if gap_ns <= 0:
            raise ValueError(f"SilenceWatch needs a gap > 0 ns, got {gap_ns}")
        self.gap_ns = int(gap_ns)
        self._steps = -1
        self._since: int | None = None

    def quiet(self, now_ns: int, steps: int, open_episode: bool) -> bool:
        """True once ``steps`` has not changed for ``gap_ns`` while the episode is open.

        A clock that went back (a restarted simulation) restarts the wait rather than firing."""
        if not open_episode or steps != self._steps or self._since is None or now_ns < self._since:
            self._steps, self._since = steps, now_ns
            return False
        return now_ns - self._since >= self.gap_ns

    def rearm(self) -> None:
        """Forget the last count (after the episode was ended, by this watch or by a gap)."""
        self._steps, self._since = -1, None


__all__ = ["GAP_TIMER_FRACTION", "SilenceWatch", "apart", "gap_ends_episode", "gap_windows"]
