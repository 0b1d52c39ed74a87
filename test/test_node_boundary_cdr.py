"""ompn_node's boundary encoder writes exactly the bytes of the general DiagnosticArray codec."""

from __future__ import annotations

import numpy as np
import pytest

from ompn_ros.data.messages import StampRangeError, deserialize, encode_diagnostic_status
from ompn_ros.detect.online import BoundaryEvent
from ompn_ros.nodes.ompn_node_boundary import BoundaryEncoder, boundary_values


def test_same_bytes_as_the_codec_for_many_events() -> None:
    rng = np.random.default_rng(3)
    names = ("ompn_node/subtask_boundary", "a/subtask_boundary", "node_with_a_longer_name_x/subtask_boundary")
    for name in names:
        enc = BoundaryEncoder(name)
        for _ in range(300):
            event = BoundaryEvent(
                step=int(rng.integers(0, 10 ** int(rng.integers(1, 7)))),
                detected_at=int(rng.integers(0, 10**6)), subtask=int(rng.integers(0, 12)),
                score=float(rng.normal() * 10 ** int(rng.integers(-3, 4))), level=int(rng.integers(-1, 4)),
                stamp_ns=int(rng.integers(0, 2**31 * 10**9)) if rng.random() < 0.8 else 0,
                final=bool(rng.random() < 0.2),
            )  # fmt: skip
            stamp = event.stamp_ns or int(rng.integers(1, 2**31 * 10**9))
            want = encode_diagnostic_status(stamp, name, "boundary", boundary_values(event))
            assert enc.encode(stamp, event) == want, event
    msg = deserialize(enc.encode(7, event), "diagnostic_msgs/msg/DiagnosticArray")
    assert [kv.key for kv in msg.status[0].values] == list(boundary_values(event))
    assert msg.status[0].values[-1].value == ("true" if event.final else "false")


def test_a_stamp_out_of_range_raises_like_the_codec() -> None:
    event = BoundaryEvent(step=1, detected_at=2, subtask=0, score=0.5, level=1, stamp_ns=0)
    with pytest.raises(StampRangeError):
        BoundaryEncoder("n/subtask_boundary").encode(2**31 * 10**9, event)
