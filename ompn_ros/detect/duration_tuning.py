"""The threshold of the duration decoders ('hsmm', 'head_hsmm'), chosen on target boundaries.

:func:`calibrate_duration` fits the duration model of mode 'hsmm' (:mod:`ompn_ros.detect.duration`)
on target boundaries (labels or a label-free reference) and chooses its posterior threshold with the
tuning's objective (:func:`~ompn_ros.detect.tune.objective_key`) within a mean-delay budget;
:func:`calibrate_head_duration` does the same for the duration decoder over the boundary head.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ompn_ros.detect.duration import DurationDetector, DurationModel, fit_duration_model
from ompn_ros.detect.errors import CalibrationError
from ompn_ros.detect.head_duration import decode_head_duration
from ompn_ros.detect.online import (
    DURATION_MODE,
    HEAD_DURATION_MODE,
    BoundaryEvent,
    DetectorConfig,
    run_detector,
)
from ompn_ros.detect.tune import Objective, objective_key
from ompn_ros.metrics import alignment_accuracy, labels_from_boundaries, mean_f1

DURATION_THRESHOLDS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.85, 0.9, 0.95, 0.98, 0.99)
"""The posterior thresholds :func:`calibrate_duration` chooses from: the higher, the later and surer
the boundaries (docs/design.md#delay-budget)."""


@dataclass(frozen=True)
class DurationCalibration:
    """The fitted duration model, the chosen 'hsmm' detector and its metrics against the targets."""

    model: DurationModel
    config: DetectorConfig
    metrics: dict[str, float]


def calibrate_duration(
    scores: Sequence[np.ndarray],
    target_boundaries: Sequence[np.ndarray],
    lag: int,
    objective: Objective = "align",
    thresholds: Sequence[float] = DURATION_THRESHOLDS,
    max_delay: float | None = None,
) -> DurationCalibration:
    """Fit the duration model on ``target_boundaries`` (each episode's segment ends, its last step
    included) and choose the threshold of the 'hsmm' detector with ``lag`` by :func:`objective_key`
    against the same targets, among the thresholds whose mean delay (steps from an inner boundary to
    its publication, those decided at the episode end included) is at most ``max_delay`` (None: any;
    none within it: the threshold of the shortest delay).  O(len(thresholds) · Σ T · K · n²), ``n``
    the steps between published boundaries."""
    model = fit_duration_model(scores, target_boundaries)
    detector = DurationDetector(model, lag)

    def events(threshold: float) -> list[list[BoundaryEvent]]:
        detector.threshold = threshold
        return [run_detector(detector, s) for s in scores]

    high, metrics = _pick_threshold(events, target_boundaries, [len(s) for s in scores], objective,
                                    thresholds, max_delay)
    return DurationCalibration(model, DetectorConfig(mode=DURATION_MODE, high=high, lag=lag), metrics)


def calibrate_head_duration(
    model: DurationModel,
    rows: Sequence[np.ndarray],
    target_boundaries: Sequence[np.ndarray],
    lag: int,
    objective: Objective = "align",
    thresholds: Sequence[float] = DURATION_THRESHOLDS,
    max_delay: float | None = None,
) -> DurationCalibration:
    """The threshold of mode 'head_hsmm' (the duration decoder of ``model`` over the boundary head's
    probabilities ``rows`` ``[T, max_lag + 1]`` per episode) with ``lag``, chosen as
    :func:`calibrate_duration` chooses it, against ``target_boundaries``."""

    def events(threshold: float) -> list[list[BoundaryEvent]]:
        config = DetectorConfig(mode=HEAD_DURATION_MODE, high=threshold, lag=lag)
        return [decode_head_duration(model, r, config) for r in rows]

    high, metrics = _pick_threshold(events, target_boundaries, [len(r) for r in rows], objective,
                                    thresholds, max_delay)
    return DurationCalibration(model, DetectorConfig(mode=HEAD_DURATION_MODE, high=high, lag=lag), metrics)


def _pick_threshold(
    decode: Callable[[float], list[list[BoundaryEvent]]], targets: Sequence[np.ndarray],
    lengths: Sequence[int],
    objective: Objective, thresholds: Sequence[float], max_delay: float | None,
) -> tuple[float, dict[str, float]]:
    """The threshold whose decoding ``decode(θ)`` is best by :func:`objective_key` against ``targets``
    among those of mean delay at most ``max_delay`` (None: any; none within it: the shortest delay);
    returned with its metrics."""
    if not thresholds:
        raise CalibrationError("thresholds: need at least one")
    if max_delay is not None and not max_delay > 0:
        raise CalibrationError(f"max_delay must be > 0 steps, got {max_delay!r}")
    labels = [labels_from_boundaries(b, n) for b, n in zip(targets, lengths, strict=True)]
    rows = [_events_row(decode(threshold), targets, labels) for threshold in thresholds]
    allowed = [i for i, row in enumerate(rows) if max_delay is None or row["delay_mean"] <= max_delay]
    if allowed:
        best = max(allowed, key=lambda i: (objective_key(rows[i], objective), -i))
    else:
        best = min(range(len(rows)), key=lambda i: (rows[i]["delay_mean"], i))
    return float(thresholds[best]), rows[best]


def _events_row(events: Sequence[Sequence[BoundaryEvent]], targets: Sequence[np.ndarray],
                labels: Sequence[np.ndarray]) -> dict[str, float]:
    """F1, alignment and mean delay of a decoder's ``events`` against ``targets``."""
    preds = [np.array([e.step for e in evs], dtype=np.int64) for evs in events]
    delays = [e.detected_at - e.step for evs in events for e in evs if not e.final]
    align = alignment_accuracy(preds, labels, "strict")
    return {"f1_tol0": mean_f1(preds, targets, 0).f1, "f1_tol1": mean_f1(preds, targets, 1).f1,
            "align": align, "align_strict": align,
            "delay_mean": float(np.mean(delays)) if delays else 0.0}


__all__ = [
    "DURATION_THRESHOLDS",
    "DurationCalibration",
    "calibrate_duration",
    "calibrate_head_duration",
]
