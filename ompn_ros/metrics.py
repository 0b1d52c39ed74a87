"""Task-decomposition metrics: F1 with tolerance and alignment accuracy (paper Appendix D).

Boundaries are step indices ``b`` meaning "step ``b`` is the last step of a subtask"; ground-truth
boundaries come from :func:`ompn_ros.data.episode.boundaries_from_labels` (they always include the
last step ``T − 1``).  Labels are 0-based subtask ordinals within the episode.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ompn_ros.errors import OMPNError

AlignVariant = Literal["authors", "strict"]


class MetricError(OMPNError, ValueError):
    """Invalid input to a metric (names the argument at fault)."""


@dataclass(frozen=True)
class F1Result:
    """Precision, recall and F1 (for one episode, or averaged over episodes)."""

    precision: float
    recall: float
    f1: float


def _as_index_array(values: Sequence[int] | np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(values)
    if arr.ndim != 1:
        raise MetricError(f"{name} must be a 1-D sequence of step indices, got shape {arr.shape}")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        if not np.all(np.equal(np.mod(arr, 1), 0)):
            raise MetricError(f"{name} must contain integer step indices, got {arr.tolist()}")
    return arr.astype(np.int64)


def f1_with_tolerance(pred: Sequence[int] | np.ndarray, gt: Sequence[int] | np.ndarray, tol: int) -> F1Result:
    """F1 of predicted vs ground-truth boundaries for one episode (docs/craft.md §5.4).

    ``precision = #{p ∈ pred : ∃ g ∈ gt, |p − g| ≤ tol} / #pred`` and
    ``recall = #{g ∈ gt : ∃ p ∈ pred, |g − p| ≤ tol} / #gt``; ``F1 = 2PR / (P + R)`` or 0 if
    ``P + R = 0``.  **Not one-to-one**: one prediction may cover several ground-truth boundaries and
    vice versa (the authors' definition; the paper labels the recall formula "precision").  A step
    predicted twice is one boundary (an episode end at the step of the last subtask's end:
    docs/design.md#episode-end).  An empty ``pred`` gives precision 0; an empty ``gt`` gives recall 0.
    """
    if int(tol) != tol or tol < 0:
        raise MetricError(f"tol must be a non-negative integer, got {tol!r}")
    p = np.unique(_as_index_array(pred, "pred"))
    g = _as_index_array(gt, "gt")
    if p.size == 0 or g.size == 0:
        # no prediction: nothing is precise and no GT boundary is found; no GT: nothing to recall and
        # no prediction can match
        return F1Result(0.0, 0.0, 0.0)
    close = np.abs(p[:, None] - g[None, :]) <= tol  # [pred, gt]
    precision = float(close.any(axis=1).mean())
    recall = float(close.any(axis=0).mean())
    f1 = 0.0 if precision + recall == 0 else 2 * precision * recall / (precision + recall)
    return F1Result(precision, recall, f1)


def mean_f1(
    preds: Sequence[Sequence[int] | np.ndarray],
    gts: Sequence[Sequence[int] | np.ndarray],
    tol: int,
) -> F1Result:
    """Per-episode :func:`f1_with_tolerance`, then the plain mean of P, R and F1 over episodes."""
    if len(preds) != len(gts):
        raise MetricError(f"preds has {len(preds)} episodes but gts has {len(gts)}")
    if len(preds) == 0:
        raise MetricError("mean_f1 needs at least one episode")
    results = [f1_with_tolerance(p, g, tol) for p, g in zip(preds, gts, strict=True)]
    return F1Result(
        float(np.mean([r.precision for r in results])),
        float(np.mean([r.recall for r in results])),
        float(np.mean([r.f1 for r in results])),
    )


def labels_from_boundaries(
    boundaries: Sequence[int] | np.ndarray,
    length: int,
    variant: AlignVariant = "authors",
    num_subtasks: int | None = None,
) -> np.ndarray:
    """Decode sorted boundaries ``b_1 < … < b_K`` into per-step labels ``[length]`` (int64).

    Steps ``(b_{i−1}, b_i]`` (``b_0 = −1``) get label ``i − 1``.  Steps after the last boundary:

    * ``variant='authors'`` (Craft ``get_subtask_seq``, docs/craft.md §5.5): they keep the default
      label **0**, which is a valid subtask id, so they can be accidentally "correct".
    * ``variant='strict'`` (what ompn_dial's ``get_subtask_seq`` does by filling with the last sketch
      token): they belong to the episode's final subtask, label ``num_subtasks − 1``.
      ``num_subtasks`` defaults to ``len(boundaries)`` (the last predicted segment continues).

    Duplicate boundaries are merged; a boundary outside ``[0, length)`` is an error.
    """
    if int(length) != length or length < 0:
        raise MetricError(f"length must be a non-negative integer, got {length!r}")
    b = np.unique(_as_index_array(boundaries, "boundaries"))
    if b.size and (b[0] < 0 or b[-1] >= length):
        raise MetricError(f"boundaries {b.tolist()} fall outside the episode of length {length}")
    if variant == "authors":
        fill = 0
    elif variant == "strict":
        count = len(b) if num_subtasks is None else num_subtasks
        if count < 1 and length > 0:
            raise MetricError("strict decoding needs num_subtasks >= 1 or at least one boundary")
        fill = count - 1
    else:
        raise MetricError(f"variant must be 'authors' or 'strict', got {variant!r}")
    labels = np.full(int(length), fill, dtype=np.int64)
    start = 0
    for i, end in enumerate(b):
        labels[start : end + 1] = i
        start = int(end) + 1
    return labels


def alignment_counts(
    pred_boundaries: Sequence[int] | np.ndarray,
    gt_labels: Sequence[int] | np.ndarray,
    variant: AlignVariant = "authors",
) -> tuple[int, int]:
    """(correct steps, total steps) of one episode (strict: ``K = max(gt_labels) + 1`` subtasks)."""
    gt = _as_index_array(gt_labels, "gt_labels")
    num = int(gt.max()) + 1 if gt.size else None
    decoded = labels_from_boundaries(pred_boundaries, gt.size, variant, num_subtasks=num)
    return int(np.sum(decoded == gt)), int(gt.size)


def alignment_accuracy(
    pred_boundaries: Sequence[Sequence[int] | np.ndarray],
    gt_labels: Sequence[Sequence[int] | np.ndarray],
    variant: AlignVariant = "authors",
) -> float:
    """Alignment accuracy (paper Appendix D.2), **micro-averaged over steps** of all episodes.

    ``Σ_episodes #{t : decoded_t == gt_t} / Σ_episodes T`` (a length-weighted mean, docs/craft.md
    §5.5, docs/dial.md §4.6).  For ``variant='strict'`` the number of subtasks of each episode is taken as
    ``max(gt_labels) + 1`` (the K the user gives the detector).
    """
    if len(pred_boundaries) != len(gt_labels):
        raise MetricError(
            f"pred_boundaries has {len(pred_boundaries)} episodes but gt_labels has {len(gt_labels)}"
        )
    correct = total = 0
    for pred, gt in zip(pred_boundaries, gt_labels, strict=True):
        c, n = alignment_counts(pred, gt, variant)
        correct += c
        total += n
    if total == 0:
        raise MetricError("alignment_accuracy needs at least one step")
    return correct / total
