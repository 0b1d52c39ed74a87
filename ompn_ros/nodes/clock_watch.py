"""The node's watch on ``/clock`` (``use_sim_time``): negative times, stalls and forward jumps.

rclpy 7.1.6 turns every ``/clock`` message into a ``Time`` and raises ``ValueError`` on a negative one
inside its own subscription callback, which ends the node's process (a simulator restarted an hour back
from 1 004 s publishes -2 596 s).  :func:`guard_clock_topic` puts a check in front of rclpy's handler: a
negative time is dropped (counted and warned by the node); anything else goes on to rclpy.

:class:`ClockWatch` is the ROS-free rule, O(1) per ``/clock`` message and per check:

* a forward jump: one ``/clock`` message more than ``jump_forward_ns`` ahead of the previous one (a
  simulator restarted later, a bag played with a gap) -- the node starts a new episode and counts it,
  as it does for a clock that goes back (``clock_jump_back``, judged on the input stamps);
* a stall: the simulated time has not advanced for ``stall_ns`` of the steady clock since it last did
  (a paused or hung simulator whose data still flows; the node's stamps would then pile up at one
  instant), reported once per stall by :meth:`ClockWatch.stalled`, re-armed when the time moves again.

The node checks stalls from a timer on the steady clock, which keeps ticking (and keeps
``/diagnostics`` alive) while ``/clock`` stands still.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Literal

__all__ = ["ClockWatch", "Verdict", "clock_ns", "guard_clock_topic"]

Verdict = Literal["negative", "forward", "ok"]


def clock_ns(msg: Any) -> int:
    """The time of a ``rosgraph_msgs/Clock`` message in ns (negative when ``sec`` is)."""
    return int(msg.clock.sec) * 1_000_000_000 + int(msg.clock.nanosec)


class ClockWatch:
    """Judges ``/clock`` times (ns) against the steady clock (ns); 0 turns a check off."""

    def __init__(self, stall_ns: int = 0, jump_forward_ns: int = 0) -> None:
        self.stall_ns, self.jump_forward_ns = int(stall_ns), int(jump_forward_ns)
        self._last: int | None = None  # last /clock time
        self._moved_at: int | None = None  # steady time of its last advance
        self._reported = False

    def on_clock(self, now_ns: int, steady_ns: int) -> Verdict:
        """The verdict on one ``/clock`` time; a negative one changes nothing."""
        if now_ns < 0:
            return "negative"
        last, self._last = self._last, now_ns
        if last is None or now_ns != last:
            self._moved_at, self._reported = steady_ns, False
        if last is not None and self.jump_forward_ns > 0 and now_ns - last > self.jump_forward_ns:
            return "forward"
        return "ok"

    def stalled(self, steady_ns: int) -> bool:
        """True once per stall: the time has not advanced for ``stall_ns`` since it last did."""
        if self.stall_ns <= 0 or self._moved_at is None or self._reported:
            return False
        if steady_ns - self._moved_at < self.stall_ns:
            return False
        self._reported = True
        return True

    @property
    def last_ns(self) -> int | None:
        return self._last


def guard_clock_topic(node: Any, accept: Callable[[Any], bool]) -> None:
    """Call ``accept(msg)`` before rclpy's own ``/clock`` handler of ``node``; a message it refuses
    never reaches rclpy.  Covers the subscription made at start (``use_sim_time`` given) and one made
    later (the parameter set at run time)."""
    source = getattr(node, "_time_source", None)
    if source is None:
        return
    inner = source.clock_callback

    def guarded(msg: Any) -> None:
        if accept(msg):
            inner(msg)

    source.clock_callback = guarded  # what rclpy subscribes when use_sim_time is set later
    sub = getattr(source, "_clock_sub", None)
    if sub is not None:
        sub.callback = guarded
