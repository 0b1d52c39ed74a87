"""The pause and idle gate of a stream: when a pause ends the episode, which observations idle holds.

:class:`PauseGate` is the part of the stream rule (:mod:`ompn_ros.stream.rule`) that applies the cuts
of :mod:`ompn_ros.data.cuts` to a live stream; it decides and the rule applies the decision to the
episode:

* ``episode_gap``: a step stamped more than that after the previous one ends the episode (the bag
  reader's ``split: gaps``, :mod:`ompn_ros.data.cuts.gap`), as does a silence of that long on the
  receiver's clock (:class:`~ompn_ros.data.cuts.SilenceWatch`, polled by a timer);
* ``idle_s``: idle observations are held until the reader's ``split: idle`` rule decides them
  (:class:`~ompn_ros.data.cuts.IdleGate`).

Every call is O(1) per observation, amortised.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from ompn_ros.data.cuts import IdleGate, SilenceWatch, SpeedElements, gap_ends_episode

__all__ = ["IdleDecisions", "PauseGate", "PauseLimits"]

IdleDecisions = list[tuple[str, np.ndarray | None, int]]
"""What the idle rule decided, in order: ``(kind, observation or None, stamp)`` (:meth:`IdleGate.push`)."""


class PauseLimits(Protocol):
    """What the gate reads of the stream's limits (:class:`~ompn_ros.stream.rule.StreamLimits`)."""

    gap_ns: int
    idle_s: float
    idle_ns: int
    idle_speed: float
    idle_elements: SpeedElements


class PauseGate:
    """The pause and idle rules of one stream rule, armed by :meth:`arm` (off before, and when the
    limits ask for neither).

    :attr:`silence` watches for a pause on the receiver's clock (``episode_gap``); :attr:`idle` holds the
    idle observations (``idle_s``)."""

    def __init__(self) -> None:
        self.silence: SilenceWatch | None = None  # episode_gap, armed by arm()
        self.idle: IdleGate | None = None  # idle_s: the reader's split: idle rule

    def arm(self, limits: PauseLimits) -> None:
        """Start the pause and idle rules ``limits`` ask for (the node: on activation)."""
        self.silence = SilenceWatch(limits.gap_ns) if limits.gap_ns > 0 else None
        self.idle = (IdleGate(limits.idle_ns, limits.idle_speed, limits.idle_elements)
                     if float(limits.idle_s) > 0 else None)

    def disarm(self) -> None:
        self.silence = self.idle = None

    @staticmethod
    def gap(stamp_ns: int, last_ns: int | None, gap_ns: int) -> bool:
        """Whether ``stamp_ns`` comes more than ``gap_ns`` (``episode_gap``; 0: off) after ``last_ns``."""
        return bool(gap_ns) and gap_ends_episode(stamp_ns, last_ns, gap_ns)

    def quiet(self, clock: Callable[[], int], steps: int, open_episode: bool) -> bool:
        """Polled by a timer: whether the open episode had no new step for ``episode_gap`` of ``clock``
        (read only when the rule is armed)."""
        watch = self.silence
        return watch is not None and watch.quiet(clock(), steps, open_episode)

    def hold(self, data: Any, stamp_ns: int) -> IdleDecisions | None:
        """Give a stamped observation to the idle rule: what it decided now; ``None`` when the rule is
        off (the observation is stepped as it is)."""
        if self.idle is None:
            return None
        return self.idle.push(np.array(data, dtype=np.float32), stamp_ns)

    def flush(self) -> IdleDecisions:
        """The input ends (a marker, a reset): what the idle rule held, decided as at the end of a bag."""
        return [] if self.idle is None else self.idle.flush()

    @property
    def decided(self) -> tuple[int, int] | None:
        """After an ``end`` the idle rule decided: (observations from the final one to the one that
        decided, its stamp) (:attr:`IdleGate.decided`)."""
        return None if self.idle is None else self.idle.decided

    def paused(self) -> None:
        """A pause ended the episode: the silence watch and the idle rule start again."""
        if self.silence is not None:
            self.silence.rearm()
        if self.idle is not None:
            self.idle.reset()
