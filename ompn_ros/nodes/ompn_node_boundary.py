"""The CDR of ``ompn_node``'s ``~/boundary`` event, built with its constant part encoded once.

The boundary is the latency-critical output of the node (its observation -> ``~/boundary`` time is a
target in BENCHMARKS.md), so the bytes that never change for a node (encapsulation header, empty
frame id, status count, level, status name, message, hardware id, value count) are encoded at
configure and only the stamp and the seven values are written per event: about a sixth of the time
of the general :func:`ompn_ros.data.messages.encode_diagnostic_status`, whose bytes it reproduces
exactly (tested).  O(total value length) per event.
"""

from __future__ import annotations

import struct
from typing import Final

from ompn_ros.data.messages import encode_diagnostic_status, split_stamp
from ompn_ros.detect.online import BoundaryEvent

BOUNDARY_KEYS: Final = ("step", "subtask", "score", "level", "detected_at", "stamp_ns", "final")
"""The keys of a boundary status, in message order."""

_STAMP = struct.Struct("<iI")
_U32 = struct.Struct("<I")
_ZEROS = (b"", b"\0", b"\0\0", b"\0\0\0")


def boundary_values(event: BoundaryEvent) -> dict[str, object]:
    """The values of ``event`` as the boundary status carries them (see ``ompn_node``'s docstring)."""
    return {
        "step": event.step,
        "subtask": event.subtask,
        "score": f"{event.score:.6f}",
        "level": event.level,
        "detected_at": event.detected_at,
        "stamp_ns": event.stamp_ns,
        "final": event.final,
    }


class BoundaryEncoder:
    """Encoder of one node's boundary events.

    Args:
        status_name: the status name (``'<node>/subtask_boundary'``).
        message: the status message.
    """

    def __init__(self, status_name: str, message: str = "boundary") -> None:
        empty = encode_diagnostic_status(0, status_name, message, {})  # ends with the value count 0
        self._head = empty[:4]
        self._middle = empty[12:-4] + _U32.pack(len(BOUNDARY_KEYS))
        self._keys = [k.encode() + b"\0" for k in BOUNDARY_KEYS]

    def encode(self, stamp_ns: int, event: BoundaryEvent) -> bytes:
        """The CDR of the ``DiagnosticArray`` of ``event`` stamped ``stamp_ns``; raises
        :class:`~ompn_ros.data.messages.StampRangeError` when the stamp does not fit."""
        values = (
            str(event.step), str(event.subtask), f"{event.score:.6f}", str(event.level),
            str(event.detected_at), str(event.stamp_ns), "true" if event.final else "false",
        )  # fmt: skip
        parts = [self._head, _STAMP.pack(*split_stamp(stamp_ns)), self._middle]
        size = 8 + len(self._middle)  # body bytes so far (CDR aligns relative to the body)
        for key, text in zip(self._keys, values, strict=True):
            for data in (key, text.encode() + b"\0"):
                pad = -size % 4
                parts += (_ZEROS[pad], _U32.pack(len(data)), data)
                size += pad + 4 + len(data)
        return b"".join(parts)
