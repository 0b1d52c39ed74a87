"""Whole-episode boundaries without labels: the references the label-free calibration agrees with.

:func:`reference_boundaries` computes them from one model's expansion distributions: the paper's
automatic threshold (Lu et al., ICLR 2021, Algorithm 2) with the boundary at the onset of each run
above it (``'auto_threshold_onset'``) or at its last step as in Algorithm 1 (``'auto_threshold'``),
or the constrained Top-K with K = the automatic threshold's count of runs, counted per episode
(``'constrained_top_k'``) or pooled: the median count over the episodes of the same task
(``'pooled_top_k'``, :func:`pooled_counts`); ``'onset_and_pooled'`` combines two
(:data:`COMBINED`).  Which of them ``ompn_train`` uses is
:data:`ompn_ros.detect.defaults.LABEL_FREE_REFERENCE` (docs/design.md#label-free-calibration).
:func:`agreement` is the label-free checkpoint-selection criterion built on the same pieces.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, get_args

import numpy as np

from ompn_ros.detect.errors import CalibrationError
from ompn_ros.detect.grid import (
    detect_grid,
    evaluate_grid,
    mean_f1_masks,
    padded_scores,
    scores_from_p_hats,
    target_masks,
)
from ompn_ros.detect.offline import (
    auto_threshold,
    constrained_top_k_boundaries,
    depth_scores,
    standardise,
)
from ompn_ros.detect.online import DetectorConfig

Reference = Literal[
    "auto_threshold_onset", "auto_threshold", "constrained_top_k", "pooled_top_k", "onset_and_pooled"
]
REFERENCES: tuple[Reference, ...] = get_args(Reference)
COMBINED: dict[str, tuple[Reference, ...]] = {"onset_and_pooled": ("auto_threshold_onset", "pooled_top_k")}
"""References made of others: the calibration maximises the mean of the parts' metrics."""


def estimated_count(p_hat: np.ndarray) -> int:
    """Number of boundaries of the automatic threshold (Algorithm 2, then Algorithm 1 with every
    falling edge plus the last step): the label-free estimate of K."""
    std = standardise(depth_scores(p_hat))
    threshold = auto_threshold(std).threshold
    above = std > threshold
    return int(np.count_nonzero(above[:-1] & ~above[1:])) + 1


def pooled_counts(p_hats: Sequence[np.ndarray], tasks: Sequence[str] | None = None) -> list[int]:
    """Per episode, the number of subtasks estimated from its whole task: the median of
    :func:`estimated_count` over the episodes with the same task name (all episodes when ``tasks``
    is None), halves rounded up.  A task's demonstrations share their subtask count far more often
    than one episode's automatic threshold finds it.  O(E log E) after the counts."""
    if tasks is not None and len(tasks) != len(p_hats):
        raise CalibrationError(f"tasks: {len(tasks)} names for {len(p_hats)} episodes")
    names = list(tasks) if tasks is not None else [""] * len(p_hats)
    counts = np.array([estimated_count(p) for p in p_hats], dtype=np.float64)
    median = {t: int(np.floor(np.median(counts[[n == t for n in names]]) + 0.5)) for t in set(names)}
    return [median[n] for n in names]


def reference_boundaries(
    p_hat: np.ndarray,
    reference: Reference = "auto_threshold_onset",
    min_length: int = 2,
    count: int | None = None,
) -> np.ndarray:
    """Whole-episode boundaries of one episode without labels (see the module docstring); the last
    step is always one.  ``min_length`` is the constrained Top-K's; ``count`` its K, required by
    ``'pooled_top_k'`` (:func:`pooled_counts`)."""
    if reference not in REFERENCES:
        raise CalibrationError(f"reference must be one of {REFERENCES}, got {reference!r}")
    if reference in COMBINED:
        raise CalibrationError(f"reference {reference!r} combines {COMBINED[reference]}: ask for each part")
    if reference == "pooled_top_k" and count is None:
        raise CalibrationError("reference 'pooled_top_k' needs the episode's count (pooled_counts)")
    p = np.asarray(p_hat, dtype=np.float64)
    std = standardise(depth_scores(p))
    if reference in ("auto_threshold", "auto_threshold_onset"):
        above = std > auto_threshold(std).threshold
        if reference == "auto_threshold":
            edges = np.flatnonzero(above[:-1] & ~above[1:])  # last step of each run
        else:
            edges = np.flatnonzero(~above[:-1] & above[1:]) + 1  # first step of each run
        return np.unique(np.append(edges, len(std) - 1)).astype(np.int64)
    k = estimated_count(p) if count is None else count
    return constrained_top_k_boundaries(p, k, min_length=min_length)


def references(
    p_hats: Sequence[np.ndarray], reference: Reference, min_length: int, tasks: Sequence[str] | None
) -> list[np.ndarray]:
    """:func:`reference_boundaries` of every episode (pooled counts for ``'pooled_top_k'``)."""
    counts: list[int | None] = (
        list(pooled_counts(p_hats, tasks)) if reference == "pooled_top_k" else [None] * len(p_hats)
    )
    return [reference_boundaries(p, reference, min_length, k) for p, k in zip(p_hats, counts, strict=True)]


SELECTION_GRID_HIGHS = tuple(round(float(h), 2) for h in np.arange(0.05, 0.91, 0.05))


def agreement(
    p_hats: Sequence[np.ndarray], reference: Reference = "auto_threshold_onset", min_length: int = 2
) -> float:
    """Label-free checkpoint-selection criterion in [0, 1]: how well the best causal detector of the
    grid can reproduce the model's own whole-episode segmentation on these episodes.

    ``(F1(tol 1) + alignment) / 2`` of the best setting against :func:`reference_boundaries`, with
    the episode's last step removed from both boundary sets before the F1 (every detector gets it
    for free) and an episode whose reference has no inner boundary counting 0: a model whose
    expansion scores carry no subtask structure cannot score by agreeing on nothing.
    """
    refs = references(p_hats, reference, min_length, None)
    scores = scores_from_p_hats(p_hats)
    grid = [DetectorConfig(high=h) for h in SELECTION_GRID_HIGHS]
    rows = evaluate_grid(scores, grid, refs)
    marks = detect_grid(scores, grid)
    _, lengths = padded_scores(scores)
    gt = target_masks(refs, lengths, marks.shape[-1])
    ends = np.arange(len(scores)), lengths - 1
    gt[ends] = False
    marks[:, ends[0], ends[1]] = False
    inner_f1 = mean_f1_masks(marks, gt, 1)
    values = [(float(inner_f1[g]) + rows[g]["align"]) / 2 for g in range(len(grid))]
    return max(values)


__all__ = [
    "COMBINED",
    "REFERENCES",
    "SELECTION_GRID_HIGHS",
    "Reference",
    "agreement",
    "estimated_count",
    "pooled_counts",
    "reference_boundaries",
    "references",
]
