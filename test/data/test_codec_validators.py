"""The one sketch validator, the stamp classifier and the detector's end-of-episode fallback."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ompn_ros.detect.online import DetectorConfig, OnlineDetector
from ompn_ros.stream.clock import classify_stamp
from ompn_ros.validate import SketchError, validate_observation, validate_sketch

S = 1_000_000_000


@pytest.mark.parametrize(
    ("sketch", "kwargs", "match"),
    [([], {}, "non-empty"), ([[1, 2]], {}, "1-D"), ([1.5, 2.0], {}, "integers"), ([True], {}, "integers"),
     ([7, 9], {"vocab": 5}, r"outside the vocabulary 0\.\.4"), ([-1, 2], {}, "outside"),
     ([2**40], {}, "outside"), ([1, 2, 3], {"length": 4}, "4 ids"),
     ([1, 1, 2], {"no_immediate_repeat": True}, "repeat"), (["a"], {}, "integers")],
)  # fmt: skip
def test_sketch_validator_names_what_is_wrong(sketch: list, kwargs: dict, match: str) -> None:
    with pytest.raises(SketchError, match=match):
        validate_sketch(sketch, **kwargs)


def test_sketch_validator_accepts_and_normalises() -> None:
    out = validate_sketch(np.array([3, 0, 3], dtype=np.int32), vocab=4, length=3, no_immediate_repeat=True)
    assert out.dtype == np.int64 and out.tolist() == [3, 0, 3]


def test_observation_validator_is_the_segmenter_rule() -> None:
    arr = np.arange(4, dtype=np.float32)
    assert validate_observation(arr, 4) is arr  # the hot path converts nothing
    with pytest.raises(ValueError, match="NaN/Inf value \\(first at index 1\\)"):
        validate_observation([0.0, float("inf"), 1.0, 2.0], 4)


@pytest.mark.parametrize(
    ("stamp", "last", "now", "verdict"),
    [(5 * S, 4 * S, 5 * S, "ok"), (3 * S, 4 * S, 5 * S, "ok"), (2 * S, 4 * S, 5 * S, "jump_back"),
     (70 * S, None, 5 * S, "future"), (70 * S, None, 0, "ok"), (10**18, 4 * S, 5 * S, "future")],
)  # fmt: skip
def test_classify_stamp(stamp: int, last: int | None, now: int, verdict: str) -> None:
    assert classify_stamp(stamp, last, now, jump_back_ns=S + S // 2, max_lead_ns=60 * S) == verdict


@settings(max_examples=200, deadline=None)
@given(poison=st.lists(st.integers(-(2**62), 2**62), max_size=6), start=st.integers(0, 10**12))
def test_no_stamp_sequence_wedges_a_stream(poison: list[int], start: int) -> None:
    """After any stamps, a 25 Hz stream with current stamps is accepted once it is more than
    ``jump_back_ns`` past them (at worst a small step back is rejected until then): never a wedge."""
    last: int | None = None
    now = start + 10 * S

    def offer(stamp: int) -> bool:
        nonlocal last
        verdict = classify_stamp(stamp, last, now, jump_back_ns=S, max_lead_ns=60 * S)
        ok = verdict == "jump_back" or (verdict == "ok" and (last is None or stamp > last))
        last = stamp if ok else last  # what StreamingSegmenter keeps (a jump starts a new episode)
        return ok

    for stamp in poison:
        offer(stamp)
    accepted = [offer(start + k * 40_000_000) for k in range(60)]
    assert all(accepted[26:])  # 26 x 40 ms > the 1 s window


def test_end_episode_with_a_step_too_far_back_closes_at_the_last_step_seen() -> None:
    det = OnlineDetector(DetectorConfig(high=0.99))
    for t in range(10):
        det.update(0.1, level=2, stamp_ns=(t + 1) * 1000)
    event = det.end_episode(0)
    assert event is not None and event.step == 9 and event.stamp_ns == 10_000
    assert np.isfinite(event.score) and event.final
