"""The duration (HSMM) decoder: its span posterior and closing path against brute force, the lag, a
boundary published later than its lag, the cap at K − 1 inner boundaries, the episode end, a planted
false alarm it rejects, and its errors."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.detect.duration import (
    DurationDetector,
    DurationModel,
    _closing_path,
    _end_posterior,
    decode_episode,
    fit_duration_model,
)
from ompn_ros.detect.duration_tuning import DURATION_THRESHOLDS, calibrate_duration
from ompn_ros.detect.errors import (
    CalibrationError,
    DetectorConfigError,
    DetectorSettingsError,
    DurationModelError,
)
from ompn_ros.detect.factory import make_detector
from ompn_ros.detect.online import DetectorConfig, OnlineDetector, detect_sequence, run_detector
from ompn_ros.detect.settings import DetectorSettings, load_detector_settings
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


@pytest.fixture(scope="module")
def random_model() -> DurationModel:
    """Random hazards and score histograms (6 bins), so that every path term matters."""
    rng = np.random.default_rng(11)
    return DurationModel(subtasks=K, hazard=rng.uniform(0.05, 0.95, size=(K, 9)),
                         f0=rng.dirichlet(np.ones(6)),
                         f1=rng.dirichlet(np.ones(6)))


def length_pmf(model: DurationModel, i: int, u: int, running: bool) -> float:
    """P(L_i = u), or P(L_i >= u) when ``running``, from the hazards (the definition)."""
    h = model.hazard[i]
    top = h.size - 1
    survive = math.prod(1.0 - h[min(v, top)] for v in range(1, u))
    return survive if running else survive * h[min(u, top)]


def path_probability(model: DurationModel, bins: list[int], j: int, ends: tuple[int, ...], final: bool,
                     u0: int = 0) -> float:
    """P(scores, segment ends at ``ends``) for a span in which segment ``j`` had lasted ``u0`` steps before
    index 0; with ``final`` the last index ends the episode (no score term there) and closes the last
    segment."""
    p, start, seg = 1.0, -u0, j
    for i, b in enumerate(bins):
        last = final and i == len(bins) - 1
        if i in ends or last:
            p *= length_pmf(model, seg, i - start + 1, running=False) * (1.0 if last else model.f1[b])
            start, seg = i + 1, seg + 1
        else:
            p *= model.f0[b]
    if not final:
        p *= length_pmf(model, seg, len(bins) - start + 1, running=True)
    return p


def brute_posterior(model: DurationModel, bins: list[int], j: int, u0: int, first: int, last: int
                    ) -> tuple[float, int]:
    """P(segment j ended in [first, last]) and its most probable end there, summing every path."""
    n, k = len(bins), model.subtasks
    by_end: dict[int, float] = {}
    total = 0.0
    for count in range(0, k - j):  # segments j … K - 2 may end inside the span
        for ends in itertools.combinations(range(n), count):
            if ends and ends[0] < first:
                continue
            p = path_probability(model, bins, j, ends, final=False, u0=u0)
            total += p
            if ends:
                by_end[ends[0]] = by_end.get(ends[0], 0.0) + p
    inside = {e: p for e, p in by_end.items() if e <= last}
    best = max(inside, key=lambda e: inside[e]) if inside else -1
    return sum(inside.values()) / total, best


SPANS = [(0, 0, 1, 5), (1, 0, 0, 3), (2, 0, 0, 6), (0, 0, 1, 0), (1, 3, 0, 6), (2, 70, 0, 2), (0, 90, 0, 4),
         (1, 61, 0, 6), (0, 62, 0, 3)]  # u0 61 / 62: the lengths cross the end of the tables inside the span


@pytest.mark.parametrize(("j", "u0", "first", "last"), SPANS)
def test_span_posterior_equals_the_sum_over_every_path(random_model: DurationModel, j: int, u0: int,
                                                       first: int, last: int):
    model = random_model
    rng = np.random.default_rng(j * 10 + last)
    bins = [int(b) for b in rng.integers(0, model.bins, size=7)]
    log_p, log_s = model.lengths
    got, end = _end_posterior(log_p, log_s, model.logs[2], model.logs[3], np.array(bins, dtype=np.int64),
                              j, u0, first, last)
    want, want_end = brute_posterior(model, bins, j, u0, first, last)
    assert got == pytest.approx(want, rel=1e-9, abs=1e-300)
    assert end == want_end


CLOSINGS = [(0, 0, 1, 9), (0, 0, 0, 8), (1, 0, 0, 9), (1, 2, 1, 7), (2, 80, 0, 8), (3, 0, 0, 4), (0, 0, 1, 3),
            (0, 60, 0, 9)]


@pytest.mark.parametrize(("j", "u0", "first", "size"), CLOSINGS)
def test_closing_path_is_the_most_probable_segmentation(random_model: DurationModel, j: int, u0: int,
                                                        first: int, size: int):
    model = random_model
    rng = np.random.default_rng(j + size)
    bins = [int(b) for b in rng.integers(0, model.bins, size=size)]
    got = _closing_path(*model.lengths, model.logs[2], model.logs[3], np.array(bins, dtype=np.int64), j, u0,
                        first)
    segs = min(model.subtasks - j, size - first)
    candidates = [c for c in itertools.combinations(range(first, size - 1), segs - 1)]
    best = max(candidates, key=lambda c: path_probability(model, bins, j, c, final=True, u0=u0))
    assert got.tolist() == [*best, size - 1]


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
        assert all(e.detected_at - e.step >= 4 for e in inner)  # the lag, after the step is decided
        assert np.mean([e.detected_at - e.step for e in inner]) < 4.5  # clear peaks: published at once
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


# Expansion scores of three Craft episodes (makebed) replayed through the shipped checkpoint; live, the
# done step (score 0.95 here) made the decoder publish the last real step as an inner boundary.
RECORDED = [
    [0.5, 0.13, 0.01, 0.01, 0.01, 0.0, 0.0, 0.0, 0.48, 0.09, 0.31, 0.07, 0.01, 0.01, 0.0, 0.32, 0.0, 0.02,
     0.36, 0.4, 0.01, 0.02, 0.48],
    [0.5, 0.44, 0.0, 0.3, 0.03, 0.01, 0.01, 0.02, 0.02, 0.01, 0.12, 0.0, 0.0, 0.01, 0.0, 0.01, 0.49],
    [0.5, 0.01, 0.01, 0.07, 0.49, 0.0, 0.0, 0.01, 0.01, 0.01, 0.02, 0.48, 0.05, 0.01, 0.13, 0.07, 0.11, 0.01,
     0.0, 0.0, 0.01, 0.0, 0.0, 0.03, 0.02, 0.48],
]


@pytest.mark.parametrize("scores", RECORDED)
def test_the_done_step_after_the_last_action_never_enters_the_decoder(scores: list[float]):
    """Live, an episode's last observation (the 'done' step, a high score: the memory expands from the
    top) arrives before the end marker closes the episode at the step before it.  The boundaries are
    those of the same episode replayed without that observation, K of them."""
    settings = load_detector_settings(shipped_checkpoint("craft"))
    assert settings.duration_model is not None
    replayed = run_detector(make_detector(settings.online, settings.duration_model), np.array(scores))
    live = make_detector(settings.online, settings.duration_model)
    events = [e for e in (live.update(x) for x in [*scores, 0.95]) if e is not None]
    events += live.close(len(scores) - 1)
    assert [(e.step, e.subtask, e.final) for e in events] == [(e.step, e.subtask, e.final) for e in replayed]
    assert len(events) == settings.duration_model.subtasks and events[-1].final
    assert events[-1].step == len(scores) - 1


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


def test_a_boundary_not_published_at_its_lag_is_published_later(model: DurationModel):
    """A first subtask shorter than any fitted one, ending on a weak peak: at lag 0 its end is not yet
    likely enough; the low steps after it make it so, and that same step is published then."""
    s = np.full(22, 0.1)
    s[0] = 0.0
    s[[9, 15]] = 0.7  # segments of 4, 6, 6 and 6 steps
    s[3] = 0.5
    events = run_detector(DurationDetector(model, lag=0, threshold=0.9), s)
    assert [e.step for e in events] == [3, 9, 15, 21]
    assert events[0].detected_at == 8 and [e.detected_at for e in events[1:3]] == [10, 16]
    s[3] = 0.7  # a clear peak is published as soon as its step is decided (when the next arrives)
    assert run_detector(DurationDetector(model, lag=0, threshold=0.9), s)[0].detected_at == 4


def test_the_threshold_is_chosen_within_the_delay_budget():
    """On weak, noisy peaks a surer threshold waits longer; the calibration keeps the mean delay within
    the budget, takes the best alignment there, and refuses a budget that is not positive."""
    rng = np.random.default_rng(5)
    scores, bounds = planted(9, 120)
    noisy = [np.clip(s + rng.normal(0.0, 0.25, s.size), 0.0, 1.0) for s in scores]
    free = calibrate_duration(noisy, bounds, lag=0)
    tight = calibrate_duration(noisy, bounds, lag=0, max_delay=1.5)
    assert tight.metrics["delay_mean"] <= 1.5 < free.metrics["delay_mean"]
    assert tight.config.high < free.config.high and tight.metrics["align"] < free.metrics["align"]
    impossible = calibrate_duration(noisy, bounds, lag=3, max_delay=1.5)  # none within: the shortest delay
    shortest = min(calibrate_duration(noisy, bounds, lag=3, thresholds=(t,)).metrics["delay_mean"]
                   for t in DURATION_THRESHOLDS)
    assert impossible.metrics["delay_mean"] == shortest >= 3
    with pytest.raises(CalibrationError, match="max_delay must be > 0"):
        calibrate_duration(noisy, bounds, lag=0, max_delay=0.0)
