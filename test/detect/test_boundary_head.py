"""The learned boundary head (``ompn_ros.detect.head``, ``ompn_ros.train.boundary_head``): its decoding,
its file, its training and choice on validation, and the segmenter running it."""

from __future__ import annotations

import dataclasses
import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from ompn_ros.app.detector_tuning import tune_detector
from ompn_ros.checkpoints import shipped_checkpoint
from ompn_ros.data.episode import Episode
from ompn_ros.detect.defaults import DURATION_GAIN
from ompn_ros.detect.errors import BoundaryHeadError, DetectorConfigError, DetectorSettingsError
from ompn_ros.detect.head import (
    HEAD_FILE,
    HeadDetector,
    decode_rows,
    decoded_steps,
    head_outputs,
)
from ompn_ros.detect.online import DetectorConfig
from ompn_ros.detect.settings import DetectorSettings, load_detector_settings, save_detector_settings
from ompn_ros.model.load import stepper_from_checkpoint
from ompn_ros.segmenter import StreamingSegmenter
from ompn_ros.train.boundary_head import (
    GAPS,
    THETAS,
    _choosing_figures,
    choose_on_rows,
    choose_rule,
    score_rule,
    targets,
    train_head,
)
from sim_nodes.registry import expert_episode

torch = pytest.importorskip("torch")
from toy_heads import _toy_head, checkpoint_with_head  # noqa: E402

torch.set_num_threads(1)


def _cfg(lag: int, theta: float = 0.5, gap: int = 1) -> DetectorConfig:
    return DetectorConfig(mode="head", high=theta, lag=lag, min_segment_length=gap)


def _rows(length: int, fire: dict[tuple[int, int], float], lags: int = 4) -> np.ndarray:
    q = np.zeros((length, lags))
    for (t, j), v in fire.items():
        q[t, j] = v
    return q


def test_a_boundary_is_read_at_its_lag_and_published_one_step_after_the_row() -> None:
    events = decode_rows(_rows(12, {(6, 2): 0.9}), _cfg(2), peak=False)
    assert [(e.step, e.detected_at, e.final) for e in events] == [(4, 7, False), (11, 11, True)]
    assert [e.subtask for e in events] == [0, 1]


def test_gap_peak_and_threshold_hold_boundaries_back() -> None:
    q = _rows(20, {(5, 1): 0.8, (7, 1): 0.8, (12, 1): 0.4, (15, 1): 0.7, (15, 0): 0.9})
    assert [e.step for e in decode_rows(q, _cfg(1), False)] == [4, 6, 14, 19]
    assert [e.step for e in decode_rows(q, _cfg(1, gap=3), False)] == [4, 14, 19]
    assert [e.step for e in decode_rows(q, _cfg(1), True)] == [4, 6, 19]  # row 15: lag 0 likelier
    assert [e.step for e in decode_rows(q, _cfg(1, theta=0.3), False)] == [4, 6, 11, 14, 19]


def test_the_episode_end_reads_the_last_row_at_the_smaller_lags() -> None:
    q = _rows(10, {(9, 1): 0.9, (9, 2): 0.2})
    events = decode_rows(q, _cfg(3), False)
    assert [(e.step, e.detected_at) for e in events] == [(8, 9), (9, 9)]
    assert not events[0].final and events[1].final


def test_a_done_observation_after_the_last_step_places_no_boundary() -> None:
    """The row of the done step (after the last real one) is never taken in (closed at T - 1)."""
    head = _toy_head(window=2, features=2, lags=2)
    detector = HeadDetector(head, _cfg(1, theta=0.5))
    outs = np.array([[0.0, 0.0]] * 6 + [[5.0, 0.0]])  # the last row (the done step) fires at lag 1
    for x in outs:
        detector.feed(x)
        assert detector.update(0.0) is None
    events = detector.close(last_step=5)
    assert [(e.step, e.final) for e in events] == [(5, True)]


def test_the_streaming_detector_equals_the_decoding_of_the_whole_episode() -> None:
    rng = np.random.default_rng(3)
    head = _toy_head(window=3, features=4, lags=4)
    noisy = tuple((w + rng.normal(0, 0.3, w.shape), b) for w, b in head.weights)
    head = dataclasses.replace(head, weights=noisy)
    for trial in range(5):
        outs = rng.normal(0, 2, (40, 4))
        want = decode_rows(head.probabilities(outs), _cfg(1, theta=0.3, gap=2), peak=trial % 2 == 1)
        detector = HeadDetector(dataclasses.replace(head, peak=trial % 2 == 1), _cfg(1, theta=0.3, gap=2))
        got = []
        for x in outs:
            detector.feed(x)
            got += [e for e in [detector.update(0.0)] if e is not None]
        got += detector.close()
        assert [(e.step, e.detected_at) for e in got] == [(e.step, e.detected_at) for e in want]
        assert len(want) > 2


