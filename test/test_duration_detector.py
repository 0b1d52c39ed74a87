"""The fixed-lag duration (HSMM) decoder: its window likelihood against brute force, the lag, the cap at
K − 1 inner boundaries, the episode end, a planted false alarm it rejects, and its errors."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from ompn_ros.detect.duration import (
    DurationDetector,
    DurationModel,
    DurationModelError,
    _window,
    decode_episode,
    fit_duration_model,
    make_detector,
)
from ompn_ros.detect.online import DetectorConfig, DetectorConfigError, OnlineDetector, detect_sequence
from ompn_ros.detect.settings import DetectorSettings, DetectorSettingsError
from ompn_ros.metrics import alignment_accuracy, labels_from_boundaries

K, LENGTHS = 4, (5, 6, 7)


def planted(seed: int, n: int, false_alarm: float = 0.0) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """``n`` episodes of K segments of 5–7 steps: score 0.7 ± 0.05 at a segment's last step, 0.1 ± 0.05
    elsewhere; with probability ``false_alarm`` a spurious 0.55 two steps after an inner boundary."""
    rng = np.random.default_rng(seed)
    scores, bounds = [], []
    for _ in range(n):
        ends = np.cumsum(rng.choice(LENGTHS, size=K)) - 1
        s = np.clip(rng.normal(0.1, 0.05, ends[-1] + 1), 0.0, 1.0)
        s[ends[:-1]] = np.clip(rng.normal(0.7, 0.05, K - 1), 0.0, 1.0)
        for b in ends[:-1]:
            if rng.random() < false_alarm:
                s[b + 2] = 0.55
        s[0] = 0.0
        scores.append(s)
        bounds.append(ends.astype(np.int64))
    return scores, bounds


@pytest.fixture(scope="module")
def model() -> DurationModel:
    return fit_duration_model(*planted(0, 300))


def brute_window(model: DurationModel, bins: list[int], j: int, u: int, final: bool) -> float:
    """log P(window) summed over every end/continue path (the definition the kernel implements)."""
    h, f0, f1, k = model.hazard, model.f0, model.f1, model.subtasks
    total = 0.0
    for path in itertools.product((False, True), repeat=len(bins)):  # True: the step ends its segment
        seg, dur, p = j, u, 1.0
        for i, (ends, b) in enumerate(zip(path, bins)):
            hz = h[seg, min(dur, h.shape[1] - 1)]
            last = final and i == len(bins) - 1
            if last:
                p *= hz * f1[b] if ends and seg == k - 1 else 0.0
            elif seg == k - 1:
                p *= 0.0 if ends else f0[b]
                dur += 1
            elif ends:
                p, seg, dur = p * hz * f1[b], seg + 1, 1
            else:
                p, dur = p * (1 - hz) * f0[b], dur + 1
        total += p
    return math.log(total) if total > 0 else -math.inf


@pytest.mark.parametrize(("j", "u", "final"), [(0, 1, False), (1, 4, False), (2, 3, True), (3, 2, False),
                                               (2, 6, False), (1, 2, True)])
def test_window_likelihood_equals_the_sum_over_every_path(model: DurationModel, j: int, u: int, final: bool):
    rng = np.random.default_rng(j * 10 + u)
    bins = [int(b) for b in rng.integers(0, model.bins, size=5)]
    got = _window(*model.logs, np.array(bins, dtype=np.int64), j, u, final)
    want = brute_window(model, bins, j, u, final)
    if math.isinf(want):
        assert got < -1e200
    else:
        assert got == pytest.approx(want, rel=1e-9)


def test_fit_recovers_the_count_and_lengths(model: DurationModel):
    assert model.subtasks == K and model.episodes == 300
    length_pmf = model.hazard[0, 1:] * np.cumprod(np.r_[1.0, 1.0 - model.hazard[0, 1:-1]])
    assert set(np.argsort(length_pmf)[-3:] + 1) == set(LENGTHS)  # the three most likely lengths
    assert model.f1[model.bin_of(0.7)] > 20 * model.f1[model.bin_of(0.1)]
    assert model.f0[model.bin_of(0.1)] > 20 * model.f0[model.bin_of(0.7)]


def test_a_false_alarm_after_a_boundary_is_rejected_where_a_threshold_fires(model: DurationModel):
    scores, bounds = planted(7, 60, false_alarm=1.0)
    labels = [labels_from_boundaries(b, len(s)) for s, b in zip(scores, bounds)]
    threshold = [np.array([e.step for e in detect_sequence(s, DetectorConfig(high=0.4))]) for s in scores]
    decoded = [decode_episode(model, s, lag=2, threshold=0.5) for s in scores]
    assert alignment_accuracy(decoded, labels, "strict") == 1.0
    assert alignment_accuracy(threshold, labels, "strict") < 0.9


def test_lag_and_cap_at_k_minus_one_inner_boundaries(model: DurationModel):
    scores, bounds = planted(3, 20)
    for s, b in zip(scores, bounds):
        s = s.copy()
        s[-2] = 0.9  # a fifth "boundary" inside the last segment is never published
        detector = DurationDetector(model, lag=3, threshold=0.5)
        inner = [e for e in (detector.update(float(x)) for x in s) if e is not None]
        closing = detector.close()
        assert [e.step for e in inner + closing] == b.tolist()
        assert all(e.detected_at - e.step == 3 for e in inner)
        assert closing[-1].final and closing[-1].step == len(s) - 1
        assert [e.subtask for e in inner + closing] == list(range(K))


def test_the_episode_end_decides_the_boundaries_still_inside_the_lag(model: DurationModel):
    scores, bounds = planted(4, 1)
    s, b = scores[0], bounds[0]
    detector = DurationDetector(model, lag=8, threshold=0.5)
    seen = [e for e in (detector.update(float(x)) for x in s) if e is not None]
    late = detector.close()
    assert [e.step for e in seen + late] == b.tolist()
    assert [e for e in late if not e.final] and all(e.detected_at == len(s) - 1 for e in late)


def test_model_round_trip_and_settings(model: DurationModel):
    again = DurationModel.from_dict(model.to_dict())
    assert again.subtasks == model.subtasks and np.allclose(again.hazard, model.hazard, atol=1e-7)
    config = DetectorConfig(mode="hsmm", high=0.5, lag=2)
    settings = DetectorSettings(online=config, duration_model=model)
    back = DetectorSettings.from_dict(settings.to_dict())
    assert back.online == config and back.duration_model is not None
    assert "mode=hsmm lag=2" in back.describe()
    with pytest.raises(DetectorSettingsError, match="needs a 'duration_model'"):
        DetectorSettings(online=config)
    bad = settings.to_dict()
    bad["duration_model"]["hazard"][0][1] = 1.5
    with pytest.raises(DetectorSettingsError, match=r"duration_model.*strictly between 0 and 1"):
        DetectorSettings.from_dict(bad, origin="x/detector.json")


def test_make_detector_and_bad_parameters(model: DurationModel):
    assert isinstance(make_detector(DetectorConfig(high=0.3), None), OnlineDetector)
    assert make_detector(DetectorConfig(mode="hsmm", high=0.3, lag=4), model).lag == 4  # type: ignore[union-attr]
    with pytest.raises(DurationModelError, match="needs a duration model"):
        make_detector(DetectorConfig(mode="hsmm", high=0.3), None)
    with pytest.raises(DetectorConfigError, match="'lag' must be an integer in \\[0, 10\\]"):
        DetectorConfig(mode="hsmm", high=0.3, lag=11)
    with pytest.raises(DetectorConfigError, match="probability in \\(0, 1\\)"):
        DetectorConfig(mode="hsmm", high=1.0)
    with pytest.raises(DurationModelError, match="not sorted segment ends"):
        fit_duration_model([np.zeros(5)], [np.array([3, 2, 4])])
    with pytest.raises(DurationModelError, match="as many boundary arrays"):
        fit_duration_model([np.zeros(5)], [])
