"""Causal boundary detectors on tiny hand-made score sequences."""

from __future__ import annotations

import numpy as np
import pytest

from ompn_ros.detect.errors import DetectorConfigError
from ompn_ros.detect.online import (
    BoundaryEvent,
    DetectorConfig,
    OnlineDetector,
    detect_sequence,
    expansion_level,
    expansion_score,
    expansion_scores,
    subtask_ends,
)


def paper_algorithm1(scores: np.ndarray, thr: float) -> list[int]:
    """The paper's Algorithm 1 without the last-K truncation (reference, written from the tex)."""
    preds, prev = [], False
    for t, s in enumerate(scores):
        curr = bool(s > thr)
        if prev and not curr:
            preds.append(t - 1)
        prev = curr
    preds.append(len(scores) - 1)
    return preds


def steps(events: list[BoundaryEvent]) -> list[int]:
    return [e.step for e in events]


def test_falling_edge_matches_algorithm1_on_random_sequences() -> None:
    rng = np.random.default_rng(0)
    for _ in range(200):
        scores = rng.random(rng.integers(1, 40))
        scores[0] = 0.0  # the detector forces step 0 low, like the authors' evaluation
        thr = float(rng.choice([0.3, 0.5, 0.7]))
        got = steps(detect_sequence(scores, DetectorConfig(high=thr)))
        ref = paper_algorithm1(scores, thr)
        # Algorithm 1 may append L-1 twice when the last step is a falling edge's t-1
        assert got == sorted(set(ref))


def test_falling_edge_commit_lag_is_one_step() -> None:
    scores = [0.0, 0.1, 0.9, 0.8, 0.1, 0.1, 0.95, 0.2, 0.1]
    events = detect_sequence(scores, DetectorConfig(high=0.5))
    assert steps(events) == [3, 6, 8]
    assert [e.detected_at for e in events] == [4, 7, 8]
    assert [e.subtask for e in events] == [0, 1, 2]
    assert events[0].score == pytest.approx(0.8)
    assert events[-1].final and not events[0].final


def test_hysteresis_ignores_chatter_inside_a_run() -> None:
    scores = [0.0, 0.8, 0.45, 0.8, 0.45, 0.2, 0.1]
    plain = detect_sequence(scores, DetectorConfig(high=0.5))
    hyst = detect_sequence(scores, DetectorConfig(high=0.5, low=0.3))
    assert steps(plain) == [1, 3, 6]
    assert steps(hyst) == [4, 6]
    # a dip that never reaches 'high' does not start a run
    assert steps(detect_sequence([0.0, 0.45, 0.2], DetectorConfig(high=0.5, low=0.3))) == [2]


def test_min_segment_length_drops_short_segments() -> None:
    scores = [0.0, 0.9, 0.1, 0.9, 0.1, 0.1, 0.1, 0.9, 0.1, 0.1]
    assert steps(detect_sequence(scores, DetectorConfig(high=0.5))) == [1, 3, 7, 9]
    events = detect_sequence(scores, DetectorConfig(high=0.5, min_segment_length=3))
    # 1 (segment of 2 steps) dropped; 3 closes [0..3] (4 steps); 7 closes [4..7]
    assert steps(events) == [3, 7, 9]
    assert [e.subtask for e in events] == [0, 1, 2]


def test_rising_edge_and_peak_modes_cut_the_delay() -> None:
    scores = [0.0, 0.2, 0.6, 0.9, 0.7, 0.6, 0.2, 0.1]
    fall = detect_sequence(scores, DetectorConfig(high=0.5))
    peak = detect_sequence(scores, DetectorConfig(high=0.5, mode="peak"))
    rise = detect_sequence(scores, DetectorConfig(high=0.5, mode="rising_edge"))
    assert [(e.step, e.detected_at) for e in fall[:1]] == [(5, 6)]
    assert [(e.step, e.detected_at) for e in peak[:1]] == [(3, 4)]
    assert [(e.step, e.detected_at) for e in rise[:1]] == [(2, 2)]
    for events in (fall, peak, rise):
        assert len(events) == 2 and events[-1].step == 7


