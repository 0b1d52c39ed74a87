"""Annotated-bag building blocks without a bag: segment labels, ~/pi rows, boundary bytes, topics."""

from __future__ import annotations

import numpy as np
import pytest

from ompn_ros.app.annotate import boundary_message, episode_messages, output_topics, pi_rows, segment_labels
from ompn_ros.app.errors import AnnotateError
from ompn_ros.data import messages as m
from ompn_ros.data.messages import SubtaskBoundary, decode_subtask_boundary
from ompn_ros.detect.online import BoundaryEvent
from ompn_ros.segmenter import ReplayResult


def _event(step: int, detected_at: int, subtask: int, final: bool = False) -> BoundaryEvent:
    return BoundaryEvent(step=step, detected_at=detected_at, subtask=subtask, score=0.25, level=2,
                         stamp_ns=0, final=final)


EVENTS = [_event(2, 4, 0), _event(5, 6, 1), _event(7, 7, 2, final=True)]


def _result(steps: int, n: int = 2) -> ReplayResult:
    rng = np.random.default_rng(0)
    pi = rng.dirichlet(np.ones(n), size=steps)
    pi_end = rng.uniform(0, 0.2, size=steps)
    return ReplayResult(p_hat=np.zeros((steps, n + 1)), pi=pi, pi_end=pi_end,
                        expected_position=pi @ np.arange(1, n + 1), scores=np.zeros(steps),
                        boundaries=list(EVENTS))


def test_segment_labels_boundary_and_causal() -> None:
    assert segment_labels(EVENTS, 8).tolist() == [0, 0, 0, 1, 1, 1, 2, 2]
    # causally the first boundary (step 2) is known only at step 4
    assert segment_labels(EVENTS, 8, "causal").tolist() == [0, 0, 0, 0, 1, 1, 2, 2]
    assert segment_labels([], 3).tolist() == [0, 0, 0]
    with pytest.raises(AnnotateError, match="labels must be"):
        segment_labels(EVENTS, 8, "later")  # type: ignore[arg-type]


def test_pi_rows_match_the_node_layout() -> None:
    result = _result(8)
    rows = pi_rows(result)
    assert rows.shape == (8, 4) and rows.dtype == np.float32
    np.testing.assert_array_equal(rows[:, :2], result.pi.astype(np.float32))
    np.testing.assert_array_equal(rows[:, 2], result.expected_position.astype(np.float32))
    np.testing.assert_array_equal(rows[:, 3], result.pi_end.astype(np.float32))


def test_boundary_message_decodes_to_the_event() -> None:
    raw = boundary_message(EVENTS[1], 1_500_000_123, "/ompn_node", 4, np.array([7, 9]), 1_600_000_000)
    assert decode_subtask_boundary(raw) == SubtaskBoundary(
        stamp_ns=1_500_000_123, frame_id="", node="/ompn_node", episode=4, step=5, subtask=1, subtask_id=9,
        score=0.25, memory_level=2, decided_step=6, decided_stamp_ns=1_600_000_000, final=False)
    unknown = decode_subtask_boundary(boundary_message(EVENTS[2], 1, "/n", 1, np.array([7, 9]), 1))
    assert (unknown.subtask_id, unknown.final) == (-1, True)  # no sketch entry for the third subtask


def test_episode_messages_order_and_stamps() -> None:
    stamps = np.arange(9, dtype=np.int64) * 100 + 1000  # T + 1 observations
    topics, node = output_topics("/ompn_node")
    msgs = episode_messages(stamps, _result(8), 0, topics, node)
    assert [(x.stamp, x.topic) for x in msgs if x.topic == topics["boundary"]] == [
        (1400, "/ompn_node/boundary"), (1600, "/ompn_node/boundary"), (1700, "/ompn_node/boundary")]
    at_1400 = [x.topic for x in msgs if x.stamp == 1400]
    assert at_1400 == [topics["boundary"], topics["state"], topics["pi"], topics["segment"]]
    decoded = [decode_subtask_boundary(x.data) for x in msgs if x.topic == topics["boundary"]]
    assert [(b.episode, b.step, b.decided_stamp_ns, b.final) for b in decoded] == [
        (1, 2, 1400, False), (1, 5, 1600, False), (1, 7, 1700, True)]
    segs = [m.parse_int32(x.data) for x in msgs if x.topic == topics["segment"]]
    assert segs == segment_labels(EVENTS, 8).tolist()
    with pytest.raises(AnnotateError, match="episode #3: 5 observation stamps for 8 replayed steps"):
        episode_messages(stamps[:5], _result(8), 3, topics, node)


def test_output_topics_and_bad_namespace() -> None:
    topics, node = output_topics("robot/ompn")
    assert topics == {"state": "/robot/ompn/state", "pi": "/robot/ompn/pi", "segment": "/robot/ompn/segment",
                      "boundary": "/robot/ompn/boundary"}
    assert node == "/robot/ompn"
    for bad in ("/", "", "/a b", "/1node"):
        with pytest.raises(AnnotateError, match="namespace must be a ROS name"):
            output_topics(bad)
