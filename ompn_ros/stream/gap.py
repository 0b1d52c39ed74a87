"""Episodes split by pauses: the ``episode_gap`` and ``idle_s`` rules of the stream rule
(:mod:`ompn_ros.stream.rule`), which ``ompn_node`` and the offline stream replay both run.

A robot that publishes no episode markers still pauses between tasks.  The bag reader's ``split: gaps``
(``time_gap``, :func:`ompn_ros.data.reader.align.windows_from_gaps`) starts an episode wherever two
consecutive step stamps lie more than ``time_gap`` apart; :func:`gap_ends_episode` is that rule for one
incoming step, so the node and the reader cut a stream in the same places.

Waiting for the next episode's first step would delay the end boundary of the last segment by the
whole pause, so :class:`SilenceWatch` also ends an open episode once no step has been accepted for
``episode_gap`` seconds of the receiver's clock (the node polls it from a timer; its clock is simulated
time under ``use_sim_time``, so a paused simulation does not end episodes).  A timer of period ``p`` ends the
episode between ``gap`` and ``gap + p`` after its last step.  Both are O(1) per call.

A driver that keeps publishing while the robot waits never pauses: :class:`IdleGate` applies the
reader's ``split: idle`` rule (:mod:`ompn_ros.data.idle`) instead.
"""

from __future__ import annotations

import numpy as np

from ompn_ros.data.idle import ALL_ELEMENTS, IdleSplitter, SpeedElements, step_still

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




class IdleGate:
    """``idle_s``: the reader's ``split: idle`` rule (:class:`ompn_ros.data.idle.IdleSplitter`) over the
    node's observations, still by :func:`ompn_ros.data.idle.step_still` on ``elements`` (the node sees no
    commands, so only ``idle_speed`` makes a step still).  Still observations are held until the rule
    decides them: :meth:`push` returns ``(kind, observation, stamp)`` in order, ``kind`` ``start``
    (reset, then step it), ``step`` (step it) or ``end`` (step it when given, then close the episode;
    ``None``: the last stepped observation is the final one).  After an ``end`` that :meth:`push` gave,
    :attr:`decided` is ``(observations from the final one to the one that decided, its stamp)``: the
    rule waits ``idle_s`` before it can end an episode.  O(1) per step, amortised."""

    def __init__(self, idle_ns: int, idle_speed: float, elements: SpeedElements = ALL_ELEMENTS) -> None:
        self.idle_speed = float(idle_speed)
        self.elements = elements
        self.splitter = IdleSplitter(idle_ns)
        self.decided: tuple[int, int] | None = None
        self._prev: tuple[np.ndarray, int] | None = None
        self._pending: dict[int, tuple[np.ndarray, int]] = {}

    def push(self, obs: np.ndarray, stamp_ns: int) -> list[tuple[str, np.ndarray | None, int]]:
        prev_obs, prev_ns = self._prev if self._prev is not None else (None, None)
        still = step_still(prev_obs, prev_ns, obs, stamp_ns, self.idle_speed, self.elements)
        self._prev = (obs, stamp_ns)
        cuts = self.splitter.push(stamp_ns, still)
        row = self.splitter.rows - 1
        self._pending[row] = (obs, stamp_ns)
        out: list[tuple[str, np.ndarray | None, int]] = []
        for cut in cuts:
            x, s = self._pending.pop(cut.row, (None, stamp_ns))
            out.append((cut.kind, x, s))
            if cut.kind == "end":
                self.decided = (row - cut.row, stamp_ns)
        # Every held row is pending, and a row stops being held only in a push that decides it (a cut,
        # popped above) or ends the episode (nothing held after it): so the pending rows are the held
        # ones once the undecided rest is dropped, which happens only when nothing is held (O(1)
        # amortised, whatever the pause's length; rebuilding the held set here made each still step
        # cost O(held)).
        if self.splitter.held == 0:
            self._pending.clear()
        return out

    def flush(self) -> list[tuple[str, np.ndarray | None, int]]:
        """An episode marker or ``~/reset``: the stream the rule sees ends here, as a bag ends for the
        reader.  The open episode ends at its first held still observation (returned as ``end``), the
        other held ones are trimmed, and the next observation is judged afresh."""
        last_ns = self._prev[1] if self._prev is not None else 0
        out: list[tuple[str, np.ndarray | None, int]] = []
        self.decided = None
        for cut in self.splitter.finish():
            x, s = self._pending.get(cut.row, (None, last_ns))
            out.append((cut.kind, x, s))
        self._prev, self._pending = None, {}
        return out

    @property
    def trimmed(self) -> int:
        return self.splitter.trimmed

    def reset(self) -> None:
        """Forget the held observations and the open episode (the episode was ended otherwise)."""
        trimmed = self.splitter.trimmed + len(self._pending)
        self.splitter = IdleSplitter(self.splitter.idle_ns, trimmed=trimmed)
        self._prev, self._pending, self.decided = None, {}, None


__all__ = ["GAP_TIMER_FRACTION", "IdleGate", "SilenceWatch", "gap_ends_episode"]
