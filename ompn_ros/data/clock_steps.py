"""Which clock stepped: the rule the bag reader and the node share to tell a clock step from a pause.

Two clocks stamp every message: the receiver's (the recording PC's log stamp in a bag, the node's
clock live) and, for topics with a header, the sender's (``header.stamp``, the robot's clock).  A
real pause shows on both alike.  A clock step (an NTP correction setting one clock back or forward by
seconds in one go) changes the lag between them by at least :data:`STEP_NS`; the clock that moved is
the one whose interval left its period, or went back (:func:`header_moved`).

* The batch form reads a topic whole, in recording order, and asks for the lag change to last
  (``ompn_ros.data.reader.steps.lag_steps``: the medians of the messages on either side).
* The live form, :class:`LiveClockSteps`, sees one message at a time: it judges each against the
  one before it and has no later messages to confirm a step with, so the stream rule asks it only
  where a stamp would otherwise cut the stream (a step back beyond ``clock_jump_back``, forward
  beyond ``episode_gap``); there a message delivered late is no candidate (docs/specs.md, "Clocks").

Cost: O(1) per message, two integers of state per clock.
"""

from __future__ import annotations

__all__ = ["STEP_NS", "LiveClockSteps", "header_moved"]

STEP_NS = 100_000_000
"""A clock step is at least this large (0.1 s): delivery jitter stays far below it."""


def header_moved(d_log: int, d_header: int, period_log: int, period_header: int) -> bool:
    """Of a lag change between two messages (intervals ``d_log`` on the receiver's clock, ``d_header``
    on the header clock), whether the header clock moved: it went back, or its interval left its
    period by more than the receiver's did (a receiver's clock that went back moved itself)."""
    return d_header < 0 or (d_log >= 0 and abs(d_header - period_header) > abs(d_log - period_log))


class LiveClockSteps:
    """The live form: the header clock's steps, judged message by message against the receiver's clock.

    :meth:`step` takes each message's header stamp and the receiver's clock at its arrival, in
    arrival order; a receiver's clock at 0 or below (sim time before the first ``/clock``) says
    nothing and is skipped.  The periods are the last intervals without a lag change."""

    def __init__(self) -> None:
        self.forget()

    def forget(self) -> None:
        """Start again (a new episode): the next message has nothing to be judged against."""
        self.header = self.receive = 0
        self.period_header = self.period_receive = 0

    def step(self, header_ns: int, receive_ns: int) -> int:
        """The header clock's step before this message in ns (negative: back), 0 when there is none."""
        if receive_ns <= 0:
            return 0
        last_header, last_receive = self.header, self.receive
        self.header, self.receive = header_ns, receive_ns
        if last_receive <= 0:
            return 0
        d_header, d_receive = header_ns - last_header, receive_ns - last_receive
        if abs(d_header - d_receive) < STEP_NS:
            if d_header > 0 and d_receive > 0:
                self.period_header, self.period_receive = d_header, d_receive
            return 0
        if not header_moved(d_receive, d_header, self.period_receive, self.period_header):
            return 0
        return d_header - self.period_header
