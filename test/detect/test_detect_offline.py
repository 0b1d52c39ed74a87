"""Hand-worked examples for the offline boundary detectors (ompn_ros.detect.offline)."""

from __future__ import annotations

import numpy as np
import pytest

from ompn_ros.detect.errors import DetectorError
from ompn_ros.detect.offline import (
    FALLBACK_THRESHOLD,
    auto_threshold,
    auto_threshold_boundaries,
    boundaries_from_threshold,
    constrained_top_k_boundaries,
    depth_scores,
    standardise,
    threshold_boundaries,
    top_k_boundaries,
)

# n = 2 slots; columns [pi_end, top, bottom]
P_HAT = np.array(
    [
        [0.0, 1.0, 0.0],  # t0: hard-coded "expand from the top" (forced to the bottom by the detectors)
        [0.0, 0.0, 1.0],  # code 0.0   paper 1.0
        [0.0, 0.9, 0.1],  # code 0.9   paper 1.9
        [0.0, 0.1, 0.9],  # code 0.1   paper 1.1
        [0.5, 0.5, 0.0],  # code 1.5   paper 2.0 (slots renormalised to [1, 0])
        [0.0, 0.2, 0.8],  # code 0.2   paper 1.2
    ]
)


def test_depth_scores_code_weighting() -> None:
    np.testing.assert_allclose(depth_scores(P_HAT, "code"), [0.0, 0.0, 0.9, 0.1, 1.5, 0.2])


def test_depth_scores_paper_weighting() -> None:
    np.testing.assert_allclose(depth_scores(P_HAT, "paper"), [1.0, 1.0, 1.9, 1.1, 2.0, 1.2])


def test_first_step_not_forced_keeps_top_expansion() -> None:
    assert depth_scores(P_HAT, "code", force_first_bottom=False)[0] == pytest.approx(1.0)
    assert depth_scores(P_HAT, "paper", force_first_bottom=False)[0] == pytest.approx(2.0)


def test_top_k_picks_highest_scores_sorted_by_time() -> None:
    np.testing.assert_array_equal(top_k_boundaries(P_HAT, 2), [2, 4])
    np.testing.assert_array_equal(top_k_boundaries(P_HAT, 1), [4])
    assert top_k_boundaries(P_HAT, 2).dtype == np.int64


def test_top_k_code_and_paper_weighting_differ_on_pi_end() -> None:
    # t1 has a high expansion (top slot), t2 mostly pi_end with the rest at the bottom:
    # code counts pi_end as the highest level (1.2 > 0.8), the paper ignores it (1.0 < 1.8).
    p_hat = np.array([[0, 1, 0], [0.0, 0.8, 0.2], [0.6, 0.0, 0.4]], dtype=float)
    np.testing.assert_array_equal(top_k_boundaries(p_hat, 1, weighting="code"), [2])
    np.testing.assert_array_equal(top_k_boundaries(p_hat, 1, weighting="paper"), [1])


def test_top_k_excludes_first_step_and_breaks_ties_early() -> None:
    p_hat = np.tile([0.0, 1.0, 0.0], (4, 1))  # scores [0 (forced), 1, 1, 1]
    np.testing.assert_array_equal(top_k_boundaries(p_hat, 2), [1, 2])
    np.testing.assert_array_equal(top_k_boundaries(p_hat, 10), [1, 2, 3])
    np.testing.assert_array_equal(top_k_boundaries(p_hat, 10, exclude_first=False), [0, 1, 2, 3])