def test_run_open_at_episode_end_is_closed_by_the_end() -> None:
    events = detect_sequence([0.0, 0.1, 0.9, 0.9], DetectorConfig(high=0.5))
    assert steps(events) == [3]
    assert events[0].final


def test_end_episode_with_done_step_excluded() -> None:
    det = OnlineDetector(DetectorConfig(high=0.5))
    # real steps 0..4, step 5 is the 'done' observation
    for s in [0.0, 0.1, 0.9, 0.1, 0.9]:
        det.update(s)
    falling = det.update(0.1)  # falling edge at the done step commits step 4 = T-1
    assert falling is not None and falling.step == 4
    end = det.end_episode(last_step=4)  # the last subtask's end is out: the episode end, no repeat
    assert end is not None and end.episode_end and end.final
    assert (end.step, end.subtask, end.score, end.level) == (4, 2, 0.0, 0)  # subtask: the count
    det.reset()
    for s in [0.0, 0.1, 0.1, 0.1]:
        det.update(s)
    final = det.end_episode(last_step=2)
    assert final is not None and (final.step, final.detected_at, final.subtask) == (2, 3, 0)
    with pytest.raises(RuntimeError):
        det.update(0.3)


def test_first_step_forced_low_unless_disabled() -> None:
    scores = [0.9, 0.1, 0.1]
    assert steps(detect_sequence(scores, DetectorConfig(high=0.5))) == [2]
    cfg = DetectorConfig(high=0.5, force_first_step_low=False)
    assert steps(detect_sequence(scores, cfg)) == [0, 2]


def test_event_carries_level_and_stamp_of_the_boundary_step() -> None:
    levels = np.array([1, 1, 3, 4, 1])
    stamps = np.array([10, 20, 30, 40, 50])
    events = detect_sequence([0.0, 0.1, 0.9, 0.8, 0.1], DetectorConfig(high=0.5), levels, stamps)
    assert (events[0].step, events[0].level, events[0].stamp_ns) == (3, 4, 40)


def test_expansion_score_weights_and_level() -> None:
    # p_hat = [pi_end, top, middle, bottom]
    assert expansion_score(np.array([0, 0, 0, 1.0])) == 0.0
    assert expansion_score(np.array([1.0, 0, 0, 0])) == 1.0
    assert expansion_score(np.array([0, 1.0, 0, 0])) == pytest.approx(2 / 3)
    assert expansion_score(np.array([0.5, 0, 0, 0.5])) == pytest.approx(0.5)
    assert expansion_level(np.array([0, 0, 0, 1.0])) == 1
    assert expansion_level(np.array([0, 1.0, 0, 0])) == 3
    assert expansion_level(np.array([0.7, 0.1, 0.1, 0.1])) == 4
    batch = np.array([[0, 0, 0, 1.0], [0, 1.0, 0, 0]])
    np.testing.assert_allclose(expansion_scores(batch), [0, 2 / 3])


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"high": 1.5}, "high"),
        ({"high": 0.5, "low": 0.6}, "low"),
        ({"min_segment_length": 0}, "min_segment_length"),
        ({"mode": "edge"}, "mode"),
        ({"offset": 11}, "offset"),
        ({"offset": -1}, "offset"),
        ({"offset": 1.5}, "offset"),
        ({"mode": "hsmm", "high": 0.5, "offset": 2}, "offset"),
    ],
)
def test_config_validation_names_the_parameter(kwargs: dict, name: str) -> None:
    with pytest.raises(DetectorConfigError, match=name):
        DetectorConfig(**kwargs)
    with pytest.raises(DetectorConfigError, match="unknown"):
        DetectorConfig.from_dict({"hihg": 0.3})


