"""The detector grid evaluated at once: every setting on every episode in one vectorised pass.

:func:`evaluate_grid` scores all settings of a grid against target boundaries (``O(G·E·T)`` numpy
work for G settings, E episodes, T steps), with exactly the semantics of
:class:`~ompn_ros.detect.online.OnlineDetector` closed by ``end_episode``; :func:`grid_on_labels`
adds each setting's metrics per episode, which the one-standard-error rule of a tuning on labels
needs (:func:`~ompn_ros.detect.tune.pick_within_error`).  The choices made with these figures are
:mod:`ompn_ros.detect.calibrate` and :mod:`ompn_ros.detect.choose`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ompn_ros.detect.errors import CalibrationError
from ompn_ros.detect.online import MODES, DetectorConfig, expansion_scores
from ompn_ros.detect.tune import MATCH_TOLERANCE

LAG = {"falling_edge": 1, "peak": 1, "rising_edge": 0}
"""Steps between a boundary and its emission, per mode (see :mod:`ompn_ros.detect.online`)."""


def scores_from_p_hats(p_hats: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Per-step online detector scores (``expansion_scores``) of ``[T, n+1]`` p_hat sequences."""
    return [expansion_scores(np.asarray(p, dtype=np.float64)) for p in p_hats]


def padded_scores(scores: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Scores zero-padded to ``[E, T_max]`` and the episodes' lengths ``[E]``."""
    if not scores:
        raise CalibrationError("scores: need at least one episode")
    lengths = np.array([len(s) for s in scores], dtype=np.int64)
    if lengths.min() < 1:
        raise CalibrationError(f"scores: episode #{int(np.argmin(lengths))} has no steps")
    out = np.zeros((len(scores), int(lengths.max())))
    for i, s in enumerate(scores):
        out[i, : len(s)] = s
    return out, lengths


def detect_grid(scores: Sequence[np.ndarray], grid: Sequence[DetectorConfig]) -> np.ndarray:
    """Boundary masks ``[G, E, T_max]`` of every setting on every episode (episode end closed).

    Equal to the steps of :func:`~ompn_ros.detect.online.detect_sequence`'s events per setting and
    episode, each once (the episode end, at ``T - 1``, may share its step with the last boundary).
    """
    padded, lengths = padded_scores(scores)
    n_eps, t_max = padded.shape
    high = np.array([c.high for c in grid])[:, None]
    low = np.array([c.low_threshold for c in grid])[:, None]
    min_len = np.array([c.min_segment_length for c in grid])[:, None]
    mode = np.array([MODES.index(c.mode) for c in grid])[:, None]
    force = np.array([c.force_first_step_low for c in grid])[:, None]
    offset = np.array([c.offset for c in grid], dtype=np.int64)[:, None]
    rising, peak = mode == MODES.index("rising_edge"), mode == MODES.index("peak")
    shape = (len(grid), n_eps)
    in_run = np.zeros(shape, bool)
    committed = np.zeros(shape, bool)
    prev = np.zeros(shape)
    last = np.full(shape, -1, dtype=np.int64)
    marks = np.zeros((len(grid), n_eps, t_max), bool)
    for t in range(t_max):
        active = (t < lengths)[None, :]
        score = np.broadcast_to(padded[:, t][None, :], shape)
        if t == 0:
            score = np.where(force, 0.0, score)
        starts = active & ~in_run & (score > high)
        ends = active & in_run & (score <= low)
        peaks = active & in_run & ~ends & peak & ~committed & (score < prev)
        at_t = starts & rising
        at_prev = (ends & ~committed) | peaks
        emit_t = at_t & (t - last >= min_len)
        emit_prev = at_prev & (t - 1 - last >= min_len)
        emit = emit_t | emit_prev  # never both: one needs a run to start, the other one to be on
        moved = np.maximum(np.where(emit_t, t, t - 1) - offset, last + 1)  # the detector's offset
        g_at, e_at = np.nonzero(emit)
        marks[g_at, e_at, moved[g_at, e_at]] = True
        last = np.where(emit, moved, last)
        committed = np.where(starts, rising, committed | peaks)
        in_run = (in_run | starts) & ~ends
        prev = np.where(active, score, prev)
    marks[:, np.arange(n_eps), lengths - 1] = True  # end_episode closes the last segment at T - 1
    return marks


def target_masks(boundaries: Sequence[np.ndarray], lengths: np.ndarray, t_max: int) -> np.ndarray:
    """Boundary masks ``[E, T_max]`` of per-episode boundary steps (each inside its episode)."""
    out = np.zeros((len(boundaries), t_max), bool)
    for i, b in enumerate(boundaries):
        b = np.asarray(b, dtype=np.int64)
        if b.size and (b.min() < 0 or b.max() >= lengths[i]):
            raise CalibrationError(f"target boundaries of episode #{i} fall outside its {lengths[i]} steps")
        out[i, b] = True
    return out


def _dilate(mask: np.ndarray, tol: int) -> np.ndarray:
    out = mask.copy()
    for d in range(1, tol + 1):
        out[..., d:] |= mask[..., :-d]
        out[..., :-d] |= mask[..., d:]
    return out


def mean_f1_masks(pred: np.ndarray, gt: np.ndarray, tol: int) -> np.ndarray:
    """Per-setting mean over episodes of the per-episode F1 (``ompn_ros.metrics.mean_f1``)."""
    n_pred, n_gt = pred.sum(-1), gt.sum(-1)
    hit_p = (pred & _dilate(gt, tol)[None]).sum(-1)
    hit_g = (gt[None] & _dilate(pred, tol)).sum(-1)
    precision = np.where(n_pred > 0, hit_p / np.maximum(n_pred, 1), 0.0)
    recall = np.where(n_gt > 0, hit_g / np.maximum(n_gt, 1), 0.0)
    total = precision + recall
    f1 = np.where(total > 0, 2 * precision * recall / np.where(total > 0, total, 1.0), 0.0)
    return f1.mean(-1)


def _delay(pred: np.ndarray, gt: np.ndarray, lengths: np.ndarray, lag: np.ndarray) -> np.ndarray:
    """Mean delay ``detected_at − g`` over the non-final targets matched within ``MATCH_TOLERANCE``."""
    n_eps, t_max = gt.shape
    inner_gt = gt.copy()
    inner_gt[np.arange(n_eps), lengths - 1] = False
    inner = pred.copy()
    inner[:, np.arange(n_eps), lengths - 1] = False
    best = np.full(pred.shape, np.inf)
    for d in range(MATCH_TOLERANCE, -MATCH_TOLERANCE - 1, -1):  # the earliest detection wins
        shifted = np.zeros_like(inner)
        if d >= 0:
            shifted[..., : t_max - d] = inner[..., d:]
        else:
            shifted[..., -d:] = inner[..., :d]
        best = np.where(shifted, float(d), best)
    best = np.where(inner_gt[None], best, np.inf)
    found = np.isfinite(best)
    count = found.sum((1, 2))
    total = np.where(found, best, 0.0).sum((1, 2)) + lag * count
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def evaluate_grid(
    scores: Sequence[np.ndarray],
    grid: Sequence[DetectorConfig],
    target_boundaries: Sequence[np.ndarray],
    target_labels: Sequence[np.ndarray] | None = None,
) -> list[dict[str, float]]:
    """Metrics of every setting's online boundaries against target boundaries, one dict per setting.

    Keys ``f1_tol0``, ``f1_tol1`` (mean over episodes), ``align`` and ``align_strict`` (steps over
    all episodes; equal here because the online boundaries always end at ``T − 1``) and
    ``delay_mean``.  ``target_labels`` (per-step subtask ordinals) default to the labels the
    target boundaries decode to.
    """
    if len(target_boundaries) != len(scores):
        raise CalibrationError(
            f"got {len(target_boundaries)} target episodes for {len(scores)} score sequences"
        )
    marks = detect_grid(scores, grid)
    _, lengths = padded_scores(scores)
    t_max = marks.shape[-1]
    gt = target_masks(target_boundaries, lengths, t_max)
    valid = np.arange(t_max)[None, :] < lengths[:, None]
    if target_labels is None:
        labels = np.cumsum(gt, -1) - gt
    else:
        labels = np.full((len(scores), t_max), -1, dtype=np.int64)
        for i, lab in enumerate(target_labels):
            if len(lab) != lengths[i]:
                raise CalibrationError(
                    f"target_labels of episode #{i}: {len(lab)} steps, scores have {lengths[i]}"
                )
            labels[i, : lengths[i]] = lab
    decoded = np.cumsum(marks, -1) - marks
    align = ((decoded == labels[None]) & valid[None]).sum((1, 2)) / lengths.sum()
    lag = np.array([LAG[c.mode] + c.offset for c in grid], dtype=np.float64)  # offset: unless clamped
    f1_0, f1_1 = mean_f1_masks(marks, gt, 0), mean_f1_masks(marks, gt, 1)
    delay = _delay(marks, gt, lengths, lag)
    return [
        {
            "f1_tol0": float(f1_0[g]),
            "f1_tol1": float(f1_1[g]),
            "align": float(align[g]),
            "align_strict": float(align[g]),
            "delay_mean": float(delay[g]),
        }
        for g in range(len(grid))
    ]


def label_boundaries(labels: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Each episode's subtask ends (the steps before a label change, and its last step)."""
    labels = [np.asarray(lab, dtype=np.int64) for lab in labels]
    bounds = [np.flatnonzero(np.diff(lab) != 0) if len(lab) else lab for lab in labels]
    return [np.append(b, len(lab) - 1) for b, lab in zip(bounds, labels, strict=True)]


@dataclass(frozen=True)
class GridRows:
    """A grid's metrics on a set of episodes, and one setting's metrics per episode (``per_episode(g)``)."""

    rows: list[dict[str, float]]
    per_episode: Callable[[int], list[dict[str, float]]]
    lengths: list[int]


def grid_rows(
    scores: Sequence[np.ndarray],
    grid: Sequence[DetectorConfig],
    target_boundaries: Sequence[np.ndarray],
    target_labels: Sequence[np.ndarray] | None = None,
) -> GridRows:
    """:func:`evaluate_grid` of the whole set, and of each episode alone on request."""

    def per_episode(g: int) -> list[dict[str, float]]:
        return [evaluate_grid([scores[i]], [grid[g]], [target_boundaries[i]],
                              None if target_labels is None else [target_labels[i]])[0]
                for i in range(len(scores))]

    rows = evaluate_grid(scores, grid, target_boundaries, target_labels)
    return GridRows(rows, per_episode, [len(s) for s in scores])


def grid_on_labels(scores: Sequence[np.ndarray], labels: Sequence[np.ndarray],
                   grid: Sequence[DetectorConfig]) -> GridRows:
    """:func:`grid_rows` against the labelled subtask boundaries (:func:`label_boundaries`)."""
    labels = [np.asarray(lab, dtype=np.int64) for lab in labels]
    return grid_rows(scores, grid, label_boundaries(labels), labels)


__all__ = [
    "LAG",
    "GridRows",
    "detect_grid",
    "evaluate_grid",
    "grid_on_labels",
    "grid_rows",
    "label_boundaries",
    "mean_f1_masks",
    "padded_scores",
    "scores_from_p_hats",
    "target_masks",
]
