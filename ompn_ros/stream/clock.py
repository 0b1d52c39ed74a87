"""The clocks of a stream: where a stamp lies, and which clock stepped.

:class:`StreamClocks` is the part of the stream rule (:mod:`ompn_ros.stream.rule`) that reads the
clocks; it decides and the rule applies the decision to the episode:

* a stamp taken from the receiver's clock is kept strictly increasing (:meth:`StreamClocks.receive_stamp`);
* a stamp too far ahead of the receiver's clock is from the future, one too far behind the last step a
  clock restart (:func:`classify_stamp`);
* a step of the stamps' clock is told from a restart or a pause by the clock beside it: header stamps
  against the receiver's clock, reception stamps from the node's wall clock against its steady clock
  (:mod:`ompn_ros.data.clock_steps`, the bag reader's rule; docs/specs.md, "Clocks").

Every call is O(1).
"""

from __future__ import annotations

from typing import Literal, Protocol

from ompn_ros.data.clock_steps import LiveClockSteps

__all__ = ["ClockLimits", "StampClass", "StreamClocks", "classify_stamp", "restart_line", "step_line"]

StampClass = Literal["ok", "future", "jump_back"]


def classify_stamp(
    stamp_ns: int, last_ns: int | None, now_ns: int, *, jump_back_ns: int, max_lead_ns: int
) -> StampClass:
    """Where ``stamp_ns`` lies against the last accepted stamp and the receiver's clock (O(1)).

    ``'future'``: more than ``max_lead_ns`` ahead of ``now_ns`` (checked when both are > 0; a clock at 0
    is sim time before the first ``/clock``).  ``'jump_back'``: more than ``jump_back_ns`` before
    ``last_ns``: the source's clock restarted (a sim restart, a bag replayed in a loop), so a new
    episode begins.  ``'ok'`` otherwise; a small step back stays an out-of-order rejection of
    :meth:`StreamingSegmenter.step`.  Together these make a single stamp unable to wedge a stream.
    """
    if max_lead_ns > 0 and now_ns > 0 and stamp_ns - now_ns > max_lead_ns:
        return "future"
    if last_ns is not None and last_ns - stamp_ns > jump_back_ns:
        return "jump_back"
    return "ok"


class ClockLimits(Protocol):
    """What the clocks read of the stream's limits (:class:`~ompn_ros.stream.rule.StreamLimits`)."""

    jump_back_ns: int
    max_lead_ns: int
    header_topic: str


class StreamClocks:
    """The clocks a stream's stamps are judged by, for one stream rule.

    :attr:`last_receive_ns` is the last stamp :meth:`receive_stamp` gave; :attr:`steps` follows the
    stamps' clock against the clock beside it once :meth:`arm` was called (``None`` before: no step is
    seen)."""

    def __init__(self) -> None:
        self.last_receive_ns = 0  # of receive_stamp()
        self.steps: LiveClockSteps | None = None  # the stamps' clock's steps, armed by arm()

    def arm(self) -> None:
        """Judge the steps of header stamps, or of stamps given with a steady clock, from now on."""
        self.steps = LiveClockSteps()

    def disarm(self) -> None:
        self.steps = None

    def receive_stamp(self, now_ns: int, jump_back_ns: int) -> int:
        """A stamp from the receiver's clock, kept strictly increasing (a clock that stands still, e.g.
        sim time between ``/clock`` ticks, must not turn into out-of-order rejections); a clock that
        went back further than ``jump_back_ns`` is taken as it is."""
        last = self.last_receive_ns
        stamp = now_ns if (now_ns > last or last - now_ns > jump_back_ns) else last + 1
        self.last_receive_ns = stamp
        return stamp

    def judge(self, stamp_ns: int, last_ns: int | None, now_ns: int, against_ns: int | None,
              limits: ClockLimits) -> tuple[StampClass, int]:
        """Where ``stamp_ns`` lies (:func:`classify_stamp`) and, unless it is from the future, the step of
        the stamps' clock before it in ns (0: none; :meth:`step`)."""
        verdict = classify_stamp(
            stamp_ns, last_ns, now_ns, jump_back_ns=limits.jump_back_ns, max_lead_ns=limits.max_lead_ns
        )
        if verdict == "future":
            return verdict, 0
        return verdict, self.step(stamp_ns, now_ns, against_ns, bool(limits.header_topic))

    def step(self, stamp_ns: int, now_ns: int, against_ns: int | None, header: bool) -> int:
        """The step of the stamps' clock before this stamp in ns (0: none).  Header stamps (``header``)
        are judged against ``against_ns`` when given, else ``now_ns`` (the receiver's clock at the
        message's arrival: for a step the assembler released later, the step message's); other stamps
        only against a given ``against_ns`` (the node's steady clock beside its wall-clock reception
        stamps)."""
        clock = self.steps
        if clock is None:
            return 0
        if header:
            return clock.step(stamp_ns, now_ns if against_ns is None else against_ns)
        return 0 if against_ns is None else clock.step(stamp_ns, against_ns)


def restart_line(last_ns: int | None, stamp_ns: int, clock_jump_back: float) -> str:
    """The warning of a clock restart: the stamps went back from ``last_ns`` to ``stamp_ns``."""
    return (f"input clock jumped back from {last_ns} to {stamp_ns} ns (more than "
            f"clock_jump_back={clock_jump_back} s): starting a new episode")


def step_line(size: int, header_topic: str) -> str:
    """The warning of a step of ``size`` ns of the stamps' clock that the clock beside it did not take:
    the header clock of ``header_topic``, or ('') the node's wall clock stamping at reception."""
    way = "back" if size < 0 else "forward"
    if header_topic:
        return (f"the header clock of '{header_topic}' steps {way} {abs(size) / 1e9:.3f} s and the node's "
                "clock does not (an NTP correction on the robot?): the episode goes on in arrival order; "
                "a robot clock kept in step (chrony) avoids it")
    return (f"the node's clock stamping the observations at reception steps {way} {abs(size) / 1e9:.3f} s "
            "and its steady clock does not (an NTP correction on this PC?): the episode goes on in "
            "arrival order; a PC clock that is slewed rather than stepped avoids it")
