"""Offline subtask-boundary detectors over a whole episode of expansion distributions.

Every detector reads ``p_hat`` of shape ``[T, n + 1]`` ordered ``[π_end, slot n (top), …, slot 1
(bottom)]`` (unnormalised, rows sum to 1), i.e. the teacher-forced output for the ``T`` real steps
of an episode (the appended done step removed).  Boundaries are returned as sorted int64 step
indices; a boundary ``b`` means "step ``b`` is the last step of a subtask".

Two ways of summarising ``p_hat`` into one score per step are offered (higher = the memory expands
from a higher level = more likely a boundary):

* ``weighting='code'`` (authors' code, docs/craft.md §5.2–5.3, docs/dial.md §4.5): ``a_t = Σ_k w_k p̂_t[k]``
  with ``w = [n, n−1, …, 0]``, so ``π_end`` weighs ``n`` and the bottom slot ``0``.
* ``weighting='paper'`` (paper §3.3): ``π_avg = Σ_{i=1..n} i·π_i`` over the *normalised* slot
  distribution ``π = p̂[slots] / (1 − π_end)``, lowest slot ``i = 1``; ``π_end`` is ignored.

In both, step 0 is forced to "expand at the bottom" by default (the code does this because the
first step hard-codes an expansion from the top slot, docs/craft.md §3.6).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from ompn_ros.detect.errors import DetectorError

Weighting = Literal["code", "paper"]
Standardisation = Literal["code", "minmax"]

FALLBACK_THRESHOLD = 0.5
"""Threshold used by :func:`auto_threshold` when the score curve has no peak or no valley."""


@dataclass(frozen=True)
class AutoThreshold:
    """Result of the automatic threshold selection (paper Algorithm 2).

    Attributes:
        threshold: the selected threshold ((upper + lower) / 2, or the fallback).
        upper: the highest peak value (``nan`` when there is no peak).
        lower: the lowest valley value (``nan`` when there is no valley).
        fallback: True when there was no peak or no valley and ``FALLBACK_THRESHOLD`` was used.
    """

    threshold: float
    upper: float
    lower: float
    fallback: bool


def _check_p_hat(p_hat: np.ndarray) -> np.ndarray:
    arr = np.asarray(p_hat, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] < 2:
        raise DetectorError(f"p_hat must have shape [T, n+1] with n >= 1, got shape {arr.shape}")
    if arr.shape[0] == 0:
        raise DetectorError("p_hat is empty (T = 0): an episode needs at least one step")
    if not np.all(np.isfinite(arr)):
        raise DetectorError("p_hat contains NaN or infinite values")
    return arr


def _check_k(k: int) -> int:
    if int(k) != k or k < 1:
        raise DetectorError(f"k (number of boundaries) must be a positive integer, got {k!r}")
    return int(k)


def depth_scores(
    p_hat: np.ndarray, weighting: Weighting = "code", force_first_bottom: bool = True
) -> np.ndarray:
    """Per-step expected expansion height, higher = higher expansion (``[T]`` float64).

    ``weighting='code'``: ``a_t = Σ_k (n − k) p̂_t[k]`` (π_end → n, top slot → n−1, bottom → 0).
    This is ``n − depth_t`` with the Top-K "depth" of docs/craft.md §5.2, so the K largest scores are the
    K smallest depths.  ``weighting='paper'``: ``π_avg = Σ_{i=1..n} i·π_i`` (paper §3.3).
    With ``force_first_bottom`` step 0 gets the bottom-slot value (code: 0, paper: 1).
    """
    arr = _check_p_hat(p_hat)
    n = arr.shape[1] - 1
    if weighting == "code":
        weights = np.arange(n, -1, -1, dtype=np.float64)  # [n, n-1, ..., 0]
        scores = arr @ weights
        bottom = 0.0
    elif weighting == "paper":
        slots = arr[:, 1:]  # top first
        total = slots.sum(axis=1, keepdims=True)
        pi = slots / np.maximum(total, 1e-12)
        weights = np.arange(n, 0, -1, dtype=np.float64)  # top slot is i = n, bottom is i = 1
        scores = pi @ weights
        bottom = 1.0
    else:
        raise DetectorError(f"weighting must be 'code' or 'paper', got {weighting!r}")
    if force_first_bottom:
        scores[0] = bottom
    return scores


pi_avg = depth_scores
"""Alias: the paper calls the per-step score π_avg (expected expansion position)."""


def top_k_boundaries(
    p_hat: np.ndarray,
    k: int,
    weighting: Weighting = "code",
    exclude_first: bool = True,
) -> np.ndarray:
    """Top-K detection (docs/craft.md §5.2): the ``k`` steps with the highest score, sorted by time.

    Ties are broken towards the earlier step (deterministic; the code's ``torch.topk`` leaves them
    implementation-defined).  With ``exclude_first`` step 0 can never be chosen (in the code step 0
    can only be chosen through ties, since it is forced to the bottom).  If fewer than ``k``
    candidate steps exist, all candidates are returned.
    """
    k = _check_k(k)
    scores = depth_scores(p_hat, weighting)
    candidates = np.arange(1 if exclude_first else 0, len(scores))
    order = np.argsort(-scores[candidates], kind="stable")
    chosen = candidates[order[:k]]
    return np.sort(chosen).astype(np.int64)


def constrained_top_k_boundaries(
    p_hat: np.ndarray,
    k: int,
    *,
    min_length: int = 2,
    end_is_boundary: bool = True,
    weighting: Weighting = "code",
) -> np.ndarray:
    """Top-K restricted to boundary sets every episode can have (our extension; not in the paper).

    Plain Top-K (:func:`top_k_boundaries`) picks the ``k`` steps whose scores
    (:func:`depth_scores`) have the largest sum.  This detector maximises the same sum, but only
    over sets in which

    * every subtask lasts at least ``min_length`` steps (``b_1 + 1 ≥ min_length`` and
      ``b_{i+1} − b_i ≥ min_length``), so one expansion spread over two neighbouring steps cannot
      take two of the ``k`` places, and
    * with ``end_is_boundary``, the last step ``T − 1`` is one of the boundaries: an episode ends
      when its last subtask ends, and the ground truth always contains ``T − 1``.

    The maximum is found exactly by dynamic programming over (boundary count, last boundary),
    ``O(k·T)``; ties go to the earlier steps.  With ``min_length = 1`` and ``end_is_boundary=False``
    it is plain Top-K (up to ties at step 0).  When the episode is too short for ``k`` subtasks of
    ``min_length`` steps, ``min_length`` is lowered to ``T // k``; when ``T < k`` every step is
    returned.
    """
    k = _check_k(k)
    if isinstance(min_length, bool) or int(min_length) != min_length or min_length < 1:
        raise DetectorError(f"min_length (steps per subtask) must be an integer >= 1, got {min_length!r}")
    scores = depth_scores(p_hat, weighting)
    length = len(scores)
    if length <= k:
        return np.arange(length, dtype=np.int64)
    gap = min(int(min_length), length // k)
    # best[c, t]: the largest score sum of c + 1 boundaries with the last one at step t
    best = np.full((k, length), -np.inf)
    prev = np.zeros((k, length), dtype=np.int64)
    best[0, gap - 1 :] = scores[gap - 1 :]
    steps = np.arange(length)
    for c in range(1, k):
        # the best predecessor at or before each step (its running maximum; the first one on ties)
        running = np.maximum.accumulate(best[c - 1])
        rises = np.concatenate([[best[c - 1, 0] > -np.inf], best[c - 1, 1:] > running[:-1]])
        first = np.maximum.accumulate(np.where(rises, steps, 0))
        best[c, gap:] = scores[gap:] + running[:-gap]
        prev[c, gap:] = first[:-gap]
    last = length - 1 if end_is_boundary else int(np.argmax(best[k - 1]))
    chosen = [last]
    for c in range(k - 1, 0, -1):
        last = int(prev[c, last])
        chosen.append(last)
    return np.asarray(chosen[::-1], dtype=np.int64)


def standardise(scores: np.ndarray, mode: Standardisation = "code") -> np.ndarray:
    """Scale scores for thresholding.

    ``mode='code'`` reproduces the authors' code: ``a / (max − min)`` **without subtracting the
    min** (docs/craft.md §5.3, docs/dial.md §4.5 (b)); with step 0 forced to the bottom the min is 0 under the
    code weighting, so this equals ``a / max``.  ``mode='minmax'`` is the strict ``(a − min) / (max −
    min)`` of the paper's wording ("standardize from 0 to 1").  A constant curve (max == min) maps to
    all zeros in both modes, so no step is above any threshold ≥ 0.
    """
    arr = np.asarray(scores, dtype=np.float64)
    if arr.ndim != 1 or arr.size == 0:
        raise DetectorError(f"scores must be a non-empty 1-D array, got shape {arr.shape}")
    span = float(arr.max() - arr.min())
    if span <= 0.0:
        return np.zeros_like(arr)
    if mode == "code":
        return arr / span
    if mode == "minmax":
        return (arr - arr.min()) / span
    raise DetectorError(f"standardisation mode must be 'code' or 'minmax', got {mode!r}")


def boundaries_from_threshold(std_scores: np.ndarray, threshold: float, k: int) -> np.ndarray:
    """Paper Algorithm 1 on already standardised scores.

    Every falling edge (score ``> threshold`` at ``t − 1``, not at ``t``) gives boundary ``t − 1``;
    the last step ``L − 1`` is always appended, then the last ``k`` entries are kept.  Fewer than
    ``k`` may be returned.  (If the curve is above the threshold at ``L − 1`` no falling edge is
    recorded there, and ``L − 1`` appears once.)
    """
    k = _check_k(k)
    arr = np.asarray(std_scores, dtype=np.float64)
    if arr.ndim != 1 or arr.size == 0:
        raise DetectorError(f"std_scores must be a non-empty 1-D array, got shape {arr.shape}")
    above = arr > threshold
    falling = np.flatnonzero(above[:-1] & ~above[1:])  # index t-1 of each falling edge at t
    preds = np.concatenate([falling, [arr.size - 1]]).astype(np.int64)
    return preds[-k:]


def threshold_boundaries(
    p_hat: np.ndarray,
    threshold: float,
    k: int,
    weighting: Weighting = "code",
    standardisation: Standardisation = "code",
) -> np.ndarray:
    """Threshold detection (paper §3.3 and Algorithm 1; docs/dial.md §4.5 steps 1–4)."""
    std = standardise(depth_scores(p_hat, weighting), standardisation)
    return boundaries_from_threshold(std, threshold, k)


def auto_threshold(std_scores: np.ndarray) -> AutoThreshold:
    """Paper Algorithm 2: midway between the highest peak and the lowest valley.

    A peak is an interior index ``i`` with ``d[i−1] > 0`` and ``d[i] < 0`` (``d`` = first
    difference), a valley the reverse.  The authors' code crashes when there is no peak or no
    valley (e.g. a monotone curve); here the threshold falls back to ``FALLBACK_THRESHOLD`` (0.5)
    and ``fallback`` is set.
    """
    arr = np.asarray(std_scores, dtype=np.float64)
    if arr.ndim != 1 or arr.size == 0:
        raise DetectorError(f"std_scores must be a non-empty 1-D array, got shape {arr.shape}")
    diff = np.diff(arr)
    if diff.size < 2:
        return AutoThreshold(FALLBACK_THRESHOLD, float("nan"), float("nan"), True)
    prev, curr = diff[:-1], diff[1:]
    peaks = np.flatnonzero((curr < 0) & (prev > 0)) + 1
    valleys = np.flatnonzero((curr > 0) & (prev < 0)) + 1
    upper = float(arr[peaks].max()) if peaks.size else float("nan")
    lower = float(arr[valleys].min()) if valleys.size else float("nan")
    if peaks.size == 0 or valleys.size == 0:
        return AutoThreshold(FALLBACK_THRESHOLD, upper, lower, True)
    return AutoThreshold((upper + lower) / 2.0, upper, lower, False)


def auto_threshold_boundaries(
    p_hat: np.ndarray,
    k: int,
    weighting: Weighting = "code",
    standardisation: Standardisation = "code",
) -> tuple[np.ndarray, AutoThreshold]:
    """Threshold detection with the automatically selected threshold (the paper's Dial method)."""
    std = standardise(depth_scores(p_hat, weighting), standardisation)
    auto = auto_threshold(std)
    return boundaries_from_threshold(std, auto.threshold, k), auto