def test_the_detector_refuses_what_it_cannot_read() -> None:
    head = _toy_head(window=2, features=3, lags=3)
    with pytest.raises(BoundaryHeadError, match="lag 0 … 2"):
        HeadDetector(head, _cfg(3))
    detector = HeadDetector(head, _cfg(1))
    with pytest.raises(BoundaryHeadError, match="feed"):
        detector.update(0.0)
    with pytest.raises(BoundaryHeadError, match="3 outputs per step"):
        detector.feed(np.zeros(4))
    with pytest.raises(DetectorConfigError, match="'offset'"):
        DetectorConfig(mode="head", high=0.5, lag=1, offset=1)


def test_head_outputs_are_p_hat_beside_the_action_probabilities_or_mean() -> None:
    got = head_outputs(np.array([0.1, 0.9]), np.array([0.0, np.log(3.0)]), discrete=True)
    np.testing.assert_allclose(got, [0.1, 0.9, 0.25, 0.75])
    np.testing.assert_allclose(head_outputs(np.array([1.0, 0.0]), np.array([-2.0]), discrete=False),
                               [1.0, 0.0, -2.0])


def test_the_head_travels_with_the_detector_settings(tmp_path: Path) -> None:
    head = dataclasses.replace(_toy_head(window=2, features=3, lags=3), peak=True, episodes=7, rule=_cfg(1))
    settings = DetectorSettings(online=_cfg(2, theta=0.3, gap=2), head=head, provenance="a test")
    save_detector_settings(tmp_path, settings)
    back = load_detector_settings(tmp_path)
    assert back.online == settings.online and back.head is not None and back.head == head
    assert (back.head.peak, back.head.episodes, back.head.max_lag, back.head.rule) == (True, 7, 2, _cfg(1))
    outs = np.random.default_rng(0).normal(0, 1, (9, 3))
    np.testing.assert_allclose(back.head.probabilities(outs), head.probabilities(outs), atol=1e-6)
    assert "mode=head lag=2" in back.describe()


def test_a_head_file_that_disagrees_with_detector_json_is_refused_before_it_is_read(tmp_path: Path) -> None:
    save_detector_settings(tmp_path, DetectorSettings(online=_cfg(1), head=_toy_head(2, 3, 3)))
    doc = json.loads((tmp_path / "detector.json").read_text())
    doc["boundary_head"]["hidden"] = [3, 5]
    (tmp_path / "detector.json").write_text(json.dumps(doc))
    with pytest.raises(DetectorSettingsError, match=r"boundary_head.*do not match"):
        load_detector_settings(tmp_path)
    (tmp_path / HEAD_FILE).write_bytes(b"not safetensors")
    with pytest.raises(DetectorSettingsError, match="not a readable safetensors file"):
        load_detector_settings(tmp_path)
    with pytest.raises(DetectorSettingsError, match="needs a 'boundary_head'"):
        DetectorSettings(online=_cfg(1))
    beyond = r"'online.lag' 3 is beyond the boundary head's lags \(0 … 2\)"
    with pytest.raises(DetectorSettingsError, match=beyond):
        DetectorSettings(online=_cfg(3), head=_toy_head(2, 3, 3))
    with pytest.raises(BoundaryHeadError, match="its rule must be of mode 'head' with lag <= 2"):
        dataclasses.replace(_toy_head(2, 3, 3), rule=_cfg(3))


def test_targets_mark_each_inner_boundary_at_every_lag() -> None:
    y = targets(np.array([2, 7, 9]), 10, max_lag=3)
    assert y.shape == (10, 4) and y.sum() == 7  # 2 at lags 0..3, 7 at lags 0..2, 9 (the end) none
    assert y[2, 0] == y[5, 3] == y[9, 2] == 1.0 and y[9, 0] == 0.0


def _cue_episodes(rng: np.random.Generator, n: int, cue: bool) -> tuple[list[np.ndarray], list[Episode]]:
    """Outputs with a feature that spikes two steps after each boundary (or noise only)."""
    outs, eps = [], []
    for _ in range(n):
        lengths = rng.integers(6, 12, size=3)
        labels = np.repeat(np.arange(3), lengths)
        x = rng.normal(0, 1, (len(labels), 4))
        for b in np.cumsum(lengths)[:-1] - 1:
            if cue:
                x[b + 2, 0] += 6.0
        outs.append(x)
        eps.append(Episode(observations=np.zeros((len(labels) + 1, 1), np.float32),
                           actions=np.zeros(len(labels), np.int64), subtask=labels))
    return outs, eps


@pytest.mark.parametrize("cue", [True, False])
def test_a_trained_head_finds_a_late_cue_and_nothing_in_noise(cue: bool) -> None:
    rng = np.random.default_rng(1)
    train_x, train_eps = _cue_episodes(rng, 60, cue)
    val_x, val_eps = _cue_episodes(rng, 20, cue)
    head = train_head(train_x, [ep.boundaries for ep in train_eps], seed=0, epochs=15)
    choice = choose_rule(head, val_x, val_eps)
    if cue:
        assert choice.metrics["f1_tol1"] > 0.95 and choice.config.lag >= 2
    else:
        assert choice.metrics["f1_tol1"] < 0.8


