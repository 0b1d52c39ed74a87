"""Online detector calibration (ompn_ros.detect.calibrate): the vectorised grid equals the
OnlineDetector, label tuning finds planted boundaries, the label-free path agrees with its reference."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ompn_ros.detect.calibrate import calibrate_label_free, search, tune_on_labels
from ompn_ros.detect.errors import CalibrationError
from ompn_ros.detect.grid import detect_grid, evaluate_grid, scores_from_p_hats
from ompn_ros.detect.online import DetectorConfig, detect_sequence
from ompn_ros.detect.reference import agreement, estimated_count, pooled_counts, reference_boundaries
from ompn_ros.detect.tune import default_grid, offset_grid
from ompn_ros.metrics import alignment_accuracy, mean_f1


def _random_scores(seed: int, n: int = 25) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.random(int(rng.integers(1, 30))) ** 2 for _ in range(n)]


def test_grid_masks_equal_the_online_detector() -> None:
    scores = _random_scores(1)
    grid = default_grid()
    marks = detect_grid(scores, grid)
    for g in range(0, len(grid), 7):
        for e, s in enumerate(scores):
            steps = sorted({ev.step for ev in detect_sequence(s, grid[g])})  # the episode end once
            assert np.flatnonzero(marks[g, e]).tolist() == steps, (grid[g], e)


def test_grid_masks_with_an_offset_equal_the_online_detector() -> None:
    scores = _random_scores(7, n=40)
    grid = [replace(cfg, offset=offset) for cfg in default_grid()[::11] for offset in (1, 3, 10)]
    marks = detect_grid(scores, grid)
    for g, cfg in enumerate(grid):
        for e, s in enumerate(scores):
            steps = sorted({ev.step for ev in detect_sequence(s, cfg)})
            assert np.flatnonzero(marks[g, e]).tolist() == steps, (cfg, e)


def _late(seed: int, delay: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Planted episodes whose expansion score peaks ``delay`` steps after each inner boundary."""
    p_hats, labels, bounds = _planted(seed)
    late = []
    for p, b in zip(p_hats, bounds, strict=True):
        q = np.tile(p[0], (len(p), 1))
        for step in b[:-1]:
            q[min(step + delay, len(p) - 1)] = p[step]
        late.append(q)
    return late, labels


@pytest.mark.parametrize("delay", [0, 2, 3])
def test_the_offset_search_finds_how_late_the_scores_are(delay: int) -> None:
    p_hats, labels = _late(8, delay)
    scores = scores_from_p_hats(p_hats)
    without = search_grid_only(scores, labels)
    gts = [np.append(np.flatnonzero(np.diff(lab)), len(lab) - 1) for lab in labels]
    found = tune_on_labels(scores, labels, "align")  # the objective of continuous control
    result = search(scores, gts, labels, "align", offset_grid(found.config))
    assert result.config.offset == delay
    assert result.metrics["f1_tol1"] == 1.0
    if delay > 1:
        assert without["f1_tol1"] < 0.9  # a plain threshold misses boundaries this late


def search_grid_only(scores: list[np.ndarray], labels: list[np.ndarray]) -> dict[str, float]:
    """The best grid setting without the offset stage (the tuning before the offset existed)."""
    gts = [np.append(np.flatnonzero(np.diff(lab)), len(lab) - 1) for lab in labels]
    rows = evaluate_grid(scores, default_grid(), gts, labels)
    return max(rows, key=lambda row: (row["f1_tol1"], row["align_strict"]))


def test_grid_metrics_equal_the_metric_functions() -> None:
    scores = _random_scores(2)
    rng = np.random.default_rng(3)
    labels = [np.unique(np.sort(rng.integers(0, 3, len(s))), return_inverse=True)[1] for s in scores]
    gts = [np.append(np.flatnonzero(np.diff(lab)), len(lab) - 1) for lab in labels]
    grid = [DetectorConfig(high=0.3), DetectorConfig(high=0.1, low=0.05, mode="peak", min_segment_length=3)]
    rows = evaluate_grid(scores, grid, gts, labels)
    for cfg, row in zip(grid, rows, strict=True):
        preds = [np.array([e.step for e in detect_sequence(s, cfg)]) for s in scores]
        assert row["f1_tol1"] == pytest.approx(mean_f1(preds, gts, 1).f1)
        assert row["f1_tol0"] == pytest.approx(mean_f1(preds, gts, 0).f1)
        assert row["align"] == pytest.approx(alignment_accuracy(preds, labels, "authors"))


