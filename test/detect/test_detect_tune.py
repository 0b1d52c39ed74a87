"""Detector scoring and tuning on replayed score curves (ompn_ros.detect.tune), without a model."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml

from ompn_ros.data.episode import Episode
from ompn_ros.detect import params_file, tune
from ompn_ros.detect.errors import TuneError
from ompn_ros.detect.online import DetectorConfig


@dataclass
class Replay:
    scores: np.ndarray
    p_hat: np.ndarray


def _episode(subtask: list[int]) -> Episode:
    steps = len(subtask)
    return Episode(
        observations=np.zeros((steps + 1, 2), np.float32),
        actions=np.zeros(steps, np.int64),
        task="t",
        seed=0,
        subtask=np.asarray(subtask, np.int64),
    )


def _replay(peaks: list[int], steps: int, height: float) -> Replay:
    """Scores low everywhere with a peak of ``height`` at ``peaks``; p_hat expanding there."""
    scores = np.full(steps, 0.05)
    scores[peaks] = height
    p_hat = np.tile([0.0, 0.0, 1.0], (steps, 1))
    p_hat[peaks] = [0.0, 1.0, 0.0]
    return Replay(scores, p_hat)


EPISODE = _episode([0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2])  # boundaries 3, 7, 11


def test_a_detector_that_fires_at_the_boundaries_scores_perfectly():
    replay = _replay([3, 7], 12, 0.6)
    metrics = tune.score_online([replay], [EPISODE], DetectorConfig(high=0.4, mode="peak"))
    assert metrics["f1_tol1"] == 1.0 and metrics["align_strict"] == 1.0
    assert metrics["false_alarms_per_episode"] == 0.0
    # above the peaks nothing fires but the episode end: two of three boundaries missed
    blind = tune.score_online([replay], [EPISODE], DetectorConfig(high=0.9, mode="peak"))
    assert blind["f1_tol1"] < metrics["f1_tol1"]


def test_the_grid_search_finds_a_threshold_below_the_peaks():
    replay = _replay([3, 7], 12, 0.3)
    grid = [DetectorConfig(high=h, mode="peak") for h in (0.8, 0.5, 0.2)]
    best, metrics, comparison = tune.choose_on_replays([replay], [EPISODE], grid, objective="f1")
    assert best.high == 0.2 and metrics["f1_tol1"] == 1.0
    assert {"online", "offline_topk", "offline_auto"} <= set(comparison)
    assert comparison["online"] == metrics


def test_the_search_moves_late_boundaries_back_and_the_node_file_keeps_the_offset(tmp_path):
    replay = _replay([5, 9], 12, 0.6)  # each peak 2 steps after its boundary (3, 7)
    best, metrics, _ = tune.choose_on_replays([replay], [EPISODE], objective="align", long_subtasks=True)
    assert best.offset == 2 and metrics["f1_tol1"] == 1.0 and metrics["align_strict"] == 1.0
    plain, _, _ = tune.choose_on_replays([replay], [EPISODE], objective="align")  # the default: no offset
    assert plain.offset == 0
    on_time, _, _ = tune.choose_on_replays([_replay([3, 7], 12, 0.6)], [EPISODE], objective="align",
                                           long_subtasks=True)
    assert on_time.offset == 0
    path = params_file.write_node_config(tmp_path / "node.yaml", "dial", best, {"online": metrics}, "a test")
    assert params_file.load_detector_yaml(path) == best


def test_tuning_needs_labels_a_known_objective_and_matching_replays():
    replay = _replay([3, 7], 12, 0.3)
    with pytest.raises(TuneError, match="objective"):
        tune.choose_on_replays([replay], [EPISODE], objective="recall")
    unlabelled = Episode(
        observations=np.zeros((3, 2), np.float32), actions=np.zeros(2, np.int64), task="t", seed=0
    )
    with pytest.raises(TuneError, match="subtask labels"):
        tune.compare_on_replays([replay], [unlabelled], {"online": DetectorConfig()})
    with pytest.raises(TuneError, match="2 replays for 1 episodes"):
        tune.compare_on_replays([replay, replay], [EPISODE], {"online": DetectorConfig()})


def test_delays_count_late_detections_and_false_alarms():
    gt = np.array([3, 7, 11])
    stats = tune.delay_stats([[0, 3, 7, 11]], [gt], detected_at=[[0, 4, 9, 11]])
    assert stats["delay_mean"] == pytest.approx(1.5)  # 3 found at 4, 7 found at 9
    assert stats["delay_max"] == 2.0 and stats["false_alarms_per_episode"] == 1.0  # step 0
    assert stats["at_end_share"] == 0.0  # every inner detection came before the last step


def test_the_share_published_at_the_episode_end_counts_inner_detections_only():
    gt = np.array([3, 7, 11])  # 11 = T - 1 closes the episode and is never counted
    late = tune.delay_stats([[3, 7, 11]], [gt], detected_at=[[5, 11, 11]])  # 7 decided by the end
    assert late["at_end_share"] == 0.5 and late["delay_mean"] == pytest.approx(3.0)
    offline = tune.delay_stats([[3, 7, 11], [2, 5]], [gt, np.array([2, 5])],
                               detected_at=[[11, 11, 11], [5, 5]])
    assert offline["at_end_share"] == 1.0  # a whole-episode detector decides everything at the end
    assert tune.delay_stats([[11]], [gt], detected_at=[[11]])["at_end_share"] == 0.0  # no inner ones


def test_objective_orders_by_the_chosen_metric_first():
    a = {"f1_tol1": 0.9, "align_strict": 0.5, "delay_mean": 1.0}
    b = {"f1_tol1": 0.8, "align_strict": 0.7, "delay_mean": 1.0}
    assert tune.objective_key(a, "f1") > tune.objective_key(b, "f1")
    assert tune.objective_key(b, "align") > tune.objective_key(a, "align")


def _rows(*figures: tuple[float, float, float]) -> list[dict[str, float]]:
    return [{"f1_tol1": f, "align_strict": a, "delay_mean": d} for f, a, d in figures]


def test_without_a_band_the_pick_is_the_objective_order():
    rng = np.random.default_rng(3)
    rows = _rows(*[(float(f), float(a), float(d)) for f, a, d in rng.random((40, 3)).round(1)])
    for objective in ("f1", "align"):
        first = max(range(len(rows)), key=lambda g: (tune.objective_key(rows[g], objective), -g))
        assert tune.pick_setting(rows, objective, band=0.0) == first


def test_a_near_tie_on_the_objective_is_decided_by_the_other_metric():
    rows = _rows((0.40, 0.960, 1.0), (0.85, 0.957, 0.5), (0.95, 0.90, 0.5))
    assert tune.pick_setting(rows, "align", band=0.0) == 0
    assert tune.pick_setting(rows, "align", band=0.005) == 1  # 0.3 points lower, F1 45 points higher
    assert tune.pick_setting(rows, "align", band=0.002) == 0  # outside the band: not tied
    assert tune.pick_setting(rows, "f1", band=0.005) == 2


def test_standard_error_of_f1_is_that_of_a_mean_over_episodes():
    per_episode = _rows((0.5, 0.0, 0.0), (0.7, 0.0, 0.0), (0.9, 0.0, 0.0))
    assert tune.standard_error(per_episode, [10, 20, 30], "f1") == pytest.approx(0.2 / np.sqrt(3))
    assert tune.standard_error(per_episode[:1], [10], "f1") == 0.0


def test_standard_error_of_alignment_weights_episodes_by_their_steps():
    aligned = [0.9, 0.7, 0.8, 0.6]
    per_episode = _rows(*[(0.0, a, 0.0) for a in aligned])
    equal = tune.standard_error(per_episode, [50] * 4, "align")
    assert equal == pytest.approx(np.std(aligned, ddof=1) / 2)  # equal lengths: a plain mean
    long_good = tune.standard_error(per_episode, [400, 10, 10, 10], "align")
    assert long_good < equal  # one long episode dominates the pooled ratio


def test_one_standard_error_ties_settings_validation_cannot_tell_apart():
    rows = _rows((0.40, 0.960, 1.0), (0.85, 0.955, 0.5))
    noisy = _rows((0.4, 0.99, 1.0), (0.4, 0.93, 1.0))  # the best setting's episodes: 3 points apart
    steady = _rows((0.4, 0.96, 1.0), (0.4, 0.96, 1.0))
    assert tune.pick_within_error(rows, "align", lambda g: noisy, [100, 100]) == 1
    assert tune.pick_within_error(rows, "align", lambda g: steady, [100, 100]) == 0


def test_pick_setting_refuses_no_rows_and_a_negative_band():
    with pytest.raises(TuneError, match="no detector settings"):
        tune.pick_setting([], "f1")
    with pytest.raises(TuneError, match="band must be >= 0"):
        tune.pick_setting(_rows((0.5, 0.5, 1.0)), "f1", band=-0.1)


def test_node_config_round_trip(tmp_path: Path):
    config = DetectorConfig(high=0.35, low=0.25, min_segment_length=3, mode="rising_edge")
    path = params_file.write_node_config(
        tmp_path / "node.yaml", "craft", config, {"online": {"f1_tol1": 0.9}}, "a test"
    )
    assert "# ompn_node defaults for the craft domain" in path.read_text()
    assert params_file.load_detector_yaml(path) == config


def test_node_config_of_a_users_own_data_sets_no_empty_domain(tmp_path: Path):
    config = DetectorConfig(high=0.3)
    path = params_file.write_node_config(tmp_path / "node.yaml", "", config, {}, "my bag")
    params = yaml.safe_load(path.read_text())["/**/ompn_node"]["ros__parameters"]
    assert "domain" not in params and None not in params.values()
    assert params_file.load_detector_yaml(path) == config


def test_a_missing_detector_file_is_named(tmp_path: Path):
    with pytest.raises(TuneError, match=r"nope\.yaml"):
        params_file.load_detector_yaml(tmp_path / "nope.yaml")


def test_the_grid_adds_shortest_segments_relative_to_the_typical_segment_length():
    bounds = [np.array([3, 7, 11]), np.array([9, 19]), np.array([39])]
    assert tune.typical_segment_length(bounds) == 10.0  # median of 4, 10 and 40 steps per subtask
    assert tune.typical_segment_length([]) == 0.0
    assert {c.min_segment_length for c in tune.default_grid()} == {1, 3}
    assert {c.min_segment_length for c in tune.default_grid(47.0)} == {1, 3, 12, 24}
    assert {c.min_segment_length for c in tune.default_grid(6.0)} == {1, 2, 3}
    assert len(tune.default_grid(47.0)) == 18 * 2 * 4 * 3


def test_a_long_shortest_segment_removes_the_false_alarms_after_each_boundary():
    # subtasks of 20 steps; a spurious peak 4 steps after each boundary as high as the true ones
    episode = _episode([0] * 20 + [1] * 20 + [2] * 20)
    replay = _replay([19, 23, 39, 43], 60, 0.6)
    best, metrics, _ = tune.choose_on_replays([replay], [episode], objective="f1", long_subtasks=True)
    assert best.min_segment_length >= 5 and metrics["f1_tol1"] == 1.0
    old, _, _ = tune.choose_on_replays([replay], [episode], objective="f1")  # the default grid
    assert tune.score_online([replay], [episode], old)["f1_tol1"] < 1.0
