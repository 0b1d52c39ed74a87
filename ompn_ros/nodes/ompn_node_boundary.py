"""The CDR of ``ompn_node``'s ``~/boundary`` event, an ``ompn_interfaces/msg/SubtaskBoundary``.

Built by :mod:`ompn_ros.data.interfaces` (the node's name and frame id encoded once), which
``ompn_segment --annotate`` uses for annotated bags too.
"""

from __future__ import annotations

import numpy as np

from ompn_ros.data.interfaces import SubtaskBoundary, encode_subtask_boundary
from ompn_ros.detect.online import BoundaryEvent


class BoundaryEncoder:
    """CDR of one node's ``SubtaskBoundary`` events.

    Args:
        node: the node's fully qualified name (the message's ``node``).
    """

    def __init__(self, node: str) -> None:
        self.node = node

    def encode(self, event: BoundaryEvent, *, stamp_ns: int, episode: int, frame_id: str,
               sketch: np.ndarray | None, decided_stamp_ns: int) -> bytes:
        """The CDR of ``event``; raises :class:`~ompn_ros.data.messages.StampRangeError` when a stamp
        does not fit."""
        return encode_subtask_boundary(SubtaskBoundary.from_event(
            event, node=self.node, episode=episode, frame_id=frame_id, sketch=sketch,
            decided_stamp_ns=decided_stamp_ns, stamp_ns=stamp_ns))