def _planted(
    seed: int, n: int = 30, level: float = 0.3
) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """Episodes whose p_hat (n = 2 slots) expands from the top at the last step of each subtask."""
    rng = np.random.default_rng(seed)
    episodes = [_episode(rng, rng.integers(4, 9, size=int(rng.integers(2, 5))), level) for _ in range(n)]
    return [e[0] for e in episodes], [e[1] for e in episodes], [e[2] for e in episodes]


def _episode(
    rng: np.random.Generator, lengths: np.ndarray, level: float = 0.3, spurious: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(p_hat, labels, boundaries) of one episode with subtasks of ``lengths`` steps; ``spurious``: a
    weaker run above the threshold 3 steps after the first boundary."""
    lab = np.repeat(np.arange(len(lengths)), lengths)
    b = np.cumsum(lengths) - 1
    p = np.tile([0.0, 0.02, 0.98], (len(lab), 1))
    p[:, 1:] += rng.random((len(lab), 2)) * 0.02
    p[b, :] = [level, 1 - level, 0.0]  # high expansion score at the boundaries
    if spurious:
        p[b[0] + 3, :] = [0.1, 0.9, 0.0]  # weaker than a true boundary, above the threshold
    p /= p.sum(1, keepdims=True)
    return p, lab, b


def test_label_tuning_finds_the_planted_boundaries() -> None:
    p_hats, labels, _ = _planted(4)
    result = tune_on_labels(scores_from_p_hats(p_hats), labels, "f1")
    assert result.metrics["f1_tol1"] == 1.0 and result.target == "labels"
    assert result.config.high < 0.6  # the planted score is (0.3 * 2 + 0.7) / 2 = 0.65


@pytest.mark.parametrize("reference", ["auto_threshold_onset", "auto_threshold", "constrained_top_k"])
def test_label_free_calibration_recovers_planted_boundaries_without_labels(reference: str) -> None:
    p_hats, labels, bounds = _planted(5)
    for p, b in zip(p_hats, bounds, strict=True):
        assert reference_boundaries(p, reference).tolist() == b.tolist()
        assert estimated_count(p) == len(b)
    result = calibrate_label_free(p_hats, "f1", reference)
    assert result.metrics["f1_tol1"] == 1.0 and result.target == reference
    # scored against the hidden labels, the label-free setting is as good as the tuned one
    events = [[e.step for e in detect_sequence(s, result.config)] for s in scores_from_p_hats(p_hats)]
    assert alignment_accuracy(events, labels) == 1.0


def test_onset_reference_follows_plateaus_that_start_at_the_boundary() -> None:
    """Dial-like: the expansion stays high (slowly fading) for 3 steps from the last step of each subtask."""
    p_hats, labels, bounds = _planted(8)
    for p, b in zip(p_hats, bounds, strict=True):
        for step in b[:-1]:
            for j in (1, 2):
                p[step + j] = [0.3 - 0.02 * j, 0.7, 0.02 * j]
    assert [reference_boundaries(p).tolist() for p in p_hats] == [b.tolist() for b in bounds]
    ends = reference_boundaries(p_hats[0], "auto_threshold")
    assert ends[:-1].tolist() == (bounds[0][:-1] + 2).tolist()  # Algorithm 1: the plateau's last step
    result = calibrate_label_free(p_hats, "align")
    assert result.config.mode == "rising_edge"
    events = [[e.step for e in detect_sequence(s, result.config)] for s in scores_from_p_hats(p_hats)]
    assert alignment_accuracy(events, labels) == 1.0


def test_agreement_ranks_structure_above_noise() -> None:
    p_hats, _, _ = _planted(6)
    rng = np.random.default_rng(7)
    flat = [np.tile([0.0, 0.0, 1.0], (len(p), 1)) for p in p_hats]  # never expands: no structure
    noisy = [rng.dirichlet(np.ones(3), size=len(p)) for p in p_hats]
    structured = agreement(p_hats)
    assert structured > 0.95
    assert agreement(flat) < 0.6 and agreement(noisy) < structured


def test_bad_input_names_the_argument() -> None:
    with pytest.raises(CalibrationError, match="scores"):
        evaluate_grid([], default_grid(), [])
    with pytest.raises(CalibrationError, match="target"):
        evaluate_grid([np.zeros(3)], default_grid(), [np.array([5])])
    with pytest.raises(CalibrationError, match="reference"):
        reference_boundaries(np.tile([0.0, 0.5, 0.5], (4, 1)), "oracle")  # type: ignore[arg-type]
    with pytest.raises(CalibrationError, match="reference"):
        calibrate_label_free([np.tile([0.0, 0.5, 0.5], (4, 1))], "f1", "oracle")  # type: ignore[arg-type]
    with pytest.raises(CalibrationError, match="objective"):
        calibrate_label_free([np.tile([0.0, 0.5, 0.5], (4, 1))], "recall")  # type: ignore[arg-type]


def _one_task(n: int, k: int, seed: int) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """``n`` episodes of one task with ``k`` subtasks each; in every third episode a spurious run above
    the threshold in the middle of a subtask makes that episode's own count k + 1."""
    rng = np.random.default_rng(seed)
    episodes = [_episode(rng, rng.integers(6, 10, size=k), spurious=i % 3 == 0) for i in range(n)]
    return [e[0] for e in episodes], [e[1] for e in episodes], [e[2] for e in episodes]


def test_pooled_counts_take_the_median_of_each_task() -> None:
    p_hats, _, _ = _one_task(9, 3, seed=2)
    own = [estimated_count(p) for p in p_hats]
    assert own.count(4) == 3 and own.count(3) == 6  # the spurious runs fool the per-episode count
    assert pooled_counts(p_hats) == [3] * 9
    short, _, _ = _one_task(3, 2, seed=5)
    tasks = ["a"] * 9 + ["b"] * 3
    assert pooled_counts(p_hats + short, tasks) == [3] * 9 + [2] * 3  # pooled per task, not overall
    with pytest.raises(CalibrationError, match="tasks"):
        pooled_counts(p_hats, ["a"])


def test_pooled_reference_keeps_the_true_boundaries_where_the_episode_count_fails() -> None:
    """On the fooled episodes the per-episode constrained Top-K takes the spurious run; the pooled
    count does not, and the calibrated online detector then ignores the weaker runs."""
    p_hats, labels, bounds = _one_task(9, 3, seed=2)
    counts = pooled_counts(p_hats)
    fooled = [i for i, p in enumerate(p_hats) if estimated_count(p) != len(bounds[i])]
    assert fooled
    for i in fooled:
        assert reference_boundaries(p_hats[i], "constrained_top_k").tolist() != bounds[i].tolist()
        pooled = reference_boundaries(p_hats[i], "pooled_top_k", min_length=3, count=counts[i])
        assert pooled.tolist() == bounds[i].tolist()
    result = calibrate_label_free(p_hats, "f1", "pooled_top_k", min_length=3)
    assert result.metrics["f1_tol1"] == 1.0 and result.config.high >= 0.55  # the spurious runs score 0.55
    events = [[e.step for e in detect_sequence(s, result.config)] for s in scores_from_p_hats(p_hats)]
    assert alignment_accuracy(events, labels) == 1.0
    # control: agreeing with the per-episode counts, the detector also takes the spurious runs
    own = calibrate_label_free(p_hats, "f1", "constrained_top_k", min_length=3)
    events = [[e.step for e in detect_sequence(s, own.config)] for s in scores_from_p_hats(p_hats)]
    assert alignment_accuracy(events, labels) < 1.0
    with pytest.raises(CalibrationError, match="count"):
        reference_boundaries(p_hats[0], "pooled_top_k")


def test_combined_reference_maximises_the_mean_agreement_of_its_parts() -> None:
    """'onset_and_pooled': every setting is scored by the mean of its metrics against the onset and
    the pooled reference; the chosen one is the best by that mean, and its metrics are that mean."""
    p_hats, _, _ = _one_task(9, 3, seed=2)
    scores = scores_from_p_hats(p_hats)
    grid = default_grid()
    counts = pooled_counts(p_hats)
    onset = evaluate_grid(scores, grid, [reference_boundaries(p) for p in p_hats])
    refs = [reference_boundaries(p, "pooled_top_k", 3, k) for p, k in zip(p_hats, counts, strict=True)]
    pooled = evaluate_grid(scores, grid, refs)
    result = calibrate_label_free(p_hats, "align", "onset_and_pooled", min_length=3)
    chosen = grid.index(result.config)
    for key in ("f1_tol1", "align"):
        assert result.metrics[key] == pytest.approx((onset[chosen][key] + pooled[chosen][key]) / 2)
    means = [(onset[g]["align"] + pooled[g]["align"]) / 2 for g in range(len(grid))]
    assert means[chosen] == pytest.approx(max(means))
    # the two references disagree on the fooled episodes, so neither part's own best is perfect here
    assert max(means) < 1.0 and result.target == "onset_and_pooled"
    with pytest.raises(CalibrationError, match="combines"):
        reference_boundaries(p_hats[0], "onset_and_pooled")
