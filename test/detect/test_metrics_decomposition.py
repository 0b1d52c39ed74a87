"""Hand-worked examples for F1 with tolerance and alignment accuracy (ompn_ros.metrics)."""

from __future__ import annotations

import numpy as np
import pytest

from ompn_ros.data.episode import boundaries_from_labels
from ompn_ros.metrics import (
    MetricError,
    alignment_accuracy,
    alignment_counts,
    f1_with_tolerance,
    labels_from_boundaries,
    mean_f1,
)


def test_f1_tolerance_zero_and_one() -> None:
    r0 = f1_with_tolerance([3, 7], [3, 8, 12], tol=0)
    assert (r0.precision, r0.recall) == pytest.approx((0.5, 1 / 3))
    assert r0.f1 == pytest.approx(0.4)
    r1 = f1_with_tolerance([3, 7], [3, 8, 12], tol=1)
    assert (r1.precision, r1.recall, r1.f1) == pytest.approx((1.0, 2 / 3, 0.8))


def test_f1_is_not_one_to_one() -> None:
    # one prediction covers two GT boundaries, several predictions match one GT boundary
    assert f1_with_tolerance([5], [4, 6], tol=1).f1 == pytest.approx(1.0)
    assert f1_with_tolerance([4, 5, 6], [5], tol=1).f1 == pytest.approx(1.0)


def test_f1_empty_inputs() -> None:
    assert f1_with_tolerance([], [3], tol=1).f1 == 0.0
    assert f1_with_tolerance([3], [], tol=1).f1 == 0.0
    assert f1_with_tolerance([0], [9], tol=1) == f1_with_tolerance([9], [0], tol=2)


def test_mean_f1_averages_per_episode() -> None:
    res = mean_f1([[3, 7], [1]], [[3, 8, 12], [1]], tol=0)
    assert res.f1 == pytest.approx((0.4 + 1.0) / 2)
    assert res.precision == pytest.approx(0.75)
    assert res.recall == pytest.approx((1 / 3 + 1) / 2)


def test_labels_from_boundaries_variants() -> None:
    np.testing.assert_array_equal(labels_from_boundaries([1, 3], 6), [0, 0, 1, 1, 0, 0])
    np.testing.assert_array_equal(labels_from_boundaries([1, 3], 6, "strict"), [0, 0, 1, 1, 1, 1])
    np.testing.assert_array_equal(
        labels_from_boundaries([1, 3], 6, "strict", num_subtasks=3), [0, 0, 1, 1, 2, 2]
    )
    np.testing.assert_array_equal(labels_from_boundaries([3, 1, 3], 4), [0, 0, 1, 1])  # sorted, deduplicated


def test_labels_round_trip_with_ground_truth_boundaries() -> None:
    gt = np.array([0, 0, 0, 1, 1, 2, 3, 3])
    np.testing.assert_array_equal(labels_from_boundaries(boundaries_from_labels(gt), gt.size), gt)


def test_alignment_accuracy_is_micro_averaged_with_authors_quirk() -> None:
    preds = [[1, 3], [0, 3]]
    gts = [[0, 0, 1, 1, 2, 2], [0, 0, 0, 1]]
    # episode 1: authors decode [0,0,1,1,0,0] -> 4/6; episode 2: [0,1,1,1] -> 2/4
    assert alignment_counts(preds[0], gts[0]) == (4, 6)
    assert alignment_accuracy(preds, gts) == pytest.approx(6 / 10)  # not (4/6 + 2/4) / 2
    # strict: trailing steps of episode 1 get the final subtask (K = 3) -> 6/6
    assert alignment_accuracy(preds, gts, variant="strict") == pytest.approx(8 / 10)


def test_authors_quirk_can_score_trailing_zero_labels() -> None:
    assert alignment_accuracy([[]], [[0, 0, 1]]) == pytest.approx(2 / 3)
    assert alignment_accuracy([[]], [[0, 0, 1]], variant="strict") == pytest.approx(1 / 3)


def test_metric_input_errors() -> None:
    with pytest.raises(MetricError, match="tol"):
        f1_with_tolerance([1], [1], tol=-1)
    with pytest.raises(MetricError, match="episodes"):
        mean_f1([[1]], [[1], [2]], tol=0)
    with pytest.raises(MetricError, match="outside"):
        labels_from_boundaries([7], 5)
    with pytest.raises(MetricError, match="variant"):
        labels_from_boundaries([1], 5, "lenient")  # type: ignore[arg-type]
    with pytest.raises(MetricError, match="integer"):
        f1_with_tolerance([1.5], [1], tol=0)