def test_standardise_code_does_not_subtract_min() -> None:
    np.testing.assert_allclose(standardise(np.array([1.0, 2.0, 3.0]), "code"), [0.5, 1.0, 1.5])
    np.testing.assert_allclose(standardise(np.array([1.0, 2.0, 3.0]), "minmax"), [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(standardise(np.array([2.0, 2.0]), "code"), [0.0, 0.0])


def test_threshold_boundaries_falling_edges_plus_last_step() -> None:
    # standardised code scores: [0, 0, .6, .067, 1, .133]; above 0.5 at t=2 and t=4
    np.testing.assert_array_equal(threshold_boundaries(P_HAT, 0.5, 3), [2, 4, 5])
    np.testing.assert_array_equal(threshold_boundaries(P_HAT, 0.5, 2), [4, 5])
    np.testing.assert_array_equal(threshold_boundaries(P_HAT, 0.9, 5), [4, 5])


def test_algorithm1_edges() -> None:
    # ends above the threshold: no falling edge, only the appended last step
    np.testing.assert_array_equal(boundaries_from_threshold(np.array([0.0, 1.0, 1.0]), 0.5, 4), [2])
    # starts above the threshold: prev starts False, so the first falling edge is at t=1 -> 0
    np.testing.assert_array_equal(boundaries_from_threshold(np.array([1.0, 0.0, 0.0]), 0.5, 4), [0, 2])
    # strictly greater than the threshold
    np.testing.assert_array_equal(boundaries_from_threshold(np.array([0.5, 0.0]), 0.5, 4), [1])


def test_auto_threshold_midway_between_highest_peak_and_lowest_valley() -> None:
    std = np.array([0.0, 0.6, 0.2, 1.0, 0.1, 0.5, 0.3])  # peaks .6, 1, .5; valleys .2, .1
    auto = auto_threshold(std)
    assert not auto.fallback
    assert auto.upper == pytest.approx(1.0) and auto.lower == pytest.approx(0.1)
    assert auto.threshold == pytest.approx(0.55)
    np.testing.assert_array_equal(boundaries_from_threshold(std, auto.threshold, 3), [1, 3, 6])


def test_auto_threshold_falls_back_without_peak_or_valley() -> None:
    for curve in ([0.0, 0.5, 1.0], [0.0, 1.0], [0.0, 1.0, 1.0, 0.0]):  # monotone, too short, plateau
        auto = auto_threshold(np.array(curve))
        assert auto.fallback
        assert auto.threshold == FALLBACK_THRESHOLD
    only_peak = auto_threshold(np.array([0.0, 1.0, 0.0]))
    assert only_peak.fallback and only_peak.upper == 1.0 and np.isnan(only_peak.lower)


def test_auto_threshold_boundaries_on_p_hat() -> None:
    bounds, auto = auto_threshold_boundaries(P_HAT, 3)
    # std scores [0, 0, .6, .067, 1, .133]: peaks .6 and 1, valley .067 -> thr .533
    assert auto.threshold == pytest.approx((1.0 + 0.1 / 1.5) / 2)
    np.testing.assert_array_equal(bounds, [2, 4, 5])


@pytest.mark.parametrize(
    "bad",
    [np.zeros((3,)), np.zeros((0, 3)), np.zeros((3, 1)), np.array([[np.nan, 0.5, 0.5]])],
)
def test_bad_p_hat_is_rejected(bad: np.ndarray) -> None:
    with pytest.raises(DetectorError, match="p_hat"):
        top_k_boundaries(bad, 1)


def test_bad_arguments_are_rejected() -> None:
    with pytest.raises(DetectorError, match="k"):
        top_k_boundaries(P_HAT, 0)
    with pytest.raises(DetectorError, match="weighting"):
        depth_scores(P_HAT, "median")  # type: ignore[arg-type]
    with pytest.raises(DetectorError, match="standardisation"):
        standardise(np.array([0.0, 1.0]), "zscore")  # type: ignore[arg-type]


def _brute_force(scores: np.ndarray, k: int, min_length: int, end: bool) -> tuple[float, list[int]]:
    """Best score sum over every boundary set that satisfies the constraints (earliest on ties)."""
    import itertools

    best: tuple[float, list[int]] = (-np.inf, [])
    for combo in itertools.combinations(range(len(scores)), k):
        if end and combo[-1] != len(scores) - 1:
            continue
        starts = np.diff(np.concatenate([[-1], combo]))
        if starts.min() < min_length:
            continue
        total = float(scores[list(combo)].sum())
        if total > best[0] + 1e-12:
            best = (total, list(combo))
    return best


@pytest.mark.parametrize("min_length", [1, 2, 3])
@pytest.mark.parametrize("end", [True, False])
def test_constrained_top_k_is_the_best_feasible_set(min_length: int, end: bool) -> None:
    rng = np.random.default_rng(min_length + 10 * end)
    for _ in range(40):
        steps, k = int(rng.integers(9, 13)), int(rng.integers(1, 4))
        p_hat = rng.dirichlet(np.ones(3), size=steps)
        got = constrained_top_k_boundaries(p_hat, k, min_length=min_length, end_is_boundary=end)
        scores = depth_scores(p_hat)
        total, expected = _brute_force(scores, k, min_length, end)
        assert float(scores[got].sum()) == pytest.approx(total)
        np.testing.assert_array_equal(got, expected)
        assert got.dtype == np.int64 and np.all(np.diff(np.concatenate([[-1], got])) >= min_length)


def test_constrained_top_k_without_constraints_is_top_k() -> None:
    rng = np.random.default_rng(0)
    for _ in range(30):
        p_hat = rng.dirichlet(np.ones(3), size=20)
        np.testing.assert_array_equal(
            constrained_top_k_boundaries(p_hat, 4, min_length=1, end_is_boundary=False),
            top_k_boundaries(p_hat, 4),
        )


def test_constrained_top_k_keeps_one_of_two_neighbouring_peaks_and_the_end() -> None:
    # one expansion spread over steps 3 and 4 takes two places in plain Top-K; the true boundary at 7
    # (a weaker peak) and the episode end are what the constraints recover
    scores = [0.0, 0.0, 0.1, 0.9, 0.8, 0.0, 0.1, 0.5, 0.0, 0.3]
    p_hat = np.array([[0.0, s, 1.0 - s] for s in scores])
    np.testing.assert_array_equal(top_k_boundaries(p_hat, 3), [3, 4, 7])
    np.testing.assert_array_equal(constrained_top_k_boundaries(p_hat, 3), [3, 7, 9])
    np.testing.assert_array_equal(constrained_top_k_boundaries(p_hat, 3, end_is_boundary=False), [3, 7, 9])
    np.testing.assert_array_equal(constrained_top_k_boundaries(p_hat, 2, end_is_boundary=False), [3, 7])


def test_constrained_top_k_on_short_episodes() -> None:
    p_hat = np.tile([0.0, 0.5, 0.5], (5, 1))
    # 3 subtasks of >= 2 steps do not fit in 5 steps: min_length drops to 5 // 3 = 1
    got = constrained_top_k_boundaries(p_hat, 3, min_length=2)
    assert len(got) == 3 and got[-1] == 4 and len(set(got.tolist())) == 3
    np.testing.assert_array_equal(constrained_top_k_boundaries(p_hat[:2], 3), [0, 1])


@pytest.mark.parametrize("bad", [0, -1, 1.5, True])
def test_constrained_top_k_rejects_a_bad_min_length(bad: object) -> None:
    with pytest.raises(DetectorError, match="min_length"):
        constrained_top_k_boundaries(P_HAT, 2, min_length=bad)  # type: ignore[arg-type]