def test_the_choice_is_the_best_of_every_rule_scored_whole() -> None:
    """The grid scores each episode's decoding once: every rule's figures, the choice and its figures
    equal scoring every rule with :func:`score_rule` and keeping the best alignment, then F1@1, then the
    shorter lag.  Twin episodes (the same probabilities over other labels) are scored apart."""
    rng = np.random.default_rng(4)
    _, eps = _cue_episodes(rng, 6, True)
    rows = [np.clip(rng.beta(0.4, 2.0, (len(ep.subtask), 4)) + 0.5 * np.isin(
        np.arange(len(ep.subtask)), ep.boundaries[:-1] + 1)[:, None], 0, 1) for ep in eps]
    eps += [dataclasses.replace(ep, subtask=np.concatenate([ep.subtask[:2], ep.subtask[:-2]])) for ep in eps]
    rows += rows
    config, peak, metrics = choose_on_rows(rows, eps)
    whole, seen = {}, {}
    for lag, theta, gap, pk in itertools.product(range(1, 4), THETAS, GAPS, (False, True)):
        got = score_rule(rows, eps, _cfg(lag, theta, gap), pk)
        figures = _choosing_figures(rows, eps, _cfg(lag, theta, gap), pk, seen)
        assert figures == (got["align"], got["f1_tol1"])
        whole[(lag, theta, gap, pk)] = ((round(got["align"], 6), round(got["f1_tol1"], 6), -lag), got)
    best = max(whole.values(), key=lambda kv: kv[0])
    chosen = whole[(config.lag, config.high, config.min_segment_length, peak)]
    assert metrics == best[1] and chosen[0] == best[0]
    assert len({kv[0] for kv in whole.values()}) > 10  # the grid's rules differ: the choice is a real one


def test_lag_zero_reads_each_row_for_its_own_step() -> None:
    events = decode_rows(_rows(8, {(3, 0): 0.9, (7, 0): 0.9}), _cfg(0), False)
    assert [(e.step, e.detected_at, e.final) for e in events] == [(3, 4, False), (7, 7, True)]


@pytest.mark.slow  # trains a head; the choice on replays is checked fast in test_detect_choose
def test_ompn_segment_tune_runs_the_checkpoints_head_where_it_aligns_better(tmp_path: Path) -> None:
    path = checkpoint_with_head(tmp_path, "dial")
    head = load_detector_settings(path).head
    assert head is not None and head.rule is not None
    policy = stepper_from_checkpoint(path)
    eps = [expert_episode("dial", 900 + i) for i in range(6)]
    tuned = tune_detector(policy, eps, "align", "dial", 1, 6.0, head=head)
    fig = tuned.figures
    gains = fig.get("hsmm_val_align", -1.0) >= fig["threshold_val_align"] + DURATION_GAIN
    keeps = fig.get("hsmm_val_f1_tol1", -1.0) >= fig["threshold_val_f1_tol1"] - DURATION_GAIN
    before = "hsmm" if gains and keeps else "threshold"
    head_wins = fig["head_val_align"] > fig[f"{before}_val_align"]
    # the duration decoder over the head, where a duration model was fitted, runs if it aligns better still
    assert ("head_hsmm_val_align" in fig) == ("hsmm_val_align" in fig)
    both_wins = fig.get("head_hsmm_val_align", -1.0) > fig[f"{'head' if head_wins else before}_val_align"]
    assert (tuned.best.mode == "head_hsmm") == both_wins
    assert (tuned.best.mode == "head") == (head_wins and not both_wins)
    assert tuned.best.mode != "head" or tuned.metrics["align"] == fig["head_val_align"]
    assert tuned.best.mode != "head_hsmm" or tuned.model is not None
    without = tune_detector(policy, eps, "align", "dial", 1, 6.0)
    assert without.best.mode not in ("head", "head_hsmm") and "head_val_align" not in without.figures


def test_a_head_of_another_model_is_refused_when_the_segmenter_is_built() -> None:
    stepper = stepper_from_checkpoint(shipped_checkpoint("craft"))
    config = stepper.config
    outputs = config.n_slots + 1 + config.action_dim
    with pytest.raises(BoundaryHeadError, match=f"reads {outputs + 1} outputs per step and this model gives "
                                                f"{outputs}"):
        StreamingSegmenter(stepper, _cfg(1), None, _toy_head(2, outputs + 1, 3))
    segmenter = StreamingSegmenter(stepper, _cfg(1), None, _toy_head(2, outputs, 3))
    got = segmenter.step(np.zeros(config.obs_dim, dtype=np.float32))
    assert got.boundary is None and segmenter.detector.steps_seen == 1


def test_the_scoring_decoder_makes_the_streaming_decoders_decisions() -> None:
    rng = np.random.default_rng(7)
    checked = 0
    for length in (2, 3, 9, 40):
        rows = rng.uniform(0, 1, (length, 5)) ** 3
        for lag, theta, gap, peak in itertools.product(range(5), (0.05, 0.3, 0.7), (1, 3), (False, True)):
            events = decode_rows(rows, _cfg(lag, theta, gap), peak)
            steps, when = decoded_steps(rows, _cfg(lag, theta, gap), peak)
            assert (steps, when) == ([e.step for e in events], [e.detected_at for e in events]), (length, lag)
            checked += len(steps) > 1
    assert checked > 50
