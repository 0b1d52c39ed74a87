"""The duration decoder over the boundary head (mode 'head_hsmm', ``ompn_ros.detect.head_duration``): its
evidence, its stream against its batch decoding, its errors, its file, and the tuning of its threshold."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from ompn_ros.detect.duration import DurationModel, fit_duration_model
from ompn_ros.detect.duration_tuning import calibrate_head_duration
from ompn_ros.detect.errors import BoundaryHeadError, DetectorSettingsError, DurationModelError
from ompn_ros.detect.factory import make_detector
from ompn_ros.detect.head_duration import HeadDurationDecoder, HeadDurationDetector, decode_head_duration
from ompn_ros.detect.online import DetectorConfig
from ompn_ros.detect.settings import DetectorSettings, load_detector_settings, save_detector_settings
from ompn_ros.metrics import alignment_accuracy, labels_from_boundaries

pytest.importorskip("torch")
from toy_heads import _toy_head

LENGTHS = (8, 6, 10)
"""The segments of every training episode of the duration model: K = 3, 24 steps."""


def _cfg(lag: int = 1, theta: float = 0.5) -> DetectorConfig:
    return DetectorConfig(mode="head_hsmm", high=theta, lag=lag)


def _model(jitter: int = 2, seed: int = 0) -> DurationModel:
    rng = np.random.default_rng(seed)
    scores, bounds = [], []
    for _ in range(40):
        lengths = [max(2, n + int(rng.integers(-jitter, jitter + 1))) for n in LENGTHS]
        b = np.cumsum(lengths) - 1
        scores.append(rng.uniform(0, 1, b[-1] + 1))
        bounds.append(b)
    return fit_duration_model(scores, bounds)


def _sharp_rows(length: int, bounds: list[int], lags: int = 5, sure: float = 0.99) -> np.ndarray:
    """Rows whose every lag says exactly which steps are boundaries."""
    rows = np.full((length, lags), 1 - sure)
    for b in bounds:
        for j in range(lags):
            if b + j < length:
                rows[b + j, j] = sure
    return rows


def test_the_boundary_share_is_the_prior_of_a_boundary_step() -> None:
    model = _model(jitter=0)
    assert model.boundary_share == pytest.approx(2 / sum(LENGTHS), rel=0.02)


@pytest.mark.parametrize("lag", [0, 1, 3])
def test_sure_evidence_gives_the_true_boundaries_lag_plus_one_steps_later(lag: int) -> None:
    bounds = [7, 13]
    events = decode_head_duration(_model(), _sharp_rows(24, bounds), _cfg(lag, 0.9))
    assert [e.step for e in events] == [*bounds, 23] and events[-1].final
    assert [e.detected_at for e in events[:-1]] == [b + lag + 1 for b in bounds]


def test_each_step_is_weighed_by_the_newest_row_that_has_seen_it() -> None:
    """A boundary the lag-0 column announces and the later lags withdraw is not published; one that
    only the later lags see is."""
    rows = _sharp_rows(24, [7, 13])
    rows[10, 0] = 0.99  # step 10 at lag 0 only: withdrawn by the rows after it
    rows[13, 0] = 0.01  # step 13 is seen from lag 1 on
    for lag in (1, 2):
        assert [e.step for e in decode_head_duration(_model(), rows, _cfg(lag, 0.9))] == [7, 13, 23]
    early = [e.step for e in decode_head_duration(_model(), rows, _cfg(0, 0.5))]
    assert 10 in early  # at lag 0 the decoder has only the row that announces it


def test_the_stream_equals_the_decoding_of_the_whole_episode() -> None:
    rng = np.random.default_rng(5)
    head = _toy_head(window=3, features=4, lags=5)
    noisy = tuple((w + rng.normal(0, 0.4, w.shape), b) for w, b in head.weights)
    head = dataclasses.replace(head, weights=noisy)
    model, published = _model(), 0
    for trial in range(6):
        outs = rng.normal(0, 2, (30, 4))
        config = _cfg(trial % 3, (0.3, 0.7)[trial % 2])
        want = decode_head_duration(model, head.probabilities(outs), config)
        detector = HeadDurationDetector(model, head, config)
        got = []
        for x in outs:
            detector.feed(x)
            got += [e for e in [detector.update(0.0)] if e is not None]
        got += detector.close()
        assert [(e.step, e.detected_at, e.final) for e in got] == [
            (e.step, e.detected_at, e.final) for e in want]
        published += len(want) - 1
    assert published > 4


def test_a_done_observation_after_the_last_step_is_never_read() -> None:
    head = _toy_head(window=2, features=2, lags=4)
    model = _model()
    outs = np.random.default_rng(2).normal(0, 1, (24, 2))
    runs = []
    for done in (None, np.array([50.0, -50.0])):
        detector = HeadDurationDetector(model, head, _cfg(2, 0.5))
        for x in outs if done is None else [*outs, done]:
            detector.feed(x)
            detector.update(0.0)
        runs.append([(e.step, e.final) for e in detector.close(last_step=23)])
    assert runs[0] == runs[1] and runs[0][-1] == (23, True)


def test_what_the_mode_needs_is_named_when_it_is_missing(tmp_path: Path) -> None:
    head, model = _toy_head(window=2, features=3, lags=4), _model()
    with pytest.raises(BoundaryHeadError, match="'head_hsmm' needs a boundary head"):
        make_detector(_cfg(), model, None)
    with pytest.raises(DurationModelError, match="'head_hsmm' needs a duration model"):
        make_detector(_cfg(), None, head)
    assert isinstance(make_detector(_cfg(), model, head), HeadDurationDetector)
    with pytest.raises(DetectorSettingsError, match="'head_hsmm' needs a 'boundary_head'"):
        DetectorSettings(online=_cfg(), duration_model=model)
    with pytest.raises(DetectorSettingsError, match="'head_hsmm' needs a 'duration_model'"):
        DetectorSettings(online=_cfg(), head=head)
    decoder = HeadDurationDecoder(model, 3, 1, 0.5)
    with pytest.raises(BoundaryHeadError, match="use take"):
        decoder.update(0.0)
    with pytest.raises(BoundaryHeadError, match="4 lags"):
        decoder.take(np.zeros(5), 0.0)
    detector = HeadDurationDetector(model, head, _cfg())
    with pytest.raises(BoundaryHeadError, match="feed"):
        detector.update(0.0)
    with pytest.raises(DurationModelError, match="cannot become"):
        detector.configure(DetectorConfig(mode="hsmm", high=0.5, lag=1))


def test_the_mode_travels_with_the_detector_settings(tmp_path: Path) -> None:
    settings = DetectorSettings(online=_cfg(1, 0.95), duration_model=_model(), head=_toy_head(2, 3, 4),
                                provenance="a test")
    save_detector_settings(tmp_path, settings)
    loaded = load_detector_settings(tmp_path)
    assert loaded == settings and loaded.online.mode == "head_hsmm"
    assert "mode=head_hsmm lag=1 threshold=0.95" in loaded.describe()


def test_the_threshold_is_tuned_for_alignment_within_the_delay_budget() -> None:
    rng = np.random.default_rng(9)
    model, rows, bounds = _model(), [], []
    for _ in range(12):
        lengths = [max(2, n + int(rng.integers(-2, 3))) for n in LENGTHS]
        b = np.cumsum(lengths) - 1
        sure = _sharp_rows(int(b[-1]) + 1, list(b[:-1]), sure=0.8)
        rows.append(np.clip(sure + rng.normal(0, 0.25, sure.shape), 0.01, 0.99))
        bounds.append(b)
    grid = (0.2, 0.5, 0.9, 0.99)
    for budget in (None, 2.5):
        tuned = calibrate_head_duration(model, rows, bounds, 1, "align", grid, max_delay=budget)
        assert tuned.config.mode == "head_hsmm" and tuned.config.lag == 1 and tuned.config.high in grid
        events = [decode_head_duration(model, r, tuned.config) for r in rows]
        labels = [labels_from_boundaries(b, len(r)) for b, r in zip(bounds, rows, strict=True)]
        preds = [[e.step for e in evs] for evs in events]
        assert tuned.metrics["align"] == pytest.approx(alignment_accuracy(preds, labels, "strict"))
        delays = [e.detected_at - e.step for evs in events for e in evs if not e.final]
        assert budget is None or np.mean(delays) <= budget
        for theta in grid:  # no threshold within the budget aligns better
            other = [decode_head_duration(model, r, _cfg(1, theta)) for r in rows]
            late = [e.detected_at - e.step for evs in other for e in evs if not e.final]
            if budget is None or np.mean(late) <= budget:
                got = alignment_accuracy([[e.step for e in evs] for evs in other], labels, "strict")
                assert got <= tuned.metrics["align"] + 1e-12
