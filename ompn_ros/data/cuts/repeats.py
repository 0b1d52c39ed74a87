"""Messages a driver sent twice: dropped by the bag reader while reading and by ``ompn_node`` before
stepping, counted per topic (docs/bags.md).

A message is a *repeat* when its bytes equal those of the previous message of the same topic and
either its type starts with a ``std_msgs/Header`` whose stamp is not zero (the same sample sent
again, however late) or it was logged at most :data:`REPEAT_NS` after it (a headerless message:
two equal states of an idle robot one driver period apart stay two observations).  Repeats are
counted in the read report's ``duplicates`` table and named in a note; the same rule holds in strict
and non-strict reads.  Live, the receive time (or the DDS source timestamp) takes the log stamp's
place, and a decoded JointState is compared by header stamp and data (:meth:`Repeats.seen_sample`),
counted ``repeated_messages``.  :func:`unrepeated` is the rule over a bag's messages (the reader);
:class:`Repeats` is the rule for one message (both forms run it).  Cost: one bytes comparison per
message; memory: the last message per topic.
"""

from __future__ import annotations

from collections.abc import Iterator
from functools import cache

from rosbags.interfaces import Connection

from .. import messages as m

REPEAT_NS = 100_000
"""Headerless messages with equal bytes logged at most this far apart (ns) are one message sent twice
(below the period of any driver: 10 kHz)."""


@cache
def has_header(msgtype: str) -> bool:
    """Whether ``msgtype``'s first field is a ``std_msgs/msg/Header`` (unknown types: no)."""
    try:
        fields = m.typestore().fielddefs[msgtype][1]
    except KeyError:
        return False
    return bool(fields) and fields[0][1][1] in ("std_msgs/msg/Header", "std_msgs/Header")


def _header_stamped(msgtype: str, data: bytes | memoryview) -> bool:
    """Whether ``data`` starts with a ``std_msgs/Header`` whose stamp is not zero."""
    return has_header(msgtype) and bytes(data[4:12]) != bytes(8)


class Repeats:
    """The last message per topic and the repeats dropped so far (``counts``: topic -> repeats)."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}
        self._last: dict[str, tuple[int, bytes | memoryview]] = {}

    def seen(self, topic: str, msgtype: str, stamp: int, data: bytes | memoryview) -> bool:
        """Whether this message (CDR ``data`` logged or received at ``stamp``) repeats the previous one
        of ``topic`` (counted; else remembered)."""
        last = self._last.get(topic)
        if last is not None and last[1] == data and (0 <= stamp - last[0] <= REPEAT_NS
                                                     or _header_stamped(msgtype, data)):
            return self._count(topic)
        self._last[topic] = (stamp, data)
        return False

    def seen_sample(self, topic: str, header_ns: int, payload: bytes) -> bool:
        """:meth:`seen` for a decoded stamped message (``ompn_node``'s JointState): a repeat when its
        non-zero header stamp and ``payload`` (the rest of the message, as bytes) equal the previous."""
        if header_ns == 0:
            return False
        key = header_ns.to_bytes(8, "little", signed=True) + payload
        last = self._last.get(topic)
        if last is not None and last[1] == key:
            return self._count(topic)
        self._last[topic] = (header_ns, key)
        return False

    def forget(self) -> None:
        """Forget the last messages (``ompn_node``: an episode marker or ``~/reset`` starts afresh)."""
        self._last.clear()

    def _count(self, topic: str) -> bool:
        self.counts[topic] = self.counts.get(topic, 0) + 1
        return True

    @property
    def total(self) -> int:
        """Repeats dropped, all topics."""
        return sum(self.counts.values())

    def notes(self) -> list[str]:
        """One note per topic with repeats, for the bag's report."""
        return [f"topic '{topic}': {n} message(s) repeated the previous one (same bytes; same header "
                f"stamp or at most {REPEAT_NS // 1000} µs later): read once, counted in 'duplicates'"
                for topic, n in sorted(self.counts.items())]


def unrepeated(messages: Iterator[tuple[Connection, int, bytes]],
               repeats: Repeats) -> Iterator[tuple[Connection, int, bytes]]:
    """``messages`` without the repeats (counted in ``repeats``)."""
    for conn, stamp, data in messages:
        if not repeats.seen(conn.topic, conn.msgtype, stamp, data):
            yield conn, stamp, data
