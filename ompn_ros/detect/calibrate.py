"""Choosing the online detector of a checkpoint: tuned on labels, or calibrated without them.

Both variants run the same grid search (:func:`default_grid`, the grid of ``ompn_segment --tune``)
with the same objective (:func:`pick_setting`: the objective metric, then the other one, then the
shorter detection delay) over per-episode score sequences of validation episodes.  They differ in
the boundaries the online detections are scored against, and in how close to the best objective
a setting must be to count as tied on it (with labels: one standard error over the episodes,
:func:`pick_within_error`; without them: exactly equal):

* :func:`tune_on_labels`: the episodes' true subtask boundaries;
* :func:`calibrate_label_free`: a whole-episode *reference* computed from the same model's
  expansion distributions, no labels (:func:`reference_boundaries`): the paper's automatic
  threshold (Lu et al., ICLR 2021, Algorithm 2) with the boundary at the onset of each run above
  it (``'auto_threshold_onset'``, the default) or at its last step as in Algorithm 1
  (``'auto_threshold'``), or the constrained Top-K with K = the automatic threshold's count of
  runs, counted per episode (``'constrained_top_k'``) or pooled: the median count over the
  episodes of the same task (``'pooled_top_k'``, :func:`pooled_counts`), or two at once
  (``'onset_and_pooled'``: the mean of the metrics against the onset and the pooled reference).
  The causal detector is made to agree as well as possible with what the model itself says when
  it sees the whole episode.  ``ompn_train`` uses the combined reference
  (:data:`~ompn_ros.detect.defaults.LABEL_FREE_REFERENCE`; why, with its figures:
  docs/design.md#label-free-calibration).

The grid is evaluated for all settings and episodes at once (:mod:`ompn_ros.detect.grid`); the
references are :mod:`ompn_ros.detect.reference`, the duration decoders' thresholds
:mod:`ompn_ros.detect.duration_tuning`; which of these ``ompn_train`` and ``ompn_segment --tune``
run, and with which defaults, is decided in :mod:`ompn_ros.detect.choose`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ompn_ros.detect.defaults import Objective
from ompn_ros.detect.errors import CalibrationError
from ompn_ros.detect.grid import evaluate_grid, grid_rows, label_boundaries, scores_from_p_hats
from ompn_ros.detect.online import DetectorConfig
from ompn_ros.detect.reference import COMBINED, Reference, references
from ompn_ros.detect.tune import OBJECTIVES, default_grid, pick_setting, pick_within_error


@dataclass(frozen=True)
class Calibration:
    """Result of a grid search: the chosen setting, its metrics, and how it was chosen."""

    config: DetectorConfig
    metrics: dict[str, float]
    objective: Objective
    target: str  # 'labels' or the label-free reference's name
    n_episodes: int


def search(
    scores: Sequence[np.ndarray],
    target_boundaries: Sequence[np.ndarray],
    target_labels: Sequence[np.ndarray] | None,
    objective: Objective,
    grid: Sequence[DetectorConfig] | None = None,
    target: str = "labels",
) -> Calibration:
    """The grid setting :func:`pick_within_error` keeps (one standard error over the episodes)."""
    grid = _checked_grid(grid, objective)
    found = grid_rows(scores, grid, target_boundaries, target_labels)
    best = pick_within_error(found.rows, objective, found.per_episode, found.lengths)
    return Calibration(grid[best], found.rows[best], objective, target, len(scores))


def _checked_grid(grid: Sequence[DetectorConfig] | None, objective: Objective) -> list[DetectorConfig]:
    """``grid`` (default: :func:`default_grid`) as a list, after checking it and ``objective``."""
    if objective not in OBJECTIVES:
        raise CalibrationError(f"objective must be one of {OBJECTIVES}, got {objective!r}")
    grid = list(grid or default_grid())
    if not grid:
        raise CalibrationError("grid: need at least one detector setting")
    return grid


def _best(grid: list[DetectorConfig], rows: list[dict[str, float]], objective: Objective, target: str,
          n_episodes: int) -> Calibration:
    """The setting :func:`pick_setting` keeps (the label-free calibration: agreement with a reference
    the same model computed, so no standard error over episodes applies)."""
    best = pick_setting(rows, objective)
    return Calibration(grid[best], rows[best], objective, target, n_episodes)


def tune_on_labels(
    scores: Sequence[np.ndarray],
    labels: Sequence[np.ndarray],
    objective: Objective = "f1",
    grid: Sequence[DetectorConfig] | None = None,
) -> Calibration:
    """The online detector that best finds the labelled subtask boundaries (validation episodes)."""
    labels = [np.asarray(lab, dtype=np.int64) for lab in labels]
    return search(scores, label_boundaries(labels), labels, objective, grid, "labels")


def calibrate_label_free(
    p_hats: Sequence[np.ndarray],
    objective: Objective = "f1",
    reference: Reference = "auto_threshold_onset",
    *,
    min_length: int = 2,
    scores: Sequence[np.ndarray] | None = None,
    grid: Sequence[DetectorConfig] | None = None,
    tasks: Sequence[str] | None = None,
) -> Calibration:
    """The online detector that best agrees with the label-free ``reference`` on ``p_hats``.

    ``scores`` are the online scores of the same episodes (default: computed from ``p_hats``, which
    equals a streaming replay's up to float rounding); ``tasks`` the episodes' task names, which
    ``'pooled_top_k'`` pools its counts over.  A combined reference (:data:`COMBINED`) scores every
    setting by the mean of its metrics against the parts.  ``O(P·G·E·T)`` for P parts.
    """
    online = list(scores) if scores is not None else scores_from_p_hats(p_hats)
    grid = _checked_grid(grid, objective)
    parts = [
        evaluate_grid(online, grid, references(p_hats, part, min_length, tasks))
        for part in COMBINED.get(reference, (reference,))
    ]
    rows = [{key: float(np.mean([part[g][key] for part in parts])) for key in first} for g, first in
            enumerate(parts[0])]
    return _best(grid, rows, objective, reference, len(online))


__all__ = [
    "Calibration",
    "calibrate_label_free",
    "search",
    "tune_on_labels",
]