def test_offset_reports_the_boundary_earlier_but_publishes_it_at_the_same_step() -> None:
    scores = [0.0, 0.1, 0.1, 0.1, 0.9, 0.8, 0.1, 0.1, 0.1, 0.1]
    stamps = np.arange(10) * 10
    levels = np.arange(10)
    plain = detect_sequence(scores, DetectorConfig(high=0.5), levels, stamps)
    moved = detect_sequence(scores, DetectorConfig(high=0.5, offset=3), levels, stamps)
    assert [(e.step, e.detected_at) for e in plain] == [(5, 6), (9, 9)]
    assert [(e.step, e.detected_at) for e in moved] == [(2, 6), (9, 9)]  # the end is not moved
    # the moved boundary carries the score, level and stamp of the step it now names
    assert (moved[0].score, moved[0].level, moved[0].stamp_ns) == (0.1, 2, 20)


def test_offset_never_reaches_back_to_the_previous_boundary() -> None:
    scores = [0.0, 0.9, 0.1, 0.9, 0.1, 0.1]
    events = detect_sequence(scores, DetectorConfig(high=0.5, offset=5))
    # first run ends at 2 (boundary 1, moved to 0); second ends at 4 (boundary 3, moved to 1)
    assert [e.step for e in events] == [0, 1, 5]
    assert [e.subtask for e in events] == [0, 1, 2]


def test_offset_raised_inside_an_episode_names_the_oldest_step_kept() -> None:
    detector = OnlineDetector(DetectorConfig(high=0.5))
    for score in [0.0] + [0.1] * 10:
        assert detector.update(score) is None
    detector.configure(DetectorConfig(high=0.5, offset=10))
    assert detector.update(0.9) is None
    event = detector.update(0.1)  # the rule's boundary is 11; 1 is older than the 4 steps kept
    assert event is not None and event.step == 8 and event.detected_at == 12


def test_a_commit_whose_run_lasts_to_the_end_is_the_last_subtask_once() -> None:
    """Rising edge (Dial's shipped detector): the last press starts a run 1-4 steps before the episode
    ends; the episode's end closes the subtask that run ended, it adds no subtask of its own."""
    scores = [0.0, 0.1, 0.9, 0.8, 0.1, 0.1, 0.1, 0.1, 0.9, 0.9, 0.8]  # 2 presses, the last still on
    for mode in ("rising_edge", "peak"):
        events = detect_sequence(scores, DetectorConfig(high=0.5, mode=mode))
        ends = subtask_ends(events)
        assert [e.subtask for e in ends] == [0, 1], (mode, events)
        last = events[-1]
        assert last.episode_end and last.final and (last.step, last.subtask) == (10, 2)
        assert sum(e.final for e in events) == 1
    # the run ended before the episode did: the steps after it are a subtask of their own
    events = detect_sequence([*scores[:10], 0.1, 0.1, 0.1], DetectorConfig(high=0.5, mode="rising_edge"))
    assert [(e.step, e.subtask, e.final, e.episode_end) for e in events] == [
        (2, 0, False, False), (8, 1, False, False), (12, 2, True, False)]


def test_a_tail_shorter_than_min_segment_length_is_no_subtask() -> None:
    scores = [0.0, 0.1, 0.9, 0.1, 0.1, 0.1, 0.9, 0.1, 0.1]
    events = detect_sequence(scores, DetectorConfig(high=0.5, min_segment_length=3))
    assert [(e.step, e.subtask) for e in subtask_ends(events)] == [(2, 0), (6, 1)]
    assert events[-1].episode_end and events[-1].step == 8
    # without a boundary the episode is one subtask, however short
    events = detect_sequence([0.0, 0.1], DetectorConfig(high=0.5, min_segment_length=3))
    assert [(e.step, e.subtask, e.final, e.episode_end) for e in events] == [(1, 0, True, False)]
