"""Messages a publisher sent that never reached the node: gaps in the publication sequence numbers.

An observation can vanish before any callback sees it.  The input subscription keeps the last
``qos_depth`` samples (KEEP_LAST): when the node falls behind (a burst, a long step, the held steps of
an ``idle_s`` pause stepped at once), the middleware overwrites unread samples and tells nobody; its
``message_lost`` event covers samples the transport lost, not these.  Every DDS sample carries its
writer's sequence number (``publication_sequence_number`` of the message info, 1, 2, 3, ... per
publisher), so a jump from ``n`` to ``n + k`` between two received samples means ``k - 1`` were sent
and never received: :class:`SequenceGaps` counts them.

What is counted and what is not:

* counted: samples between two received ones of the same publisher, while the topic has exactly one
  publisher (a full input queue, or the transport: samples the middleware reports lost as well are
  then in both ``messages_lost`` and the gap count);
* not counted: samples before the first one received (a late joiner cannot tell them from history it
  never subscribed to), samples of a topic with several publishers (their sequence numbers interleave
  and the message info names no writer), and a publisher that restarted (its numbers begin again:
  counting restarts).

O(1) per message.
"""

from __future__ import annotations

UNSUPPORTED_LIMIT = 2**63
"""A sequence number at or above this is rmw's "not supported" value, not a count."""


class SequenceGaps:
    """The gap count of one input topic (see the module docstring)."""

    def __init__(self) -> None:
        self.missed = 0  # samples sent and never received, all publishers so far
        self._last: int | None = None
        self._publishers = 1

    def seen(self, sequence: int) -> int:
        """A received sample's publication sequence number; how many samples before it were missed."""
        if not 0 < sequence < UNSUPPORTED_LIMIT:
            return 0  # the middleware gives no number: nothing to count, nothing to remember
        last, self._last = self._last, sequence
        if last is None or sequence <= last or self._publishers != 1:
            return 0  # the first, a restarted publisher, or several publishers
        gap = sequence - last - 1
        self.missed += gap
        return gap

    def publishers(self, count: int) -> None:
        """The topic's matched publishers changed to ``count`` (rmw's ``matched`` event): counting
        starts again from the next sample."""
        self._publishers = int(count)
        self._last = None


__all__ = ["UNSUPPORTED_LIMIT", "SequenceGaps"]
