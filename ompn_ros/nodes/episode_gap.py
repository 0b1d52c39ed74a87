"""Episodes split by pauses, live: ``ompn_node``'s ``episode_gap`` (ROS-free, so it is unit-tested alone).

A robot that publishes no episode markers still pauses between tasks.  The bag reader's ``split: gaps``
(``time_gap``, :func:`ompn_ros.data.reader.align.windows_from_gaps`) starts an episode wherever two
consecutive step stamps lie more than ``time_gap`` apart; :func:`gap_ends_episode` is that rule for one
incoming step, so the node and the reader cut a stream in the same places.

Waiting for the next episode's first step would delay the end boundary of the last segment by the
whole pause, so :class:`SilenceWatch` also ends an open episode once no step has been accepted for
``episode_gap`` seconds of the node's clock (polled by a timer; the clock is simulated time under
``use_sim_time``, so a paused simulation does not end episodes).  A timer of period ``p`` ends the
episode between ``gap`` and ``gap + p`` after its last step.  Both are O(1) per call.
"""

from __future__ import annotations

GAP_TIMER_FRACTION = 0.25
"""Period of the silence timer as a fraction of ``episode_gap`` (the end lags by at most this much)."""


def gap_ends_episode(stamp_ns: int, last_ns: int | None, gap_ns: int) -> bool:
    """True when a step stamped ``stamp_ns`` starts a new episode: the split is on (``gap_ns > 0``), the
    episode has a previous step and the two stamps are more than ``gap_ns`` apart (the reader's rule)."""
    return gap_ns > 0 and last_ns is not None and stamp_ns - last_ns > gap_ns


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


__all__ = ["GAP_TIMER_FRACTION", "SilenceWatch", "gap_ends_episode"]
