"""The typed outputs' CDR (ompn_ros.data.messages): what the node publishes and annotated bags hold
decodes, with rclpy and with the rosbags typestore, to the fields it was built from."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from rclpy.serialization import deserialize_message

from ompn_interfaces.msg import SubtaskBoundary as RosBoundary
from ompn_interfaces.msg import SubtaskState as RosState
from ompn_ros.data.messages import (
    EPISODE_END,
    SUBTASK_END,
    SUBTASK_ID_UNKNOWN,
    StampRangeError,
    SubtaskBoundary,
    decode_subtask_boundary,
    encode_subtask_boundary,
    encode_subtask_state,
    join_stamp,
)
from ompn_ros.detect.online import BoundaryEvent


def _random_event(rng: np.random.Generator) -> BoundaryEvent:
    return BoundaryEvent(
        step=int(rng.integers(0, 10 ** int(rng.integers(1, 7)))), detected_at=int(rng.integers(0, 10**6)),
        subtask=int(rng.integers(0, 12)), score=float(rng.normal() * 10 ** int(rng.integers(-3, 4))),
        level=int(rng.integers(0, 5)), stamp_ns=int(rng.integers(0, 2**31 * 10**9)),
        final=bool(rng.random() < 0.2), episode_end=bool(rng.random() < 0.2),
    )  # fmt: skip


def test_rclpy_and_rosbags_decode_the_fields_of_many_events() -> None:
    rng = np.random.default_rng(3)
    for node, frame in (("/ompn_node", ""), ("/a/b/ompn_node", "base_link"), ("/x", "odd"), ("/n", "abcd")):
        for _ in range(200):
            event = _random_event(rng)
            sketch = rng.integers(0, 20, size=int(rng.integers(0, 6)))
            episode, decided = int(rng.integers(1, 10**5)), int(rng.integers(0, 2**31 * 10**9))
            raw = encode_subtask_boundary(SubtaskBoundary.from_event(
                event, node=node, episode=episode, frame_id=frame, sketch=sketch, decided_stamp_ns=decided))
            known = event.subtask < len(sketch) and not event.episode_end
            want_id = int(sketch[event.subtask]) if known else SUBTASK_ID_UNKNOWN
            msg = deserialize_message(raw, RosBoundary)
            got = (join_stamp(msg.header.stamp.sec, msg.header.stamp.nanosec), msg.header.frame_id, msg.node,
                   msg.episode, msg.step, msg.subtask, msg.subtask_id, msg.memory_level, msg.decided_step,
                   join_stamp(msg.decided_stamp.sec, msg.decided_stamp.nanosec), msg.final, msg.kind)
            assert got == (event.stamp_ns, frame, node, episode, event.step, event.subtask, want_id,
                           event.level, event.detected_at, decided, event.final, int(event.episode_end))
            assert msg.score == pytest.approx(event.score, rel=1e-6, abs=1e-30)
            fields = decode_subtask_boundary(raw)
            assert dataclasses.replace(fields, score=event.score) == SubtaskBoundary.from_event(
                event, node=node, episode=episode, frame_id=frame, sketch=sketch, decided_stamp_ns=decided)
            assert fields.score == np.float32(event.score)


def test_the_state_decodes_with_named_fields() -> None:
    for frame, n in (("", 2), ("abc", 3), ("base", 4)):
        pi = np.arange(1, n + 1, dtype=np.float32) / n
        msg = deserialize_message(encode_subtask_state(5_000_000_007, frame, 3, 41, pi, 1.5, 0.25), RosState)
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id) == (5, 7, frame)
        assert (msg.episode, msg.step, msg.expected_position, msg.pi_end) == (3, 41, 1.5, 0.25)
        assert np.array_equal(np.asarray(msg.pi), pi)


def test_a_stamp_out_of_range_raises() -> None:
    event = BoundaryEvent(step=1, detected_at=2, subtask=0, score=0.5, level=1, stamp_ns=0)
    with pytest.raises(StampRangeError):
        encode_subtask_boundary(SubtaskBoundary.from_event(event, node="/n", episode=1,
                                                           stamp_ns=2**31 * 10**9))


def test_the_episode_end_is_a_kind_of_its_own() -> None:
    """An episode end reports no subtask: kind EPISODE_END, no subtask id although the sketch has one,
    and the codec writes the kind after ``final`` (rclpy and the typestore decode it)."""
    a = BoundaryEvent(step=3, detected_at=4, subtask=0, score=0.5, level=1, stamp_ns=30)
    end = BoundaryEvent(step=9, detected_at=10, subtask=1, score=0.0, level=0, stamp_ns=90, final=True,
                        episode_end=True)
    sketch = np.array([7, 8])
    msgs = [SubtaskBoundary.from_event(e, node="/n", episode=1, sketch=sketch) for e in (a, end)]
    assert [(m.kind, m.subtask_id, m.final) for m in msgs] == [
        (SUBTASK_END, 7, False), (EPISODE_END, -1, True)]
    assert [decode_subtask_boundary(encode_subtask_boundary(m)) for m in msgs] == msgs
    ros = deserialize_message(encode_subtask_boundary(msgs[1]), RosBoundary)
    assert (ros.kind, ros.final, ros.step, ros.subtask) == (RosBoundary.EPISODE_END, True, 9, 1)
