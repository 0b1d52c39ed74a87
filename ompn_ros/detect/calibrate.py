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
  it sees the whole episode.  The per-episode count is exact on 47–89 % of validation episodes,
  the pooled one on all of them (four label-free runs, Craft and Dial).  Of the rules compared on
  validation labels over 15 checkpoints, the onset and the combined reference came within 2 points
  of the label-tuned detector on 11, the pooled one on 8, and only the combined one on every run
  trained without labels; ``ompn_train`` uses it (``LABEL_FREE_REFERENCE``;
  docs/design.md#label-free-calibration).

The grid is evaluated for all settings and episodes at once (:func:`evaluate_grid`, one vectorised
pass over time; ``O(G·E·T)`` numpy work for G settings, E episodes, T steps), with exactly the
semantics of :class:`~ompn_ros.detect.online.OnlineDetector` closed by ``end_episode``.

:func:`agreement` is the label-free checkpoint-selection criterion built on the same pieces.
:func:`calibrate_duration` fits the duration decoder of mode 'hsmm' (:mod:`ompn_ros.detect.duration`)
on target boundaries (labels or a reference) and chooses its threshold with the same objective.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np

from ompn_ros.detect.duration import DurationDetector, DurationModel, fit_duration_model
from ompn_ros.detect.errors import CalibrationError
from ompn_ros.detect.head_duration import decode_head_duration
from ompn_ros.detect.offline import (
    auto_threshold,
    constrained_top_k_boundaries,
    depth_scores,
    standardise,
)
from ompn_ros.detect.online import (
    DURATION_MODE,
    HEAD_DURATION_MODE,
    MODES,
    BoundaryEvent,
    DetectorConfig,
    expansion_scores,
    run_detector,
)
from ompn_ros.detect.tune import (
    MATCH_TOLERANCE,
    OBJECTIVES,
    Objective,
    default_grid,
    objective_key,
    pick_setting,
    pick_within_error,
)
from ompn_ros.metrics import alignment_accuracy, labels_from_boundaries, mean_f1

Reference = Literal[
    "auto_threshold_onset", "auto_threshold", "constrained_top_k", "pooled_top_k", "onset_and_pooled"
]
REFERENCES: tuple[Reference, ...] = get_args(Reference)
COMBINED: dict[str, tuple[Reference, ...]] = {"onset_and_pooled": ("auto_threshold_onset", "pooled_top_k")}
"""References made of others: the calibration maximises the mean of the parts' metrics."""
LAG = {"falling_edge": 1, "peak": 1, "rising_edge": 0}
"""Steps between a boundary and its emission, per mode (see :mod:`ompn_ros.detect.online`)."""


@dataclass(frozen=True)
class Calibration:
    """Result of a grid search: the chosen setting, its metrics, and how it was chosen."""

    config: DetectorConfig
    metrics: dict[str, float]
    objective: Objective
    target: str  # 'labels' or the label-free reference's name
    n_episodes: int


def scores_from_p_hats(p_hats: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Per-step online detector scores (``expansion_scores``) of ``[T, n+1]`` p_hat sequences."""
    return [expansion_scores(np.asarray(p, dtype=np.float64)) for p in p_hats]


def _padded(scores: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
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
    padded, lengths = _padded(scores)
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


def _targets(boundaries: Sequence[np.ndarray], lengths: np.ndarray, t_max: int) -> np.ndarray:
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


def _f1(pred: np.ndarray, gt: np.ndarray, tol: int) -> np.ndarray:
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
    _, lengths = _padded(scores)
    t_max = marks.shape[-1]
    gt = _targets(target_boundaries, lengths, t_max)
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
    f1_0, f1_1 = _f1(marks, gt, 0), _f1(marks, gt, 1)
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
    rows = evaluate_grid(scores, grid, target_boundaries, target_labels)

    def per_episode(g: int) -> list[dict[str, float]]:
        return [evaluate_grid([scores[i]], [grid[g]], [target_boundaries[i]],
                              None if target_labels is None else [target_labels[i]])[0]
                for i in range(len(scores))]

    best = pick_within_error(rows, objective, per_episode, [len(s) for s in scores])
    return Calibration(grid[best], rows[best], objective, target, len(scores))


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
    bounds = [np.flatnonzero(np.diff(lab) != 0) if len(lab) else lab for lab in labels]
    bounds = [np.append(b, len(lab) - 1) for b, lab in zip(bounds, labels, strict=True)]
    return search(scores, bounds, labels, objective, grid, "labels")


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


def _references(
    p_hats: Sequence[np.ndarray], reference: Reference, min_length: int, tasks: Sequence[str] | None
) -> list[np.ndarray]:
    """:func:`reference_boundaries` of every episode (pooled counts for ``'pooled_top_k'``)."""
    counts: list[int | None] = (
        list(pooled_counts(p_hats, tasks)) if reference == "pooled_top_k" else [None] * len(p_hats)
    )
    return [reference_boundaries(p, reference, min_length, k) for p, k in zip(p_hats, counts, strict=True)]


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
        evaluate_grid(online, grid, _references(p_hats, part, min_length, tasks))
        for part in COMBINED.get(reference, (reference,))
    ]
    rows = [{key: float(np.mean([part[g][key] for part in parts])) for key in first} for g, first in
            enumerate(parts[0])]
    return _best(grid, rows, objective, reference, len(online))


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
    refs = _references(p_hats, reference, min_length, None)
    scores = scores_from_p_hats(p_hats)
    grid = [DetectorConfig(high=h) for h in SELECTION_GRID_HIGHS]
    rows = evaluate_grid(scores, grid, refs)
    marks = detect_grid(scores, grid)
    _, lengths = _padded(scores)
    gt = _targets(refs, lengths, marks.shape[-1])
    ends = np.arange(len(scores)), lengths - 1
    gt[ends] = False
    marks[:, ends[0], ends[1]] = False
    inner_f1 = _f1(marks, gt, 1)
    values = [(float(inner_f1[g]) + rows[g]["align"]) / 2 for g in range(len(grid))]
    return max(values)


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
    "OBJECTIVES",
    "REFERENCES",
    "Calibration",
    "DurationCalibration",
    "Objective",
    "Reference",
    "agreement",
    "calibrate_duration",
    "calibrate_head_duration",
    "calibrate_label_free",
    "default_grid",
    "detect_grid",
    "estimated_count",
    "evaluate_grid",
    "objective_key",
    "pooled_counts",
    "reference_boundaries",
    "scores_from_p_hats",
    "search",
    "tune_on_labels",
]
